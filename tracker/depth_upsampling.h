// Edge-aware upsampling of a keyframe's BA-grid inverse depth and its variance to the working
// (output) resolution: joint bilateral upsampling (Kopf et al. 2007) guided by the grey image.
//
/// Each output pixel x takes a weighted mean of the 2x2 grid pixels k around it (the support of
/// bilinear interpolation):
///   w_k = b_k(x) * exp(-(I(x) - I_k)^2 / (2 sigma_range^2)),
/// with b_k(x) the bilinear weight of k at g(x) = (x - (c - 1) / 2) / c, the position of x on
/// the grid (pixel-centre convention of tracker/frontend.h), I(x) the guide at x and I_k the
/// guide's mean over cell k. Grid pixels without information (non-finite or non-positive
/// variance, non-finite value) get no weight. Where every range weight vanishes (x unlike all
/// four cells) the bilinear weights alone are used. A 2x2 support costs a quarter of the usual
/// 4x4 and keeps edges: a pixel next to an edge has a cell of its own side among the four.
/// With normalised weights a_k = w_k / sum w:
///   d(x) = sum a_k d_k,   var(x) = sum a_k var_k.
/// The variance is an approximation: for the weighted mean of correlated estimates,
/// Var(sum a_k d_k) = a^T Sigma a <= (sum a_k sigma_k)^2 <= sum a_k sigma_k^2 (Cauchy-Schwarz,
/// then Jensen), so var(x) upper-bounds the variance of the interpolated value whatever the
/// correlations between neighbouring pixels (BA marginals are strongly correlated, which makes
/// the independent-pixel rule sum a_k^2 var_k far too optimistic). It does not include the
/// interpolation error itself (the surface between grid samples is unknown).
/// Depth and its variance follow per pixel by first-order propagation: z = 1 / d,
/// var(z) = var(d) / d^4. Pixels without any informed neighbour get d = 0, z = 0 (unknown) and
/// infinite variances.
#pragma once

#include <opencv2/core.hpp>

namespace radslam {

struct DepthUpsamplingOptions {
  double sigma_range = 12.0;  // grey levels
};

struct UpsampledDepth {
  cv::Mat inv_depth;      // CV_32FC1 output size, 1/m (0 = unknown)
  cv::Mat inv_depth_var;  // CV_32FC1, 1/m^2 (+inf = unknown)
  cv::Mat depth;          // CV_32FC1, m (0 = unknown)
  cv::Mat depth_var;      // CV_32FC1, m^2 (+inf = unknown)
};

/// grid_inv_depth, grid_inv_depth_var: CV_32FC1, grid size. guide: CV_8UC1 of size
/// cell x the grid size. Throws std::invalid_argument on mismatched sizes or types.
UpsampledDepth upsampleDepth(const cv::Mat& grid_inv_depth, const cv::Mat& grid_inv_depth_var,
                             const cv::Mat& guide, int cell,
                             const DepthUpsamplingOptions& options = {});

/// RGB-D: the sensor's own resolution put back into an upsampled BA estimate. The BA grid
/// blurs every depth edge over a cell; the sensor measured each pixel. Where sensor_inv_depth
/// (CV_32FC1 output size, 1/m; NaN = none) is known, the output inverse depth is that value plus
/// `correction` (CV_32FC1 output size, 1/m): BA's correction of the sensor, its grid estimate
/// minus the sensor's where the sensor measured the cell, upsampled like the estimate (smooth,
/// keeps edges; 0 where unknown). Its variance is the estimate's plus sensor_inv_depth_var (the
/// pixel's own noise, which the cell averaged away). Elsewhere, and where the result is not
/// positive, the estimate stays. Depth and its variance follow as in upsampleDepth. Throws
/// std::invalid_argument on mismatched sizes or types.
void addSensorDetail(const cv::Mat& sensor_inv_depth, const cv::Mat& sensor_inv_depth_var,
                     const cv::Mat& correction, UpsampledDepth* estimate);

}  // namespace radslam
