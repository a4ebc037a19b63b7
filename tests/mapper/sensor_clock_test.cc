// The sensor clock scan finds the offsets a synthetic sequence's stamps were given.
#include "mapper/sensor_clock.h"

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "common/synthetic.h"

namespace radslam {
namespace {

// The synthetic room with ground truth at 20 Hz. Every second sample a frame: colour taken at
// the sample, stamped 50 ms late; depth taken 100 ms before the colour, stamped with it.
// The ground truth then fits the colour at stamp - 50 ms and the depth at stamp - 150 ms (the
// room's camera moves slowly: 10 ms would hardly show).
TEST(SensorClock, FindsTheOffsetsOfColourAndDepthStamps) {
  SyntheticConfig config;
  config.frames = 40;
  config.width = 320;
  config.height = 240;
  config.stereo = false;
  config.fps = 20;
  const SyntheticScene scene = SyntheticScene::make(config);
  Trajectory ground_truth;
  for (int j = 0; j < config.frames; ++j)
    ground_truth.push_back({scene.timestamp(j), scene.cameraPose(j)});

  std::vector<ClockFrame> frames;
  for (int j = 4; j < config.frames; j += 2) {
    ClockFrame f;
    f.t_colour = f.t_depth = scene.timestamp(j) + 0.05;
    const RenderedView colour = scene.render(scene.cameraPose(j), scene.camera(), j);
    cv::Mat grey;
    cv::cvtColor(colour.color, grey, cv::COLOR_BGR2GRAY);
    grey.convertTo(f.grey, CV_32F);
    f.depth = scene.render(scene.cameraPose(j - 2), scene.camera(), j - 2).depth;
    frames.push_back(f);
  }
  const std::vector<double> offsets = {-0.25, -0.2, -0.15, -0.1, -0.05, 0.0, 0.05};
  const ClockScan scan = scanSensorClocks(frames, ground_truth, scene.camera(), 4, offsets);
  ASSERT_EQ(scan.fits.size(), offsets.size());
  for (const ClockFit& fit : scan.fits)
    std::printf("offset %+.2f: depth within 2%% %.4f, capped mean rel %.5f; colour %.2f\n",
                fit.offset_s, fit.depth_agree, fit.depth_error, fit.colour_median_diff);
  EXPECT_DOUBLE_EQ(scan.fits[scan.best_depth].offset_s, -0.15);
  EXPECT_DOUBLE_EQ(scan.fits[scan.best_colour].offset_s, -0.05);
  // Noise-free images: at the right offsets the error is the interpolation's, and every other
  // offset is clearly worse.
  const ClockFit& depth_fit = scan.fits[scan.best_depth];
  const ClockFit& colour_fit = scan.fits[scan.best_colour];
  EXPECT_LT(depth_fit.depth_error, 0.0015);
  EXPECT_LT(colour_fit.colour_median_diff, 3.0);
  for (size_t k = 0; k < scan.fits.size(); ++k) {
    if (k != scan.best_depth) {
      EXPECT_GT(scan.fits[k].depth_error, 1.5 * depth_fit.depth_error);
    }
    if (k != scan.best_colour) {
      EXPECT_GT(scan.fits[k].colour_median_diff, 2 * colour_fit.colour_median_diff);
    }
  }
}

TEST(SensorClock, RejectsAScanWithNothingToCompare) {
  const std::vector<ClockFrame> frames(3);
  const CameraModel camera = SyntheticScene::make(SyntheticConfig{}).camera();
  EXPECT_THROW(scanSensorClocks(frames, {}, camera, 4, {0.0}), std::invalid_argument);
  EXPECT_THROW(scanSensorClocks(frames, {}, camera, 1, {}), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
