// Motion-only alignment: the pose of a non-keyframe frame against the active window's keyframes,
// whose poses and inverse depths are held fixed ("every frame gets a pose", DESIGN.md section 3).
//
// The front end computes flow keyframe -> frame for one or more keyframes of the window, writes
// target = p + flow and weight = confidence (as for DenseBaEdge), and calls align() with the
// constant-velocity prediction as the initial pose. Residual per grid pixel p of keyframe k:
//   r = target(p) - Pi(T_frame_world T_world_k Pi^-1(p, d_k(p)))         (grid pixels)
// with the same Huber kernel and depth-ratio test as dense BA (tracker/dense_ba.h), and, with a
// measured frame depth (MotionOnlyDepth), BA's depth residual of the same point.
//
// Conventions: T_world_frame is perturbed on the right, T_world_frame * Exp(delta), delta = (v, w);
// the returned covariance is of delta (as PoseStamped::covariance). It is the inverse of the
// Gauss-Newton Hessian at the solution: conditional on the keyframes' poses and depths (their own
// uncertainty is not propagated).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"
#include "tracker/dense_ba.h"

namespace radslam {

struct MotionOnlyEdge {
  int keyframe = 0;  // index into the keyframes given to align()
  /// CV_32FC2, camera grid size: for each grid pixel of the keyframe its location (u, v) in the
  /// frame's grid (pixels). Non-finite entries are ignored.
  cv::Mat target;
  /// kFlowWeightType, camera grid size: information matrices of the targets (as DenseBaEdge).
  cv::Mat weight;
};

/// The frame's measured inverse depth (1/m) and its variance (1/m^2), CV_32FC1, grid size, as
/// DenseBaKeyframe::measured_inv_depth (RGB-D: the sensor's); both empty for none. Every point
/// reprojected into the frame then also has dense BA's depth residual (tracker/dense_ba.h).
struct MotionOnlyDepth {
  cv::Mat inv_depth;
  cv::Mat inv_depth_var;
};

struct MotionOnlyOptions {
  int max_iterations = 10;                            // linear solves (accepted + rejected steps)
  RobustKernel robust_kernel = RobustKernel::kHuber;  // as DenseBaOptions
  double robust_scale = 2.4477;          // whitened px, as DenseBaOptions (<= 0: least squares)
  double min_depth_ratio = 0.2;          // as DenseBaOptions
  double depth_residual_max_jump = 0.1;  // as DenseBaOptions
  /// Levenberg-Marquardt on the 6x6 system: diag += lambda * max(diag, min_lm_diagonal).
  double initial_lambda = 1e-6;
  double lambda_up = 10.0;
  double lambda_down = 0.1;
  double max_lambda = 1e10;
  double min_lm_diagonal = 1e-6;
  double function_tolerance = 1e-12;  // stop when a step lowers the cost by less (relative)
  int min_residuals = 12;             // fewer valid pixels: not enough to trust the pose
};

struct MotionOnlyResult {
  bool ok = false;
  std::string error;
  SE3 T_world_frame;
  Mat6 covariance = Mat6::Zero();  // of delta = (v, w), right perturbation
  int iterations = 0;
  bool converged = false;
  double initial_cost = 0, final_cost = 0;  // sum of robust costs (no factor 1/2)
  double mean_reprojection_error_px = 0;    // over valid weighted pixels at the solution
  int num_residuals = 0;
};

class MotionOnlyAligner {
 public:
  explicit MotionOnlyAligner(const MotionOnlyOptions& options = {}) : options_(options) {}
  const MotionOnlyOptions& options() const { return options_; }

  /// Estimates T_world_frame from T_world_frame_init. Throws std::invalid_argument on malformed
  /// input (naming the edge and what is wrong); too few valid pixels or a degenerate Hessian give
  /// ok = false with the initial pose returned.
  MotionOnlyResult align(const CameraModel& camera, const std::vector<DenseBaKeyframe>& keyframes,
                         const std::vector<MotionOnlyEdge>& edges, const SE3& T_world_frame_init,
                         const MotionOnlyDepth& frame_depth = {}) const;

  /// Robust cost at T_world_frame with the Gauss-Newton Hessian H = sum J^T W J and gradient
  /// g = sum J^T W r (J = dr/d delta, W including the IRLS weights), so d cost / d delta = 2 g.
  double linearize(const CameraModel& camera, const std::vector<DenseBaKeyframe>& keyframes,
                   const std::vector<MotionOnlyEdge>& edges, const SE3& T_world_frame, Mat6* H,
                   Vec6* g, int* num_residuals = nullptr, double* mean_error_px = nullptr,
                   const MotionOnlyDepth& frame_depth = {}) const;

 private:
  // linearize() with the frame's measured depth as dense_ba::depthSamples gives it (empty: none),
  // converted once per align().
  double linearizeSamples(const CameraModel& camera, const std::vector<DenseBaKeyframe>& keyframes,
                          const std::vector<MotionOnlyEdge>& edges, const SE3& T_world_frame,
                          const std::vector<double>& measured,
                          const std::vector<double>& measured_var, Mat6* H, Vec6* g,
                          int* num_residuals = nullptr, double* mean_error_px = nullptr) const;

  MotionOnlyOptions options_;
};

}  // namespace radslam
