#include "tracker/motion_segmentation.h"

#include <cmath>
#include <map>
#include <stdexcept>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace radslam {

MotionSegmenter::MotionSegmenter(const MotionSegmentationParams& params)
    : params_(params), next_id_(params.first_id) {
  if (!(params.min_residual_px > 0) || !(params.depth_sigmas >= 0) ||
      !(params.relative_residual >= 0) || params.min_object_pixels < 1 || params.close_px < 0 ||
      !(params.min_overlap > 0 && params.min_overlap <= 1) || params.first_id < 1 ||
      params.first_id > 65000) {
    throw std::invalid_argument(
        "motion segmentation: need min_residual_px > 0, depth_sigmas >= 0, relative_residual >= 0, "
        "min_object_pixels >= 1, close_px >= 0, min_overlap in (0, 1], first_id in [1, 65000]");
  }
}

cv::Mat MotionSegmenter::segment(const cv::Mat& measured, const cv::Mat& predicted,
                                 const cv::Mat& depth_flow) {
  CV_Assert(measured.type() == CV_32FC2 && predicted.type() == CV_32FC2 &&
            measured.size() == predicted.size());
  CV_Assert(depth_flow.empty() ||
            (depth_flow.type() == CV_32FC1 && depth_flow.size() == measured.size()));
  const int W = measured.cols, H = measured.rows;
  const float min_r = static_cast<float>(params_.min_residual_px);
  const float sigmas = static_cast<float>(params_.depth_sigmas);
  const float relative = static_cast<float>(params_.relative_residual);
  // Moving pixels of a, carried into b along their measured flow.
  cv::Mat moving_b(measured.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < H; ++y) {
    const cv::Vec2f* m = measured.ptr<cv::Vec2f>(y);
    const cv::Vec2f* p = predicted.ptr<cv::Vec2f>(y);
    const float* d = depth_flow.empty() ? nullptr : depth_flow.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const float du = m[x][0] - p[x][0], dv = m[x][1] - p[x][1];
      const float tolerance =
          min_r + relative * std::hypot(p[x][0], p[x][1]) + (d ? sigmas * d[x] : 0.f);
      if (!(du * du + dv * dv > tolerance * tolerance)) continue;  // also NaN, inf
      const int xb = static_cast<int>(std::lround(x + m[x][0]));
      const int yb = static_cast<int>(std::lround(y + m[x][1]));
      if (xb >= 0 && yb >= 0 && xb < W && yb < H) moving_b.at<uint8_t>(yb, xb) = 255;
    }
  }
  if (params_.close_px > 0) {
    const int k = 2 * params_.close_px + 1;
    cv::morphologyEx(moving_b, moving_b, cv::MORPH_CLOSE,
                     cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k)));
  }
  cv::Mat labels, stats, centroids;
  const int n = cv::connectedComponentsWithStats(moving_b, labels, stats, centroids, 8, CV_32S);

  cv::Mat instance(measured.size(), CV_16UC1, cv::Scalar(0));
  for (int label = 1; label < n; ++label) {
    const int area = stats.at<int>(label, cv::CC_STAT_AREA);
    if (area < params_.min_object_pixels) continue;
    const cv::Mat component = labels == label;
    // The previous id it overlaps most, by intersection over union.
    int id = 0;
    double best = 0;
    if (!previous_.empty()) {
      std::map<int, int> shared;
      for (int y = 0; y < H; ++y) {
        const uint8_t* c = component.ptr<uint8_t>(y);
        const uint16_t* prev = previous_.ptr<uint16_t>(y);
        for (int x = 0; x < W; ++x) {
          if (c[x] && prev[x]) ++shared[prev[x]];
        }
      }
      for (const auto& [prev_id, common] : shared) {
        const int prev_area = cv::countNonZero(previous_ == prev_id);
        const double iou = static_cast<double>(common) / (area + prev_area - common);
        if (iou >= params_.min_overlap && iou > best) {
          best = iou;
          id = prev_id;
        }
      }
    }
    if (id == 0) id = next_id_ < 65535 ? next_id_++ : next_id_;
    instance.setTo(cv::Scalar(id), component);
  }
  previous_ = instance.clone();
  return instance;
}

}  // namespace radslam
