#include "tracker/mono_init.h"

#include "tracker/dense_ba.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace radslam {

TwoViewResult initializeTwoView(const CameraModel& grid, const cv::Mat& target,
                                const cv::Mat& weight, const TwoViewOptions& options) {
  CV_Assert(target.type() == CV_32FC2 && weight.type() == kFlowWeightType &&
            target.size() == weight.size() && target.cols == grid.width &&
            target.rows == grid.height);
  TwoViewResult result;
  std::vector<cv::Point2f> pa, pb;
  std::vector<cv::Point> cells;
  for (int v = 0; v < target.rows; ++v) {
    const cv::Vec2f* t = target.ptr<cv::Vec2f>(v);
    const cv::Vec3f* w = weight.ptr<cv::Vec3f>(v);
    for (int u = 0; u < target.cols; ++u) {
      if (!(w[u][0] > 0 || w[u][2] > 0) || !std::isfinite(t[u][0]) || !std::isfinite(t[u][1])) {
        continue;
      }
      pa.emplace_back(static_cast<float>(u), static_cast<float>(v));
      pb.emplace_back(t[u][0], t[u][1]);
      cells.emplace_back(u, v);
    }
  }
  result.correspondences = static_cast<int>(pa.size());
  if (pa.size() < 20) {
    result.why = "too few correspondences (" + std::to_string(pa.size()) + ")";
    return result;
  }
  const cv::Matx33d K(grid.fx, 0, grid.cx, 0, grid.fy, grid.cy, 0, 0, 1);
  cv::Mat mask;
  const cv::Mat E = cv::findEssentialMat(pa, pb, K, cv::RANSAC, options.ransac_confidence,
                                         options.ransac_threshold_px, mask);
  if (E.rows != 3 || E.cols != 3) {
    result.why = "no essential matrix";
    return result;
  }
  const cv::Mat ransac_inliers = mask.clone();
  cv::Mat R_cv, t_cv;
  // recoverPose keeps the RANSAC inliers in front of both cameras; [R | t] maps a to b.
  cv::recoverPose(E, pa, pb, K, R_cv, t_cv, mask);
  Mat3 R;
  Vec3 t;
  cv::cv2eigen(R_cv, R);
  cv::cv2eigen(t_cv, t);

  // A flow that the rotation alone explains has no usable translation (E's t is noise then).
  std::vector<double> rotation_residuals;
  for (int n = 0; n < ransac_inliers.rows; ++n) {
    if (!ransac_inliers.at<uint8_t>(n)) continue;
    const Vec3 q = R * Vec3((pa[n].x - grid.cx) / grid.fx, (pa[n].y - grid.cy) / grid.fy, 1.0);
    rotation_residuals.push_back(std::hypot(grid.fx * q.x() / q.z() + grid.cx - pb[n].x,
                                            grid.fy * q.y() / q.z() + grid.cy - pb[n].y));
  }
  if (!rotation_residuals.empty()) {
    std::nth_element(rotation_residuals.begin(),
                     rotation_residuals.begin() + rotation_residuals.size() / 2,
                     rotation_residuals.end());
    const double median = rotation_residuals[rotation_residuals.size() / 2];
    if (median < 2 * options.ransac_threshold_px) {
      result.why = "a rotation explains the flow (median residual " + std::to_string(median) +
                   " grid px): translation not observable";
      return result;
    }
  }

  // Inverse depth of each inlier in a for |t| = 1: b's normalised point (ub, vb) satisfies
  // ub (a_z + d t_z) = a_x + d t_x (likewise vb) with a = R (xa, ya, 1); least squares in d.
  const Vec3 centre_b = -R.transpose() * t;  // b's centre in a
  std::vector<double> inv_depths, parallax;
  std::vector<int> kept;
  for (int n = 0; n < mask.rows; ++n) {
    if (!mask.at<uint8_t>(n)) continue;
    const Vec3 xa((pa[n].x - grid.cx) / grid.fx, (pa[n].y - grid.cy) / grid.fy, 1.0);
    const double ub = (pb[n].x - grid.cx) / grid.fx, vb = (pb[n].y - grid.cy) / grid.fy;
    const Vec3 a = R * xa;
    const double c0 = ub * t.z() - t.x(), c1 = vb * t.z() - t.y();
    const double e0 = a.x() - ub * a.z(), e1 = a.y() - vb * a.z();
    const double den = c0 * c0 + c1 * c1;
    if (!(den > 0)) continue;
    const double d = (c0 * e0 + c1 * e1) / den;
    if (!(d > 0) || !std::isfinite(d)) continue;
    const Vec3 X = xa / d;
    const double cos_angle = X.dot(X - centre_b) / (X.norm() * (X - centre_b).norm());
    parallax.push_back(std::acos(std::clamp(cos_angle, -1.0, 1.0)) * 180.0 / M_PI);
    inv_depths.push_back(d);
    kept.push_back(n);
  }
  result.inliers = static_cast<int>(kept.size());
  if (result.inliers < options.min_inlier_fraction * result.correspondences) {
    result.why = "only " + std::to_string(result.inliers) + " of " +
                 std::to_string(result.correspondences) + " correspondences fit one motion";
    return result;
  }
  std::vector<double> sorted = parallax;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  result.median_parallax_deg = sorted[sorted.size() / 2];
  sorted = inv_depths;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  // Scaling t by k scales depths by k, inverse depths by 1 / k.
  const double k = sorted[sorted.size() / 2] / options.median_inv_depth;
  result.T_b_a = SE3(SO3(R), k * t);
  result.inv_depth_a =
      cv::Mat(target.size(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  for (size_t m = 0; m < kept.size(); ++m) {
    const cv::Point& c = cells[kept[m]];
    result.inv_depth_a.at<float>(c.y, c.x) = static_cast<float>(inv_depths[m] / k);
  }
  result.small_parallax = result.median_parallax_deg < options.min_parallax_deg;
  result.ok = !result.small_parallax;
  if (result.small_parallax) {
    result.why = "median parallax " + std::to_string(result.median_parallax_deg) +
                 " deg: translation too short to triangulate";
  }
  return result;
}

}  // namespace radslam
