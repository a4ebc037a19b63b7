#!/usr/bin/env bash
# Two machines on one host: network namespaces "A" and "B" joined by a veth pair, multicast
# routed over it. Player + tracker run in A, mapper + renderer + recorder in B, on udpm with
# ttl=1. The same synthetic sequence is also run with every process in one namespace (one
# host, ttl=0). The tracker is deterministic in lock-step, so both recorded trajectories must
# hold the same frames with the same poses (tolerance below). Prints the traffic per channel.
# Exit codes: 0 pass, 1 fail, 77 skip (no root, no iproute2, namespaces not permitted).
#
# usage: netns_two_machines.sh BIN_DIR   (RADSLAM_NETNS_FRAMES, default 60; KEEP=1 keeps files)
set -uo pipefail
bin="${1:?usage: netns_two_machines.sh BIN_DIR}"
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
launcher="$root/scripts/radslam"
frames="${RADSLAM_NETNS_FRAMES:-60}"
# Pose agreement required between the two runs: metres and radians (the TUM files hold
# 9 significant digits, so identical runs differ by at most rounding).
pos_tol_m=1e-6
rot_tol_rad=1e-6

skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }

[ "$(id -u)" = 0 ] || skip "creating network namespaces needs root (running as uid $(id -u))"
command -v ip >/dev/null || skip "iproute2 (ip) is not installed"
for exe in radslam-synth radslam-play radslam-tracker radslam-mapper radslam-renderer \
    radslam-record radslam-status; do
  [ -x "$bin/$exe" ] || fail "$bin/$exe is not built"
done

tag=$$
ns_a="radslamA$tag" ns_b="radslamB$tag" ns_one="radslam1$tag"
veth_a="rsa$tag" veth_b="rsb$tag"  # interface names: at most 15 characters
work=$(mktemp -d /tmp/radslam-netns.XXXXXX)
bg_pids=()

cleanup() {
  local pid ns
  for pid in "${bg_pids[@]}"; do kill -TERM "$pid" 2>/dev/null; done
  for ns in "$ns_a" "$ns_b" "$ns_one"; do
    ip netns list 2>/dev/null | grep -qw "$ns" || continue
    # Only what this test started runs in its namespaces.
    for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null; done
    ip netns del "$ns" 2>/dev/null
  done
  ip link del "$veth_a" 2>/dev/null
  if [ "${KEEP:-0}" = 1 ]; then echo "files kept in $work"; else rm -rf "$work"; fi
}
trap cleanup EXIT
trap 'echo "interrupted"; exit 1' INT TERM

if ! err=$(ip netns add "$ns_a" 2>&1); then
  skip "cannot create a network namespace: $err"
fi
ip netns add "$ns_b" && ip netns add "$ns_one" || fail "cannot create the other namespaces"
ip link add "$veth_a" type veth peer name "$veth_b" 2>"$work/err" \
    || skip "cannot create a veth pair: $(cat "$work/err")"
ip link set "$veth_a" netns "$ns_a" && ip link set "$veth_b" netns "$ns_b" \
    || fail "cannot move the veth ends into the namespaces"
ip -n "$ns_a" addr add 10.231.0.1/24 dev "$veth_a"
ip -n "$ns_b" addr add 10.231.0.2/24 dev "$veth_b"
for pair in "$ns_a:$veth_a" "$ns_b:$veth_b"; do
  ns="${pair%%:*}" dev="${pair#*:}"
  ip -n "$ns" link set lo up && ip -n "$ns" link set "$dev" up \
      && ip -n "$ns" route add 224.0.0.0/4 dev "$dev" \
      || fail "cannot bring up $dev / the multicast route in $ns"
done
ip -n "$ns_a" route get 239.255.76.67 2>/dev/null | grep -q "dev $veth_a" \
    || fail "namespace $ns_a has no multicast route over $veth_a"
echo "network: $ns_a (10.231.0.1, $veth_a) <-> $ns_b (10.231.0.2, $veth_b), multicast via veth"

echo "generating a synthetic sequence ($frames frames)"
"$bin/radslam-synth" --scene room --frames "$frames" --width 320 --height 240 --no-stereo \
    --out "$work/seq" >"$work/synth.log" 2>&1 || { cat "$work/synth.log"; fail "radslam-synth failed"; }

export RADSLAM_BIN="$bin"
config="$root/tests/integration/netns_two_machines.yaml"
run_args=(--dataset "synthetic:$work/seq" --mode mono --config "$config")

echo "run 1: every process in one namespace ($ns_one, ttl=0)"
start=$SECONDS
"$launcher" run "${run_args[@]}" --netns "$ns_one" --out "$work/one" \
    --url "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608" \
    >"$work/one.out" 2>&1 || { tail -n 30 "$work/one.out"; fail "the one-host run failed"; }
echo "  done in $((SECONDS - start)) s"

url2="udpm://239.255.76.67:7667?ttl=1&recv_buf_size=8388608"
echo "run 2: player + tracker in $ns_a, mapper + renderer + recorder in $ns_b (ttl=1)"
start=$SECONDS
"$launcher" run --only mapper,renderer,recorder --netns "$ns_b" --url "$url2" --mode mono \
    --config "$config" --out "$work/two" >"$work/two_b.out" 2>&1 &
pid_b=$!; bg_pids+=("$pid_b")
"$launcher" run "${run_args[@]}" --only player,tracker --netns "$ns_a" --url "$url2" \
    --out "$work/two_a" >"$work/two_a.out" 2>&1 \
    || { tail -n 30 "$work/two_a.out"; fail "the player/tracker side failed"; }
# B ends by itself once it has seen the player and tracker finish (bounded here).
for _ in $(seq 1 600); do kill -0 "$pid_b" 2>/dev/null || break; sleep 0.5; done
if kill -0 "$pid_b" 2>/dev/null; then
  tail -n 30 "$work/two_b.out"; fail "the mapper/renderer/recorder side did not finish in 300 s"
fi
wait "$pid_b" || { tail -n 30 "$work/two_b.out"; fail "the mapper/renderer/recorder side failed"; }
echo "  done in $((SECONDS - start)) s"

for run in one two; do
  [ -s "$work/$run/trajectory.txt" ] || fail "run '$run' wrote no trajectory"
done
echo
echo "traffic per channel, two machines (recorded in $ns_b):"
sed -n '/^  channel/,$p' "$work/two/summary.txt"
echo "traffic per channel, one host:"
sed -n '/^  channel/,$p' "$work/one/summary.txt"
echo

# Trajectory comparison: same timestamps, largest position and rotation difference.
compare() {  # reference, other
  awk -v pt="$pos_tol_m" -v rt="$rot_tol_rad" '
    function abs(x) { return x < 0 ? -x : x }
    /^#/ { next }
    FNR == NR { t[++n] = $1; x[n] = $2; y[n] = $3; z[n] = $4
                qx[n] = $5; qy[n] = $6; qz[n] = $7; qw[n] = $8; next }
    { ++m
      if (m > n || $1 != t[m]) { printf "frame %d: timestamp %s vs %s\n", m, t[m], $1; bad = 1; next }
      dp = sqrt(($2-x[m])^2 + ($3-y[m])^2 + ($4-z[m])^2)
      d = abs($5*qx[m] + $6*qy[m] + $7*qz[m] + $8*qw[m]); if (d > 1) d = 1
      dr = 2 * atan2(sqrt(1 - d*d), d)
      if (dp > maxp) maxp = dp; if (dr > maxr) maxr = dr }
    END {
      if (m != n) { printf "pose count %d vs %d\n", n, m; bad = 1 }
      printf "poses %d vs %d, max position difference %.3g m (tolerance %g), max rotation difference %.3g rad (tolerance %g)\n", n, m, maxp, pt, maxr, rt
      exit (bad || maxp > pt || maxr > rt) }' "$1" "$2"
}
echo "trajectory (every tracked frame), one host vs two machines:"
compare "$work/one/trajectory.txt" "$work/two/trajectory.txt"; traj_rc=$?
echo "keyframe poses, one host vs two machines:"
compare "$work/one/keyframes.txt" "$work/two/keyframes.txt"; kf_rc=$?
if cmp -s "$work/one/trajectory.txt" "$work/two/trajectory.txt"; then
  echo "trajectory.txt of both runs: byte-identical"
else
  echo "trajectory.txt of both runs: not byte-identical"
fi
[ $traj_rc -eq 0 ] || fail "the trajectories differ beyond the tolerance"
[ $kf_rc -eq 0 ] || fail "the keyframe poses differ beyond the tolerance"
grep -q 'mapper' "$work/two/summary.txt" || fail "the recorder in $ns_b saw no mapper STATUS"
echo "PASS"
