// Per-keyframe exposure (affine colour per channel): the analytic gradient against central
// differences, interpolation between keyframes, and training recovering a keyframe whose image
// is darker than the others while the gauge keyframe keeps the field's colours.
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "common/synthetic.h"
#include "mapper/mapper.h"

namespace radslam {
namespace {

// Squared error of the exposed colour against a target, as the trainer's colour loss.
double colorLoss(const Vec6& x, const double c[3], const double target[3]) {
  double loss = 0;
  for (int j = 0; j < 3; ++j) {
    const double e = std::exp(x[j]) * c[j] + x[3 + j] - target[j];
    loss += e * e;
  }
  return loss;
}

TEST(Exposure, GradientMatchesFiniteDifferences) {
  Vec6 x;
  x << 0.12, -0.2, 0.05, 0.03, -0.07, 0.1;
  const double c[3] = {0.3, 0.75, 0.5}, target[3] = {0.4, 0.5, 0.9};
  float gain[3], offset[3], cf[3], out[3];
  for (int j = 0; j < 3; ++j) {
    gain[j] = static_cast<float>(std::exp(x[j]));
    offset[j] = static_cast<float>(x[3 + j]);
    cf[j] = static_cast<float>(c[j]);
  }
  applyExposure(gain, offset, cf, out);
  float g_out[3], g_c[3];
  for (int j = 0; j < 3; ++j) g_out[j] = 2 * (out[j] - static_cast<float>(target[j]));
  Vec6 g_x = Vec6::Zero();
  exposureBackward(gain, cf, g_out, g_c, &g_x);
  const double h = 1e-6;
  for (int i = 0; i < 6; ++i) {
    Vec6 xp = x, xm = x;
    xp[i] += h;
    xm[i] -= h;
    const double fd = (colorLoss(xp, c, target) - colorLoss(xm, c, target)) / (2 * h);
    EXPECT_NEAR(g_x[i], fd, 1e-4 * std::max(1.0, std::abs(fd))) << "exposure parameter " << i;
  }
  for (int j = 0; j < 3; ++j) {
    double cp[3] = {c[0], c[1], c[2]}, cm[3] = {c[0], c[1], c[2]};
    cp[j] += h;
    cm[j] -= h;
    const double fd = (colorLoss(x, cp, target) - colorLoss(x, cm, target)) / (2 * h);
    EXPECT_NEAR(g_c[j], fd, 1e-4 * std::max(1.0, std::abs(fd))) << "colour channel " << j;
  }
  // No exposure gradient asked for: the colour gradient alone.
  float g_c2[3];
  exposureBackward(gain, cf, g_out, g_c2, nullptr);
  for (int j = 0; j < 3; ++j) EXPECT_EQ(g_c2[j], g_c[j]);
}

TEST(Exposure, AppliesToRendersAndInterpolates) {
  cv::Mat rgb(2, 2, CV_32FC3, cv::Scalar(0.5, 0.25, 1.0));
  Vec6 x;
  x << std::log(2.0), 0, std::log(0.5), 0.1, 0, -0.1;
  applyExposure(x, &rgb);
  const cv::Vec3f v = rgb.at<cv::Vec3f>(1, 1);
  EXPECT_NEAR(v[0], 1.1, 1e-6);
  EXPECT_NEAR(v[1], 0.25, 1e-6);
  EXPECT_NEAR(v[2], 0.4, 1e-6);
  Vec6 a = Vec6::Zero(), b = Vec6::Constant(1.0);
  EXPECT_NEAR(interpolateExposure(1.25, 1.0, a, 2.0, b)[3], 0.25, 1e-12);
  EXPECT_EQ(interpolateExposure(0.5, 1.0, a, 2.0, b), a);  // before: the first
  EXPECT_EQ(interpolateExposure(3.0, 1.0, a, 2.0, b), b);  // after: the last
  EXPECT_EQ(interpolateExposure(1.0, 1.0, a, 1.0, b), a);  // one keyframe
}

Keyframe keyframeOf(const SyntheticScene& scene, int frame, int id) {
  const Frame f = scene.frame(frame);
  Keyframe kf;
  kf.header = f.header;
  kf.keyframe_id = id;
  kf.frame_index = frame;
  kf.T_world_cam = scene.cameraPose(frame);
  kf.camera = f.camera;
  kf.color = f.color;
  kf.depth = f.depth;
  kf.depth_var = cv::Mat(f.depth.size(), CV_32FC1, cv::Scalar(1e-4));  // 1 cm
  return kf;
}

// A keyframe whose camera saw everything at 0.7 times the brightness (plus 0.02): training
// (its initial fit against the field's render, then training) finds its gain and offset, and
// the field keeps the colours of the gauge keyframe. Measured: gains 0.70, offsets 0.02.
TEST(Exposure, TrainingRecoversADarkerKeyframe) {
  SyntheticConfig config;
  config.scene = "room";
  config.frames = 40;
  config.width = 160;
  config.height = 120;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);
  MapperParams params;
  params.trainer.refine_poses = false;
  Mapper mapper(params);
  for (int i = 0; i < 4; ++i) {
    Keyframe kf = keyframeOf(scene, i * 10, i);
    if (i == 2) kf.color.convertTo(kf.color, CV_8UC3, 0.7, 0.02 * 255);
    mapper.addKeyframe(kf);
  }
  mapper.train(150);
  const KeyframeEntry& dark = mapper.keyframes().entry(mapper.keyframes().find(2));
  const KeyframeEntry& gauge = mapper.keyframes().entry(mapper.keyframes().gaugeIndex());
  std::printf("dark keyframe: gains %.3f %.3f %.3f, offsets %.3f %.3f %.3f\n",
              std::exp(dark.exposure[0]), std::exp(dark.exposure[1]), std::exp(dark.exposure[2]),
              dark.exposure[3], dark.exposure[4], dark.exposure[5]);
  EXPECT_EQ(gauge.exposure, Vec6::Zero());
  for (int j = 0; j < 3; ++j) {
    EXPECT_NEAR(std::exp(dark.exposure[j]), 0.7, 0.06) << "channel " << j;
    EXPECT_NEAR(dark.exposure[3 + j], 0.02, 0.04) << "channel " << j;
  }
  // The others stay near the identity.
  const KeyframeEntry& other = mapper.keyframes().entry(mapper.keyframes().find(1));
  for (int j = 0; j < 6; ++j) EXPECT_NEAR(other.exposure[j], 0.0, 0.04) << "parameter " << j;
}

}  // namespace
}  // namespace radslam
