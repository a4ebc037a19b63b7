// radslam-bench-mapper: training throughput of the mapper core on a synthetic scene.
// Prints rays/s and samples/s per core (thread CPU time, so other load on the machine does not
// count), the PSNR reached on the training views and the render time of one view.
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>

#include <opencv2/imgproc.hpp>

#include "common/cli.h"
#include "common/synthetic.h"
#include "mapper/mapper.h"

namespace radslam {
namespace {

double cpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

double psnr(const cv::Mat& bgr8, const cv::Mat& rgb) {
  cv::Mat ref;
  bgr8.convertTo(ref, CV_32FC3, 1 / 255.0);
  cv::cvtColor(ref, ref, cv::COLOR_BGR2RGB);
  cv::Mat d = ref - rgb;
  const cv::Scalar s = cv::mean(d.mul(d));
  return 10 * std::log10(3 / (s[0] + s[1] + s[2]));
}

int run(int argc, char** argv) {
  CommandLine cl(
      argc, argv,
      "radslam-bench-mapper [--scene room] [--width 320] [--height 240] "
      "[--keyframes 8] [--steps 200] [--batch 4096] [--patch 4] [--lr-density X] "
      "[--lr-color X] [--refine-poses true|false] [--surface-samples 16] [--threads 1] [--sh 0] "
      "[--levels 2] [--eval true|false]");
  if (cl.helpRequested()) {
    std::cout << cl.usage() << "\n";
    return 0;
  }
  SyntheticConfig config;
  config.scene = cl.get("scene", "room");
  config.width = cl.getInt("width", 320);
  config.height = cl.getInt("height", 240);
  const int num_keyframes = cl.getInt("keyframes", 8);
  const int steps = cl.getInt("steps", 200);
  const bool evaluate = cl.getBool("eval", true);
  MapperParams params;
  params.trainer.batch_rays = cl.getInt("batch", params.trainer.batch_rays);
  params.trainer.patch_size = cl.getInt("patch", params.trainer.patch_size);
  params.trainer.refine_poses = cl.getBool("refine-poses", params.trainer.refine_poses);
  params.trainer.surface_samples = cl.getInt("surface-samples", params.trainer.surface_samples);
  params.trainer.adam.lr_density =
      static_cast<float>(cl.getDouble("lr-density", params.trainer.adam.lr_density));
  params.trainer.adam.lr_color =
      static_cast<float>(cl.getDouble("lr-color", params.trainer.adam.lr_color));
  params.trainer.threads = cl.getInt("threads", 1);
  params.sh_degree = cl.getInt("sh", 0);
  params.levels = cl.getInt("levels", 2);
  cl.finish();
  config.frames = num_keyframes * 10;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);

  Mapper mapper(params);
  std::vector<Keyframe> keyframes;
  for (int i = 0; i < num_keyframes; ++i) {
    const Frame frame = scene.frame(i * 10);
    Keyframe kf;
    kf.header = frame.header;
    kf.keyframe_id = i;
    kf.frame_index = frame.frame_index;
    kf.T_world_cam = scene.cameraPose(i * 10);
    kf.camera = frame.camera;
    kf.color = frame.color;
    kf.depth = frame.depth;
    kf.depth_var = cv::Mat(frame.depth.size(), CV_32FC1, cv::Scalar(1e-4));  // 1 cm
    mapper.addKeyframe(kf);
    keyframes.push_back(kf);
  }
  const Field& field = mapper.field();
  std::printf("scene %s %dx%d, %d keyframes; fine voxel %.4f m, %zu blocks (%d fine)\n",
              config.scene.c_str(), config.width, config.height, num_keyframes,
              field.geometry().fineVoxelSize(), field.totalBlocks(),
              field.numBlocks(field.numLevels() - 1));
  mapper.train(5);  // warm-up: buffers sized
  int64_t rays = 0, samples = 0;
  const double cpu0 = cpuSeconds();
  const auto wall0 = std::chrono::steady_clock::now();
  TrainStats stats;
  std::vector<double> step_rate;  // rays per CPU second of each step
  for (int i = 0; i < steps; ++i) {
    const double c0 = cpuSeconds();
    stats = mapper.train(1);
    step_rate.push_back(stats.rays / std::max(1e-9, cpuSeconds() - c0));
    rays += stats.rays;
    samples += stats.samples;
  }
  std::sort(step_rate.begin(), step_rate.end());
  const double cpu = cpuSeconds() - cpu0;
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  std::printf("training: %d steps of %d rays, %.1f samples/ray in allocated space\n", steps,
              params.trainer.batch_rays, double(samples) / rays);
  std::printf("  %.0f rays/s per core (CPU time), %.2f M samples/s per core; wall %.0f rays/s\n",
              rays / cpu, samples / cpu / 1e6, rays / wall);
  // Other processes on the same core slow steps down unevenly: the upper quartile shows the
  // rate of an unshared core.
  std::printf("  per step: median %.0f rays/s, upper quartile %.0f rays/s\n",
              step_rate[step_rate.size() / 2], step_rate[step_rate.size() * 3 / 4]);
  std::printf("  last loss %.4f (rgb %.4f, depth %.4f)\n", stats.loss, stats.loss_rgb,
              stats.loss_depth);
  if (!evaluate) return 0;
  double sum = 0;
  const auto r0 = std::chrono::steady_clock::now();
  for (const Keyframe& kf : keyframes)
    sum += psnr(kf.color, mapper.render(kf.T_world_cam, kf.camera).color);
  const double render_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - r0).count() /
      keyframes.size();
  std::printf("PSNR on the training views: %.2f dB; render %.3f s per view\n",
              sum / keyframes.size(), render_s);
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-bench-mapper", radslam::run, argc, argv);
}
