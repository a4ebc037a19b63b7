#include "mapper/sensor_clock.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "mapper/mapping_eval.h"

namespace radslam {
namespace {

// Where frame a's pixels land in frame b (a CV_32FC2 map for cv::remap, -1 where they do not)
// and their depth there (CV_32FC1, m).
void warpMap(const cv::Mat& depth_a, const CameraModel& camera, const SE3& T_b_a, cv::Mat* map,
             cv::Mat* z_in_b) {
  map->create(depth_a.size(), CV_32FC2);
  map->setTo(cv::Scalar(-1, -1));
  z_in_b->create(depth_a.size(), CV_32FC1);
  z_in_b->setTo(0);
  for (int y = 0; y < depth_a.rows; ++y)
    for (int x = 0; x < depth_a.cols; ++x) {
      const float z = depth_a.at<float>(y, x);
      if (!(z > 0)) continue;
      const Vec3 p =
          T_b_a * Vec3(z * (x - camera.cx) / camera.fx, z * (y - camera.cy) / camera.fy, z);
      if (p.z() < 0.1) continue;
      map->at<cv::Vec2f>(y, x) =
          cv::Vec2f(static_cast<float>(camera.fx * p.x() / p.z() + camera.cx),
                    static_cast<float>(camera.fy * p.y() / p.z() + camera.cy));
      z_in_b->at<float>(y, x) = static_cast<float>(p.z());
    }
}

// Relative depth differences count up to this: beyond it a pixel sees another surface.
constexpr float kDepthRelCap = 0.05f;

float median(std::vector<float>* values) {
  if (values->empty()) return NAN;
  std::nth_element(values->begin(), values->begin() + values->size() / 2, values->end());
  return (*values)[values->size() / 2];
}

void fitDepth(const std::vector<ClockFrame>& frames, const Trajectory& gt,
              const CameraModel& camera, int gap, ClockFit* fit) {
  std::vector<float> rel;
  int64_t agree = 0;
  cv::Mat map, z, target;
  for (size_t i = 0; i + gap < frames.size(); ++i) {
    const ClockFrame &a = frames[i], &b = frames[i + gap];
    const std::optional<SE3> T_world_a = poseAt(gt, a.t_depth + fit->offset_s);
    const std::optional<SE3> T_world_b = poseAt(gt, b.t_depth + fit->offset_s);
    if (!T_world_a || !T_world_b) continue;
    warpMap(a.depth, camera, T_world_b->inverse() * *T_world_a, &map, &z);
    cv::remap(b.depth, target, map, cv::noArray(), cv::INTER_NEAREST, cv::BORDER_CONSTANT, 0);
    for (int y = 0; y < z.rows; ++y)
      for (int x = 0; x < z.cols; ++x) {
        const float za = z.at<float>(y, x), zb = target.at<float>(y, x);
        if (!(za > 0) || !(zb > 0)) continue;
        rel.push_back(std::abs(za - zb) / zb);
        agree += rel.back() < 0.02f;
      }
  }
  double truncated_sum = 0;
  for (float r : rel) truncated_sum += std::min(r, kDepthRelCap);
  fit->depth_agree = rel.empty() ? 0 : double(agree) / rel.size();
  fit->depth_error = rel.empty() ? NAN : truncated_sum / rel.size();
}

void fitColour(const std::vector<ClockFrame>& frames, const Trajectory& gt,
               const CameraModel& camera, int gap, double depth_offset_s, ClockFit* fit) {
  std::vector<float> diff;
  cv::Mat map, z, warped, gx, gy;
  for (size_t i = 0; i + gap < frames.size(); ++i) {
    const ClockFrame &a = frames[i], &b = frames[i + gap];
    const std::optional<SE3> T_world_a = poseAt(gt, a.t_colour + fit->offset_s);
    const std::optional<SE3> T_world_b = poseAt(gt, b.t_colour + fit->offset_s);
    const std::optional<SE3> T_world_a_depth = poseAt(gt, a.t_depth + depth_offset_s);
    if (!T_world_a || !T_world_b || !T_world_a_depth) continue;
    const cv::Mat depth = rotateDepth(
        a.depth, camera, (T_world_a->so3().inverse() * T_world_a_depth->so3()).matrix());
    warpMap(depth, camera, T_world_b->inverse() * *T_world_a, &map, &z);
    cv::remap(b.grey, warped, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, -1);
    cv::Sobel(a.grey, gx, CV_32F, 1, 0, 1);
    cv::Sobel(a.grey, gy, CV_32F, 0, 1, 1);
    for (int y = 0; y < z.rows; ++y)
      for (int x = 0; x < z.cols; ++x) {
        const float dx = gx.at<float>(y, x), dy = gy.at<float>(y, x);
        if (!(z.at<float>(y, x) > 0) || warped.at<float>(y, x) < 0 || dx * dx + dy * dy < 400)
          continue;
        diff.push_back(std::abs(warped.at<float>(y, x) - a.grey.at<float>(y, x)));
      }
  }
  fit->colour_median_diff = median(&diff);
}

}  // namespace

ClockScan scanSensorClocks(const std::vector<ClockFrame>& frames, const Trajectory& ground_truth,
                           const CameraModel& camera, int gap,
                           const std::vector<double>& offsets_s) {
  if (offsets_s.empty()) throw std::invalid_argument("scanSensorClocks: no offsets to try");
  if (gap < 1 || frames.size() <= static_cast<size_t>(gap))
    throw std::invalid_argument("scanSensorClocks: " + std::to_string(frames.size()) +
                                " frames make no pair " + std::to_string(gap) + " apart");
  ClockScan scan;
  for (double offset : offsets_s) {
    scan.fits.push_back({});
    scan.fits.back().offset_s = offset;
    fitDepth(frames, ground_truth, camera, gap, &scan.fits.back());
    if (scan.fits.back().depth_error < scan.fits[scan.best_depth].depth_error ||
        std::isnan(scan.fits[scan.best_depth].depth_error))
      scan.best_depth = scan.fits.size() - 1;
  }
  for (size_t k = 0; k < scan.fits.size(); ++k) {
    fitColour(frames, ground_truth, camera, gap, scan.fits[scan.best_depth].offset_s,
              &scan.fits[k]);
    // NaN (nothing seen) never wins.
    if (scan.fits[k].colour_median_diff < scan.fits[scan.best_colour].colour_median_diff ||
        std::isnan(scan.fits[scan.best_colour].colour_median_diff))
      scan.best_colour = k;
  }
  return scan;
}

}  // namespace radslam
