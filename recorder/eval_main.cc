// radslam-eval: accuracy of an estimated trajectory against ground truth (ATE,
// orientation error, RPE), printed as a table and optionally written as JSON.
#include <cstdio>
#include <iostream>
#include <stdexcept>
#include <string>

#include "common/cli.h"
#include "common/evaluation.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-eval --estimate FILE --groundtruth FILE [options]
  --estimate FILE     estimated camera-to-world trajectory
  --groundtruth FILE  ground-truth trajectory, same format
  --format F          tum (t tx ty tz qx qy qz qw) | kitti (3x4 row-major) (default tum)
  --times FILE        kitti only: time stamp (s) of row i on line i, for both files
                      (may be longer than the trajectories); default: the row index
  --alignment A       se3 | sim3 (monocular) | none (default se3)
  --max-dt S          largest time difference of a matched pair, s (default 0.02)
  --json OUT          also write the errors as JSON
Errors (missing or malformed files, no matching poses) exit with code 2.
)";

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string estimate_path = cli.get("estimate", "");
  const std::string gt_path = cli.get("groundtruth", "");
  const std::string format = cli.get("format", "tum");
  const std::string times_path = cli.get("times", "");
  const std::string alignment = cli.get("alignment", "se3");
  const double max_dt_s = cli.getDouble("max-dt", 0.02);
  const std::string json_path = cli.get("json", "");
  cli.finish();
  if (estimate_path.empty()) throw std::runtime_error("--estimate is required\n" + cli.usage());
  if (gt_path.empty()) throw std::runtime_error("--groundtruth is required\n" + cli.usage());
  if (!(max_dt_s >= 0)) throw std::runtime_error("--max-dt must be >= 0");

  const Trajectory estimate = loadTrajectory(estimate_path, format, times_path);
  const Trajectory ground_truth = loadTrajectory(gt_path, format, times_path);
  const TrajectoryErrors errors = evaluateTrajectory(estimate, ground_truth, alignment, max_dt_s);
  std::printf("radslam-eval: %s (%zu poses) vs %s (%zu poses)\n%s", estimate_path.c_str(),
              estimate.size(), gt_path.c_str(), ground_truth.size(),
              formatErrorsTable(errors).c_str());
  if (!json_path.empty()) {
    writeErrorsJson(json_path, errors);
    std::printf("  written to %s\n", json_path.c_str());
  }
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-eval", radslam::run, argc, argv);
}
