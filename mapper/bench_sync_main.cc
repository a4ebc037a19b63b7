// radslam-bench-sync: the time offsets between an RGB-D dataset's images and its ground truth
// (mapper/sensor_clock.h), as a table over trial offsets and the best pair, which
// radslam-bench-mapper takes as --sync-colour and --sync-depth.
#include <cmath>
#include <cstdio>
#include <iostream>

#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/cli.h"
#include "common/dataset.h"
#include "mapper/sensor_clock.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-bench-sync --dataset KIND:PATH [options]
  --gap N            frames between the two images of a pair (default 4)
  --width W          image width for the check (default 320; the height keeps the aspect ratio)
  --from S --to S --step S
                     trial offsets in s, added to the image stamps where ground truth is looked
                     up (default -0.04 to 0.02 in steps of 0.0025)
)";

int run(int argc, char** argv) {
  CommandLine cl(argc, argv, kUsage);
  if (cl.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string spec = cl.get("dataset", "");
  const int gap = cl.getInt("gap", 4);
  const int width = cl.getInt("width", 320);
  const double from = cl.getDouble("from", -0.04), to = cl.getDouble("to", 0.02);
  const double step = cl.getDouble("step", 0.0025);
  cl.finish();
  if (spec.empty()) throw std::runtime_error("--dataset KIND:PATH is required");
  if (gap < 1 || width < 16 || !(step > 0) || !(to >= from))
    throw std::runtime_error("--gap, --width and --step must be positive and --to >= --from");

  const std::unique_ptr<DatasetReader> dataset = openDataset(spec);
  if (!dataset->hasDepth()) throw std::runtime_error(dataset->name() + " has no depth images");
  if (dataset->groundTruth().empty())
    throw std::runtime_error(dataset->name() + " has no ground truth");
  std::string error;
  const std::optional<Frame> first = dataset->frame(0, &error);
  if (!first) throw std::runtime_error(error);
  const Undistorter undistorter(
      first->camera, width,
      static_cast<int>(std::lround(double(width) * first->camera.height / first->camera.width)));
  const CameraModel& camera = undistorter.target();

  std::vector<ClockFrame> frames;
  for (size_t i = 0; i < dataset->size(); ++i) {
    const std::optional<Frame> f = dataset->frame(i, &error);
    if (!f || f->depth.empty()) {
      std::cerr << "radslam-bench-sync: warning: frame " << i
                << " skipped: " << (f ? "no depth image" : error) << "\n";
      continue;
    }
    ClockFrame s;
    s.t_colour = dataset->timestamp(i);
    s.t_depth = s.t_colour + f->depth_time_offset_s;
    cv::Mat grey = undistorter.apply(f->color);
    if (grey.channels() == 3) cv::cvtColor(grey, grey, cv::COLOR_BGR2GRAY);
    grey.convertTo(s.grey, CV_32F);
    s.depth = undistorter.apply(f->depth, cv::INTER_NEAREST);
    frames.push_back(std::move(s));
  }

  std::vector<double> offsets;
  for (int k = 0; from + k * step <= to + 1e-9; ++k) offsets.push_back(from + k * step);
  const ClockScan scan = scanSensorClocks(frames, dataset->groundTruth(), camera, gap, offsets);

  std::printf("%s: %zu frames, pairs %d frames apart, %dx%d\n", dataset->name().c_str(),
              frames.size(), gap, camera.width, camera.height);
  std::printf("%10s %12s %12s %14s\n", "offset[s]", "depth<2%", "depth err", "colour |dI|");
  for (size_t k = 0; k < scan.fits.size(); ++k) {
    const ClockFit& fit = scan.fits[k];
    std::printf("%+10.4f %11.2f%% %12.4f %14.2f%s%s\n", fit.offset_s, 100 * fit.depth_agree,
                fit.depth_error, fit.colour_median_diff, k == scan.best_depth ? "  <- depth" : "",
                k == scan.best_colour ? "  <- colour" : "");
  }
  std::printf("best: --sync-colour %.4f --sync-depth %.4f\n", offsets[scan.best_colour],
              offsets[scan.best_depth]);
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  try {
    return radslam::run(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "radslam-bench-sync: " << e.what() << "\n";
    return 1;
  }
}
