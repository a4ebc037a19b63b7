// Trajectory evaluation: ATE after Sim(3)/SE(3) alignment, orientation error
// after rotation-only alignment, RPE; file loading and the JSON report.
#include "common/evaluation.h"

#include <sys/stat.h>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace radslam {
namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;
const std::string kDataDir = RADSLAM_SOURCE_DIR "/../shared/data";

bool exists(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0;
}

// A handheld-like ground truth: a helix with changing orientation, 30 Hz.
Trajectory syntheticGroundTruth(size_t n = 120) {
  Trajectory gt;
  for (size_t i = 0; i < n; ++i) {
    const double t = 100.0 + i / 30.0;
    const double a = 0.05 * static_cast<double>(i);
    const Vec3 position(2.0 * std::cos(a), 1.5 * std::sin(a), 0.02 * static_cast<double>(i));
    const Vec3 w(0.3 * std::sin(0.7 * a), 0.2 * std::cos(a), a);
    gt.push_back({t, SE3(SO3::exp(w), position)});
  }
  return gt;
}

Trajectory mapped(const Sim3& S, const Trajectory& trajectory) {
  Trajectory out;
  for (const StampedPose& p : trajectory) out.push_back({p.t, S.transformPose(p.T_world_cam)});
  return out;
}

TEST(EvaluateTrajectory, Sim3AlignedCopyHasZeroErrorAndRecoversScale) {
  const Trajectory gt = syntheticGroundTruth();
  // The estimate lives in its own frame at its own (monocular) scale.
  const Sim3 S_est_gt(SO3::exp(Vec3(0.5, -1.0, 2.0)), Vec3(3, -2, 1), 0.25);
  const Trajectory estimate = mapped(S_est_gt, gt);
  const TrajectoryErrors e = evaluateTrajectory(estimate, gt, "sim3");
  EXPECT_EQ(e.matched, gt.size());
  EXPECT_EQ(e.alignment, "sim3");
  EXPECT_NEAR(e.scale, 4.0, 1e-9);
  EXPECT_TRUE(e.T_gt_est.matrix().isApprox(S_est_gt.inverse().matrix(), 1e-9));
  EXPECT_LT(e.ate_rmse_m, 1e-9);
  EXPECT_LT(e.ate_max_m, 1e-9);
  EXPECT_LT(e.rot_rmse_deg, 1e-6);
  EXPECT_LT(e.rpe_trans_m, 1e-9);
  EXPECT_LT(e.rpe_rot_deg, 1e-6);

  // Rigid alignment cannot undo the scale; no alignment cannot undo anything.
  const TrajectoryErrors rigid = evaluateTrajectory(estimate, gt, "se3");
  EXPECT_EQ(rigid.scale, 1.0);
  EXPECT_GT(rigid.ate_rmse_m, 0.5);
  EXPECT_LT(rigid.rot_rmse_deg, 1e-6);  // orientations are still aligned rotation-only
  const TrajectoryErrors none = evaluateTrajectory(estimate, gt, "none");
  EXPECT_GT(none.ate_rmse_m, rigid.ate_rmse_m);
  EXPECT_GT(none.rot_rmse_deg, 10.0);
}

TEST(EvaluateTrajectory, KnownPositionNoiseGivesExpectedStatistics) {
  const Trajectory gt = syntheticGroundTruth(100);
  Trajectory estimate = gt;
  // Offsets of length 0.01, 0.02, 0.03, 0.04 m in a rotating direction.
  std::vector<double> lengths;
  for (size_t i = 0; i < estimate.size(); ++i) {
    const double length = 0.01 * static_cast<double>(1 + i % 4);
    const double a = 2.1 * static_cast<double>(i);
    estimate[i].T_world_cam.translation() +=
        length * Vec3(std::cos(a), std::sin(a), std::cos(3 * a)).normalized();
    lengths.push_back(length);
  }
  const TrajectoryErrors e = evaluateTrajectory(estimate, gt, "none");
  EXPECT_NEAR(e.ate_rmse_m, std::sqrt((1e-4 + 4e-4 + 9e-4 + 16e-4) / 4), 1e-12);
  EXPECT_NEAR(e.ate_mean_m, 0.025, 1e-12);
  EXPECT_NEAR(e.ate_median_m, 0.025, 1e-12);
  EXPECT_NEAR(e.ate_max_m, 0.04, 1e-12);
  EXPECT_NEAR(e.rot_rmse_deg, 0.0, 1e-9);
  // Alignment may only lower the error, and by little for zero-mean noise.
  const TrajectoryErrors aligned = evaluateTrajectory(estimate, gt, "se3");
  EXPECT_LE(aligned.ate_rmse_m, e.ate_rmse_m + 1e-12);
  EXPECT_GT(aligned.ate_rmse_m, 0.8 * e.ate_rmse_m);
}

TEST(EvaluateTrajectory, KnownOrientationNoiseGivesExpectedRmse) {
  const Trajectory gt = syntheticGroundTruth(200);
  Trajectory estimate;
  const SO3 R_est_gt = SO3::exp(Vec3(0.3, 0.2, -1.1));
  std::mt19937 gen(9);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<double> angles;
  for (size_t i = 0; i < gt.size(); ++i) {
    // Angle 1 or 2 deg about a random axis: RMS = sqrt(2.5) deg before alignment.
    const double angle = (i % 2 ? 2.0 : 1.0) * kDeg;
    const Vec3 axis = Vec3(u(gen), u(gen), u(gen)).normalized();
    const SE3& T = gt[i].T_world_cam;
    estimate.push_back(
        {gt[i].t, SE3(R_est_gt * T.so3() * SO3::exp(angle * axis), R_est_gt * T.translation())});
  }
  const TrajectoryErrors e = evaluateTrajectory(estimate, gt, "se3");
  EXPECT_LT(e.ate_rmse_m, 1e-9);
  // The rotation-only alignment removes R_est_gt and only a sliver of the noise.
  EXPECT_NEAR(e.rot_rmse_deg, std::sqrt(2.5), 0.02);
  EXPECT_LE(e.rot_rmse_deg, std::sqrt(2.5) + 1e-9);
}

// A perfect estimate whose camera frame is turned by a constant 1.5 deg from the ground
// truth's (a hand-eye calibration error): rotation-only alignment cannot remove it, the camera
// fit does and recovers the offset; small noise stays.
TEST(EvaluateTrajectory, CameraFrameFitRecoversAConstantCameraOffset) {
  const Trajectory gt = syntheticGroundTruth(200);
  const SO3 R_est_gt = SO3::exp(Vec3(0.3, 0.2, -1.1));
  const SO3 offset = SO3::exp(1.5 * kDeg * Vec3(0.8, -0.6, 0).normalized());
  std::mt19937 gen(4);
  std::normal_distribution<double> noise(0, 0.1 * kDeg);
  Trajectory exact, noisy;
  for (const StampedPose& p : gt) {
    const SE3& T = p.T_world_cam;
    const SO3 R = R_est_gt * T.so3() * offset;
    exact.push_back({p.t, SE3(R, R_est_gt * T.translation())});
    noisy.push_back({p.t, SE3(R * SO3::exp(Vec3(noise(gen), noise(gen), noise(gen))),
                              R_est_gt * T.translation())});
  }
  const TrajectoryErrors e = evaluateTrajectory(exact, gt, "se3");
  EXPECT_GT(e.rot_rmse_deg, 0.3);
  EXPECT_NEAR(e.camera_offset_floor_deg, e.rot_rmse_deg, 1e-6);
  EXPECT_LT(e.rot_rmse_camera_fit_deg, 1e-6);
  EXPECT_NEAR(e.camera_offset_deg, 1.5, 1e-6);
  const TrajectoryErrors n = evaluateTrajectory(noisy, gt, "se3");
  EXPECT_NEAR(n.rot_rmse_camera_fit_deg, 0.1 * std::sqrt(3.0), 0.03);
  EXPECT_NEAR(n.camera_offset_deg, 1.5, 0.05);
  // The fit itself: gt = R_est_gt^-1 est offset^-1.
  std::vector<SO3> est_r, gt_r;
  for (size_t k = 0; k < gt.size(); ++k) {
    est_r.push_back(exact[k].T_world_cam.so3());
    gt_r.push_back(gt[k].T_world_cam.so3());
  }
  const WorldAndCameraRotation fit = alignRotationsWithCameraOffset(est_r, gt_r);
  EXPECT_LT((fit.world * R_est_gt).log().norm(), 1e-8);
  EXPECT_LT((fit.camera * offset).log().norm(), 1e-8);
  EXPECT_THROW(alignRotationsWithCameraOffset({SO3()}, {SO3()}), std::invalid_argument);
}

TEST(EvaluateTrajectory, ConstantDriftGivesExactRpe) {
  // Ground truth: 0.5 m forward and 2 deg yaw per frame; the estimate's every
  // step is off by the same small motion `drift`.
  Vec6 gt_step_xi, drift;
  gt_step_xi << 0.5, 0, 0, 0, 0, 2 * kDeg;
  drift << 0.02, -0.01, 0.0, 0.0, 0.5 * kDeg, 0.0;
  const SE3 gt_step = SE3::exp(gt_step_xi);
  const SE3 est_step = gt_step * SE3::exp(drift);
  Trajectory gt, estimate;
  SE3 T_gt, T_est;
  for (int i = 0; i < 50; ++i) {
    gt.push_back({0.1 * i, T_gt});
    estimate.push_back({0.1 * i + 0.003, T_est});  // within max_dt of the truth
    T_gt = T_gt * gt_step;
    T_est = T_est * est_step;
  }
  // Exp(drift) translates by J_l(w) v, not v.
  const double expected_trans = SE3::exp(drift).translation().norm();
  for (const std::string alignment : {"none", "se3"}) {
    const TrajectoryErrors e = evaluateTrajectory(estimate, gt, alignment);
    EXPECT_NEAR(e.rpe_trans_m, expected_trans, 1e-9) << alignment;
    EXPECT_NEAR(e.rpe_rot_deg, 0.5, 1e-9) << alignment;
    EXPECT_GT(e.ate_rmse_m, 0.1) << alignment;  // the drift accumulates
  }
}

TEST(EvaluateTrajectory, MatchesByTimeWithinMaxDt) {
  const Trajectory gt = syntheticGroundTruth(60);
  Trajectory estimate;
  for (size_t i = 0; i < gt.size(); i += 2) estimate.push_back({gt[i].t + 0.01, gt[i].T_world_cam});
  estimate.push_back({500.0, SE3()});  // no ground truth near: ignored
  EXPECT_EQ(evaluateTrajectory(estimate, gt, "se3", 0.02).matched, 30u);
  EXPECT_THROW(evaluateTrajectory(estimate, gt, "se3", 0.005), std::runtime_error);
  try {
    evaluateTrajectory(estimate, gt, "se3", 0.005);
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("only 0 of 31"), std::string::npos) << e.what();
  }
}

TEST(EvaluateTrajectory, RejectsBadInput) {
  const Trajectory gt = syntheticGroundTruth(10);
  EXPECT_THROW(evaluateTrajectory(gt, gt, "affine"), std::invalid_argument);
  EXPECT_THROW(evaluateTrajectory(Trajectory(), gt, "se3"), std::runtime_error);
  const Trajectory two(gt.begin(), gt.begin() + 2);
  EXPECT_THROW(evaluateTrajectory(two, gt, "sim3"), std::runtime_error);
  EXPECT_NO_THROW(evaluateTrajectory(two, gt, "none"));
  // A monocular estimate collapsed to one point has no scale to align.
  Trajectory collapsed = gt;
  for (StampedPose& p : collapsed) p.T_world_cam.translation().setZero();
  EXPECT_THROW(evaluateTrajectory(collapsed, gt, "sim3"), std::runtime_error);
}

std::string tempPath(const std::string& name) { return ::testing::TempDir() + "/" + name; }

std::string readFile(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

TEST(ErrorsReport, JsonHasTheRequiredKeysAndValues) {
  const Trajectory gt = syntheticGroundTruth();
  const Sim3 S(SO3::exp(Vec3(0.1, 0.2, 0.3)), Vec3(1, 2, 3), 0.5);
  const TrajectoryErrors e = evaluateTrajectory(mapped(S, gt), gt, "sim3");
  const std::string path = tempPath("radslam_eval_test.json");
  writeErrorsJson(path, e);
  const std::string json = readFile(path);
  std::remove(path.c_str());
  for (const char* key : {"\"ate_rmse_m\": ", "\"ate_alignment\": \"sim3\"", "\"rot_rmse_deg\": ",
                          "\"rpe_trans_m\": ", "\"rpe_rot_deg\": ", "\"matched\": 120",
                          "\"scale\": 2", "\"ate_mean_m\": ", "\"ate_median_m\": ",
                          "\"ate_max_m\": ", "\"rot_rmse_camera_fit_deg\": ",
                          "\"camera_offset_deg\": ", "\"camera_offset_floor_deg\": "}) {
    EXPECT_NE(json.find(key), std::string::npos) << key << " in\n" << json;
  }
  EXPECT_EQ(json.front(), '{');
  EXPECT_EQ(json[json.size() - 2], '}');
  EXPECT_THROW(writeErrorsJson("/nonexistent_dir/x.json", e), std::runtime_error);
  const std::string table = formatErrorsTable(e);
  EXPECT_NE(table.find("matched poses"), std::string::npos);
  EXPECT_NE(table.find("sim3"), std::string::npos);
}

TEST(LoadTrajectory, KittiWithPrefixTimesAndErrors) {
  Trajectory t = syntheticGroundTruth(5);
  const std::string poses = tempPath("radslam_eval_kitti.txt");
  const std::string times = tempPath("radslam_eval_times.txt");
  writeKittiTrajectory(poses, t);
  {
    std::ofstream out(times);
    for (int i = 0; i < 8; ++i) out << 0.1 * i << "\n";  // longer than the trajectory
  }
  const Trajectory loaded = loadTrajectory(poses, "kitti", times);
  ASSERT_EQ(loaded.size(), 5u);
  EXPECT_DOUBLE_EQ(loaded[3].t, 0.3);
  EXPECT_TRUE(loaded[3].T_world_cam.matrix().isApprox(t[3].T_world_cam.matrix(), 1e-12));
  EXPECT_EQ(loadTrajectory(poses, "kitti")[4].t, 4.0);
  {
    std::ofstream out(times);
    out << "0.0\n0.1\n";  // too short
  }
  EXPECT_THROW(loadTrajectory(poses, "kitti", times), std::runtime_error);
  EXPECT_THROW(loadTrajectory(poses, "tum", times), std::runtime_error);
  EXPECT_THROW(loadTrajectory(poses, "euroc"), std::runtime_error);
  try {
    loadTrajectory(tempPath("missing_trajectory.txt"), "tum");
    ADD_FAILURE() << "no exception for a missing file";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("missing_trajectory.txt"), std::string::npos);
  }
  std::remove(poses.c_str());
  std::remove(times.c_str());
}

TEST(RealData, TumRpyCollapsedTrajectoryScoresItsSpread) {
  const std::string gt_path = kDataDir + "/tum_fr1_rpy/rgbd_dataset_freiburg1_rpy/groundtruth.txt";
  if (!exists(gt_path)) GTEST_SKIP() << "real data not found: " << gt_path;
  const Trajectory full = readTumTrajectory(gt_path);
  // The first 5.6 s (the staged frames), every third mocap sample (~33 Hz).
  Trajectory gt;
  for (size_t i = 0; i < full.size() && full[i].t < full.front().t + 5.6; i += 3) {
    gt.push_back(full[i]);
  }
  ASSERT_GT(gt.size(), 100u);
  // Orientation perfect up to a constant rotation, position collapsed to a point.
  const SO3 R_est_gt = SO3::exp(Vec3(0.4, -0.2, 1.0));
  Trajectory estimate;
  for (const StampedPose& p : gt)
    estimate.push_back({p.t, SE3(R_est_gt * p.T_world_cam.so3(), Vec3(1, 1, 1))});
  const TrajectoryErrors e = evaluateTrajectory(estimate, gt, "se3");
  EXPECT_EQ(e.matched, gt.size());
  EXPECT_LT(e.rot_rmse_deg, 1e-6);
  // The ATE of a point is the RMS distance of the true positions to their centroid.
  Vec3 centroid = Vec3::Zero();
  for (const StampedPose& p : gt) centroid += p.T_world_cam.translation();
  centroid /= static_cast<double>(gt.size());
  double sum = 0;
  for (const StampedPose& p : gt) sum += (p.T_world_cam.translation() - centroid).squaredNorm();
  EXPECT_NEAR(e.ate_rmse_m, std::sqrt(sum / static_cast<double>(gt.size())), 1e-9);
  EXPECT_GT(e.ate_rmse_m, 0.005);  // the README: about 3 cm
  EXPECT_LT(e.ate_rmse_m, 0.1);
}

TEST(RealData, KittiPosesWithTimesAlignUnderSim3) {
  const std::string base = kDataDir + "/kitti_odometry_07";
  const std::string gt_path = base + "/poses/07.txt";
  const std::string times_path = base + "/sequences/07/times.txt";
  if (!exists(gt_path) || !exists(times_path)) GTEST_SKIP() << "real data not found: " << base;
  const Trajectory gt = loadTrajectory(gt_path, "kitti", times_path);
  ASSERT_EQ(gt.size(), 1101u);
  // An "estimate" of the first 160 frames at a monocular scale, in KITTI format.
  const Sim3 S_est_gt(SO3::exp(Vec3(0.0, 0.3, 0.0)), Vec3(5, 0, -2), 0.05);
  const Trajectory estimate = mapped(S_est_gt, Trajectory(gt.begin(), gt.begin() + 160));
  const std::string path = tempPath("radslam_eval_kitti07.txt");
  writeKittiTrajectory(path, estimate);
  const Trajectory loaded = loadTrajectory(path, "kitti", times_path);
  std::remove(path.c_str());
  const TrajectoryErrors e = evaluateTrajectory(loaded, gt, "sim3");
  EXPECT_EQ(e.matched, 160u);
  EXPECT_NEAR(e.scale, 20.0, 1e-6);
  EXPECT_LT(e.ate_rmse_m, 1e-6);
  EXPECT_LT(e.rot_rmse_deg, 1e-6);
  EXPECT_LT(e.rpe_trans_m, 1e-6);
}

}  // namespace
}  // namespace radslam
