#include "tracker/mono_init.h"

#include "tracker/dense_ba.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace radslam {
namespace {

CameraModel gridCamera() {
  CameraModel c;
  c.width = 48;
  c.height = 36;
  c.fx = c.fy = 40;
  c.cx = 23.5;
  c.cy = 17.5;
  return c;
}

struct TwoViews {
  cv::Mat target, weight, inv_depth;  // grid of a; inverse depth in metres^-1
};

// Grid pixels of a at random depths (2-30 m: ground to far buildings) seen from b = T_b_a;
// a fraction of the targets replaced by random locations (flow failures).
TwoViews makeViews(const SE3& T_b_a, double outliers, double noise_px, std::mt19937* rng) {
  const CameraModel cam = gridCamera();
  std::uniform_real_distribution<double> depth(2, 30), any_u(0, cam.width - 1),
      any_v(0, cam.height - 1), unit(0, 1);
  std::normal_distribution<double> noise(0, noise_px);
  TwoViews views;
  views.target = cv::Mat(cam.height, cam.width, CV_32FC2);
  views.weight = cv::Mat(cam.height, cam.width, kFlowWeightType, cv::Scalar(1, 0, 1));
  views.inv_depth = cv::Mat(cam.height, cam.width, CV_32FC1);
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      const double z = depth(*rng);
      const Vec3 p = T_b_a * (z * Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1));
      cv::Vec2f t(static_cast<float>(cam.fx * p.x() / p.z() + cam.cx + noise(*rng)),
                  static_cast<float>(cam.fy * p.y() / p.z() + cam.cy + noise(*rng)));
      if (unit(*rng) < outliers) t = cv::Vec2f(float(any_u(*rng)), float(any_v(*rng)));
      views.target.at<cv::Vec2f>(v, u) = t;
      views.inv_depth.at<float>(v, u) = static_cast<float>(1 / z);
    }
  }
  return views;
}

double angleDeg(const Vec3& a, const Vec3& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)) * 180 / M_PI;
}

TEST(TwoViewInit, ForwardMotionWhileTurningIsRecovered) {
  std::mt19937 rng(3);
  // KITTI-like: 1 m forward, 0.1 m sideways, 3 deg of yaw between the keyframes.
  const SE3 T_b_a(SO3::exp(Vec3(0, 3 * M_PI / 180, 0)), Vec3(0.1, 0, -1.0));
  const TwoViews views = makeViews(T_b_a, 0.2, 0.05, &rng);
  TwoViewOptions options;
  options.median_inv_depth = 1.0;
  const TwoViewResult r = initializeTwoView(gridCamera(), views.target, views.weight, options);
  ASSERT_TRUE(r.ok) << r.why;
  EXPECT_LT((r.T_b_a.so3().inverse() * T_b_a.so3()).log().norm() * 180 / M_PI, 0.1);
  EXPECT_LT(angleDeg(r.T_b_a.translation(), T_b_a.translation()), 1.0);
  EXPECT_GT(r.inliers, 0.7 * r.correspondences);  // 80 % inliers
  EXPECT_LT(r.inliers, 0.85 * r.correspondences);
  // Inverse depths in the scene unit: the truth times one scale, median 1.
  const double scale = T_b_a.translation().norm() / r.T_b_a.translation().norm();
  std::vector<double> ratios, values;
  for (int v = 0; v < views.inv_depth.rows; ++v) {
    for (int u = 0; u < views.inv_depth.cols; ++u) {
      const float d = r.inv_depth_a.at<float>(v, u);
      if (!std::isfinite(d)) continue;
      values.push_back(d);
      ratios.push_back(d / (scale * views.inv_depth.at<float>(v, u)));
    }
  }
  std::sort(ratios.begin(), ratios.end());
  std::sort(values.begin(), values.end());
  EXPECT_NEAR(values[values.size() / 2], 1.0, 1e-6);
  EXPECT_NEAR(ratios[ratios.size() / 2], 1.0, 0.01);
  // (Far points move little: their inverse depths are the noisy ones.)
  EXPECT_NEAR(ratios[ratios.size() / 4], 1.0, 0.05);
  EXPECT_NEAR(ratios[ratios.size() * 3 / 4], 1.0, 0.05);
}

TEST(TwoViewInit, RotationAloneIsReportedAsNotObservable) {
  std::mt19937 rng(4);
  const SE3 T_b_a(SO3::exp(Vec3(0.05, 0.1, 0.02)), Vec3(0.002, 0, 0));
  const TwoViews views = makeViews(T_b_a, 0.05, 0.05, &rng);
  const TwoViewResult r = initializeTwoView(gridCamera(), views.target, views.weight);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.why.find("rotation"), std::string::npos) << r.why;
  EXPECT_FALSE(r.small_parallax);  // more baseline will not come from a rotation
}

TEST(TwoViewInit, TranslationBelowTheParallaxBoundIsReportedAsTooShort) {
  std::mt19937 rng(3);
  const SE3 T_b_a(SO3::exp(Vec3(0, 3 * M_PI / 180, 0)), Vec3(0.1, 0, -1.0));
  const TwoViews views = makeViews(T_b_a, 0.2, 0.05, &rng);
  TwoViewOptions options;
  const TwoViewResult enough = initializeTwoView(gridCamera(), views.target, views.weight, options);
  ASSERT_TRUE(enough.ok) << enough.why;
  EXPECT_FALSE(enough.small_parallax);
  options.min_parallax_deg = 2 * enough.median_parallax_deg;
  const TwoViewResult r = initializeTwoView(gridCamera(), views.target, views.weight, options);
  EXPECT_FALSE(r.ok);
  EXPECT_TRUE(r.small_parallax) << r.why;
  // The estimate is there all the same.
  EXPECT_LT((r.T_b_a.so3().inverse() * enough.T_b_a.so3()).log().norm(), 1e-9);
  EXPECT_LT((r.T_b_a.translation() - enough.T_b_a.translation()).norm(), 1e-9);
}

TEST(TwoViewInit, TooFewCorrespondences) {
  std::mt19937 rng(5);
  TwoViews views = makeViews(SE3(SO3(), Vec3(0, 0, -1)), 0, 0, &rng);
  views.weight.setTo(cv::Scalar(0, 0, 0));
  views.weight(cv::Rect(0, 0, 3, 3)).setTo(cv::Scalar(1, 0, 1));
  const TwoViewResult r = initializeTwoView(gridCamera(), views.target, views.weight);
  EXPECT_FALSE(r.ok);
  EXPECT_EQ(r.correspondences, 9);
}

}  // namespace
}  // namespace radslam
