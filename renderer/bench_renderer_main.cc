// radslam-bench-renderer: render latency of the field replica on one core, for 320x240 and
// 640x480 views of a field trained on the synthetic room (mapper's trainer), median of runs.
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <vector>

#include "common/bus.h"
#include "common/cli.h"
#include "common/lcm_log.h"
#include "renderer/demo_field.h"
#include "renderer/field_replica.h"
#include "renderer/final_outputs.h"

namespace radslam {
namespace {

double cpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

// Median CPU time of `runs` views, and the samples per ray that explain it.
void measure(const FieldReplica& replica, const std::vector<Keyframe>& keyframes,
             const CameraModel& camera, const MarchParams& params, const char* label, int runs) {
  std::vector<double> cpu, wall;
  for (int i = 0; i < runs; ++i) {
    const SE3& T = keyframes[i % keyframes.size()].T_world_cam;
    const auto w0 = std::chrono::steady_clock::now();
    const double c0 = cpuSeconds();
    const RenderImages images = replica.render(T, camera, &params);
    cpu.push_back(cpuSeconds() - c0);
    wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - w0).count());
  }
  // Samples marched per ray on a 1-in-16 subset of the rays.
  const VolumeRenderer renderer;
  double samples = 0, rays = 0;
  for (int v = 0; v < camera.height; v += 4) {
    for (int u = 0; u < camera.width; u += 4) {
      const Eigen::Vector3d dir((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1);
      samples +=
          renderer.march(replica.field(), makeRay(keyframes[0].T_world_cam, dir), params).samples;
      rays += 1;
    }
  }
  std::sort(cpu.begin(), cpu.end());
  std::sort(wall.begin(), wall.end());
  const double med = cpu[cpu.size() / 2];
  std::printf(
      "%dx%d %-24s step %.2f fine voxels, stop at T < %g: %5.1f samples/ray, median %7.1f ms "
      "CPU (%7.1f ms wall) over %d runs: %5.1f views/s on one core\n",
      camera.width, camera.height, label, params.step_fine, params.min_transmittance,
      samples / rays, 1e3 * med, 1e3 * wall[wall.size() / 2], runs, 1.0 / med);
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

int run(int argc, char** argv) {
  CommandLine cl(argc, argv,
                 "radslam-bench-renderer [--keyframes 8] [--train-width 320] [--steps 200] "
                 "[--runs 7] [--preview-step 1] [--preview-transmittance 0.01] "
                 "[--write-log FILE.lcmlog]");
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
  const std::string log_path = cl.get("write-log", "");
  cl.finish();
  if (!log_path.empty()) {
    writeDemoLog(log_path, options);
    return 0;
  }

  std::vector<Keyframe> keyframes;
  const auto mapper = makeDemoMapper(options, &keyframes);
  FieldReplica replica;  // one thread, the mapper's march parameters
  std::string error;
  if (replica.apply(mapper->makeSnapshot(), &error) != ApplyResult::kApplied) {
    std::cerr << "radslam-bench-renderer: snapshot not applied: " << error << "\n";
    return 1;
  }
  std::printf("field: %zu blocks, fine voxel %.4f m, trained %d steps on %d keyframes %dx%d\n",
              replica.field().totalBlocks(), replica.field().geometry().fineVoxelSize(),
              options.train_steps, options.keyframes, keyframes[0].camera.width,
              keyframes[0].camera.height);
  MarchParams preview = replica.marchParams();
  preview.step_fine = static_cast<float>(preview_step);
  preview.min_transmittance = static_cast<float>(preview_transmittance);
  for (const int width : {320, 640}) {
    const CameraModel camera = scaledCamera(keyframes[0].camera, width);
    measure(replica, keyframes, camera, replica.marchParams(), "exact (mapper's march)", runs);
    measure(replica, keyframes, camera, preview, "preview", runs);
  }
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-bench-renderer", radslam::run, argc, argv);
}
