// radslam-play: publishes a dataset, an LCM log or a live camera on the bus.
#include <atomic>
#include <chrono>
#include <iostream>
#include <map>
#include <regex>
#include <set>
#include <thread>
#include <utility>

#include "common/bus.h"
#include "common/camera.h"
#include "common/cli.h"
#include "common/control.h"
#include "common/dataset.h"
#include "common/lcm_log.h"
#include "common/params.h"
#include "common/process_stats.h"
#include "recorder/player.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-play --dataset KIND:PATH [options]
  KIND:PATH    tum:DIR euroc:DIR kitti:DIR replica:DIR synthetic:DIR log:FILE.lcmlog camera:N
  --url URL          LCM URL (default: LCM's default)
  --prefix P         channel prefix
  --config FILE      YAML with a "player" section (rate, lockstep, start, end, stride, ...)
  --rate R           x sensor time; 0 = as fast as possible (log: at most
                     player.log_max_mb_per_s, 20 MB/s by default)
  --lockstep         send frame k+1 only after the tracker acknowledged frame k
  --start N --end N --stride N
  --loops N          play the range N times, every other one backwards (indices and times
                     go on; long-run tests)
  --camera-config F  intrinsics of camera:N (YAML: width height fx fy cx cy, optional
                     distortion and readout_s, the rolling shutter's readout)
  --log-channels RE  log: channels to replay (default the input channels)
  --wait-for P,Q     before playing, wait (up to 30 s) for a STATUS from each process
)";

PlayerParams loadParams(const std::string& path, const std::vector<std::string>& overrides) {
  PlayerParams p;
  ParamReader reader(path, "player");
  for (const auto& o : overrides) reader.addOverride(o);
  reader.get("rate", &p.rate);
  reader.get("lockstep", &p.lockstep);
  reader.get("ack_process", &p.ack_process);
  reader.get("ack_timeout_s", &p.ack_timeout_s);
  reader.get("start", &p.start);
  reader.get("end", &p.end);
  reader.get("stride", &p.stride);
  reader.get("loops", &p.loops);
  reader.get("color_compression", &p.color_compression);
  reader.get("depth_wire_scale", &p.depth_wire_scale);
  reader.get("ground_truth", &p.ground_truth);
  reader.get("log_max_mb_per_s", &p.log_max_mb_per_s);
  reader.finish();
  if (!(p.log_max_mb_per_s >= 0))
    throw std::runtime_error(reader.source() + ": player.log_max_mb_per_s must be >= 0");
  std::cerr << "radslam-play: parameters from " << reader.source() << "\n" << reader.dump();
  return p;
}

CameraModel loadCamera(const std::string& path) {
  ParamReader reader(path, "camera");
  CameraModel camera;
  reader.get("width", &camera.width);
  reader.get("height", &camera.height);
  reader.get("fx", &camera.fx);
  reader.get("fy", &camera.fy);
  reader.get("cx", &camera.cx);
  reader.get("cy", &camera.cy);
  reader.get("distortion", &camera.distortion);
  reader.get("readout_s", &camera.readout_s);  // rolling shutter, s (0: global shutter)
  reader.finish();
  if (camera.width <= 0 || camera.fx <= 0)
    throw std::runtime_error(path + ": camera section needs width, height, fx, fy, cx, cy");
  if (!camera.distortion.empty()) camera.type = CameraModel::Type::kRadTan;
  try {
    validateCamera(camera);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(path + ": " + e.what());
  }
  return camera;
}

// Replays an LCM log in its recorded time, as lcm-logplayer does, but only the
// chosen channels, under this bus's prefix, with lock-step on CAMERA frames.
void playLog(Bus& bus, const std::string& path, const std::regex& channels,
             const PlayerParams& params, const std::function<bool(int64_t, double)>& wait_ack) {
  LogReader log(path);
  int64_t first_utime = -1;
  const auto wall_start = std::chrono::steady_clock::now();
  int64_t frames = 0;
  double bytes = 0;  // published so far
  bool lockstep = params.lockstep;
  while (auto event = log.next()) {
    if (stopRequested()) break;
    if (!std::regex_match(event->channel, channels)) continue;
    if (first_utime < 0) first_utime = event->utime;
    if (params.rate > 0) {
      const auto due = wall_start + std::chrono::microseconds(static_cast<int64_t>(
                                        (event->utime - first_utime) / params.rate));
      std::this_thread::sleep_until(due);
    } else if (params.log_max_mb_per_s > 0) {
      std::this_thread::sleep_until(wall_start + std::chrono::microseconds(static_cast<int64_t>(
                                                     bytes / params.log_max_mb_per_s)));
    }
    bytes += static_cast<double>(event->data.size());
    // Channels in the log keep the recording run's prefix: replace it by ours.
    std::string base = event->channel;
    for (const char* known :
         {channel::kCamera, channel::kGroundTruth, channel::kGroundTruthObjects, channel::kPose,
          channel::kKeyframe, channel::kObjects, channel::kField, channel::kStatus,
          channel::kRender, channel::kRenderRequest, channel::kControl}) {
      const std::string k = known;
      if (base.size() >= k.size() && base.compare(base.size() - k.size(), k.size(), k) == 0) {
        base = k;
        break;
      }
    }
    bus.publishRaw(bus.fullChannel(base), event->data.data(), event->data.size());
    if (base == channel::kCamera) {
      Frame frame;
      std::string error;
      if (lockstep && decode(event->data.data(), event->data.size(), &frame, &error) &&
          !wait_ack(frame.frame_index, params.ack_timeout_s)) {
        std::cerr << "radslam-play: warning: no acknowledgement of frame " << frame.frame_index
                  << "; continuing without lock-step\n";
        lockstep = false;
      }
      ++frames;
    }
  }
  std::cerr << "radslam-play: replayed " << frames << " frames from " << path << "\n";
}

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string source = cli.get("dataset", "");
  if (source.empty()) throw std::runtime_error("--dataset is required\n" + cli.usage());
  // Command-line options override the "player" section of the config file.
  std::vector<std::string> overrides;
  for (const char* key : {"rate", "start", "end", "stride", "loops"})
    if (cli.has(key)) overrides.push_back(std::string(key) + "=" + cli.get(key, ""));
  if (cli.has("lockstep"))
    overrides.push_back("lockstep=" +
                        std::string(cli.getBool("lockstep", true) ? "true" : "false"));
  const std::string url = cli.get("url", "");
  const std::string prefix = cli.get("prefix", "");
  const std::string camera_config = cli.get("camera-config", "");
  const std::string log_channels = cli.get("log-channels", "");
  const std::string wait_for = cli.get("wait-for", "");
  const std::string config = cli.get("config", "");
  cli.finish();
  const PlayerParams params = loadParams(config, overrides);

  installStopSignals();
  Bus bus(url, prefix, "player");
  std::atomic<int64_t> acked{-1};
  std::set<std::string> heard;
  bus.subscribe<Status>(channel::kStatus, [&](const Status& status) {
    heard.insert(status.process);
    if (status.process == params.ack_process && status.last_frame_index > acked)
      acked = status.last_frame_index;
  });
  // CONTROL REWIND from the acknowledging process (a tracker resumed from a checkpoint): play
  // again from its frame; it is repeated until served, so each token is served once.
  int64_t rewind = -1;
  std::set<std::string> rewind_tokens;
  bus.subscribe<Control>(channel::kControl, [&](const Control& control) {
    if (!control.target.empty() && control.target != "player") return;
    if (control.command == ControlCommand::kStop) requestStop();
    if (control.command != ControlCommand::kRewind || control.target.empty()) return;
    int64_t frame_index = -1;
    std::string token;
    if (!parseRewindRequest(control.argument, &frame_index, &token)) {
      std::cerr << "radslam-play: warning: CONTROL REWIND '" << control.argument
                << "' ignored (FRAME:TOKEN expected)\n";
      return;
    }
    if (!params.lockstep || !rewind_tokens.insert(token).second) return;
    rewind = frame_index;
    acked = frame_index - 1;
  });
  auto take_rewind = [&] { return std::exchange(rewind, int64_t{-1}); };
  auto wait_ack = [&](int64_t frame_index, double timeout_s) {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
    while (acked < frame_index && rewind < 0 && !stopRequested()) {
      if (std::chrono::steady_clock::now() > deadline) return false;
      bus.handle(20);
    }
    return true;
  };

  // Wait until the processes that must see frame 0 have joined the bus.
  std::set<std::string> expected;
  for (size_t begin = 0; begin < wait_for.size();) {
    const size_t comma = std::min(wait_for.find(',', begin), wait_for.size());
    if (comma > begin) expected.insert(wait_for.substr(begin, comma - begin));
    begin = comma + 1;
  }
  const auto join_deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  auto all_heard = [&] {
    for (const auto& p : expected)
      if (!heard.count(p)) return false;
    return true;
  };
  while (!all_heard() && !stopRequested() && std::chrono::steady_clock::now() < join_deadline)
    bus.handle(50);
  for (const auto& p : expected)
    if (!heard.count(p))
      std::cerr << "radslam-play: warning: no STATUS from '" << p
                << "' after 30 s; playing anyway\n";

  StatusReporter reporter("player");
  auto publish_status = [&](ProcessState state, int64_t sent, int64_t planned) {
    reporter.setState(state);
    reporter.setValue("frames_sent", static_cast<double>(sent));
    reporter.setValue("frames_total", static_cast<double>(planned));
    bus.publish(channel::kStatus, reporter.make());
  };

  const std::string kind = source.substr(0, source.find(':'));
  const std::string path =
      source.find(':') == std::string::npos ? "" : source.substr(source.find(':') + 1);
  if (kind == "log") {
    const std::regex channels(log_channels.empty() ? ".*(CAMERA|GROUND_TRUTH|GROUND_TRUTH_OBJECTS)"
                                                   : log_channels);
    publish_status(ProcessState::kRunning, 0, -1);
    playLog(bus, path, channels, params, wait_ack);
    publish_status(ProcessState::kDone, 0, -1);
    return 0;
  }

  PlayerSinks sinks;
  sinks.frame = [&](const Frame& frame) {
    {
      BusyTimer::Scope busy(reporter.busy());
      bus.publish(channel::kCamera, frame);
      reporter.itemHandled(frame.frame_index, frame.header.utime);
    }
    bus.handle(0);
  };
  sinks.ground_truth = [&](const PoseStamped& pose) { bus.publish(channel::kGroundTruth, pose); };
  sinks.ground_truth_objects = [&](const ObjectList& objects) {
    bus.publish(channel::kGroundTruthObjects, objects);
  };
  sinks.wait_for_ack = wait_ack;
  sinks.take_rewind = take_rewind;
  sinks.should_stop = [] { return stopRequested(); };
  auto last_status = std::chrono::steady_clock::now();
  sinks.progress = [&](int64_t sent, int64_t planned) {
    const auto now = std::chrono::steady_clock::now();
    if (now - last_status > std::chrono::milliseconds(500) || sent == planned) {
      publish_status(ProcessState::kRunning, sent, planned);
      last_status = now;
    }
  };
  Player player(params, sinks);
  PlayerStats stats;
  if (kind == "camera") {
    if (camera_config.empty())
      throw std::runtime_error("camera:N needs --camera-config FILE with the intrinsics");
    stats = player.playCamera(std::stoi(path), loadCamera(camera_config));
  } else {
    auto dataset = openDataset(source);
    std::cerr << "radslam-play: " << dataset->name() << ": " << dataset->size() << " frames"
              << (dataset->hasDepth() ? ", depth" : "") << (dataset->hasStereo() ? ", stereo" : "")
              << ", " << dataset->groundTruth().size() << " ground-truth poses\n";
    stats = player.play(*dataset);
  }
  publish_status(ProcessState::kDone, stats.frames_sent, stats.frames_sent);
  std::cerr << "radslam-play: sent " << stats.frames_sent << " frames in " << stats.wall_s << " s ("
            << stats.frames_skipped << " skipped, " << stats.acks_missed
            << " acknowledgements missed)\n";
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-play", radslam::run, argc, argv);
}
