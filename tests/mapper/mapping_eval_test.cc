// Evaluation helpers of the mapping benchmark: image/depth errors, poses at frame times, the
// oracle depth variance, tracker run folders and their alignment to ground truth; and the
// filling of depth holes the mapper allocates for.
#include "mapper/mapping_eval.h"

#include <stdlib.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "common/exr_io.h"
#include "mapper/mapper.h"

namespace radslam {
namespace {

std::string tempDir() {
  std::string pattern = ::testing::TempDir() + "radslam_mapeval_XXXXXX";
  const char* dir = mkdtemp(pattern.data());
  EXPECT_NE(dir, nullptr);
  return dir ? dir : "";
}

TEST(MappingEval, PsnrAndDepthError) {
  cv::Mat ref(4, 4, CV_8UC3, cv::Scalar(0, 0, 255));    // BGR red
  cv::Mat render(4, 4, CV_32FC3, cv::Scalar(1, 0, 0));  // RGB red
  EXPECT_GT(psnr(ref, render), 100);
  render.setTo(cv::Scalar(0.9, 0, 0));
  EXPECT_NEAR(psnr(ref, render), 10 * std::log10(3 / 0.01), 1e-3);  // MSE 0.01 / 3
  EXPECT_THROW(psnr(ref, cv::Mat(3, 4, CV_32FC3)), std::invalid_argument);

  cv::Mat truth(2, 2, CV_32FC1, cv::Scalar(2)), depth(2, 2, CV_32FC1, cv::Scalar(2.5));
  truth.at<float>(0, 0) = 0;  // invalid reference
  depth.at<float>(1, 1) = 0;  // unknown render
  const DepthError e = depthError(depth, truth);
  EXPECT_EQ(e.valid, 3);
  EXPECT_EQ(e.pixels, 2);
  EXPECT_NEAR(e.l1(), 0.5, 1e-9);
  EXPECT_NEAR(e.coverage(), 2.0 / 3, 1e-9);
  // Both counted pixels have reference 2 m: bin [2, 3), error +0.5 m.
  EXPECT_EQ(e.bin_pixels[2], 2);
  EXPECT_NEAR(e.bin_signed[2], 1.0, 1e-9);
  EXPECT_NEAR(e.bin_abs[2], 1.0, 1e-9);

  // Bins by reference depth, the last one open: 0.5 m -> 0, 7 m -> 3; signed errors kept.
  cv::Mat far_truth = (cv::Mat_<float>(1, 2) << 0.5f, 7.f);
  cv::Mat far_render = (cv::Mat_<float>(1, 2) << 0.6f, 6.f);
  DepthError f = depthError(far_render, far_truth);
  f += e;
  EXPECT_EQ(f.pixels, 4);
  EXPECT_EQ(f.bin_pixels[0], 1);
  EXPECT_EQ(f.bin_pixels[3], 1);
  EXPECT_NEAR(f.bin_signed[0], 0.1, 1e-6);
  EXPECT_NEAR(f.bin_signed[3], -1.0, 1e-6);
  EXPECT_NEAR(f.bin_abs[3], 1.0, 1e-6);
  EXPECT_EQ(f.bin_pixels[2], 2);
}

TEST(MappingEval, PoseAtInterpolatesWithinGaps) {
  Trajectory t = {{1.0, SE3(SO3(), Vec3(0, 0, 0))},
                  {1.1, SE3(SO3::exp(Vec3(0, 0, 0.2)), Vec3(1, 0, 0))},
                  {5.0, SE3()}};
  const std::optional<SE3> mid = poseAt(t, 1.05, 0.2);
  ASSERT_TRUE(mid);
  EXPECT_NEAR(mid->translation().x(), 0.5, 1e-9);
  EXPECT_NEAR(mid->so3().log().z(), 0.1, 1e-9);
  EXPECT_FALSE(poseAt(t, 0.9, 0.2));
  EXPECT_FALSE(poseAt(t, 1.05, 0.05));  // the 0.1 s gap is too long
  EXPECT_FALSE(poseAt(t, 3.0, 0.2));    // across a 3.9 s gap
  EXPECT_TRUE(poseAt(t, 5.0));
}

TEST(MappingEval, SensorVarianceGrowsWithDepthAndAtEdges) {
  cv::Mat depth(5, 8, CV_32FC1, cv::Scalar(1));
  depth.colRange(4, 8).setTo(3);
  depth.at<float>(0, 0) = 0;
  const cv::Mat var = sensorDepthVariance(depth);
  EXPECT_TRUE(std::isinf(var.at<float>(0, 0)));
  const float sigma1 = std::sqrt(var.at<float>(2, 1)), sigma3 = std::sqrt(var.at<float>(2, 6));
  EXPECT_NEAR(sigma1, 0.0012 + 0.0019 * 0.36, 1e-6);
  EXPECT_GT(sigma3, sigma1);
  EXPECT_NEAR(std::sqrt(var.at<float>(2, 3)), sigma1 + 1.0, 1e-5);  // a 2 m step next to it

  // With a foreground edge band of 2 px, the near side's last 2 columns are no measurement;
  // the far side and the rest of the near side keep theirs.
  const cv::Mat banded = sensorDepthVariance(depth, 2);
  for (int y = 0; y < depth.rows; ++y)
    for (int x = 0; x < depth.cols; ++x) {
      const bool near_edge = x == 2 || x == 3;
      EXPECT_EQ(std::isinf(banded.at<float>(y, x)), near_edge || (y == 0 && x == 0)) << x;
      if (!std::isinf(banded.at<float>(y, x))) {
        EXPECT_EQ(banded.at<float>(y, x), var.at<float>(y, x));
      }
    }
}

TEST(MappingEval, ReadsATrackerRunAndAlignsItToGroundTruth) {
  const std::string dir = tempDir();
  EXPECT_THROW(readTrackerRun(dir), std::runtime_error);  // nothing there
  // Ground truth: a rotating, translating camera; the estimate is the same in a frame rotated,
  // shifted and scaled by 0.5.
  const Sim3 S_est_gt(SO3::exp(Vec3(0.1, -0.2, 0.3)), Vec3(1, 2, 3), 0.5);
  Trajectory gt, est;
  for (int i = 0; i < 10; ++i) {
    const SE3 T(SO3::exp(Vec3(0, 0.1 * i, 0)), Vec3(0.1 * i, 0.02 * i * i, 0));
    gt.push_back({100.0 + 0.1 * i, T});
    est.push_back({100.0 + 0.1 * i, S_est_gt.transformPose(T)});
  }
  writeTumTrajectory(dir + "/trajectory.txt", est);
  writeTumTrajectory(dir + "/keyframes.txt", {est[0], est[5]});
  EXPECT_THROW(readTrackerRun(dir), std::runtime_error);  // keyframe EXRs missing
  std::filesystem::create_directories(dir + "/keyframes");
  for (int i : {0, 5}) {
    char stem[64];
    std::snprintf(stem, sizeof(stem), "%.6f", est[i].t);
    writeExr(dir + "/keyframes/" + stem + ".exr",
             {{"depth", cv::Mat(3, 4, CV_32FC1, cv::Scalar(2))},
              {"sigma", cv::Mat(3, 4, CV_32FC1, cv::Scalar(0.1))}});
  }
  // The keyframe images are optional; one of the depth's size is read.
  char stem[64];
  std::snprintf(stem, sizeof(stem), "%.6f", est[5].t);
  const std::string png = dir + "/keyframes/" + stem + ".png";
  cv::imwrite(png, cv::Mat(3, 4, CV_8UC3, cv::Scalar(1, 2, 3)));
  const TrackerRun run = readTrackerRun(dir);
  ASSERT_EQ(run.keyframes.size(), 2u);
  EXPECT_EQ(run.trajectory.size(), 10u);
  EXPECT_EQ(run.keyframes[1].depth.size(), cv::Size(4, 3));
  EXPECT_FLOAT_EQ(run.keyframes[1].sigma.at<float>(1, 1), 0.1f);
  EXPECT_TRUE(run.keyframes[0].color.empty());
  ASSERT_EQ(run.keyframes[1].color.size(), cv::Size(4, 3));
  EXPECT_EQ(run.keyframes[1].color.at<cv::Vec3b>(2, 3), cv::Vec3b(1, 2, 3));
  cv::imwrite(png, cv::Mat(5, 4, CV_8UC3, cv::Scalar(1, 2, 3)));
  EXPECT_THROW(readTrackerRun(dir), std::runtime_error);  // another size
  std::filesystem::remove(png);

  for (double scale : {0.0, 2.0}) {  // Umeyama scale, given scale
    const Sim3 S = alignToGroundTruth(est, gt, scale);
    EXPECT_NEAR(S.scale(), 2.0, 1e-6);
    for (size_t i = 0; i < gt.size(); ++i) {
      const SE3 T = S.transformPose(est[i].T_world_cam);
      EXPECT_LT((T.translation() - gt[i].T_world_cam.translation()).norm(), 1e-6);
      EXPECT_LT((T.so3().inverse() * gt[i].T_world_cam.so3()).log().norm(), 1e-6);
    }
  }
  EXPECT_THROW(alignToGroundTruth(est, {}), std::invalid_argument);
}

TEST(MapperHoles, FillDepthHolesTakesTheNearbyFarDepth) {
  cv::Mat depth(32, 32, CV_32FC1, cv::Scalar(1));
  depth.colRange(16, 32).setTo(2);
  depth(cv::Rect(8, 8, 16, 8)).setTo(0);  // a hole on the step
  depth(cv::Rect(0, 24, 8, 8)).setTo(0);  // a hole in the near half
  const cv::Mat filled = fillDepthHoles(depth);
  EXPECT_EQ(cv::countNonZero(filled <= 0), 0);
  EXPECT_FLOAT_EQ(filled.at<float>(10, 10), 2.f);  // the far side of the step
  EXPECT_FLOAT_EQ(filled.at<float>(28, 3), 1.f);
  EXPECT_FLOAT_EQ(filled.at<float>(0, 0), 1.f);  // valid depths untouched
  EXPECT_EQ(cv::countNonZero(fillDepthHoles(cv::Mat::zeros(4, 4, CV_32FC1))), 0);
}

}  // namespace
}  // namespace radslam
