#!/usr/bin/env bash
# Faults during a run of the whole set (udpm on this host, lock-step playback of a synthetic
# sequence), each against an undisturbed run of the same sequence:
#   1. lost messages: every process drops 5% of the KEYFRAME and FIELD messages it publishes
#      (RADSLAM_DROP, evenly spread: the 10th, 30th, ...). The mapper must ask the tracker for
#      the lost keyframes and end with all of them; the renderer must follow the field through
#      the gaps (same final version as the mapper's) and end exact (lost snapshot chunks are
#      asked for again).
#   2. every process but the player killed in turn: the tracker gets SIGKILL once its first
#      checkpoint exists, the mapper once its own exists and the tracker has resumed, the
#      renderer once the mapper has resumed, the recorder once the renderer was restarted; the
#      launcher (--restart tracker,mapper,renderer,recorder) restarts all four. The tracker
#      resumes from its checkpoint and the player plays again from the frame after it; the
#      mapper resumes from its checkpoint, asks for the keyframes it lacks and ends with all of
#      them; the renderer re-syncs by snapshot; the recorder continues its log (--resume) and
#      its exports hold what it heard before the kill.
# The tracker is deterministic in lock-step (also across its checkpoint): its trajectory must
# equal the undisturbed one.
# Exit codes: 0 pass, 1 fail, 77 skip (no multicast route on this host).
#
# usage: faults.sh BIN_DIR   (RADSLAM_FAULT_FRAMES, default 240; KEEP=1 keeps the files)
set -uo pipefail
bin="${1:?usage: faults.sh BIN_DIR}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
launcher="$root/scripts/radslam"
frames="${RADSLAM_FAULT_FRAMES:-240}"

skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }

for exe in radslam-synth radslam-play radslam-tracker radslam-mapper radslam-renderer \
    radslam-record radslam-status; do
  [ -x "$bin/$exe" ] || fail "$bin/$exe is not built"
done
command -v ip >/dev/null && ! ip route get 239.255.76.67 >/dev/null 2>&1 \
    && skip "no route for multicast on this host (ip route add 224.0.0.0/4 dev lo)"

work=$(mktemp -d /tmp/radslam-faults.XXXXXX)
cleanup() { if [ "${KEEP:-0}" = 1 ]; then echo "files kept in $work"; else rm -rf "$work"; fi; }
trap cleanup EXIT

echo "generating a synthetic sequence ($frames frames)"
"$bin/radslam-synth" --scene room --frames "$frames" --width 320 --height 240 --no-stereo \
    --out "$work/seq" >"$work/synth.log" 2>&1 || { cat "$work/synth.log"; fail "radslam-synth failed"; }
export RADSLAM_BIN="$bin"
# An own port and prefix: other runs on this host are not disturbed, nor disturb.
url="udpm://239.255.76.67:7681?ttl=0&recv_buf_size=8388608"
args=(--dataset "synthetic:$work/seq" --mode rgbd --config "$root/tests/integration/faults.yaml"
      --url "$url" --prefix "FAULTS$$_")

run() {  # name, launcher options...
  local name="$1"; shift
  local start=$SECONDS
  "$launcher" run "${args[@]}" --out "$work/$name" "$@" >"$work/$name.out" 2>&1 \
      || { tail -n 30 "$work/$name.out"; fail "run '$name' failed"; }
  echo "  run '$name' done in $((SECONDS - start)) s"
}
# Keyframe ids in a keyframe list (TUM lines: the stamp names the keyframe).
keyframe_count() { grep -vc '^#' "$1"; }
final_version() {  # log, process -> its final field version
  sed -n "s/^radslam-$2: final field version \([0-9]*\),.*/\1/p" "$1" | tail -n 1
}

echo "run 'clean': undisturbed"
run clean
echo "run 'drops': 5% of KEYFRAME and FIELD lost"
RADSLAM_DROP="KEYFRAME=0.05,FIELD=0.05" run drops

echo "run 'kill': tracker, mapper, renderer and recorder killed, restarted by the launcher"
"$launcher" run "${args[@]}" --out "$work/kill" --rate 0.5 \
    --restart tracker,mapper,renderer,recorder --checkpoint-s 2 >"$work/kill.out" 2>&1 &
launcher_pid=$!
killed=0
for _ in $(seq 1 600); do
  kill -0 "$launcher_pid" 2>/dev/null || break
  if [ $killed -eq 0 ] && [ -s "$work/kill/tracker.ckpt" ]; then
    pkill -KILL -f "radslam-tracker .*--out $work/kill" && killed=1 && echo "  tracker killed"
  elif [ $killed -eq 1 ] && [ -s "$work/kill/mapper.ckpt" ] \
      && grep -q 'resumed from' "$work/kill/logs/tracker.log" 2>/dev/null; then
    pkill -KILL -f "radslam-mapper .*--out $work/kill" && killed=2 && echo "  mapper killed"
  elif [ $killed -eq 2 ] && grep -q 'resumed from' "$work/kill/logs/mapper.log" 2>/dev/null; then
    pkill -KILL -f "radslam-renderer .*--out $work/kill" && killed=3 && echo "  renderer killed"
  elif [ $killed -eq 3 ] && grep -q 'restarted by the launcher' "$work/kill/logs/renderer.log"; then
    pkill -KILL -f "radslam-record .*--out $work/kill" && killed=4 && echo "  recorder killed"
  fi
  sleep 0.2
done
wait "$launcher_pid" || { tail -n 30 "$work/kill.out"; fail "run 'kill' failed"; }
[ $killed -eq 4 ] || fail "run 'kill' ended before all four kills (stage $killed)"
grep 'radslam-record: resuming' "$work/kill/logs/recorder.log" \
    || fail "run 'kill': the restarted recorder did not resume its log"

echo
status=0
check() {  # condition message
  if eval "$1"; then echo "  ok: $2"; else echo "  FAILED: $2"; status=1; fi
}
kf_clean=$(keyframe_count "$work/clean/keyframes.txt")
for name in clean drops kill; do
  dir="$work/$name"
  echo "$name:"
  check "cmp -s '$work/clean/trajectory.txt' '$dir/trajectory.txt'" \
      "trajectory identical to the undisturbed run's ($(grep -vc '^#' "$dir/trajectory.txt") poses)"
  kf_mapper=$(keyframe_count "$dir/mapper_keyframes.txt")
  check "[ '$kf_mapper' = '$kf_clean' ]" \
      "the mapper ends with every keyframe ($kf_mapper of $kf_clean)"
  v_mapper=$(final_version "$dir/logs/mapper.log" mapper)
  v_renderer=$(final_version "$dir/logs/renderer.log" renderer)
  check "[ -n '$v_mapper' ] && [ '$v_mapper' = '$v_renderer' ]" \
      "the renderer's final field version is the mapper's ($v_renderer vs $v_mapper)"
  b_mapper=$(sed -n 's/^radslam-mapper: final field version [0-9]*, \([0-9]*\) blocks.*/\1/p' \
      "$dir/logs/mapper.log" | tail -n 1)
  b_renderer=$(sed -n 's/^radslam-renderer: final field version [0-9]*, \([0-9]*\) blocks.*/\1/p' \
      "$dir/logs/renderer.log" | tail -n 1)
  # Lost deltas and snapshot chunks leave a few blocks behind (those not changed since).
  enough=0
  [ -n "$b_renderer" ] && [ -n "$b_mapper" ] && [ $((100 * b_renderer)) -ge $((95 * b_mapper)) ] \
      && enough=1
  check "[ $enough = 1 ]" \
      "the renderer holds ${b_renderer:-?} of the mapper's ${b_mapper:-?} blocks (at least 95%)"
  renderer_state=$(sed -n 's/^radslam-renderer: final field version [0-9]*, [0-9]* blocks, \(.*\)/\1/p' \
      "$dir/logs/renderer.log" | tail -n 1)
  # Exact, not only at the same version: lost chunks of its snapshots were sent again.
  check "[[ '$renderer_state' == 'every update applied'* ]]" \
      "the renderer's replica is exact: ${renderer_state:-no final line}"
done
drops=$(cat "$work"/drops/logs/*.log | grep -c 'fault injection: dropped')
check "[ $drops -gt 0 ]" "messages were dropped in run 'drops' ($drops logged)"
check "grep -q 'asking the tracker again for keyframes' '$work/drops/logs/mapper.log'" \
    "the mapper asked again for lost keyframes: $(grep -o 'keyframes [0-9,]*$' "$work/drops/logs/mapper.log" | tr '\n' ' ')"
check "grep -q 'resumed from' '$work/kill/logs/tracker.log'" \
    "the restarted tracker $(grep -o 'resumed from.*' "$work/kill/logs/tracker.log" | head -n 1)"
check "grep -q 'playing again from frame' '$work/kill/logs/player.log'" \
    "the player $(grep -o 'playing again from frame [0-9]*' "$work/kill/logs/player.log" | head -n 1)"
check "grep -q 'resumed from' '$work/kill/logs/mapper.log'" \
    "the restarted mapper $(grep -o 'resumed from.*' "$work/kill/logs/mapper.log" | head -n 1)"
check "[ \$(grep -c 'restarting it' '$work/kill.out') -ge 4 ]" \
    "the launcher restarted all four: $(grep -o '[a-z]* (pid [0-9]*) exited (code [0-9]*)' "$work/kill.out" | tr '\n' ' ')"
[ $status -eq 0 ] || fail "see above"
echo "PASS"
