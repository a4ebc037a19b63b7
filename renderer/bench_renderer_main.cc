// radslam-bench-renderer: render latency of the field replica on one core, for 320x240 and
// 640x480 views of a field trained on the synthetic room (mapper's trainer) or loaded from a
// mapper checkpoint, median of runs.
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <vector>

#include "common/bus.h"
#include "common/cli.h"
#include "common/lcm_log.h"
#include "mapper/preview_field.h"
#include "renderer/demo_field.h"
#include "renderer/field_replica.h"
#include "renderer/final_outputs.h"
#include "renderer/renderer_node.h"

namespace radslam {
namespace {

double cpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

// Median CPU time of `runs` views, and the samples per ray that explain it.
// A view of the replica with params: the replica's march, or the baked copy when given.
RenderImages renderWith(const FieldReplica& replica, const PreviewField* baked, const SE3& T,
                        const CameraModel& camera, const MarchParams& params) {
  if (!baked) return replica.render(T, camera, &params);
  return baked->render(replica.field(), T, camera, params, Eigen::Vector3f::Zero());
}

void measure(const FieldReplica& replica, const std::vector<Keyframe>& keyframes,
             const CameraModel& camera, const MarchParams& params, const char* label, int runs,
             const PreviewField* baked = nullptr) {
  std::vector<double> cpu, wall;
  for (int i = 0; i < runs; ++i) {
    const SE3& T = keyframes[i % keyframes.size()].T_world_cam;
    const auto w0 = std::chrono::steady_clock::now();
    const double c0 = cpuSeconds();
    const RenderImages images = renderWith(replica, baked, T, camera, params);
    cpu.push_back(cpuSeconds() - c0);
    wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count());
  }
  // Samples marched per ray on a 1-in-16 subset of the rays.
  const VolumeRenderer renderer;
  double samples = 0, rays = 0;
  for (int v = 0; v < camera.height; v += 4) {
    for (int u = 0; u < camera.width; u += 4) {
      const Eigen::Vector3d dir((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1);
      const Ray ray = makeRay(keyframes[0].T_world_cam, dir);
      samples += baked ? baked->march(replica.field(), ray, params, Eigen::Vector3f::Zero()).samples
                       : renderer.march(replica.field(), ray, params).samples;
      rays += 1;
    }
  }
  std::sort(cpu.begin(), cpu.end());
  std::sort(wall.begin(), wall.end());
  const double med = cpu[cpu.size() / 2];
  std::printf(
      "%dx%d %-20s step %.2f, T < %g, skip < %g, adaptive %g/%g: %5.1f samples/ray, median "
      "%7.1f ms CPU (%7.1f ms wall) over %d runs: %5.1f views/s on one core\n",
      camera.width, camera.height, label, params.step_fine, params.min_transmittance,
      params.skip_thickness, params.max_sample_thickness, params.max_step_fine, samples / rays,
      1e3 * med, 1e3 * wall[wall.size() / 2], runs, 1.0 / med);
}

// How far a render with `params` is from the exact march over the first `views` keyframe
// poses: colour PSNR (dB, RGB in [0, 1]), the largest depth difference where both have a depth,
// and the pixels with a depth in one only.
void compareWithExact(const FieldReplica& replica, const std::vector<Keyframe>& keyframes,
                      const CameraModel& camera, const MarchParams& exact,
                      const MarchParams& params, const char* label, int views,
                      const PreviewField* baked = nullptr) {
  double sq = 0, max_depth = 0;
  long long values = 0, validity = 0;
  for (int i = 0; i < views; ++i) {
    const SE3& T = keyframes[i % keyframes.size()].T_world_cam;
    const RenderImages a = replica.render(T, camera, &exact);
    const RenderImages b = renderWith(replica, baked, T, camera, params);
    cv::Mat diff;
    cv::subtract(a.color, b.color, diff);
    sq += diff.dot(diff);
    values += static_cast<long long>(diff.total()) * 3;
    for (int v = 0; v < camera.height; ++v)
      for (int u = 0; u < camera.width; ++u) {
        const float da = a.depth.at<float>(v, u), db = b.depth.at<float>(v, u);
        if ((da > 0) != (db > 0)) ++validity;
        if (da > 0 && db > 0) max_depth = std::max(max_depth, double(std::abs(da - db)));
      }
  }
  const double mse = sq / std::max<long long>(1, values);
  std::printf(
      "%dx%d %-22s vs exact over %d views: colour PSNR %.1f dB, max depth difference %.4f m, "
      "%lld pixels with a depth in one only\n",
      camera.width, camera.height, label, views, mse > 0 ? 10 * std::log10(1 / mse) : INFINITY,
      max_depth, validity);
}

// A small LCM log of a mapping run (FIELD updates as training goes, CAMERA, POSE, KEYFRAME,
// GROUND_TRUTH) for trying `radslam view` without a full run.
void writeDemoLog(const std::string& path, const DemoFieldOptions& options) {
  DemoFieldOptions o = options;
  o.train_steps = 0;
  std::vector<Keyframe> keyframes;
  const auto mapper = makeDemoMapper(o, &keyframes);
  LogWriter log(path);
  auto put = [&](int64_t utime, const char* channel, const auto& msg) {
    const std::vector<uint8_t> bytes = encode(msg);
    log.write(utime, channel, bytes.data(), bytes.size());
  };
  int64_t version = 0;
  for (size_t i = 0; i < keyframes.size(); ++i) {
    const Keyframe& kf = keyframes[i];
    Frame frame;
    frame.header = kf.header;
    frame.frame_index = kf.frame_index;
    frame.camera = kf.camera;
    frame.color = kf.color;
    put(kf.header.utime, channel::kCamera, frame);
    PoseStamped pose;
    pose.header = kf.header;
    pose.frame_index = kf.frame_index;
    pose.T_world_cam = kf.T_world_cam;
    put(kf.header.utime, channel::kPose, pose);
    pose.state = TrackingState::kGroundTruth;
    put(kf.header.utime, channel::kGroundTruth, pose);
    put(kf.header.utime, channel::kKeyframe, kf);
    mapper->train(std::max(1, options.train_steps / static_cast<int>(keyframes.size())));
    FieldUpdate update = mapper->makeUpdate(version);
    version = update.version;
    update.header.utime = kf.header.utime;
    put(kf.header.utime, channel::kField, update);
  }
  std::printf("wrote %lld events to %s\n", static_cast<long long>(log.eventsWritten()),
              path.c_str());
}

// The live cost of the baked preview copy: the FIELD updates of a recorded run applied in order
// to a replica, the copy brought fully up to date after each (as the first live view after an
// update would), and what that took.
int replayFieldUpdates(const std::string& log_path, float skip_thickness) {
  LogReader log(log_path);
  FieldReplica replica;
  PreviewField preview(skip_thickness);
  // And as the renderer's live views do: a budget per view, views_per_update views per update.
  const RendererParams live;
  const int views_per_update = 2;
  PreviewField budgeted(skip_thickness);
  std::vector<double> ms, stale;
  double total_s = 0;
  int updates = 0;
  while (const auto event = log.next()) {
    if (event->channel != channel::kField) continue;
    FieldUpdate update;
    std::string error;
    if (!decode(event->data.data(), event->data.size(), &update, &error) ||
        replica.apply(update, &error) == ApplyResult::kInvalid) {
      std::cerr << "radslam-bench-renderer: " << log_path << ": skipped a FIELD message: " << error
                << "\n";
      continue;
    }
    ++updates;
    const double c0 = cpuSeconds();
    preview.refresh(replica.field());
    const double dt = cpuSeconds() - c0;
    total_s += dt;
    ms.push_back(1e3 * dt);
    int left = 0;
    for (int v = 0; v < views_per_update; ++v)
      left = budgeted.refresh(replica.field(), live.preview_refresh_s);
    stale.push_back(
        100.0 * left /
        std::max<size_t>(1, replica.field().numBlocks(replica.field().numLevels() - 1)));
  }
  if (ms.empty()) {
    std::cerr << "radslam-bench-renderer: " << log_path << " has no FIELD messages\n";
    return 1;
  }
  std::vector<double> sorted = ms;
  std::sort(sorted.begin(), sorted.end());
  std::printf(
      "%d FIELD updates (%zu blocks at the end): bringing the preview copy up to date after each "
      "took median %.1f ms, 90th percentile %.1f ms, max %.1f ms CPU, %.1f s in all; copy %.1f "
      "MB\n",
      updates, replica.field().totalBlocks(), sorted[sorted.size() / 2],
      sorted[sorted.size() * 9 / 10], sorted.back(), total_s, preview.bytes() / 1e6);
  std::vector<double> stale_sorted = stale;
  std::sort(stale_sorted.begin(), stale_sorted.end());
  std::printf(
      "with %g s per view and %d views per update: stale fine blocks after the views median "
      "%.1f%%, max %.1f%%, after the last update %.1f%%\n",
      live.preview_refresh_s, views_per_update, stale_sorted[stale_sorted.size() / 2],
      stale_sorted.back(), stale.back());
  return 0;
}

int run(int argc, char** argv) {
  CommandLine cl(argc, argv,
                 "radslam-bench-renderer [--checkpoint RUN/mapper.ckpt] [--keyframes 8] "
                 "[--train-width 320] [--steps 200] [--runs 7] [--preview-step 1] "
                 "[--preview-transmittance 0.01] [--preview-skip 0.05] [--preview-thickness 0.05] "
                 "[--fast-thickness 0.05] "
                 "[--fast-max-step 4] "
                 "[--exact-runs 0] [--compare-views 3] [--preview-only] [--width 320|640] "
                 "[--write-log FILE.lcmlog] [--replay-log RUN/run.lcmlog]");
  if (cl.helpRequested()) {
    std::cout << cl.usage() << "\n";
    return 0;
  }
  DemoFieldOptions options;
  options.keyframes = cl.getInt("keyframes", 8);
  options.width = cl.getInt("train-width", 320);
  options.train_steps = cl.getInt("steps", 200);
  options.batch_rays = 2048;
  const int runs = std::max(1, cl.getInt("runs", 7));
  const double preview_step = cl.getDouble("preview-step", 1.0);
  const double preview_transmittance = cl.getDouble("preview-transmittance", 0.01);
  const double preview_skip = cl.getDouble("preview-skip", RendererParams().preview_skip_thickness);
  const double preview_thickness =
      cl.getDouble("preview-thickness", RendererParams().preview_max_sample_thickness);
  const std::string log_path = cl.get("write-log", "");
  const std::string replay_log = cl.get("replay-log", "");
  const std::string checkpoint = cl.get("checkpoint", "");
  const int exact_runs = cl.getInt("exact-runs", 0);
  const double fast_thickness = cl.getDouble("fast-thickness", 0.05);
  const double fast_max_step = cl.getDouble("fast-max-step", 4);
  const int compare_views = cl.getInt("compare-views", 3);
  const bool preview_only = cl.getBool("preview-only", false);
  const int only_width = cl.getInt("width", 0);
  cl.finish();
  if (!log_path.empty()) {
    writeDemoLog(log_path, options);
    return 0;
  }
  if (!replay_log.empty()) return replayFieldUpdates(replay_log, static_cast<float>(preview_skip));

  std::vector<Keyframe> keyframes;
  std::unique_ptr<Mapper> mapper;
  if (checkpoint.empty()) {
    mapper = makeDemoMapper(options, &keyframes);
  } else {
    // Views from the checkpoint's keyframe poses (as the mapper refined them).
    mapper = std::make_unique<Mapper>();
    mapper->loadCheckpoint(checkpoint);
    const KeyframeStore& store = mapper->keyframes();
    for (int i = 0; i < store.size(); ++i) {
      const KeyframeEntry& entry = store.entry(i);
      Keyframe kf = entry.keyframe;
      kf.T_world_cam = entry.T_world_cam;
      keyframes.push_back(kf);
    }
    if (keyframes.empty() || mapper->field().empty()) {
      std::cerr << "radslam-bench-renderer: checkpoint " << checkpoint
                << " has no keyframes or an empty field\n";
      return 1;
    }
  }
  FieldReplica replica;  // one thread, the mapper's march parameters
  std::string error;
  if (replica.apply(mapper->makeSnapshot(), &error) != ApplyResult::kApplied) {
    std::cerr << "radslam-bench-renderer: snapshot not applied: " << error << "\n";
    return 1;
  }
  std::printf("field: %zu blocks, fine voxel %.4f m, %s, %zu keyframes %dx%d\n",
              replica.field().totalBlocks(), replica.field().geometry().fineVoxelSize(),
              checkpoint.empty() ? "demo field" : checkpoint.c_str(), keyframes.size(),
              keyframes[0].camera.width, keyframes[0].camera.height);
  {
    // The density bounds of every block, built once (then kept current per changed block).
    const double c0 = cpuSeconds();
    replica.field().densityBounds(0);
    std::printf("density bounds of all blocks built in %.1f ms CPU\n", 1e3 * (cpuSeconds() - c0));
  }
  PreviewField baked(static_cast<float>(preview_skip));
  {
    const double c0 = cpuSeconds();
    baked.refresh(replica.field());
    std::printf("baked preview copy of all blocks built in %.1f ms CPU, %.1f MB\n",
                1e3 * (cpuSeconds() - c0), baked.bytes() / 1e6);
  }
  const MarchParams mapper_march = replica.marchParams();
  MarchParams exact = mapper_march;
  exact.skip_thickness = 0;
  // The mapper's march with the adaptive step, and a preview that also steps and stops sooner.
  MarchParams fast = mapper_march;
  fast.max_sample_thickness = static_cast<float>(fast_thickness);
  fast.max_step_fine = static_cast<float>(fast_max_step);
  // The renderer's live-view march (RendererParams defaults, step and stop as given).
  MarchParams preview = mapper_march;
  RendererParams renderer_params;
  renderer_params.preview_step_fine = preview_step;
  renderer_params.preview_min_transmittance = preview_transmittance;
  renderer_params.preview_skip_thickness = preview_skip;
  renderer_params.preview_max_sample_thickness = preview_thickness;
  applyPreview(renderer_params, &preview);
  for (const int width : {320, 640}) {
    if (only_width > 0 && width != only_width) continue;
    const CameraModel camera = scaledCamera(keyframes[0].camera, width);
    if (exact_runs > 0)
      measure(replica, keyframes, camera, exact, "exact (fixed step)", exact_runs);
    if (!preview_only) {
      measure(replica, keyframes, camera, mapper_march, "mapper's march", runs);
      measure(replica, keyframes, camera, fast, "adaptive step", runs);
    }
    measure(replica, keyframes, camera, preview, "preview, unbaked", runs);
    measure(replica, keyframes, camera, preview, "preview", runs, &baked);
    if (compare_views > 0) {
      if (!preview_only) {
        compareWithExact(replica, keyframes, camera, exact, mapper_march, "mapper's march",
                         compare_views);
        compareWithExact(replica, keyframes, camera, exact, fast, "adaptive step", compare_views);
      }
      compareWithExact(replica, keyframes, camera, exact, preview, "preview, unbaked",
                       compare_views);
      compareWithExact(replica, keyframes, camera, exact, preview, "preview", compare_views,
                       &baked);
    }
  }
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-bench-renderer", radslam::run, argc, argv);
}
