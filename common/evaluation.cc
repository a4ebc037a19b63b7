#include "common/evaluation.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "common/alignment.h"

namespace radslam {
namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;

double rms(const std::vector<double>& values) {
  double sum = 0;
  for (double v : values) sum += v * v;
  return values.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(values.size()));
}

std::string fixed(double value, int decimals) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, value);
  return buffer;
}

// RMS geodesic angle (rad) of R_dst_i^-1 R_left R_src_i R_right.
double rotationRms(const std::vector<SO3>& src, const std::vector<SO3>& dst, const SO3& left,
                   const SO3& right) {
  double sum = 0;
  for (size_t k = 0; k < src.size(); ++k)
    sum += (dst[k].inverse() * left * src[k] * right).log().squaredNorm();
  return std::sqrt(sum / static_cast<double>(src.size()));
}

// Scores ground truth rotated by the fitted camera offset alone, as rot_rmse_deg would.
void cameraOffsetFit(const std::vector<SO3>& est, const std::vector<SO3>& gt,
                     TrajectoryErrors* errors) {
  const WorldAndCameraRotation fit = alignRotationsWithCameraOffset(est, gt);
  errors->rot_rmse_camera_fit_deg = rotationRms(est, gt, fit.world, fit.camera) * kRadToDeg;
  errors->camera_offset_deg = fit.camera.log().norm() * kRadToDeg;
  std::vector<SO3> rotated(gt.size());
  for (size_t k = 0; k < gt.size(); ++k) rotated[k] = gt[k] * fit.camera;
  errors->camera_offset_floor_deg =
      rotationRms(rotated, gt, alignRotationOnly(rotated, gt), SO3()) * kRadToDeg;
}

}  // namespace

// Alternating the two rotation-only alignments for a start, then Gauss-Newton on both
// (r_i = log(R_gt_i^-1 A R_est_i X), A <- Exp(a) A, X <- X Exp(x)).
WorldAndCameraRotation alignRotationsWithCameraOffset(const std::vector<SO3>& est,
                                                      const std::vector<SO3>& gt) {
  if (est.size() != gt.size() || est.size() < 2)
    throw std::invalid_argument(
        "alignRotationsWithCameraOffset: needs at least 2 pairs of rotations");
  SO3 A = alignRotationOnly(est, gt), X;
  std::vector<SO3> src(est.size()), dst(est.size());
  for (size_t k = 0; k < gt.size(); ++k) dst[k] = gt[k].inverse();
  constexpr int kRounds = 3;
  for (int round = 0; round < kRounds; ++round) {
    // gt_i^-1 ~= X^-1 (A est_i)^-1, then gt_i ~= A (est_i X).
    for (size_t k = 0; k < est.size(); ++k) src[k] = (A * est[k]).inverse();
    X = alignRotationOnly(src, dst).inverse();
    for (size_t k = 0; k < est.size(); ++k) src[k] = est[k] * X;
    A = alignRotationOnly(src, gt);
  }
  constexpr int kIterations = 10;
  for (int it = 0; it < kIterations; ++it) {
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
    for (size_t k = 0; k < est.size(); ++k) {
      const SO3 M = A * est[k] * X;
      const Vec3 r = (gt[k].inverse() * M).log();
      Eigen::Matrix<double, 3, 6> J;
      J.leftCols<3>() = SO3::rightJacobianInverse(r) * M.matrix().transpose();
      J.rightCols<3>() = SO3::rightJacobianInverse(r);
      H += J.transpose() * J;
      g += J.transpose() * r;
    }
    const Eigen::Matrix<double, 6, 1> step = -H.ldlt().solve(g);
    const SO3 A_try = SO3::exp(step.head<3>()) * A, X_try = X * SO3::exp(step.tail<3>());
    if (!(rotationRms(est, gt, A_try, X_try) < rotationRms(est, gt, A, X))) break;
    A = A_try;
    X = X_try;
  }
  return {A, X};
}

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid), values.end());
  const double upper = values[mid];
  if (values.size() % 2 == 1) return upper;
  const double lower =
      *std::max_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid));
  return 0.5 * (lower + upper);
}

TrajectoryErrors evaluateTrajectory(const Trajectory& estimate, const Trajectory& ground_truth,
                                    const std::string& alignment, double max_dt_s) {
  if (alignment != "se3" && alignment != "sim3" && alignment != "none") {
    throw std::invalid_argument("unknown alignment '" + alignment +
                                "' (expected se3, sim3 or none)");
  }
  const auto pairs = associateByTime(estimate, ground_truth, max_dt_s);
  const size_t needed = alignment == "none" ? 2 : 3;
  if (pairs.size() < needed) {
    throw std::runtime_error(
        "only " + std::to_string(pairs.size()) + " of " + std::to_string(estimate.size()) +
        " estimated poses have a ground-truth pose within " + formatDouble(max_dt_s) + " s (need " +
        std::to_string(needed) + "); check the time stamps and --max-dt");
  }

  TrajectoryErrors errors;
  errors.matched = pairs.size();
  errors.alignment = alignment;

  std::vector<Vec3> est_positions, gt_positions;
  std::vector<SO3> est_rotations, gt_rotations;
  for (const auto& [i, j] : pairs) {
    est_positions.push_back(estimate[i].T_world_cam.translation());
    gt_positions.push_back(ground_truth[j].T_world_cam.translation());
    est_rotations.push_back(estimate[i].T_world_cam.so3());
    gt_rotations.push_back(ground_truth[j].T_world_cam.so3());
  }
  if (alignment != "none") {
    try {
      errors.T_gt_est = alignUmeyama(est_positions, gt_positions, alignment == "sim3");
    } catch (const std::invalid_argument& e) {
      throw std::runtime_error(alignment + " alignment failed: " + e.what());
    }
  }
  errors.scale = errors.T_gt_est.scale();

  // Estimated poses in the ground-truth frame.
  std::vector<SE3> aligned, truth;
  for (const auto& [i, j] : pairs) {
    aligned.push_back(errors.T_gt_est.transformPose(estimate[i].T_world_cam));
    truth.push_back(ground_truth[j].T_world_cam);
  }

  std::vector<double> ate;
  for (size_t k = 0; k < aligned.size(); ++k) {
    ate.push_back((aligned[k].translation() - truth[k].translation()).norm());
  }
  errors.ate_rmse_m = rms(ate);
  double sum = 0;
  for (double e : ate) sum += e;
  errors.ate_mean_m = sum / static_cast<double>(ate.size());
  errors.ate_median_m = median(ate);
  errors.ate_max_m = *std::max_element(ate.begin(), ate.end());

  const SO3 R_gt_est = alignment == "none" ? SO3() : alignRotationOnly(est_rotations, gt_rotations);
  std::vector<double> angles;
  for (size_t k = 0; k < pairs.size(); ++k) {
    angles.push_back((gt_rotations[k].inverse() * R_gt_est * est_rotations[k]).log().norm());
  }
  errors.rot_rmse_deg = rms(angles) * kRadToDeg;
  if (alignment != "none") cameraOffsetFit(est_rotations, gt_rotations, &errors);

  std::vector<double> rpe_trans, rpe_rot;
  for (size_t k = 0; k + 1 < aligned.size(); ++k) {
    const SE3 gt_delta = truth[k].inverse() * truth[k + 1];
    const SE3 est_delta = aligned[k].inverse() * aligned[k + 1];
    const SE3 error = gt_delta.inverse() * est_delta;
    rpe_trans.push_back(error.translation().norm());
    rpe_rot.push_back(error.so3().log().norm());
  }
  errors.rpe_trans_m = rms(rpe_trans);
  errors.rpe_rot_deg = rms(rpe_rot) * kRadToDeg;
  return errors;
}

Trajectory loadTrajectory(const std::string& path, const std::string& format,
                          const std::string& times_path) {
  if (format == "tum") {
    if (!times_path.empty()) {
      throw std::runtime_error(times_path + ": a times file applies to KITTI trajectories only (" +
                               path + " is read as TUM, which has its own stamps)");
    }
    return readTumTrajectory(path);
  }
  if (format != "kitti") {
    throw std::runtime_error(path + ": unknown trajectory format '" + format +
                             "' (expected tum or kitti)");
  }
  Trajectory trajectory = readKittiTrajectory(path);
  if (times_path.empty()) return trajectory;
  const std::vector<NumericRow> times = readNumericRows(times_path, 1, "time stamp in s");
  if (times.size() < trajectory.size()) {
    throw std::runtime_error(times_path + ": " + std::to_string(times.size()) +
                             " time stamps but " + path + " has " +
                             std::to_string(trajectory.size()) + " poses");
  }
  for (size_t i = 0; i < trajectory.size(); ++i) trajectory[i].t = times[i].values[0];
  return trajectory;
}

std::string formatErrorsTable(const TrajectoryErrors& e) {
  std::ostringstream out;
  const auto row = [&out](const std::string& name, const std::string& value) {
    out << "  " << name << std::string(name.size() < 26 ? 26 - name.size() : 1, ' ') << value
        << "\n";
  };
  row("matched poses", std::to_string(e.matched));
  row("alignment", e.alignment);
  row("scale", formatDouble(e.scale));
  row("ATE RMSE [m]", fixed(e.ate_rmse_m, 4));
  row("ATE mean [m]", fixed(e.ate_mean_m, 4));
  row("ATE median [m]", fixed(e.ate_median_m, 4));
  row("ATE max [m]", fixed(e.ate_max_m, 4));
  row("orientation RMSE [deg]", fixed(e.rot_rmse_deg, 3));
  row("  camera frame fitted", fixed(e.rot_rmse_camera_fit_deg, 3) + " (offset " +
                                   fixed(e.camera_offset_deg, 2) + " deg, which alone scores " +
                                   fixed(e.camera_offset_floor_deg, 3) + ")");
  row("RPE trans RMSE [m]", fixed(e.rpe_trans_m, 4));
  row("RPE rot RMSE [deg]", fixed(e.rpe_rot_deg, 3));
  return out.str();
}

std::string errorsToJson(const TrajectoryErrors& e) {
  std::ostringstream out;
  out << "{\n"
      << "  \"ate_rmse_m\": " << formatDouble(e.ate_rmse_m) << ",\n"
      << "  \"ate_mean_m\": " << formatDouble(e.ate_mean_m) << ",\n"
      << "  \"ate_median_m\": " << formatDouble(e.ate_median_m) << ",\n"
      << "  \"ate_max_m\": " << formatDouble(e.ate_max_m) << ",\n"
      << "  \"ate_alignment\": \"" << e.alignment << "\",\n"
      << "  \"rot_rmse_deg\": " << formatDouble(e.rot_rmse_deg) << ",\n"
      << "  \"rot_rmse_camera_fit_deg\": " << formatDouble(e.rot_rmse_camera_fit_deg) << ",\n"
      << "  \"camera_offset_deg\": " << formatDouble(e.camera_offset_deg) << ",\n"
      << "  \"camera_offset_floor_deg\": " << formatDouble(e.camera_offset_floor_deg) << ",\n"
      << "  \"rpe_trans_m\": " << formatDouble(e.rpe_trans_m) << ",\n"
      << "  \"rpe_rot_deg\": " << formatDouble(e.rpe_rot_deg) << ",\n"
      << "  \"matched\": " << e.matched << ",\n"
      << "  \"scale\": " << formatDouble(e.scale) << "\n"
      << "}\n";
  return out.str();
}

void writeErrorsJson(const std::string& path, const TrajectoryErrors& errors) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  out << errorsToJson(errors);
  out.close();
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace radslam
