// Initial inverse depths of a new keyframe on the BA grid, and the RGB-D inverse-depth prior:
// sensor depth reduced to the grid, the stereo disparity, and the previous keyframe's depths
// carried over along the measured flow.
#pragma once

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"

namespace radslam {

/// Sensor depth (CV_32FC1 working resolution, m, 0 = invalid) reduced to the grid: the median
/// of the valid values (within [min_m, max_m]) of each cell x cell block, 0 where fewer than
/// min_fraction of its pixels are valid. The median keeps one surface at depth edges; for an
/// even count it is the mean of the two middle values in inverse depth, so that a slanted
/// plane's cell gets the depth at the cell centre.
cv::Mat sensorDepthToGrid(const cv::Mat& depth, int cell, double min_fraction, double min_m,
                          double max_m);

/// Inverse-depth prior from grid depth z (m; 0 = none) with sigma_z = a + b (z - z0)^2 (m):
/// mean 1/z, variance sigma_z^2 / z^4 (first order); NaN mean and 0 variance where z = 0.
void depthPrior(const cv::Mat& grid_depth, double a, double b, double z0, cv::Mat* inv_depth,
                cv::Mat* inv_depth_var);

/// Per-pixel metric depth (CV_32FC1 m, 0 = unknown) from a rectified left -> right flow: the
/// disparity is -flow.x; rows off by more than a pixel or disparities under half a pixel are
/// not trusted.
cv::Mat flowStereoDepth(const cv::Mat& flow_lr, double fx, double baseline_m);

/// Per-pixel metric depth (CV_32FC1 m, 0 = unknown) of a rectified grey pair (CV_8UC1, same
/// size) by OpenCV's semi-global matching: 5 px blocks, 3-way, sub-pixel, left-right checked,
/// speckles removed. The disparity search reaches depths down to min_depth_m (at most half the
/// width). Both images are padded on the left by the search range, so that the left border,
/// whose search would leave the right image, keeps the matches that stay inside it.
cv::Mat semiGlobalStereoDepth(const cv::Mat& left, const cv::Mat& right, double fx,
                              double baseline_m, double min_depth_m);

/// Inverse depth from a rectified stereo edge (grid targets in the right image, weights):
/// d = (u - u_right) / (fx * baseline) (1/m) where the weight is positive and the disparity
/// is at least min_disparity_px grid px; NaN elsewhere.
cv::Mat stereoInverseDepth(const cv::Mat& target, const cv::Mat& weight, double fx_grid,
                           double baseline_m, double min_disparity_px = 0.05);

/// Carries keyframe a's inverse depths to a new keyframe b: each grid pixel p of a with a
/// valid flow target (weight > 0) lands at the nearest grid pixel of b with inverse depth
/// d_b = d_a / (z_b / z_a), z_b / z_a from T_b_a; where several land, the nearest surface
/// (largest d_b) wins. NaN where nothing lands.
cv::Mat splatInverseDepth(const cv::Mat& inv_depth_a, const cv::Mat& target, const cv::Mat& weight,
                          const SE3& T_b_a, const CameraModel& grid);

/// Replaces non-finite or non-positive values: by the first finite positive value of
/// `preferred` at that pixel (when not empty), else by `fallback`.
void fillInverseDepth(cv::Mat* inv_depth, const cv::Mat& preferred, double fallback);

}  // namespace radslam
