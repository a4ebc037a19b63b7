// Rolling shutter: the rotation between consecutive frames (tracker/rotation_alignment.h), the
// resampling of a rolling-shutter frame as seen at its middle row (ImagePreparer), and the
// tracker on a synthetic rolling-shutter sequence.
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/evaluation.h"
#include "common/synthetic.h"
#include "tracker/frontend.h"
#include "tracker/rotation_alignment.h"
#include "tracker/tracker.h"

namespace radslam {
namespace {

constexpr double kDeg = M_PI / 180;

CameraModel pinhole(int w, int h, double f) {
  CameraModel c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = f;
  c.cx = 0.5 * (w - 1) + 3.25;
  c.cy = 0.5 * (h - 1) - 2.5;
  return c;
}

// Smooth random texture: blurred noise, contrast stretched.
cv::Mat texture(int w, int h, uint64_t seed) {
  cv::Mat noise(h, w, CV_32FC1);
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 2.0);
  cv::Mat out;
  cv::normalize(noise, noise, 20, 235, cv::NORM_MINMAX);
  noise.convertTo(out, CV_8UC1);
  return out;
}

// b(x) = a(Pi(R_b_a^T Pi^-1(x))) + offset: the view of a turned by R_b_a.
cv::Mat turned(const cv::Mat& a, const CameraModel& cam, const SO3& R_b_a, double offset) {
  cv::Mat map(a.size(), CV_32FC2);
  const Mat3 R_a_b = R_b_a.inverse().matrix();
  for (int v = 0; v < a.rows; ++v) {
    for (int u = 0; u < a.cols; ++u) {
      const Vec3 ray = R_a_b * Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
      map.at<cv::Vec2f>(v, u) = cv::Vec2f(static_cast<float>(cam.fx * ray.x() / ray.z() + cam.cx),
                                          static_cast<float>(cam.fy * ray.y() / ray.z() + cam.cy));
    }
  }
  cv::Mat b;
  cv::remap(a, b, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  b.convertTo(b, CV_8UC1, 1.0, offset);
  return b;
}

TEST(RotationAlignment, WarpJacobianMatchesFiniteDifferences) {
  const CameraModel cam = pinhole(96, 72, 80);
  for (const Eigen::Vector2d& px : {Eigen::Vector2d(5, 7), Eigen::Vector2d(48, 36),
                                    Eigen::Vector2d(90, 60), Eigen::Vector2d(12, 66)}) {
    const Eigen::Matrix<double, 2, 3> J = rotationWarpJacobian(cam, px.x(), px.y());
    const Vec3 ray((px.x() - cam.cx) / cam.fx, (px.y() - cam.cy) / cam.fy, 1.0);
    constexpr double h = 1e-6;
    for (int k = 0; k < 3; ++k) {
      const Vec3 step = h * Vec3::Unit(k);
      const Eigen::Vector2d plus = project(cam, SO3::exp(step) * ray);
      const Eigen::Vector2d minus = project(cam, SO3::exp(-step) * ray);
      const Eigen::Vector2d numeric = (plus - minus) / (2 * h);
      EXPECT_NEAR((J.col(k) - numeric).norm(), 0, 1e-5 * (1 + numeric.norm()))
          << "pixel " << px.transpose() << " axis " << k;
    }
  }
}

TEST(RotationAlignment, RecoversARotationAndABrightnessOffset) {
  const CameraModel cam = pinhole(384, 288, 300);
  const cv::Mat a = texture(cam.width, cam.height, 7);
  const SO3 R_b_a = SO3::exp(Vec3(0.8, -1.5, 0.6) * kDeg);
  const cv::Mat b = turned(a, cam, R_b_a, 9.0);
  const ImagePyramid pa = coarsePyramid(a, cam, 1, 3);
  const ImagePyramid pb = coarsePyramid(b, cam, 1, 3);
  ASSERT_EQ(pa.levels.size(), 3u);
  EXPECT_EQ(pa.levels[0].size(), cv::Size(192, 144));
  EXPECT_DOUBLE_EQ(pa.cameras[0].fx, 150);

  const RotationAlignment found = alignRotation(pa, pb, SO3(), RotationAlignmentOptions());
  ASSERT_TRUE(found.ok);
  const double error_deg = (found.R_b_a.inverse() * R_b_a).log().norm() / kDeg;
  EXPECT_LT(error_deg, 0.01) << "found " << found.R_b_a.log().transpose() / kDeg;
  EXPECT_NEAR(found.brightness_offset, 9.0, 1.0);
  EXPECT_GT(found.pixels, 1000);

  // Images with nothing in common: refused, the initial guess kept.
  const cv::Mat other = texture(cam.width, cam.height, 8);
  const RotationAlignment refused =
      alignRotation(pa, coarsePyramid(other, cam, 1, 3), SO3(), RotationAlignmentOptions());
  EXPECT_FALSE(refused.ok);
  EXPECT_TRUE(refused.R_b_a.matrix().isApprox(Mat3::Identity()));
}

TEST(RotationAlignment, PyramidRefusesBadInput) {
  const CameraModel cam = pinhole(64, 48, 50);
  EXPECT_THROW(coarsePyramid(cv::Mat(48, 64, CV_32FC1), cam, 0, 1), std::invalid_argument);
  EXPECT_THROW(coarsePyramid(cv::Mat(48, 64, CV_8UC1), cam, 0, 3), std::invalid_argument);
  EXPECT_THROW(coarsePyramid(cv::Mat(48, 64, CV_8UC1), cam, 2, 1), std::invalid_argument);
}

// For a distorted camera: the source pixel of each working pixel, undistorted to its ray and
// turned back by the rotation since the middle row at its own input row, is the working
// pixel's ray.
TEST(ImagePreparer, RollingShutterMapFollowsTheRowTimes) {
  CameraModel tum = pinhole(640, 480, 517.3);
  tum.type = CameraModel::Type::kRadTan;
  tum.distortion = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
  constexpr double kReadoutS = 0.03;
  const ImagePreparer prep(tum, 384, 8, kReadoutS);
  const Vec3 omega(0.4, -2.0, 0.7);  // rad/s
  const cv::Mat map = prep.rollingShutterMap(omega);
  ASSERT_EQ(map.type(), CV_32FC2);
  const CameraModel& work = prep.geometry().working;
  ASSERT_EQ(map.size(), cv::Size(work.width, work.height));
  EXPECT_TRUE(prep.rollingShutterMap(Vec3::Zero()).empty());
  EXPECT_TRUE(ImagePreparer(tum, 384, 8, 0).rollingShutterMap(omega).empty());

  const cv::Mat D(tum.distortion);
  double worst_px = 0, worst_border_px = 0, largest_shift_px = 0;
  cv::Mat global_x, global_y;
  Undistorter(tum, work.width, work.height).sourcePixels(0, &global_x, &global_y);
  for (int v = 4; v < work.height - 4; v += 9) {
    for (int u = 4; u < work.width - 4; u += 11) {
      const cv::Vec2f source = map.at<cv::Vec2f>(v, u);
      std::vector<cv::Point2f> in{cv::Point2f(source[0], source[1])}, normal;
      cv::undistortPoints(in, normal, cameraMatrix(tum), D);
      const double dt = (source[1] / (tum.height - 1) - 0.5) * kReadoutS;
      const Vec3 ray = SO3::exp(dt * omega) * Vec3(normal[0].x, normal[0].y, 1.0);
      const Eigen::Vector2d back = project(work, ray);
      const bool border = u < 16 || v < 16 || u >= work.width - 16 || v >= work.height - 16;
      double& worst = border ? worst_border_px : worst_px;
      worst = std::max(worst, (back - Eigen::Vector2d(u, v)).norm());
      largest_shift_px =
          std::max(largest_shift_px, std::hypot<double>(source[0] - global_x.at<float>(v, u),
                                                        source[1] - global_y.at<float>(v, u)));
    }
  }
  EXPECT_LT(worst_px, 0.05);  // working px
  // Near the corners the undistortion map curves between its pixels.
  EXPECT_LT(worst_border_px, 0.2);
  EXPECT_GT(largest_shift_px, 8.0);  // input px: the correction is not negligible
}

// The synthetic room at 320 x 240, monocular, through a rolling shutter.
SyntheticScene fastRoom(int frames, double readout_s) {
  SyntheticConfig config;
  config.scene = "room";
  config.width = 320;
  config.height = 240;
  config.frames = frames;
  config.stereo = false;
  config.readout_s = readout_s;
  config.fps = 15;  // the room's orbit, twice as fast: about 20 deg/s
  return SyntheticScene::make(config);
}

// A rolling-shutter frame resampled at the camera's angular velocity matches the global-shutter
// frame of the same time; without the correction it does not. (The camera also moves during
// the readout, about a pixel for the nearest surfaces, which the correction leaves.)
TEST(ImagePreparer, UndoesTheRollingShutterOfASyntheticFrame) {
  constexpr double kReadoutS = 0.06;
  const SyntheticScene rolling = fastRoom(40, kReadoutS);
  const SyntheticScene global = fastRoom(40, 0);
  constexpr int kFrame = 20;
  // The camera's angular velocity at the frame, by central differences of its path.
  const SE3 before = rolling.cameraPose(kFrame - 1), after = rolling.cameraPose(kFrame + 1);
  const Vec3 omega = (before.so3().inverse() * after.so3()).log() * rolling.fps() / 2;
  ASSERT_GT(omega.norm(), 0.3);  // rad/s

  const Frame rs_frame = rolling.frame(kFrame);
  const Frame gs_frame = global.frame(kFrame);
  ASSERT_DOUBLE_EQ(rs_frame.camera.readout_s, kReadoutS);
  const ImagePreparer prep(rs_frame.camera, 320, 8, kReadoutS);
  const ImagePreparer plain(gs_frame.camera, 320, 8, 0);
  const PreparedImage corrected = prep.prepare(rs_frame, false, omega);
  const PreparedImage uncorrected = prep.prepare(rs_frame, false, Vec3::Zero());
  const PreparedImage reference = plain.prepare(gs_frame, false);
  const cv::Rect inner(24, 24, 320 - 48, 240 - 48);
  const double corrected_error =
      cv::norm(corrected.grey(inner), reference.grey(inner), cv::NORM_L1) / inner.area();
  const double uncorrected_error =
      cv::norm(uncorrected.grey(inner), reference.grey(inner), cv::NORM_L1) / inner.area();
  std::printf("mean abs grey difference to the global-shutter frame: %.2f corrected, %.2f not\n",
              corrected_error, uncorrected_error);
  EXPECT_LT(corrected_error, 0.5 * uncorrected_error)
      << corrected_error << " vs " << uncorrected_error << " grey levels";
}

// Keyframe 0 is made before any angular velocity is known; the second frame measures it and
// keyframe 0's images are made again, as seen at their middle row.
TEST(Tracker, FirstKeyframeIsUndistortedOnceTheSecondFrameMeasuresTheRotation) {
  constexpr double kReadoutS = 0.06;
  constexpr int kFirst = 20;
  const SyntheticScene rolling = fastRoom(kFirst + 2, kReadoutS);
  const SyntheticScene global = fastRoom(kFirst + 2, 0);
  TrackerParams params;
  params.mode = "rgbd";
  Tracker tracker(params);
  tracker.process(rolling.frame(kFirst));
  const std::vector<Keyframe> before = tracker.republishKeyframes({0});
  tracker.process(rolling.frame(kFirst + 1));
  const std::vector<Keyframe> after = tracker.republishKeyframes({0});
  ASSERT_EQ(before.size(), 1u);
  ASSERT_EQ(after.size(), 1u);

  const CameraModel& working = after[0].camera;
  const ImagePreparer plain(global.frame(kFirst).camera, working.width, 8, 0);
  const cv::Mat reference = plain.prepare(global.frame(kFirst), false).grey;
  const cv::Rect inner(24, 24, working.width - 48, working.height - 48);
  auto error = [&](const Keyframe& k) {
    cv::Mat grey;
    cv::cvtColor(k.color, grey, cv::COLOR_BGR2GRAY);
    return cv::norm(grey(inner), reference(inner), cv::NORM_L1) / inner.area();
  };
  std::printf("keyframe 0 against the global-shutter frame: %.2f grey levels after, %.2f before\n",
              error(after[0]), error(before[0]));
  EXPECT_LT(error(after[0]), 0.5 * error(before[0]));
}

double orientationErrorDeg(const std::vector<Frame>& frames, const std::vector<SE3>& truth,
                           double readout_s) {
  TrackerParams params;
  params.mode = "rgbd";
  params.rolling_shutter_readout_s = readout_s;
  Tracker tracker(params);
  for (const Frame& f : frames) tracker.process(f);
  const TrackerOutput final_output = tracker.finish();
  Trajectory estimate, ground_truth;
  for (size_t i = 0; i < final_output.refreshed_poses.size(); ++i) {
    const PoseStamped& p = final_output.refreshed_poses[i];
    estimate.push_back({p.header.utime * 1e-6, p.T_world_cam});
    ground_truth.push_back({frames[i].header.utime * 1e-6, truth[i]});
  }
  return evaluateTrajectory(estimate, ground_truth, "se3").rot_rmse_deg;
}

// The tracker on a rolling-shutter sequence: with the camera's readout it tracks the camera
// better than as a global shutter.
TEST(Tracker, TracksARollingShutterSequenceBetterWithItsReadout) {
  constexpr int kFrames = 30;
  constexpr double kReadoutS = 0.06;
  const SyntheticScene scene = fastRoom(kFrames, kReadoutS);
  std::vector<Frame> frames;
  std::vector<SE3> truth;
  for (int i = 0; i < kFrames; ++i) {
    frames.push_back(scene.frame(i));
    truth.push_back(scene.cameraPose(i));
  }
  const double with_readout = orientationErrorDeg(frames, truth, -1);  // the camera's
  const double as_global = orientationErrorDeg(frames, truth, 0);
  std::printf("orientation error: %.3f deg with the readout, %.3f deg as a global shutter\n",
              with_readout, as_global);
  EXPECT_LT(with_readout, 0.7 * as_global) << with_readout << " vs " << as_global << " deg";
}

// A depth image exposed before its colour image (depth_delay_s): turned by the camera's rotation
// meanwhile, the keyframes' depth lines up with their colour images again.
TEST(Tracker, DepthDelayTurnsTheDepthToTheColourImagesPose) {
  constexpr int kFrames = 12;
  constexpr double kDelayS = 0.04;
  const SyntheticScene scene = fastRoom(kFrames + 2, 0);
  std::vector<Frame> frames;
  for (int i = 1; i <= kFrames; ++i) {
    // The camera kDelayS earlier, at its angular velocity (the few mm it moves are left out).
    const SE3 T_world_cam = scene.cameraPose(i);
    const Vec3 omega =
        (scene.cameraPose(i - 1).so3().inverse() * scene.cameraPose(i + 1).so3()).log() *
        scene.fps() / 2;
    const SE3 T_world_depth(T_world_cam.so3() * SO3::exp(-kDelayS * omega),
                            T_world_cam.translation());
    Frame f = scene.frame(i);
    f.depth = scene.render(T_world_depth, scene.camera(), i).depth;
    frames.push_back(f);
  }
  auto keyframe_depth_error = [&](double delay_s) {
    TrackerParams params;
    params.mode = "rgbd";
    params.depth_delay_s = delay_s;
    Tracker tracker(params);
    for (const Frame& f : frames) tracker.process(f);
    double sum = 0;
    int64_t count = 0;
    for (const Keyframe& k : tracker.republishKeyframes({})) {
      if (k.keyframe_id == 0) continue;  // made before any angular velocity was known
      const Frame truth = scene.frame(static_cast<int>(k.frame_index));
      const ImagePreparer plain(truth.camera, k.camera.width, 8, 0);
      const cv::Mat true_depth = plain.prepare(truth, false).depth;
      for (int y = 0; y < true_depth.rows; ++y)
        for (int x = 0; x < true_depth.cols; ++x) {
          const float a = k.depth.at<float>(y, x), b = true_depth.at<float>(y, x);
          if (a > 0 && b > 0) {
            sum += std::abs(a - b);
            ++count;
          }
        }
    }
    EXPECT_GT(count, 10000);
    return sum / std::max<int64_t>(1, count);
  };
  const double turned = keyframe_depth_error(kDelayS);
  const double as_is = keyframe_depth_error(0);
  std::printf("keyframe depth error: %.4f m turned, %.4f m as exposed\n", turned, as_is);
  EXPECT_LT(turned, 0.6 * as_is) << turned << " vs " << as_is << " m";
}

}  // namespace
}  // namespace radslam
