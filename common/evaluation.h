// Trajectory accuracy against ground truth: absolute trajectory error (ATE)
// after SE(3)/Sim(3) alignment, orientation error after rotation-only
// alignment, and relative pose error (RPE) between consecutive frames.
#pragma once

#include <string>
#include <vector>

#include "common/lie.h"
#include "common/trajectory.h"

namespace radslam {

struct TrajectoryErrors {
  size_t matched = 0;  // estimated poses with a ground-truth pose within max_dt_s
  // ATE: distance between aligned estimated and true camera centres (m).
  double ate_rmse_m = 0, ate_mean_m = 0, ate_median_m = 0, ate_max_m = 0;
  // RMSE of the geodesic angle between estimated and true orientations after
  // the best rotation-only alignment of the orientations (deg); the score of
  // rotation-dominant sequences such as TUM fr1/rpy.
  double rot_rmse_deg = 0;
  // Diagnostic: the same with a constant rotation on the camera side fitted too (R_gt_cam_i ~=
  // R_gt_est R_est_cam_i R_cam_offset): what is left when the ground truth's camera frame is
  // rotated from the images' (a hand-eye calibration error). The offset's angle, and the score
  // rot_rmse_deg gives a perfect estimate taken in that rotated frame (deg).
  double rot_rmse_camera_fit_deg = 0;
  double camera_offset_deg = 0;
  double camera_offset_floor_deg = 0;
  // RMSE of the relative pose error between consecutive matched frames
  // (delta = 1 frame) after alignment: translation (m) and angle (deg).
  double rpe_trans_m = 0, rpe_rot_deg = 0;
  std::string alignment;  // "se3", "sim3" or "none"
  double scale = 1.0;     // scale of T_gt_est (1 unless sim3)
  Sim3 T_gt_est;          // the alignment applied to the estimate
};

/// Matches estimate to ground truth by time stamp (associateByTime, within
/// max_dt_s seconds), aligns the estimate's camera centres to the ground truth's
/// with `alignment` ("se3", "sim3" or "none") and computes the errors. With
/// "none" the orientations are not aligned either: the estimate is taken to be
/// in the ground-truth frame already.
/// Throws std::invalid_argument on an unknown alignment and std::runtime_error
/// when fewer than 3 poses match (2 with "none") or the alignment is degenerate.
TrajectoryErrors evaluateTrajectory(const Trajectory& estimate, const Trajectory& ground_truth,
                                    const std::string& alignment, double max_dt_s = 0.02);

/// Rotations fitted together so that R_gt_i ~= world R_est_i camera (least squares on the
/// geodesic angles): the alignment of the two worlds and a constant rotation on the camera
/// side, by which the ground truth's camera frame is rotated from the images' (a hand-eye
/// calibration error). Needs at least 2 pairs of the same count (std::invalid_argument).
struct WorldAndCameraRotation {
  SO3 world, camera;
};
WorldAndCameraRotation alignRotationsWithCameraOffset(const std::vector<SO3>& est,
                                                      const std::vector<SO3>& gt);

/// Reads a trajectory file in `format` "tum" or "kitti". For KITTI, times_path
/// (optional) is a file of one time stamp (s) per line, e.g. KITTI's times.txt;
/// row i of the trajectory gets stamp i, so a trajectory covering the first N
/// frames of a longer sequence may use the full times file. Without it the
/// stamps are the row indices. Throws std::runtime_error naming the file.
Trajectory loadTrajectory(const std::string& path, const std::string& format,
                          const std::string& times_path = "");

/// Median of the values (mean of the two middle ones for an even count); 0 when empty.
double median(std::vector<double> values);

/// A small aligned text table of the errors, one quantity per line.
std::string formatErrorsTable(const TrajectoryErrors& errors);

/// JSON object with keys ate_rmse_m, ate_mean_m, ate_median_m, ate_max_m,
/// ate_alignment, rot_rmse_deg, rot_rmse_camera_fit_deg, camera_offset_deg,
/// camera_offset_floor_deg, rpe_trans_m, rpe_rot_deg, matched, scale.
std::string errorsToJson(const TrajectoryErrors& errors);

/// Writes errorsToJson to path; throws std::runtime_error naming the file.
void writeErrorsJson(const std::string& path, const TrajectoryErrors& errors);

}  // namespace radslam
