// radslam-mapper: the radiance-field mapper on the bus (KEYFRAME, CONTROL in; FIELD,
// MAPPER_POSE, STATUS out; checkpoint, PLY and renders in --out at the end).
#include <filesystem>
#include <iostream>

#include "common/bus.h"
#include "common/cli.h"
#include "mapper/mapper_node.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-mapper [options]
  --url URL        LCM URL (default: LCM's default)
  --prefix P       channel prefix
  --config FILE    YAML with a "mapper" section (every key optional; unknown keys are errors)
  --mode M         mono | rgbd | stereo: the depth loss follows the tracker's variances in
                   every mode; accepted for the launcher
  --set KEY=VALUE  override mapper parameters (comma-separate several: a=1,b=2)
  --out DIR        run folder: mapper.ckpt, map_points.ply, map_mesh.ply, renders/
  --resume FILE    continue from this checkpoint (a restart after a crash); a missing file
                   is a warning and the mapper starts empty
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
  const std::string mode = cli.get("mode", "mono");
  const std::string set = cli.get("set", "");
  const std::string out = cli.get("out", "");
  const std::string resume = cli.get("resume", "");
  cli.finish();
  if (mode != "mono" && mode != "rgbd" && mode != "stereo")
    throw std::runtime_error("--mode must be mono, rgbd or stereo, got '" + mode + "'");

  std::vector<std::string> overrides;
  for (size_t start = 0; start < set.size();) {
    const size_t comma = set.find(',', start);
    const std::string item = set.substr(start, comma == std::string::npos ? comma : comma - start);
    if (!item.empty()) overrides.push_back(item);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  std::string dump, source;
  const MapperNodeParams params = loadMapperParams(config, overrides, &dump, &source);
  std::cerr << "radslam-mapper: parameters from " << source << "\n" << dump;

  installStopSignals();
  Bus bus(url, prefix, "mapper");
  MapperNode node(&bus, params, out);
  if (!resume.empty()) {
    if (std::filesystem::exists(resume)) {
      node.resume(resume);
    } else {
      std::cerr << "radslam-mapper: warning: no checkpoint " << resume << " to resume from\n";
    }
  }
  std::cerr << "radslam-mapper: " << mode << " mode, listening on "
            << bus.fullChannel(channel::kKeyframe) << "\n";
  return node.run();
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-mapper", radslam::run, argc, argv);
}
