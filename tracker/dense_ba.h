// Dense bundle adjustment over keyframe poses and per-pixel inverse depths (DROID-SLAM's BA, as
// used by NeRF-SLAM) with exact marginal covariances. DESIGN.md section 3.
//
// How the front end uses it
// -------------------------
// The front end owns a DenseBaProblem: the active window's keyframes (pose + inverse depth at BA
// grid resolution, e.g. 80x60 for 640x480 input) and the flow edges between them. Each round it
//  1. computes dense flow i -> j for every edge (warm-started from reprojectKeyframe(), which gives
//     the correspondence field predicted by the current estimate), writes target = p + flow and
//     weight = confidence into the edge;
//  2. calls DenseBundleAdjuster::optimize(&problem) for a few iterations (poses and inverse depths
//     are refined in place);
//  3. repeats 1-2 two or three times per new keyframe, then calls computeMarginals() for the
//     covariances it publishes on KEYFRAME / POSE.
// Keyframes leaving the window are simply erased from the vector (and their edges removed);
// older keyframes kept as anchors are flagged fixed_pose. Non-keyframes get their pose from
// MotionOnlyAligner (tracker/motion_only.h) against the same DenseBaKeyframe structs.
//
// Conventions
// -----------
//  - T_world_cam maps camera points to world. Poses are perturbed on the right,
//    T_world_cam <- T_world_cam * Exp(delta), delta = (v, w) (translation first), so
//    pose covariances have the meaning of PoseStamped::covariance.
//  - Pixel coordinates: (u, v) = (column, row) of the BA grid, pixel centres at integers.
//  - Residual of edge (i, j) at grid pixel p of keyframe i with inverse depth d:
//      r = target(p) - Pi(T_j_world T_world_i Pi^-1(p, d))            (pixels, grid of j)
//    whitened by weight(p) = W, the 2 x 2 information matrix of target(p) (flow confidence,
//    with the aperture problem's direction), and passed through a robust kernel on
//    s = sqrt(r^T W r). Cost = sum of rho(s^2) (rho(s^2) = s^2 for inliers, no factor 1/2)
//    + sum over priors of (d - mu)^2 / var
//    + per keyframe with a level prior, (mean over its prior pixels of (mu - d))^2 / level_var
//    + per edge (i, j) into a keyframe j with a measured inverse depth m_j, per point used above,
//      rho(r_z^2 / var) with r_z = m_j(pixel) - d_j: the measurement interpolated where the point
//      lands against the point's own inverse depth d_j = d / z_j-ratio in camera j (RGB-D
//      odometry's geometric term), m_j from a plane fitted to the 3 x 3 samples around the
//      landing, var the largest of their variances times the measurement's number of uses
//      (dense_ba::sampleDepth; points landing at a depth edge have none).
//  - Points whose depth ratio z_j / z_i falls below min_depth_ratio are dropped for that
//    linearisation (see dense_ba::reproject in tracker/dense_ba_kernel.h).
//  - Normal equations [C E; E^T P][dxi; dd] = [v; w] with P per keyframe diagonal (plus a rank-one
//    term for a level prior, inverted by Sherman-Morrison); the poses are solved from the Schur
//    complement H_T = C - E P^-1 E^T (ReducedCameraSolver), then dd = P^-1 (w - E^T dxi).
#pragma once

#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"
#include "tracker/reduced_camera_solver.h"

namespace radslam {

using Mat26 = Eigen::Matrix<double, 2, 6>;

/// Pixel type of flow weight images: the information matrix W = Sigma^-1 (1/px^2) of a target
/// (u, v), as (W_uu, W_uv, W_vv). An edge along u constrains only v: W then has a large W_vv,
/// and at any angle one large eigenvalue across it.
constexpr int kFlowWeightType = CV_32FC3;

/// The information matrix of a weight pixel, or false when it carries none: non-finite
/// entries, a negative diagonal or a zero one on both axes. The cross term is clamped so that
/// W stays positive semi-definite.
inline bool flowInformation(const cv::Vec3f& w, double* uu, double* uv, double* vv) {
  if (!(std::isfinite(w[0]) && std::isfinite(w[1]) && std::isfinite(w[2]) && w[0] >= 0 &&
        w[2] >= 0 && (w[0] > 0 || w[2] > 0))) {
    return false;
  }
  *uu = w[0];
  *vv = w[2];
  *uv = w[1];
  if (*uv * *uv > *uu * *vv) *uv = std::copysign(std::sqrt(*uu * *vv), *uv);
  return true;
}

struct DenseBaKeyframe {
  SE3 T_world_cam;
  /// CV_32FC1, camera grid size, 1/m (monocular: 1/scene unit). Refined in place.
  cv::Mat inv_depth;
  /// Not a variable (window anchors). The gauge option may fix further keyframes.
  bool fixed_pose = false;
  /// Optional inverse-depth prior (RGB-D): mean (1/m) and variance (1/m^2), CV_32FC1, grid size,
  /// both empty for none. Pixels with a non-finite mean or a variance that is not > 0 and finite
  /// have no prior. From sensor depth z with std sigma_z: mean 1/z, var = sigma_z^2 / z^4.
  cv::Mat prior_inv_depth;
  cv::Mat prior_inv_depth_var;
  /// Optional prior on the keyframe's level (1/m^2; 0 = none): variance of the mean of
  /// (prior_inv_depth - inv_depth) over the pixels with a prior. It holds the level harder
  /// than a weak per-pixel prior does without flattening the shape (monocular: the scale,
  /// tracker/tracker.h mono_level_rel_sigma).
  double prior_level_var = 0;
  /// Optional measured inverse depth of this keyframe's view (RGB-D: the sensor, 1/m) and its
  /// variance (1/m^2), CV_32FC1, grid size, both empty for none; pixels without a measurement
  /// as for the prior. Every edge into this keyframe then also has a depth residual per point
  /// (see the cost above): the flow fixes where the points land, this how far they are. The
  /// residuals of all edges into the keyframe and its prior (RGB-D: the same sensor data) use
  /// one measurement, whose noise they share: each residual's variance is multiplied by the
  /// number of those uses, so that together they count it about once.
  cv::Mat measured_inv_depth;
  cv::Mat measured_inv_depth_var;
};

/// Correspondences from keyframe i to keyframe j (or to i's own rigidly attached second camera).
struct DenseBaEdge {
  int i = 0;  // source keyframe: owns the inverse depths
  int j = 0;  // target keyframe; ignored when T_i_other is set
  /// CV_32FC2, camera grid size: for each grid pixel p of keyframe i, its location (u, v) in the
  /// target camera's grid (pixels). Non-finite entries are ignored.
  cv::Mat target;
  /// kFlowWeightType, camera grid size: the information matrix of each target (flow
  /// confidence); pixels for which flowInformation() is false are not used.
  cv::Mat weight;
  /// Fixed-relative-pose edge (stereo): the target camera is rigidly attached to keyframe i at
  /// T_i_other (e.g. T_left_right, baseline along +x) with the same intrinsics (rectified). Its
  /// residual depends only on the inverse depths (the pose Jacobians cancel) and fixes scale.
  std::optional<SE3> T_i_other;
};

struct DenseBaProblem {
  /// Pinhole camera at BA grid resolution (no distortion: the front end undistorts), shared by
  /// all keyframes.
  CameraModel camera;
  std::vector<DenseBaKeyframe> keyframes;
  std::vector<DenseBaEdge> edges;
};

/// Which poses are held fixed on top of the keyframes flagged fixed_pose ("first" = index 0 of
/// DenseBaProblem::keyframes, "second" = index 1).
enum class DenseBaGauge {
  kFlaggedOnly,       // only DenseBaKeyframe::fixed_pose
  kFirstPose,         // + keyframe 0 (RGB-D, stereo: the data fixes the scale)
  kFirstTwoPoses,     // + keyframes 0 and 1 (monocular: two fixed poses also fix the scale)
  kFirstPoseAndScale  // + keyframe 0 and the distance between the camera centres of 0 and 1
                      //   (monocular; keyframe 1 keeps 5 dof: rotation and baseline direction)
};

/// Robust kernels of the reprojection residuals (tracker/dense_ba_kernel.h).
enum class RobustKernel { kHuber, kCauchy };

/// "huber" or "cauchy"; throws std::invalid_argument otherwise.
RobustKernel parseRobustKernel(const std::string& name);

struct DenseBaOptions {
  /// Default kFirstTwoPoses (monocular, the simplest complete gauge). Use kFirstPose with RGB-D
  /// priors or stereo edges, kFirstPoseAndScale to let the second keyframe rotate and move on
  /// the sphere of its baseline.
  DenseBaGauge gauge = DenseBaGauge::kFirstTwoPoses;
  /// Maximum linear solves (accepted + rejected Levenberg-Marquardt steps) per optimize().
  int max_iterations = 10;
  /// Robust kernel on the whitened residual norm s (dense_ba_kernel.h) and its scale (<= 0:
  /// plain least squares). Scale sqrt(chi2_2(0.95)) = 2.4477: with correct weights 95% of
  /// inlier pixels keep (nearly) full weight (a 2-d whitened residual has s^2 ~ chi2(2)), so
  /// the kernel costs little efficiency and only gross flow errors are down-weighted.
  RobustKernel robust_kernel = RobustKernel::kHuber;
  double robust_scale = 2.4477;
  /// Points with z_j / z_i below this are dropped (DROID-SLAM's MIN_DEPTH = 0.2 on the same
  /// homogeneous z).
  double min_depth_ratio = 0.2;
  /// Depth residuals skip points whose nine nearest measurements spread by more than this
  /// fraction of the largest (a depth edge among them, or a slant too steep for the grid).
  double depth_residual_max_jump = 0.1;
  /// Inverse depths are clamped to this range at the start and after every step (1/m; a
  /// non-finite start value becomes min_inv_depth).
  double min_inv_depth = 1e-3;
  double max_inv_depth = 1e2;
  /// Levenberg-Marquardt (Marquardt's scaled damping): diag(C) += lambda * max(diag(C),
  /// min_lm_diagonal) on the poses (floored as in Ceres), P *= 1 + lambda on the inverse depths
  /// (which keeps the Schur term of a linearisation valid for every lambda); lambda *= lambda_up
  /// on a step that does not decrease the cost, *= lambda_down on one that does.
  double initial_lambda = 1e-4;
  double lambda_up = 10.0;
  double lambda_down = 0.1;
  double min_lambda = 1e-12;
  double max_lambda = 1e10;
  double min_lm_diagonal = 1e-6;
  /// Stop when an accepted step lowers the cost by less than this fraction, or when a step is
  /// below step_tolerance (pose: max |delta| in m / rad; inverse depth: max |dd| / d).
  double function_tolerance = 1e-12;
  double step_tolerance = 1e-10;
  ReducedCameraSolverOptions solver;
  /// How computeMarginals() gets e^T H_T^-1 e: from the blocks of H_T^-1 (fast) or as
  /// ||L^-1 P e||^2 by triangular solves (same value; kept to cross-check).
  enum class DepthMarginal { kInverseBlocks, kHalfSolve };
  DepthMarginal depth_marginal = DepthMarginal::kInverseBlocks;
};

/// What optimize() reports (also for STATUS).
struct DenseBaSummary {
  bool ok = false;
  std::string error;   // why !ok (e.g. the reduced system never became positive definite)
  int iterations = 0;  // linear solves
  int accepted_steps = 0;
  bool converged = false;
  double initial_cost = 0;  // see the cost definition above
  double final_cost = 0;
  double final_lambda = 0;
  int num_residuals = 0;  // valid (pixel, edge) pairs at the last evaluation
  /// Per keyframe: mean ||r|| (grid pixels) over its outgoing edges' valid weighted pixels at the
  /// final state; 0 when it has none.
  std::vector<double> mean_reprojection_error_px;
  bool used_cholmod = false;
  double linearize_ms = 0, solve_ms = 0, total_ms = 0;  // wall time spent
};

/// Marginal covariances at the current state, from the undamped Hessian (IRLS weights of the
/// robust kernel at that state). Exact for the linearised problem:
///   Sigma_T = H_T^-1, Sigma_d(p) = 1/P_p + e_p^T H_T^-1 e_p / P_p^2 (= diagonal of the full
///   inverse), with e_p the column of E of pixel p.
struct DenseBaMarginals {
  bool ok = false;
  std::string error;
  /// Per keyframe: 6x6 covariance of delta = (v, w) (right perturbation of T_world_cam), zero
  /// for fixed poses (and rank 5 for the second keyframe under kFirstPoseAndScale).
  std::vector<Mat6> pose_covariance;
  /// Per keyframe, CV_32FC1 grid size: inverse-depth variance (1/m^2); +infinity at pixels
  /// without any information (no valid residual and no prior).
  std::vector<cv::Mat> inv_depth_var;
  /// Per keyframe, CV_32FC1: depth variance by first-order propagation var(d) / d^4 (m^2).
  std::vector<cv::Mat> depth_var;
};

/// A linearised Levenberg-Marquardt step (for tests and custom loops). Per keyframe.
struct DenseBaStep {
  std::vector<Vec6> dxi;           // pose step delta (v, w); zero for fixed poses
  std::vector<cv::Mat> dd;         // CV_64FC1 inverse-depth step; 0 where a pixel is not a variable
  std::vector<Vec6> pose_rhs;      // v = -sum J_pose^T W r per keyframe (before the gauge)
  std::vector<cv::Mat> depth_rhs;  // CV_64FC1, w = -sum J_d^T W r (+ prior)
  std::vector<cv::Mat> depth_hessian;  // CV_64FC1, P (undamped)
  double cost = 0;
};

/// The residual of one pixel of edge (i, j) with Jacobians wrt right perturbations of T_world_i
/// and T_world_j (2x6, (v, w)) and wrt the inverse depth d. Returns false when the point is
/// dropped (depth ratio below min_depth_ratio). For the reference and the tests; the optimiser's
/// inner loops use the same kernel (dense_ba::reproject).
bool denseBaResidual(const CameraModel& camera, const SE3& T_world_i, const SE3& T_world_j,
                     double u, double v, double d, const Eigen::Vector2d& target,
                     double min_depth_ratio, Eigen::Vector2d* r, Mat26* H_i = nullptr,
                     Mat26* H_j = nullptr, Eigen::Vector2d* H_d = nullptr);

/// The depth residual of one pixel of edge (i, j) into a keyframe with a measured inverse depth
/// (CV_32FC1 mean and variance, grid size), with the sample's weight 1 / var (which BA divides
/// among the measurement's uses, see DenseBaKeyframe::measured_inv_depth) and Jacobians of
/// r wrt right perturbations of T_world_i, T_world_j and wrt d. False when the point is dropped
/// or lands where the measurement gives none (dense_ba::sampleDepth). For the reference and the
/// tests, as denseBaResidual.
bool denseBaDepthResidual(const CameraModel& camera, const SE3& T_world_i, const SE3& T_world_j,
                          double u, double v, double d, const cv::Mat& measured_inv_depth,
                          const cv::Mat& measured_inv_depth_var, double min_depth_ratio,
                          double max_jump, double* r, double* weight,
                          Eigen::Matrix<double, 1, 6>* H_i = nullptr,
                          Eigen::Matrix<double, 1, 6>* H_j = nullptr, double* H_d = nullptr);

/// The correspondence field predicted by the current estimate: for each grid pixel of keyframe
/// i, its projection into camera T_world_j (CV_32FC2; NaN where dropped). The front end uses
/// it to warm-start flow (flow = prediction - pixel grid).
cv::Mat reprojectKeyframe(const CameraModel& camera, const DenseBaKeyframe& keyframe,
                          const SE3& T_world_j, double min_depth_ratio = 0.2);

/// Throws std::invalid_argument naming the keyframe / edge and what is wrong (sizes, types,
/// indices, camera). Called by every DenseBundleAdjuster entry point.
void validateDenseBaProblem(const DenseBaProblem& problem);

/// Dense BA solver with reusable workspace. One instance per thread (not thread-safe).
class DenseBundleAdjuster {
 public:
  explicit DenseBundleAdjuster(const DenseBaOptions& options = {});
  ~DenseBundleAdjuster();
  DenseBundleAdjuster(const DenseBundleAdjuster&) = delete;
  DenseBundleAdjuster& operator=(const DenseBundleAdjuster&) = delete;

  const DenseBaOptions& options() const { return options_; }
  void setOptions(const DenseBaOptions& options) { options_ = options; }

  /// Runs Levenberg-Marquardt from the problem's current poses and inverse depths and writes the
  /// result back into problem->keyframes. Throws std::invalid_argument on malformed input; a
  /// numerical failure gives summary.ok = false with the state left at the best point found.
  DenseBaSummary optimize(DenseBaProblem* problem);

  /// Marginal covariances at the problem's current state (call after optimize()). ok = false
  /// when a free pose is unobservable (H_T singular, e.g. a keyframe without valid residuals or
  /// an unfixed monocular gauge).
  DenseBaMarginals computeMarginals(const DenseBaProblem& problem);

  /// Sum of robust costs at the current state (see the cost definition above).
  double evaluateCost(const DenseBaProblem& problem);

  /// One damped Gauss-Newton step at the current state without applying it. Returns false (with
  /// *error) when the damped reduced system is not positive definite (the right-hand sides and
  /// the depth Hessian are filled in either case).
  bool computeStep(const DenseBaProblem& problem, double lambda, DenseBaStep* step,
                   std::string* error = nullptr);

 private:
  class System;
  DenseBaOptions options_;
  std::unique_ptr<System> system_;  // workspace reused across calls
};

}  // namespace radslam
