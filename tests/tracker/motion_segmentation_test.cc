#include "tracker/motion_segmentation.h"

#include <limits>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

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

TEST(MotionSegmenter, RejectsBadParameters) {
  MotionSegmentationParams params;
  params.min_residual_px = 0;
  EXPECT_THROW(MotionSegmenter{params}, std::invalid_argument);
}

}  // namespace
}  // namespace radslam
