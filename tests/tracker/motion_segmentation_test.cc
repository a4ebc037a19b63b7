#include "tracker/motion_segmentation.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace radslam {
namespace {

// A static scene flowing 3 px right, with a 40 x 40 object that stays put in the image (it
// moves with the camera), a 10 x 10 one that does too (too small) and a region whose depth is
// unknown (sky) where the flow disagrees as well.
struct Flows {
  cv::Mat measured, predicted, depth_flow;
};

Flows makeFlows(int object_x) {
  Flows f;
  f.predicted = cv::Mat(120, 160, CV_32FC2, cv::Scalar(3, 0));
  f.measured = f.predicted.clone();
  f.measured(cv::Rect(object_x, 50, 40, 40)).setTo(cv::Scalar(0, 0));
  f.measured(cv::Rect(130, 100, 10, 10)).setTo(cv::Scalar(0, 0));
  f.measured(cv::Rect(0, 0, 160, 20)).setTo(cv::Scalar(0, 0));
  f.depth_flow = cv::Mat(120, 160, CV_32FC1, cv::Scalar(0.1));
  f.depth_flow(cv::Rect(0, 0, 160, 20)).setTo(std::numeric_limits<float>::infinity());
  return f;
}

TEST(MotionSegmenter, FindsTheObjectAndKeepsItsId) {
  MotionSegmentationParams params;
  params.min_residual_px = 1.0;
  params.relative_residual = 0.1;
  params.min_object_pixels = 400;
  MotionSegmenter segmenter(params);
  Flows f = makeFlows(40);
  const cv::Mat first = segmenter.segment(f.measured, f.predicted, f.depth_flow);
  ASSERT_EQ(first.type(), CV_16UC1);
  const uint16_t id = first.at<uint16_t>(70, 60);
  EXPECT_GE(id, params.first_id);
  // The object, carried along its (zero) flow: the same square in b.
  const cv::Mat object = first == id;
  EXPECT_NEAR(cv::countNonZero(object), 40 * 40, 40 * 4);
  EXPECT_EQ(cv::countNonZero(first(cv::Rect(0, 0, 160, 20))), 0);    // unknown depth
  EXPECT_EQ(cv::countNonZero(first(cv::Rect(125, 95, 20, 20))), 0);  // too small
  EXPECT_EQ(cv::countNonZero(first > 0), cv::countNonZero(object));  // one object
  // Next frame, the object a little further: the same id.
  f = makeFlows(46);
  const cv::Mat second = segmenter.segment(f.measured, f.predicted, f.depth_flow);
  EXPECT_EQ(second.at<uint16_t>(70, 70), id);
  // Without a depth-flow map the sky is judged too (and is large enough to count).
  MotionSegmenter blind(params);
  const cv::Mat all = blind.segment(f.measured, f.predicted);
  EXPECT_GT(cv::countNonZero(all(cv::Rect(0, 0, 160, 20))), 1000);
}

TEST(MotionSegmenter, StaticSceneHasNoObjects) {
  MotionSegmenter segmenter;
  Flows f = makeFlows(40);
  f.measured = f.predicted.clone();
  EXPECT_EQ(cv::countNonZero(segmenter.segment(f.measured, f.predicted, f.depth_flow)), 0);
}

// A textured image whose content moves 3 px right (the static scene) except a 40 x 40 object
// that stays put. Measured flows: right on the object, and a failed flow (random, as at a thin
// pole or on a long flow) on a 30 x 30 static patch. The photometric test keeps the object and
// drops the failed patch, which the flow residual alone takes for a second object.
TEST(MotionSegmenter, PhotometricTestKeepsObjectsAndDropsFailedFlow) {
  cv::Mat texture(120, 160, CV_8UC1);
  cv::randu(texture, 0, 255);
  cv::GaussianBlur(texture, texture, cv::Size(0, 0), 1.5);
  cv::Mat b(texture.size(), CV_8UC1);
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, 3, 0, 1, 0);
  cv::warpAffine(texture, b, shift, b.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  const cv::Rect object(40, 50, 40, 40), failed(110, 20, 30, 30);
  texture(object).copyTo(b(object));
  Flows f = makeFlows(object.x);
  cv::Mat noise(failed.size(), CV_32FC2);
  cv::randu(noise, -4, 4);
  f.measured(failed) += noise;
  f.measured(failed) += cv::Scalar(0, 5);

  const cv::Mat preference = photometricPreference(texture, b, f.measured, f.predicted);
  ASSERT_EQ(preference.type(), CV_32FC1);
  EXPECT_GT(cv::mean(preference(object - cv::Point(-5, -5) - cv::Size(10, 10)))[0], 8);
  EXPECT_LT(cv::mean(preference(failed))[0], 0);
  EXPECT_NEAR(cv::mean(preference(cv::Rect(10, 95, 30, 20)))[0], 0, 0.5);  // static, right flow
  EXPECT_TRUE(std::isnan(preference.at<float>(60, 159)));                  // both ends outside b

  MotionSegmentationParams params;
  params.min_residual_px = 1.0;
  params.relative_residual = 0.1;
  params.min_object_pixels = 400;
  MotionSegmenter flow_only(params), with_photo(params);
  const cv::Mat two = flow_only.segment(f.measured, f.predicted, f.depth_flow);
  EXPECT_GT(cv::countNonZero(two(failed)), 400) << "the failed flow looks like an object";
  const cv::Mat one = with_photo.segment(f.measured, f.predicted, f.depth_flow, {}, preference);
  EXPECT_EQ(cv::countNonZero(one(failed)), 0);
  EXPECT_NEAR(cv::countNonZero(one), object.area(), 0.1 * object.area());
}

// The camera drives 0.3 m forward towards a textured wall 5 m ahead; a 40 x 40 px patch of it
// (a car ahead) drives along and stays where it was in the image and in depth. Its flow is
// (almost) what the static scene predicts near the image centre, its depth is not.
struct ForwardScene {
  CameraModel camera;
  SE3 T_b_a = SE3(SO3(), Vec3(0, 0, -0.3));
  cv::Mat depth_a, depth_b, grey_a, grey_b, flow, predicted;
  cv::Rect patch{60, 40, 40, 40};
};

ForwardScene makeForwardScene() {
  ForwardScene s;
  s.camera.width = 160;
  s.camera.height = 120;
  s.camera.fx = s.camera.fy = 150;
  s.camera.cx = 80;
  s.camera.cy = 60;
  const cv::Size size(160, 120);
  s.depth_a = cv::Mat(size, CV_32FC1, cv::Scalar(5.0));
  s.depth_b = cv::Mat(size, CV_32FC1, cv::Scalar(4.7));
  s.depth_b(s.patch).setTo(5.0);
  s.grey_a = cv::Mat(size, CV_8UC1);
  cv::randu(s.grey_a, 0, 255);
  s.flow = cv::Mat(size, CV_32FC2);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const float scale = 5.0f / 4.7f;  // the static wall expands about the centre
      s.flow.at<cv::Vec2f>(y, x) = {(x - 80) * (scale - 1), (y - 60) * (scale - 1)};
    }
  s.predicted = s.flow.clone();
  s.flow(s.patch).setTo(cv::Scalar(0, 0));
  // b's image: a's texture carried along the flow (nearest), so every flow checks out.
  s.grey_b = cv::Mat(size, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const cv::Vec2f f = s.flow.at<cv::Vec2f>(y, x);
      const int xb = static_cast<int>(std::lround(x + f[0])),
                yb = static_cast<int>(std::lround(y + f[1]));
      if (xb >= 0 && yb >= 0 && xb < 160 && yb < 120)
        s.grey_b.at<uint8_t>(yb, xb) = s.grey_a.at<uint8_t>(y, x);
    }
  return s;
}

TEST(DepthDisagreement, FlagsMotionAlongTheRayThatFlowMisses) {
  const ForwardScene s = makeForwardScene();
  const cv::Mat z = depthDisagreement(s.depth_a, s.depth_b, s.grey_a, s.grey_b, s.flow, cv::Mat(),
                                      s.T_b_a, s.camera, 0.0012, 0.0019, 0.4);
  ASSERT_EQ(z.type(), CV_32FC1);
  // Inside the patch: 0.3 m against sigma_z(5 m) ~ 0.041 m in each depth, over a 5 x 5 window.
  const float inside = z.at<float>(60, 80);
  EXPECT_NEAR(inside,
              0.3 / std::hypot(0.0012 + 0.0019 * 4.6 * 4.6, 0.0012 + 0.0019 * 4.6 * 4.6) * 5, 0.5);
  EXPECT_LT(std::abs(z.at<float>(100, 20)), 1.0);  // the static wall
  // Not judged: no depth in a, a landing on another texture, an untrusted flow.
  cv::Mat depth_a = s.depth_a.clone(), grey_b = s.grey_b.clone();
  depth_a.at<float>(100, 20) = 0;
  cv::Mat untrusted(s.depth_a.size(), CV_32FC1, cv::Scalar(0.1));
  untrusted.at<float>(20, 140) = std::numeric_limits<float>::infinity();
  const cv::Vec2f f = s.flow.at<cv::Vec2f>(20, 20);
  grey_b.at<uint8_t>(static_cast<int>(std::lround(20 + f[1])),
                     static_cast<int>(std::lround(20 + f[0]))) ^= 0x80;
  const cv::Mat holes = depthDisagreement(depth_a, s.depth_b, s.grey_a, grey_b, s.flow, untrusted,
                                          s.T_b_a, s.camera, 0.0012, 0.0019, 0.4);
  EXPECT_TRUE(std::isnan(holes.at<float>(100, 20)));
  EXPECT_TRUE(std::isnan(holes.at<float>(20, 140)));
  EXPECT_TRUE(std::isnan(holes.at<float>(20, 20)));
  EXPECT_FALSE(std::isnan(holes.at<float>(21, 21)));

  // The flow test alone finds nothing; with the depth test the patch is one object.
  MotionSegmentationParams params;
  params.min_object_pixels = 400;
  MotionSegmenter flow_only(params), with_depth(params);
  const cv::Mat depth_flow(s.flow.size(), CV_32FC1, cv::Scalar(0.1));
  EXPECT_EQ(cv::countNonZero(flow_only.segment(s.flow, s.predicted, depth_flow)), 0);
  const cv::Mat instance = with_depth.segment(s.flow, s.predicted, depth_flow, z);
  const cv::Mat object = instance == instance.at<uint16_t>(60, 80);
  EXPECT_GT(instance.at<uint16_t>(60, 80), 0);
  // The 5 x 5 window widens it by up to 2 px each side.
  EXPECT_GE(cv::countNonZero(object), 40 * 40 - 40 * 4);
  EXPECT_LE(cv::countNonZero(object), 44 * 44);
  EXPECT_EQ(cv::countNonZero(instance > 0), cv::countNonZero(object));
}

TEST(MotionSegmenter, RejectsBadParameters) {
  MotionSegmentationParams params;
  params.min_residual_px = 0;
  EXPECT_THROW(MotionSegmenter{params}, std::invalid_argument);
}

}  // namespace
}  // namespace radslam
