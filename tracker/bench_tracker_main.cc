// radslam-bench-tracker: runs the tracker core in-process (no bus) over a dataset and prints
// accuracy (ATE, orientation error, RPE), speed (frames per second of process() calls) and
// peak memory: one human line, one "RESULT" tab-separated line for scripts/bench, one JSON line.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>

#include <map>
#include <sstream>

#include "common/cli.h"
#include "common/dataset.h"
#include "common/evaluation.h"
#include "common/keyframe_files.h"
#include "common/process_stats.h"
#include "common/trajectory.h"
#include "tracker/tracker_node.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-bench-tracker --dataset KIND:PATH [options]
  --dataset KIND:PATH  tum:DIR kitti:DIR euroc:DIR replica:DIR synthetic:DIR
  --mode M             mono | rgbd | stereo (default mono)
  --start N --end N    frame range [start, end) (default all)
  --config FILE        YAML with a "tracker" section
  --set KEY=VALUE      override tracker parameters (comma-separated)
  --name NAME          sequence name in the output (default: the dataset folder's name)
  --trajectory FILE    write the final trajectory (TUM format)
  --json FILE          write the result as JSON
  --out DIR            write DIR/trajectory.txt, DIR/keyframes.txt (TUM format) and
                       DIR/keyframes/<timestamp>.exr and .png (depth, sigma and the colour image;
                       the run-folder layout)
                       and DIR/keyframes/camera.yaml (the keyframe images' pinhole intrinsics)
  --quiet              no per-frame progress
  --verbose            one line per frame: state, tracked cells, flow, parallax, keyframes
)";

double cpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

std::string jsonNumber(double v) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream s;
  s.precision(6);
  s << v;
  return s.str();
}

std::string sequenceName(const std::string& spec) {
  std::string path = spec.substr(spec.find(':') + 1);
  while (path.size() > 1 && path.back() == '/') path.pop_back();
  return std::filesystem::path(path).filename().string();
}

/// The recorder's run-folder layout, so that the mapper's benchmark reads either.
void writeRunFolder(const std::string& dir, const Trajectory& estimate,
                    const std::map<int64_t, Keyframe>& keyframes) {
  std::filesystem::create_directories(dir + "/keyframes");
  writeTumTrajectory(dir + "/trajectory.txt", estimate);
  Trajectory keyframe_poses;
  for (const auto& [id, k] : keyframes) {
    keyframe_poses.push_back({static_cast<double>(k.header.utime) * 1e-6, k.T_world_cam});
    writeKeyframeFiles(dir + "/keyframes", k);
  }
  if (!keyframes.empty()) {
    // Keyframe images are undistorted at the working resolution: their own intrinsics.
    const CameraModel& c = keyframes.begin()->second.camera;
    std::ofstream yaml(dir + "/keyframes/camera.yaml");
    yaml << "%YAML:1.0\nwidth: " << c.width << "\nheight: " << c.height << "\nfx: " << c.fx
         << "\nfy: " << c.fy << "\ncx: " << c.cx << "\ncy: " << c.cy << "\n";
    if (!yaml) throw std::runtime_error("cannot write " + dir + "/keyframes/camera.yaml");
  }
  std::sort(keyframe_poses.begin(), keyframe_poses.end(),
            [](const StampedPose& a, const StampedPose& b) { return a.t < b.t; });
  writeTumTrajectory(dir + "/keyframes.txt", keyframe_poses);
}

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string spec = cli.get("dataset", "");
  const std::string mode = cli.get("mode", "mono");
  const int start = cli.getInt("start", 0);
  const int end_arg = cli.getInt("end", -1);
  const std::string config = cli.get("config", "");
  const std::string set = cli.get("set", "");
  std::string name = cli.get("name", "");
  const std::string trajectory_path = cli.get("trajectory", "");
  const std::string json_path = cli.get("json", "");
  const std::string out_dir = cli.get("out", "");
  const bool quiet = cli.getBool("quiet", false);
  const bool verbose = cli.getBool("verbose", false);
  cli.finish();
  if (spec.empty()) throw std::runtime_error("--dataset is required\n" + cli.usage());
  if (name.empty()) name = sequenceName(spec);

  std::vector<std::string> overrides{"mode=" + mode};
  std::stringstream items(set);
  for (std::string item; std::getline(items, item, ',');) {
    if (!item.empty()) overrides.push_back(item);
  }
  const TrackerParams params = loadTrackerParams(config, overrides);
  const auto dataset = openDataset(spec);
  const int end = end_arg < 0 ? static_cast<int>(dataset->size())
                              : std::min(end_arg, static_cast<int>(dataset->size()));

  Tracker tracker(params);
  std::map<int64_t, PoseStamped> poses;       // latest per frame index, as the recorder keeps them
  std::map<int64_t, Keyframe> keyframe_msgs;  // latest version per keyframe id
  const auto keep = [&](const std::vector<Keyframe>& list) {
    if (out_dir.empty()) return;
    for (const Keyframe& k : list) keyframe_msgs[k.keyframe_id] = k;
  };
  double wall_s = 0, cpu_s = 0;
  int frames = 0, skipped = 0;
  for (int i = start; i < end; ++i) {
    std::string error;
    const std::optional<Frame> frame = dataset->frame(static_cast<size_t>(i), &error);
    if (!frame) {
      std::cerr << "radslam-bench-tracker: warning: skipped frame " << i << ": " << error << "\n";
      ++skipped;
      continue;
    }
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = cpuSeconds();
    TrackerOutput out;
    try {
      out = tracker.process(*frame);
    } catch (const std::invalid_argument& e) {
      std::cerr << "radslam-bench-tracker: warning: skipped " << e.what() << "\n";
      ++skipped;
      continue;
    }
    cpu_s += cpuSeconds() - c0;
    wall_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ++frames;
    if (out.has_pose) poses[out.pose.frame_index] = out.pose;
    keep(out.keyframes);
    if (verbose) {
      const TrackerStats& s = out.stats;
      std::fprintf(stderr,
                   "  frame %d: %s, tracked %.2f, flow %.2f px, parallax %.2f px, %d keyframes, "
                   "window %d, %d edges, BA cost %.4g, align %.2f deg, kf BA %.2f deg, %.1f ms "
                   "(flow %.1f, BA %.1f)\n",
                   i, out.has_pose ? trackingStateName(out.pose.state) : "no pose",
                   s.valid_fraction, s.mean_flow_px, s.mean_parallax_px, s.keyframes, s.window_size,
                   s.edges, s.ba_cost, s.alignment_deg, s.keyframe_ba_deg, s.frame_ms, s.flow_ms,
                   s.ba_ms);
    } else if (!quiet && (frames % 20 == 0)) {
      std::cerr << "  frame " << i << ": " << out.stats.keyframes << " keyframes, flow "
                << out.stats.flow_ms << " ms, BA " << out.stats.ba_ms << " ms, frame "
                << out.stats.frame_ms << " ms\n";
    }
  }
  const TrackerOutput final_out = tracker.finish();
  for (const PoseStamped& p : final_out.refreshed_poses) poses[p.frame_index] = p;
  keep(final_out.keyframes);

  Trajectory estimate;
  for (const auto& [index, pose] : poses) {
    if (pose.state == TrackingState::kTracking) {
      estimate.push_back({static_cast<double>(pose.header.utime) * 1e-6, pose.T_world_cam});
    }
  }
  if (!trajectory_path.empty()) writeTumTrajectory(trajectory_path, estimate);
  if (!out_dir.empty()) writeRunFolder(out_dir, estimate, keyframe_msgs);

  const std::string alignment = params.mode == "mono" ? "sim3" : "se3";
  TrajectoryErrors errors;
  bool evaluated = false;
  std::string eval_error;
  if (!dataset->groundTruth().empty()) {
    try {
      errors = evaluateTrajectory(estimate, dataset->groundTruth(), alignment);
      evaluated = true;
    } catch (const std::exception& e) {
      eval_error = e.what();
    }
  } else {
    eval_error = "no ground truth";
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double fps = wall_s > 0 ? frames / wall_s : 0;
  const double cpu_fps = cpu_s > 0 ? frames / cpu_s : 0;
  const double rss = peakRssMb();
  const int keyframes = final_out.stats.keyframes;
  const double ate = evaluated ? errors.ate_rmse_m : nan;
  const double rot = evaluated ? errors.rot_rmse_deg : nan;
  const double rpe_t = evaluated ? errors.rpe_trans_m : nan;
  const double rpe_r = evaluated ? errors.rpe_rot_deg : nan;

  std::printf("%s %s: %d frames, %zu with pose, %d keyframes (%d loop edges), ", name.c_str(),
              mode.c_str(), frames, estimate.size(), keyframes, final_out.stats.loop_edges);
  if (evaluated) {
    std::printf(
        "ATE %.4f m (%s), orientation %.3f deg (%.3f with the camera frame fitted: %.2f deg "
        "apart, which alone scores %.3f), RPE %.4f m / %.3f deg, ",
        ate, alignment.c_str(), rot, errors.rot_rmse_camera_fit_deg, errors.camera_offset_deg,
        errors.camera_offset_floor_deg, rpe_t, rpe_r);
  } else {
    std::printf("not evaluated (%s), ", eval_error.c_str());
  }
  std::printf("%.1f fps (%.1f per CPU second), peak RSS %.0f MB\n", fps, cpu_fps, rss);
  std::printf("RESULT\t%s\t%s\t%d\t%zu\t%d\t%s\t%s\t%s\t%s\t%.2f\t%.2f\t%.0f\n", name.c_str(),
              mode.c_str(), frames, estimate.size(), keyframes, jsonNumber(ate).c_str(),
              jsonNumber(rot).c_str(), jsonNumber(rpe_t).c_str(), jsonNumber(rpe_r).c_str(), fps,
              cpu_fps, rss);
  std::ostringstream json;
  json << "{\"sequence\": \"" << name << "\", \"mode\": \"" << mode << "\", \"frames\": " << frames
       << ", \"frames_with_pose\": " << estimate.size() << ", \"keyframes\": " << keyframes
       << ", \"skipped\": " << skipped << ", \"alignment\": \"" << alignment
       << "\", \"ate_rmse_m\": " << jsonNumber(ate) << ", \"rot_rmse_deg\": " << jsonNumber(rot)
       << ", \"rpe_trans_m\": " << jsonNumber(rpe_t) << ", \"rpe_rot_deg\": " << jsonNumber(rpe_r)
       << ", \"fps\": " << jsonNumber(fps) << ", \"fps_cpu\": " << jsonNumber(cpu_fps)
       << ", \"wall_s\": " << jsonNumber(wall_s) << ", \"peak_rss_mb\": " << jsonNumber(rss) << "}";
  std::printf("%s\n", json.str().c_str());
  if (!json_path.empty()) {
    std::ofstream out(json_path);
    if (!(out << json.str() << "\n")) throw std::runtime_error("cannot write " + json_path);
  }
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  radslam::keepImageAllocationsMapped();
  return radslam::runMain("radslam-bench-tracker", radslam::run, argc, argv);
}
