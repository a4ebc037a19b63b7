// Dense correspondences for dense BA: OpenCV DIS optical flow at working resolution, warm-started
// from the flow the current estimate predicts, reduced to the BA grid with a per-pixel
// confidence (the edge weight). DROID-SLAM's ConvGRU replaced by classical flow (DESIGN.md 3).
//
/// Confidence model. For grid pixel p (a c x c cell of working pixels, c = 8) the flow target
/// is the mean flow over the cell. Its 2 x 2 covariance, in grid px^2, is
///
///   Sigma = sigma0^2 I                    noise floor of a well-textured, consistent cell
///         + 2 fb_gain M                   M: mean over the cell of e e^T, e = f_ab(x) +
///                                         f_ba(x + f_ab(x)) the forward-backward error, grid
///                                         px (an isotropic error adds fb_gain |e|^2 to each
///                                         component; a flow that slides along a stripe errs
///                                         along it only)
///         + (e_ph / photo_scale)^2 I      e_ph: RMS over the cell of the photometric residual
///                                         I_a(x) - I_b(x + f_ab(x)) minus its cell mean (robust
///                                         to exposure changes), grey levels
///         + grad_gain J^-1                J = mean(g g^T) + grad_floor I, the cell's structure
///                                         tensor, (grey/working px)^2: Lucas-Kanade's flow
///                                         covariance is proportional to J^-1, so flow along a
///                                         stripe (aperture problem), at any angle, gets no
///                                         weight and flow across it keeps its weight
///
/// The statistics use every other pixel of every other row of the cell (16 of 64 for c = 8: a
/// quarter of the cost and plenty for a cell statistic); the target uses all pixels. The
/// weight is the information matrix Sigma^-1 (kFlowWeightType, tracker/dense_ba.h); it is 0
/// (a failure) when e_fb = sqrt(tr M) > fb_max_px, e_ph > photo_max, fewer than half of the
/// cell's pixels land inside b, the target leaves b or the flow is not finite. The terms add
/// as independent error sources; the constants and their calibration are documented at
/// FlowOptions.
#pragma once

#include <string>
#include <utility>

#include <opencv2/core.hpp>
#include <opencv2/video/tracking.hpp>

#include "tracker/frontend.h"

namespace radslam {

struct FlowOptions {
  /// DIS preset: "ultrafast", "fast" or "medium".
  std::string preset = "fast";
  /// Finest pyramid level DIS estimates (0 = working resolution); the BA grid is 1/8 of it, so
  /// level 2 (1/4) is already finer than the grid.
  int finest_scale = 2;
  /// Variational refinement iterations per level (the presets use 5). None are needed once the
  /// flow is averaged over 8x8 cells: on the synthetic room the grid error is the same with 0
  /// or 1, and 0 saves 40% of the flow time.
  int variational_iterations = 0;
  int patch_size = 8;    // px at each level (the preset's default is 8)
  int patch_stride = 4;  // px (preset default 4 for fast, 3 for medium)
  bool spatial_propagation = true;
  /// Gaussian sigma (working px) the initial flow is smoothed with before it warps b
  /// (WarmStart::kWarp): a prediction from noisy per-pixel depths would warp b into a jagged
  /// image DIS cannot undo; a smooth warp leaves DIS a smooth residual (measured on the
  /// synthetic street with depths 30 % off per pixel: near-ground median error 0.11 grid px
  /// smoothed, 0.65 unsmoothed).
  double warp_smoothing_px = 12.0;
  // Confidence constants (see the model above), calibrated on the synthetic room (image noise
  // 2 grey levels, frame gaps 2 to 6, flow warm-started 0.3 px off the truth): per component,
  // the mean squared error is about 0.003 + 1.0 e_fb^2 over the deciles of e_fb, and grows
  // with [J^-1]_kk about 0.2 px^2 per unit over its informative range; the photometric
  // residual barely predicts the error there (it matters for occlusions and specularities of
  // real images), so its scale is large and it acts mostly through photo_max.
  double sigma0_px = 0.05;     // grid px
  double fb_gain = 1.0;        // dimensionless
  double fb_max_px = 0.75;     // grid px
  double photo_scale = 100.0;  // grey levels per grid px of standard deviation
  double photo_max = 40.0;     // grey levels
  double grad_gain = 0.2;      // (grey levels / working px)^2 x grid px^2
  double grad_floor = 1.0;     // (grey levels / working px)^2, regularises J
};

/// How a predicted flow warm-starts DIS.
enum class WarmStart {
  /// DIS starts from it at its coarsest level, where it is downsampled: robust to a wrong
  /// prediction (DIS re-estimates the flow), but flow that varies fast across the image (near
  /// ground under forward motion) is re-estimated with DIS's shrinking bias.
  kCoarse,
  /// b is warped by it and DIS measures the residual from zero, composed with it: accurate
  /// where the prediction is close (after BA), but a wrong prediction that leaves little
  /// residual texture to disagree with can be confirmed rather than corrected.
  kWarp,
};

/// Flow from one image to another with DIS. Each flow gets a DIS instance of its own: one
/// instance reused carries state from one call to the next (OpenCV 4.6; the same image pair
/// gave a different flow after other pairs), and a flow must depend on its inputs alone so
/// that a tracker resumed from a checkpoint continues exactly.
class DenseFlow {
 public:
  /// Throws std::invalid_argument on an unknown preset or out-of-range option.
  explicit DenseFlow(const FlowOptions& options);
  const FlowOptions& options() const { return options_; }

  /// Flow a -> b (CV_32FC2, a's size, working px: x in a matches x + flow(x) in b). `init`,
  /// when not empty (CV_32FC2, a's size), is the predicted flow that warm-starts DIS.
  cv::Mat compute(const cv::Mat& grey_a, const cv::Mat& grey_b, const cv::Mat& init = {},
                  WarmStart warm_start = WarmStart::kCoarse);

 private:
  cv::Ptr<cv::DISOpticalFlow> makeDis() const;

  FlowOptions options_;
};

/// x + flow(x) per pixel (CV_32FC2), the map cv::remap takes; a non-finite flow maps far
/// outside the image (remap then gives the border value). flow: CV_32FC2, the part of a field
/// whose top-left pixel is at `origin`.
cv::Mat flowTargetMap(const cv::Mat& flow, cv::Point origin = {});

/// The grey images a and b for DIS with their moving pixels painted over by the static scene:
/// b's take a's grey where the static backward flow flow_ba sends them, then a's take that
/// painted b's grey where the static forward flow flow_ab sends them. An object then moves with
/// the static scene as far as DIS can tell; left in, its motion spreads over the static pixels
/// around it through DIS's patches, up to a patch at its coarsest level. Only DIS sees the
/// painted images: the moving pixels stay out of every correspondence. Returns a and b
/// themselves when neither has a mask or a flow is empty. grey: CV_8UC1; moving: CV_8UC1 (255 =
/// moving) or empty; flows: CV_32FC2 (working px), all of one size.
std::pair<cv::Mat, cv::Mat> paintOutMoving(const cv::Mat& grey_a, const cv::Mat& moving_a,
                                           const cv::Mat& grey_b, const cv::Mat& moving_b,
                                           const cv::Mat& flow_ab, const cv::Mat& flow_ba);

/// Gaussian blur (sigma_px, reflected border) of a smooth field such as a predicted flow, at a
/// fraction of cv::GaussianBlur's cost for a wide sigma: the field is padded, averaged over k x k
/// blocks (k up to 4, about sigma / 3), blurred there and upsampled bilinearly, with the blocks'
/// and the interpolation's own spread taken off the sigma. Off cv::GaussianBlur by under 0.02 px
/// for sigma 12 on a predicted flow with 4 px of noise per grid cell, about 10x faster
/// (384 x 288, CV_32FC2). Any type cv::GaussianBlur takes; sigma_px > 0.
cv::Mat wideGaussianBlur(const cv::Mat& field, double sigma_px);

/// Working-resolution flow predicted by grid targets (CV_32FC2 grid, location in b's grid;
/// NaN where there is no prediction): flow = cell * (target - p), non-finite entries replaced
/// by the median of the finite ones (0 if none), upsampled bilinearly (pixel-centre convention
/// of frontend.h). Returns an empty matrix when targets is empty.
cv::Mat predictedFlow(const cv::Mat& grid_targets, const GridGeometry& geometry);

/// Per-edge result: what DenseBaEdge needs, plus figures.
struct Correspondences {
  cv::Mat target;             // CV_32FC2 grid size: location in b's grid (grid px)
  cv::Mat weight;             // kFlowWeightType grid size: Sigma^-1 (1/grid px^2) of (u, v)
  double valid_fraction = 0;  // pixels with weight > 0
  double median_fb_px = 0;    // median over valid cells of e_fb (grid px)
  // CV_8UC1 grid, 255 where the refinement's start check dropped a cell the flow found
  // (RefineOptions::start_check_px); empty when the check is off.
  cv::Mat leaning;
};

/// Grid correspondences a -> b from the forward flow (a -> b) and, when not empty, the
/// backward flow (b -> a) for the forward-backward term (without it e_fb = 0). Images are
/// CV_8UC1 working size.
Correspondences flowToCorrespondences(const cv::Mat& grey_a, const cv::Mat& grey_b,
                                      const cv::Mat& flow_ab, const cv::Mat& flow_ba,
                                      const GridGeometry& geometry, const FlowOptions& options);

/// Structure tensor J = mean(g g^T) of each grid cell, (grey/working px)^2, as CV_32FC3
/// (Jxx, Jxy, Jyy) of grid size, from imageGradients() (tracker/frontend_refine.h). Pixels of
/// `moving` (CV_8UC1 working size, non-zero = moving; empty = none) add nothing: a cell's flow
/// is its static pixels', and a moving object's texture says nothing of it. Depends on the
/// image and the mask only (cache it per keyframe).
cv::Mat cellStructureTensor(const cv::Mat& gradients, int cell, const cv::Mat& moving = {});

/// As flowToCorrespondences with the structure tensor of a precomputed, and optional masks of
/// moving objects (CV_8UC1 working size, non-zero = moving; empty = none) that keep them out
/// of camera tracking: a's moving pixels are left out of each cell's flow and statistics (a
/// cell needs half of its pixels static), and a pixel whose match lands on a moving pixel of b
/// counts as unmatched.
Correspondences flowToCorrespondences(const cv::Mat& grey_a, const cv::Mat& grey_b,
                                      const cv::Mat& flow_ab, const cv::Mat& flow_ba,
                                      const cv::Mat& structure_a, const GridGeometry& geometry,
                                      const FlowOptions& options, const cv::Mat& moving_a = {},
                                      const cv::Mat& moving_b = {});

}  // namespace radslam
