// radslam-tracker: dense SLAM front end on the bus (CAMERA in; POSE, KEYFRAME, STATUS out).
#include <filesystem>
#include <iostream>

#include "common/bus.h"
#include "common/cli.h"
#include "tracker/tracker_node.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-tracker [options]
  --url URL        LCM URL (default: LCM's default)
  --prefix P       channel prefix
  --config FILE    YAML with a "tracker" section (every key optional; unknown keys are errors)
  --mode M         mono | rgbd | stereo (overrides the config's tracker.mode)
  --set KEY=VALUE  override one tracker parameter (comma-separate several: a=1,b=2)
  --queue N        frames kept waiting when they arrive faster than tracked (default 4)
  --out DIR        run folder (accepted for the launcher; the tracker writes nothing there)
  --checkpoint FILE  write a checkpoint there every --checkpoint-s seconds (default 20) and
                   after re-publishing keyframes (off without this option)
  --checkpoint-s S
  --resume FILE    continue from this checkpoint (a restart after a crash) and ask the player
                   to play again from the frame after it; a missing file is a warning
)";

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string url = cli.get("url", "");
  const std::string prefix = cli.get("prefix", "");
  const std::string config = cli.get("config", "");
  const std::string mode = cli.get("mode", "");
  const std::string set = cli.get("set", "");
  TrackerNodeOptions options;
  options.max_queue = cli.getInt("queue", options.max_queue);
  cli.get("out", "");
  options.checkpoint_path = cli.get("checkpoint", "");
  options.checkpoint_period_s = cli.getDouble("checkpoint-s", 20.0);
  const std::string resume = cli.get("resume", "");
  cli.finish();

  std::vector<std::string> overrides;
  if (!mode.empty()) overrides.push_back("mode=" + mode);
  size_t start = 0;
  while (start < set.size()) {
    const size_t comma = set.find(',', start);
    const std::string item =
        set.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    if (!item.empty()) overrides.push_back(item);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  std::string dump, source;
  const TrackerParams params = loadTrackerParams(config, overrides, &dump, &source);
  std::cerr << "radslam-tracker: parameters from " << source << "\n" << dump;

  installStopSignals();
  Bus bus(url, prefix, "tracker");
  TrackerNode node(&bus, params, options);
  if (!resume.empty()) {
    if (std::filesystem::exists(resume)) {
      node.resume(resume);
    } else {
      std::cerr << "radslam-tracker: warning: no checkpoint " << resume << " to resume from\n";
    }
  }
  std::cerr << "radslam-tracker: " << params.mode << " mode, listening on "
            << bus.fullChannel(channel::kCamera) << "\n";
  return node.run();
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  radslam::keepImageAllocationsMapped();
  return radslam::runMain("radslam-tracker", radslam::run, argc, argv);
}
