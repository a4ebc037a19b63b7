#include "tracker/frontend_depth.h"

#include "tracker/dense_ba.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <opencv2/calib3d.hpp>

namespace radslam {
namespace {
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
}  // namespace

cv::Mat sensorDepthToGrid(const cv::Mat& depth, int cell, double min_fraction, double min_m,
                          double max_m) {
  CV_Assert(depth.type() == CV_32FC1 && cell >= 1 && depth.cols % cell == 0 &&
            depth.rows % cell == 0);
  cv::Mat out(depth.rows / cell, depth.cols / cell, CV_32FC1, cv::Scalar(0));
  std::vector<float> values;
  values.reserve(cell * cell);
  const double needed = min_fraction * cell * cell;
  for (int v = 0; v < out.rows; ++v) {
    for (int u = 0; u < out.cols; ++u) {
      values.clear();
      for (int y = v * cell; y < (v + 1) * cell; ++y) {
        const float* row = depth.ptr<float>(y);
        for (int x = u * cell; x < (u + 1) * cell; ++x) {
          if (row[x] >= min_m && row[x] <= max_m) values.push_back(row[x]);
        }
      }
      if (values.empty() || values.size() < needed) continue;
      // The median; for an even count the two middle values are averaged in inverse depth,
      // which is linear across a plane, so a slanted surface's cell gets its centre's depth
      // (either middle value alone lies half a pixel off it).
      const size_t mid = values.size() / 2;
      std::nth_element(values.begin(), values.begin() + mid, values.end());
      float z = values[mid];
      if (values.size() % 2 == 0) {
        const float below = *std::max_element(values.begin(), values.begin() + mid);
        z = 2.0f * below * z / (below + z);
      }
      out.at<float>(v, u) = z;
    }
  }
  return out;
}

void depthPrior(const cv::Mat& grid_depth, double a, double b, double z0, cv::Mat* inv_depth,
                cv::Mat* inv_depth_var) {
  CV_Assert(grid_depth.type() == CV_32FC1);
  inv_depth->create(grid_depth.size(), CV_32FC1);
  inv_depth_var->create(grid_depth.size(), CV_32FC1);
  for (int v = 0; v < grid_depth.rows; ++v) {
    const float* z = grid_depth.ptr<float>(v);
    float* d = inv_depth->ptr<float>(v);
    float* var = inv_depth_var->ptr<float>(v);
    for (int u = 0; u < grid_depth.cols; ++u) {
      if (!(z[u] > 0) || !std::isfinite(z[u])) {
        d[u] = kNaN;
        var[u] = 0;
        continue;
      }
      const double sigma_z = a + b * (z[u] - z0) * (z[u] - z0);
      const double z2 = static_cast<double>(z[u]) * z[u];
      d[u] = static_cast<float>(1.0 / z[u]);
      var[u] = static_cast<float>(sigma_z * sigma_z / (z2 * z2));
    }
  }
}

cv::Mat flowStereoDepth(const cv::Mat& flow_lr, double fx, double baseline_m) {
  cv::Mat depth(flow_lr.size(), CV_32FC1, cv::Scalar(0));
  for (int y = 0; y < flow_lr.rows; ++y) {
    const cv::Vec2f* f = flow_lr.ptr<cv::Vec2f>(y);
    float* z = depth.ptr<float>(y);
    for (int x = 0; x < flow_lr.cols; ++x) {
      const float disparity = -f[x][0];
      if (disparity > 0.5f && std::abs(f[x][1]) < 1.f) {
        z[x] = static_cast<float>(fx * baseline_m / disparity);
      }
    }
  }
  return depth;
}

cv::Mat semiGlobalStereoDepth(const cv::Mat& left, const cv::Mat& right, double fx,
                              double baseline_m, double min_depth_m) {
  CV_Assert(left.type() == CV_8UC1 && right.type() == CV_8UC1 && left.size() == right.size());
  CV_Assert(fx > 0 && baseline_m > 0 && min_depth_m > 0);
  // SGBM searches a multiple of 16 disparities.
  const double max_disparity = fx * baseline_m / min_depth_m;
  const int range = std::clamp(16 * static_cast<int>(std::ceil(max_disparity / 16)), 16,
                               std::max(16, 16 * (left.cols / 32)));
  const int block = 5;
  const cv::Ptr<cv::StereoSGBM> sgbm = cv::StereoSGBM::create(
      0, range, block, 8 * block * block, 32 * block * block,
      /*disp12MaxDiff=*/1, /*preFilterCap=*/31, /*uniquenessRatio=*/10,
      /*speckleWindowSize=*/100, /*speckleRange=*/2, cv::StereoSGBM::MODE_SGBM_3WAY);
  cv::Mat left_padded, right_padded, disparity16;
  cv::copyMakeBorder(left, left_padded, 0, 0, range, 0, cv::BORDER_REPLICATE);
  cv::copyMakeBorder(right, right_padded, 0, 0, range, 0, cv::BORDER_REPLICATE);
  sgbm->compute(left_padded, right_padded, disparity16);
  cv::Mat depth(left.size(), CV_32FC1, cv::Scalar(0));
  const double fb16 = 16 * fx * baseline_m;  // disparities come in 1/16 px
  for (int y = 0; y < depth.rows; ++y) {
    const int16_t* d = disparity16.ptr<int16_t>(y) + range;
    float* z = depth.ptr<float>(y);
    // At least half a pixel, and not matched into the replicated padding.
    for (int x = 0; x < depth.cols; ++x) {
      if (d[x] >= 8 && d[x] <= 16 * x) z[x] = static_cast<float>(fb16 / d[x]);
    }
  }
  return depth;
}

cv::Mat stereoInverseDepth(const cv::Mat& target, const cv::Mat& weight, double fx_grid,
                           double baseline_m, double min_disparity_px) {
  CV_Assert(target.type() == CV_32FC2 && weight.type() == kFlowWeightType &&
            target.size() == weight.size() && fx_grid > 0 && baseline_m > 0);
  cv::Mat out(target.size(), CV_32FC1, cv::Scalar(kNaN));
  for (int v = 0; v < target.rows; ++v) {
    const cv::Vec2f* t = target.ptr<cv::Vec2f>(v);
    const cv::Vec3f* w = weight.ptr<cv::Vec3f>(v);
    float* d = out.ptr<float>(v);
    for (int u = 0; u < target.cols; ++u) {
      if (!(w[u][0] > 0)) continue;
      const double disparity = u - t[u][0];
      if (disparity >= min_disparity_px)
        d[u] = static_cast<float>(disparity / (fx_grid * baseline_m));
    }
  }
  return out;
}

cv::Mat splatInverseDepth(const cv::Mat& inv_depth_a, const cv::Mat& target, const cv::Mat& weight,
                          const SE3& T_b_a, const CameraModel& grid) {
  CV_Assert(inv_depth_a.type() == CV_32FC1 && target.type() == CV_32FC2 &&
            weight.type() == kFlowWeightType && inv_depth_a.size() == target.size() &&
            target.size() == weight.size());
  cv::Mat out(inv_depth_a.size(), CV_32FC1, cv::Scalar(kNaN));
  const Mat3 R = T_b_a.rotation();
  const Vec3 t = T_b_a.translation();
  for (int v = 0; v < target.rows; ++v) {
    const float* da = inv_depth_a.ptr<float>(v);
    const cv::Vec2f* tg = target.ptr<cv::Vec2f>(v);
    const cv::Vec3f* w = weight.ptr<cv::Vec3f>(v);
    const double y = (v - grid.cy) / grid.fy;
    for (int u = 0; u < target.cols; ++u) {
      if (!(w[u][0] > 0) || !(da[u] > 0) || !std::isfinite(da[u])) continue;
      const int ub = static_cast<int>(std::lround(tg[u][0]));
      const int vb = static_cast<int>(std::lround(tg[u][1]));
      if (ub < 0 || vb < 0 || ub >= out.cols || vb >= out.rows) continue;
      // Homogeneous point R (x, y, 1) + t d: its z is z_b / z_a (see dense_ba_kernel.h).
      const double x = (u - grid.cx) / grid.fx;
      const double ratio = R(2, 0) * x + R(2, 1) * y + R(2, 2) + t(2) * da[u];
      if (!(ratio > 0.1)) continue;
      const float db = static_cast<float>(da[u] / ratio);
      float& o = out.at<float>(vb, ub);
      if (!(o >= db)) o = db;  // NaN or farther: the nearer surface occludes
    }
  }
  return out;
}

void fillInverseDepth(cv::Mat* inv_depth, const cv::Mat& preferred, double fallback) {
  CV_Assert(inv_depth->type() == CV_32FC1);
  CV_Assert(preferred.empty() ||
            (preferred.type() == CV_32FC1 && preferred.size() == inv_depth->size()));
  for (int v = 0; v < inv_depth->rows; ++v) {
    float* d = inv_depth->ptr<float>(v);
    const float* p = preferred.empty() ? nullptr : preferred.ptr<float>(v);
    for (int u = 0; u < inv_depth->cols; ++u) {
      if (std::isfinite(d[u]) && d[u] > 0) continue;
      d[u] = (p && std::isfinite(p[u]) && p[u] > 0) ? p[u] : static_cast<float>(fallback);
    }
  }
}

}  // namespace radslam
