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

// A smooth texture: a pose error of a pixel changes it by less than the grey check's 12 levels.
uint8_t smoothGrey(double x, double y) {
  return cv::saturate_cast<uint8_t>(128 + 60 * std::sin(0.3 * x) * std::cos(0.25 * y));
}

// Thresholds for makeFlows' scene: a 3 px residual is strong evidence, the 40 x 40 object large
// enough.
MotionSegmentationParams squareParams() {
  MotionSegmentationParams params;
  params.min_residual_px = 1.0;
  params.relative_residual = 0.1;
  params.min_object_pixels = 400;
  return params;
}

TEST(MotionSegmenter, FindsTheObjectAndKeepsItsId) {
  const MotionSegmentationParams params = squareParams();
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

  const MotionSegmentationParams params = squareParams();
  MotionSegmenter flow_only(params), with_photo(params);
  const cv::Mat two = flow_only.segment(f.measured, f.predicted, f.depth_flow);
  EXPECT_GT(cv::countNonZero(two(failed)), 400) << "the failed flow looks like an object";
  const cv::Mat one = with_photo.segment(f.measured, f.predicted, f.depth_flow, {}, preference);
  EXPECT_EQ(cv::countNonZero(one(failed)), 0);
  EXPECT_NEAR(cv::countNonZero(one), object.area(), 0.1 * object.area());
}

// The same scene on a smooth bright background, with a dark static pole whose flow failed
// (random within 12 px, as for a pole passing close to the camera): judged moving, its pixels
// are carried along that flow over the background, and closing fills the scatter into a blob
// several times the pole's size. The carry test leaves out regions where too many flows land off
// their pixel's grey value: the pole, not the object.
TEST(MotionSegmenter, CarryTestDropsPixelsAFailedFlowScatters) {
  const cv::Size size(160, 120);
  cv::Mat a(size, CV_8UC1), b(size, CV_8UC1);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      a.at<uint8_t>(y, x) = static_cast<uint8_t>(smoothGrey(x, y) / 4 + 150);
      b.at<uint8_t>(y, x) = static_cast<uint8_t>(smoothGrey(x - 3, y) / 4 + 150);
    }
  const cv::Rect object(40, 50, 40, 40), pole(120, 25, 6, 70);
  a(object).copyTo(b(object));
  a(pole).setTo(20);
  b(pole + cv::Point(3, 0)).setTo(20);
  Flows f = makeFlows(object.x);
  cv::Mat scatter(pole.size(), CV_32FC2);
  cv::randu(scatter, -12, 12);
  f.measured(pole) += scatter;

  const cv::Mat error = landingGreyError(a, b, f.measured);
  ASSERT_EQ(error.type(), CV_32FC1);
  EXPECT_EQ(cv::countNonZero(error(object) != 0), 0);                    // carried onto itself
  EXPECT_EQ(cv::countNonZero(error(cv::Rect(10, 95, 30, 20)) != 0), 0);  // static, right flow
  EXPECT_GT(cv::countNonZero(error(pole) > 50), pole.area() / 2);        // lands off the pole
  EXPECT_TRUE(std::isnan(error.at<float>(60, 158)));                     // lands outside b

  const MotionSegmentationParams params = squareParams();
  MotionSegmenter without(params), with(params);
  const cv::Mat blob = without.segment(f.measured, f.predicted, f.depth_flow);
  const cv::Mat kept = with.segment(f.measured, f.predicted, f.depth_flow, {}, {}, error);
  const cv::Rect right_half(100, 0, 60, 120);
  EXPECT_GT(cv::countNonZero(blob(right_half)), 3 * pole.area()) << "the closed scatter";
  EXPECT_LT(cv::countNonZero(kept(right_half)), 1.5 * pole.area());
  EXPECT_EQ(cv::countNonZero(kept(object)), object.area());
  EXPECT_EQ(cv::countNonZero(blob(object)), object.area());

  // A tenth of the object's flows miss as well (a textureless truck side): the region is kept.
  cv::Mat misses(object.size(), CV_8UC1);
  cv::randu(misses, 0, 10);
  cv::Mat object_scatter(object.size(), CV_32FC2);
  cv::randu(object_scatter, -12, 12);
  object_scatter.setTo(cv::Scalar(0, 0), misses > 0);
  f.measured(object) += object_scatter;
  const cv::Mat some_missed = landingGreyError(a, b, f.measured);
  EXPECT_GT(cv::countNonZero(some_missed(object) > 8), 0);
  MotionSegmenter again(params);
  const cv::Mat whole = again.segment(f.measured, f.predicted, f.depth_flow, {}, {}, some_missed);
  EXPECT_GT(cv::countNonZero(whole(object)), 0.95 * object.area());
}

// 160 x 120 px, 150 px focal length, principal point in the middle.
CameraModel smallCamera() {
  CameraModel camera;
  camera.width = 160;
  camera.height = 120;
  camera.fx = camera.fy = 150;
  camera.cx = 80;
  camera.cy = 60;
  return camera;
}

// The camera drives 0.3 m forward towards a textured wall 5 m ahead; a 40 x 40 px patch of it
// (a car ahead) drives along and stays where it was in the image and in depth. Its flow is
// (almost) what the static scene predicts near the image centre, its depth is not.
struct ForwardScene {
  CameraModel camera = smallCamera();
  SE3 T_b_a = SE3(SO3(), Vec3(0, 0, -0.3));
  cv::Mat depth_a, depth_b, grey_a, grey_b, flow, predicted;
  cv::Rect patch{60, 40, 40, 40};
};

ForwardScene makeForwardScene() {
  ForwardScene s;
  const cv::Size size(160, 120);
  s.depth_a = cv::Mat(size, CV_32FC1, cv::Scalar(5.0));
  s.depth_b = cv::Mat(size, CV_32FC1, cv::Scalar(4.7));
  s.depth_b(s.patch).setTo(5.0);
  const float scale = 5.0f / 4.7f;  // the static wall expands about the centre
  s.flow = cv::Mat(size, CV_32FC2);
  s.grey_a = cv::Mat(size, CV_8UC1);
  s.grey_b = cv::Mat(size, CV_8UC1);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      s.flow.at<cv::Vec2f>(y, x) = {(x - 80) * (scale - 1), (y - 60) * (scale - 1)};
      s.grey_a.at<uint8_t>(y, x) = smoothGrey(x, y);
      // b: the wall's texture expanded, the patch's where it was.
      const bool in_patch = s.patch.contains(cv::Point(x, y));
      s.grey_b.at<uint8_t>(y, x) =
          in_patch ? smoothGrey(x, y) : smoothGrey(80 + (x - 80) / scale, 60 + (y - 60) / scale);
    }
  s.predicted = s.flow.clone();
  s.flow(s.patch).setTo(cv::Scalar(0, 0));
  return s;
}

TEST(DepthDisagreement, FlagsMotionAlongTheRayThatFlowMisses) {
  const ForwardScene s = makeForwardScene();
  const cv::Mat z = depthDisagreement(s.depth_a, s.depth_b, s.grey_a, s.grey_b, cv::Mat(), s.T_b_a,
                                      s.camera, 0.0012, 0.0019, 0.4);
  ASSERT_EQ(z.type(), CV_32FC1);
  // Inside the patch: 0.3 m against sigma_z(4.7 m) and sigma_z(5 m), over a 5 x 5 window.
  const double s_a = 0.0012 + 0.0019 * 4.3 * 4.3, s_b = 0.0012 + 0.0019 * 4.6 * 4.6;
  EXPECT_NEAR(z.at<float>(60, 80), 0.3 / std::hypot(s_a, s_b) * 5, 0.5);
  EXPECT_LT(std::abs(z.at<float>(100, 20)), 1.0);  // the static wall
  // Not judged: no depth in a, a landing on another texture, an untrusted flow.
  cv::Mat depth_a = s.depth_a.clone(), grey_b = s.grey_b.clone();
  depth_a.at<float>(100, 20) = 0;
  cv::Mat untrusted(s.depth_a.size(), CV_32FC1, cv::Scalar(0.1));
  untrusted.at<float>(20, 140) = std::numeric_limits<float>::infinity();
  const cv::Vec2f f = s.predicted.at<cv::Vec2f>(20, 20);
  const cv::Point landing(static_cast<int>(std::lround(20 + f[0])),
                          static_cast<int>(std::lround(20 + f[1])));
  grey_b(cv::Rect(landing - cv::Point(1, 1), cv::Size(3, 3))) += cv::Scalar(100);
  const cv::Mat holes = depthDisagreement(depth_a, s.depth_b, s.grey_a, grey_b, untrusted, s.T_b_a,
                                          s.camera, 0.0012, 0.0019, 0.4);
  EXPECT_TRUE(std::isnan(holes.at<float>(100, 20)));
  EXPECT_TRUE(std::isnan(holes.at<float>(20, 140)));
  EXPECT_TRUE(std::isnan(holes.at<float>(20, 20)));
  EXPECT_FALSE(std::isnan(holes.at<float>(24, 24)));

  // The flow test alone finds nothing; with the depth test the patch is one object.
  MotionSegmentationParams params;
  params.min_object_pixels = 400;
  MotionSegmenter flow_only(params), with_depth(params);
  const cv::Mat depth_flow(s.flow.size(), CV_32FC1, cv::Scalar(0.1));
  EXPECT_EQ(cv::countNonZero(flow_only.segment(s.flow, s.predicted, depth_flow)), 0);
  const cv::Mat instance = with_depth.segment(s.flow, s.predicted, depth_flow, z);
  const cv::Mat object = instance == instance.at<uint16_t>(60, 80);
  EXPECT_GT(instance.at<uint16_t>(60, 80), 0);
  // The static prediction of the patch's rim lands on the wall in b: its depth agrees there,
  // which the 5 x 5 window partly makes up for.
  EXPECT_GE(cv::countNonZero(object), 36 * 36);
  EXPECT_LE(cv::countNonZero(object), 44 * 44);
  EXPECT_EQ(cv::countNonZero(instance > 0), cv::countNonZero(object));
}

// The camera moves 0.2 m sideways past a post 2 m away in front of a wall 5 m away: in b the
// post hides wall pixels that a saw. Their depth in b is the post's, which is what the static
// scene predicts there: they are occluded, not moving.
TEST(DepthDisagreement, DoesNotJudgePointsTheStaticSceneHides) {
  const CameraModel camera = smallCamera();
  const SE3 T_b_a(SO3(), Vec3(-0.2, 0, 0));  // b is 0.2 m right of a: the scene moves left
  const cv::Size size(160, 120);
  const cv::Range post_a(100, 110), post_b(85, 95);  // 15 px left in b, the wall 6 px
  cv::Mat depth_a(size, CV_32FC1, cv::Scalar(5.0)), depth_b(size, CV_32FC1, cv::Scalar(5.0));
  depth_a.colRange(post_a).setTo(2.0);
  depth_b.colRange(post_b).setTo(2.0);
  const cv::Mat grey(size, CV_8UC1, cv::Scalar(128));  // uniform: the grey check passes
  const cv::Mat z = depthDisagreement(depth_a, depth_b, grey, grey, cv::Mat(), T_b_a, camera,
                                      0.0012, 0.0019, 0.4);
  // Wall pixels of a at x 91..100 land behind the post (x 85..94 in b).
  for (int x = 92; x <= 99; ++x) EXPECT_TRUE(std::isnan(z.at<float>(60, x))) << "x " << x;
  // Everything judged agrees with the static scene, the post and the wall next to it included.
  cv::Mat judged = z == z;
  double largest = 0;
  cv::minMaxLoc(cv::abs(z), nullptr, &largest, nullptr, nullptr, judged);
  EXPECT_LT(largest, 4.0);
  EXPECT_FALSE(std::isnan(z.at<float>(60, 105)));  // the post
  EXPECT_FALSE(std::isnan(z.at<float>(60, 80)));   // the wall left of it

  // Seen from b, the post is what the static scene puts there: it occludes nothing.
  cv::Mat occluding;
  depthDisagreement(depth_a, depth_b, grey, grey, cv::Mat(), T_b_a, camera, 0.0012, 0.0019, 0.4,
                    &occluding);
  double most = 0;
  cv::minMaxLoc(occluding, nullptr, &most, nullptr, nullptr, occluding == occluding);
  EXPECT_LT(most, 4.0);
  EXPECT_FALSE(std::isnan(occluding.at<float>(60, 90)));
}

// The camera moves 0.2 m sideways along a wall 5 m away; in b a box 2 m away has moved in
// front of it (a door swinging towards the camera). No pixel of a saw the box, so no flow
// carries it into b, and a's wall points that land behind it have another grey there. Seen
// from b, its pixels are nearer than every static point of a that lands on them.
TEST(DepthDisagreement, FlagsWhatMovedInFrontOfTheStaticSceneWhereItIsInTheFrame) {
  const CameraModel camera = smallCamera();
  const SE3 T_b_a(SO3(), Vec3(-0.2, 0, 0));
  const cv::Size size(160, 120);
  const cv::Rect box(60, 40, 30, 30);
  const cv::Mat depth_a(size, CV_32FC1, cv::Scalar(5.0));
  cv::Mat depth_b = depth_a.clone(), grey_b(size, CV_8UC1, cv::Scalar(128));
  depth_b(box).setTo(2.0);
  grey_b(box).setTo(40);
  const cv::Mat grey_a(size, CV_8UC1, cv::Scalar(128));
  cv::Mat occluding;
  const cv::Mat z = depthDisagreement(depth_a, depth_b, grey_a, grey_b, cv::Mat(), T_b_a, camera,
                                      0.0012, 0.0019, 0.4, &occluding);
  ASSERT_EQ(occluding.type(), CV_32FC1);
  ASSERT_EQ(occluding.size(), size);
  // Inside the box: 3 m against sigma_z(5 m) and sigma_z(2 m), far beyond 4.
  EXPECT_GT(occluding.at<float>(55, 75), 20.0);
  EXPECT_LT(std::abs(occluding.at<float>(60, 20)), 1.0);   // the wall
  EXPECT_LT(std::abs(occluding.at<float>(60, 130)), 1.0);  // the wall right of the box
  // From a's side the wall points behind the box are not judged: their grey is the box's.
  EXPECT_TRUE(std::isnan(z.at<float>(55, 81)));

  // Segmented: without it the flow (static everywhere) finds nothing; with it, the box.
  const cv::Mat flow(size, CV_32FC2, cv::Scalar(-6, 0));
  const cv::Mat depth_flow(size, CV_32FC1, cv::Scalar(0.1));
  MotionSegmenter without, with;
  EXPECT_EQ(cv::countNonZero(without.segment(flow, flow, depth_flow, z)), 0);
  const cv::Mat instance = with.segment(flow, flow, depth_flow, z, {}, {}, occluding);
  EXPECT_GT(instance.at<uint16_t>(55, 75), 0);
  EXPECT_GE(cv::countNonZero(instance(box)), 0.8 * box.area());
  // The 5 x 5 window reaches 2 px past the box.
  EXPECT_LE(cv::countNonZero(instance), 1.4 * box.area());
}

// A static scene flowing 3 px right. Object A (strong: it stays put) has a strip of weak evidence
// next to it (1 px of flow residual: above 0.7 of the 1.3 px tolerance, below it); a patch of
// the same weak evidence lies apart. At the right edge the static scene carries pixels out of
// view: a strip there whose flow stays put (a flow that found nothing to match) lies apart,
// object B's part there joins its in-view part.
TEST(MotionSegmenter, WeakEvidenceCountsWhereItJoinsStrongEvidence) {
  const cv::Rect object_a(20, 40, 40, 40), weak_strip(60, 40, 20, 40), weak_patch(100, 5, 30, 30),
      leaving(154, 5, 6, 40), object_b(120, 60, 40, 40);
  cv::Mat predicted(120, 160, CV_32FC2, cv::Scalar(3, 0));
  cv::Mat measured = predicted.clone();
  measured(object_a).setTo(cv::Scalar(0, 0));
  measured(weak_strip).setTo(cv::Scalar(2, 0));
  measured(weak_patch).setTo(cv::Scalar(2, 0));
  measured(leaving).setTo(cv::Scalar(0, 0));
  measured(object_b).setTo(cv::Scalar(0, 0));
  MotionSegmentationParams params;
  params.min_residual_px = 1.0;
  params.relative_residual = 0.1;
  params.min_object_pixels = 100;
  params.close_px = 0;
  params.weak_fraction = 0.7;
  MotionSegmenter segmenter(params);
  const cv::Mat instance = segmenter.segment(measured, predicted);
  const uint16_t a = instance.at<uint16_t>(60, 40), b = instance.at<uint16_t>(80, 140);
  EXPECT_GT(a, 0);
  EXPECT_GT(b, 0);
  EXPECT_EQ(cv::countNonZero(instance == a), object_a.area());
  EXPECT_EQ(cv::countNonZero(instance == b), object_b.area());
  // The weak strip, carried 2 px right along its measured flow.
  EXPECT_EQ(cv::countNonZero(instance(weak_strip + cv::Point(2, 0))), weak_strip.area());
  EXPECT_EQ(cv::countNonZero(instance > 0), object_a.area() + weak_strip.area() + object_b.area());
  EXPECT_EQ(cv::countNonZero(instance(weak_patch + cv::Point(2, 0))), 0);
  EXPECT_EQ(cv::countNonZero(instance(leaving)), 0);

  // weak_fraction 1: the weak strip no longer counts; the part of B leaving the view still does.
  params.weak_fraction = 1.0;
  MotionSegmenter strong_only(params);
  const cv::Mat strict = strong_only.segment(measured, predicted);
  EXPECT_EQ(cv::countNonZero(strict > 0), object_a.area() + object_b.area());
}

// A sideways move of t: the flow at depth z is fx t / z, so a depth one sigma nearer in inverse
// depth changes it by fx t sigma_z / z^2 everywhere; no depth, no bound.
TEST(FlowFromDepthNoise, SidewaysMoveGivesFxTimesTheInverseDepthSigma) {
  const CameraModel camera = smallCamera();
  const double t = 0.1, z = 5, sigma_a = 0.01, sigma_b = 0.002;
  cv::Mat depth(120, 160, CV_32FC1, cv::Scalar(z));
  depth(cv::Rect(0, 0, 10, 10)).setTo(0);
  const SE3 T_b_a(SO3(), Vec3(-t, 0, 0));
  const cv::Mat change = flowFromDepthNoise(depth, T_b_a, camera, sigma_a, sigma_b, 0.0);
  ASSERT_EQ(change.type(), CV_32FC1);
  const double expected = camera.fx * t * (sigma_a + sigma_b * z * z) / (z * z);
  for (const cv::Point px : {cv::Point(80, 60), cv::Point(150, 110), cv::Point(20, 100)})
    EXPECT_NEAR(change.at<float>(px), expected, 1e-4 * expected);
  EXPECT_TRUE(std::isinf(change.at<float>(5, 5)));
}

// A road 1.5 m below the camera, pitched 4 deg, and the rear of a truck 6 m ahead that covers
// more of the lower half than the road: the largest plane there is not the ground.
TEST(GroundPlane, FindsTheRoadBesideALargerTruck) {
  const CameraModel camera = smallCamera();
  const double pitch = 4 * M_PI / 180, height = 1.5;
  const Vec3 normal(0, std::cos(pitch), std::sin(pitch));
  const cv::Rect truck(0, 50, 100, 70);
  cv::Mat depth(120, 160, CV_32FC1, cv::Scalar(0));
  cv::Mat road(depth.size(), CV_8UC1, cv::Scalar(0));
  cv::Mat road_far = road.clone();        // the road's pixels 12-40 m ahead
  cv::Mat truck_off_road = road.clone();  // the truck's pixels more than 0.1 m off the road
  for (int v = 0; v < depth.rows; ++v)
    for (int u = 0; u < depth.cols; ++u) {
      const Vec3 ray((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1);
      if (truck.contains(cv::Point(u, v))) {
        depth.at<float>(v, u) = 6;
        truck_off_road.at<uint8_t>(v, u) = std::abs(normal.dot(6 * ray) - height) > 0.1 ? 255 : 0;
      } else if (normal.dot(ray) > 0) {
        depth.at<float>(v, u) = static_cast<float>(height / normal.dot(ray));
        const float z = depth.at<float>(v, u);
        road.at<uint8_t>(v, u) = v >= 60 && z < 12 ? 255 : 0;
        road_far.at<uint8_t>(v, u) = v >= 60 && z >= 12 && z < 40 ? 255 : 0;
      }
    }
  const GroundParams params;
  const std::optional<Plane> plane = fitGroundPlane(depth, camera, params);
  ASSERT_TRUE(plane);
  const cv::Mat ground =
      planePixels(depth, camera, *plane, params.max_range_m, params.inlier_threshold_m);
  ASSERT_GT(cv::countNonZero(road), 1000);
  EXPECT_GT(cv::countNonZero(ground & road), 0.95 * cv::countNonZero(road));
  EXPECT_EQ(cv::countNonZero(ground & truck_off_road), 0);
  EXPECT_EQ(cv::countNonZero(ground & road_far), 0);
  // Labelled beyond the fit's range (the road below an object 20 m ahead), the plane holds.
  const cv::Mat far = planePixels(depth, camera, *plane, 40, 0.04);
  ASSERT_GT(cv::countNonZero(road_far), 100);
  EXPECT_GT(cv::countNonZero(far & road_far), 0.95 * cv::countNonZero(road_far));
  EXPECT_EQ(cv::countNonZero(far & truck_off_road), 0);

  // Without the road only walls are left: no ground.
  cv::Mat walls = depth.clone();
  walls.setTo(cv::Scalar(6), road);
  walls.setTo(cv::Scalar(0), depth > 6.01f);
  EXPECT_FALSE(fitGroundPlane(walls, camera));
}

TEST(MotionSegmenter, RejectsBadParameters) {
  MotionSegmentationParams params;
  params.min_residual_px = 0;
  EXPECT_THROW(MotionSegmenter{params}, std::invalid_argument);
  params = MotionSegmentationParams();
  params.weak_fraction = 0;
  EXPECT_THROW(MotionSegmenter{params}, std::invalid_argument);
  params = MotionSegmentationParams();
  params.carry_grey_error = -1;
  EXPECT_THROW(MotionSegmenter{params}, std::invalid_argument);
}

}  // namespace
}  // namespace radslam
