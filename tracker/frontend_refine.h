// Sub-pixel refinement of BA-grid correspondences: translational inverse-compositional
// Lucas-Kanade on each grid cell, started from the DIS target.
//
/// Why: DIS averages overlapping patch displacements weighted by their matching error, which
/// shrinks flow where it varies across the image (measured on the synthetic room: divergent
/// flow of forward motion comes out ~25% short, lateral flow 2-3% short), and that bias
/// becomes a trajectory scale and rotation error. Lucas-Kanade on the cell's own pixels
/// estimates the cell's displacement without that averaging and costs about a DIS call at
/// 512x384. A translation is the flow at the cell's gradient-weighted point; where the flow
/// changes across the cell, affine_iterations move it to the cell centre.
///
/// Model per cell (c x c working pixels x of image a, displacement d of the cell, brightness
/// offset o): minimise sum_x (I_b(x + d) - I_a(x) - o)^2. Inverse compositional: the Hessian
/// H = sum [g; 1][g; 1]^T uses a's gradients g only, so it is built once per cell, and each
/// iteration warps b, solves H [delta; o] = sum [g; 1] r and updates d <- d - delta.
#pragma once

#include <opencv2/core.hpp>

namespace radslam {

struct RefineOptions {
  int iterations = 4;             // per cell
  double max_shift_px = 4.0;      // working px: a cell moving further from its DIS start keeps it
  double min_det = 1e-3;          // (grey^2/px^2)^2 x pixels^2: cells with a singular H are skipped
  double converged_px = 0.01;     // working px: stop when the update is smaller
  int margin = 0;                 // working px added around the cell on each side
  bool brightness_offset = true;  // estimate a per-cell brightness offset
  bool reject_failures = true;    // a cell that cannot be refined gets weight 0
  // Then affine Lucas-Kanade iterations (0 = none): displacement, its gradient across the
  // window and the offset, with the displacement at the window centre, where BA puts it (a
  // translation measured the forward flow of a road ahead short). 4 iterations take about
  // 3.4x the time of the whole translation on a 512x384 street pair (docs/tracker.md).
  int affine_iterations = 0;
  // Start check (0 = off): the translation is run again from start_check_px further along the
  // cell's start flow (start_check_iterations iterations); a cell whose two runs end more than
  // start_check_tolerance_px apart leans on where it starts and fails. DIS's flow is short
  // where it varies, and such a cell keeps part of that shortfall (docs/tracker.md, step 2).
  double start_check_px = 0;              // working px
  double start_check_tolerance_px = 0.3;  // working px
  int start_check_iterations = 8;
};

/// Gradients of a grey image for refinement: Sobel / 8 (grey levels per px), CV_32FC2 (gx, gy).
cv::Mat imageGradients(const cv::Mat& grey);

/// Refines target (CV_32FC2 grid: location of each cell of a in b's grid) in place for the cells
/// with a finite target and a positive weight. A cell whose window leaves a or b, whose H is
/// singular or which moves more than max_shift_px keeps its target and, with reject_failures,
/// gets weight 0 (its correspondence is not reliable). grey_a, grey_b: CV_8UC1 of one size,
/// cell x the grid size; gradients_a from imageGradients(grey_a). Returns the cells refined.
/// moving_a (CV_8UC1 of a's size, non-zero = moving object; empty = none): pixels left out of
/// the cells' windows. A cell that fails the start check gets its refined target and weight 0,
/// and 255 in `leaning` (CV_8UC1 grid) when given.
int refineTargets(const cv::Mat& grey_a, const cv::Mat& gradients_a, const cv::Mat& grey_b,
                  int cell, const RefineOptions& options, cv::Mat* target, cv::Mat* weight,
                  const cv::Mat& moving_a = {}, cv::Mat* leaning = nullptr);

}  // namespace radslam
