#include "tracker/motion_segmentation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <stdexcept>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "tracker/frontend_flow.h"
#include "tracker/joints.h"

namespace radslam {

namespace {

// |b - grey| closest to zero over the 3 x 3 pixels of b around (xb, yb), which must be inside b:
// a landing a pixel off still finds its own grey value.
int greyErrorNear(uint8_t grey, const cv::Mat& grey_b, int xb, int yb) {
  int best = 255;
  for (int dy = -1; dy <= 1; ++dy) {
    const uint8_t* b = grey_b.ptr<uint8_t>(yb + dy);
    for (int dx = -1; dx <= 1; ++dx) best = std::min(best, std::abs(grey - b[xb + dx]));
  }
  return best;
}

// Carries pixels of a into b along their rays: p_b = z R r(x, y) + t. R r is linear in x along
// a row, which saves unprojecting every pixel (staticFlowFromDepth on 640 x 480: 8.9 -> 1.7 ms).
class RayTransfer {
 public:
  RayTransfer(const SE3& T_b_a, const CameraModel& camera)
      : camera_(camera),
        R_(T_b_a.rotation()),
        t_(T_b_a.translation()),
        step_(R_.col(0) / camera.fx) {}

  // The rotated ray of pixel (0, y); ray(x) then gives the rest of the row.
  void setRow(int y) {
    ray_0_ = R_ * Vec3(-camera_.cx / camera_.fx, (y - camera_.cy) / camera_.fy, 1.0);
  }
  Vec3 ray(int x) const { return ray_0_ + x * step_; }
  Vec3 point(const Vec3& ray, double z) const { return z * ray + t_; }
  Eigen::Vector2d pixel(const Vec3& p_b) const {
    return {camera_.fx * p_b.x() / p_b.z() + camera_.cx,
            camera_.fy * p_b.y() / p_b.z() + camera_.cy};
  }

 private:
  const CameraModel& camera_;
  const Mat3 R_;
  const Vec3 t_;
  const Vec3 step_;
  Vec3 ray_0_ = Vec3::Zero();
};

}  // namespace

MotionSegmenter::MotionSegmenter(const MotionSegmentationParams& params)
    : params_(params), next_id_(params.first_id) {
  if (!(params.min_residual_px > 0) || !(params.depth_sigmas >= 0) ||
      !(params.relative_residual >= 0) || params.min_object_pixels < 1 || params.close_px < 0 ||
      !(params.min_overlap > 0 && params.min_overlap <= 1) || params.first_id < 1 ||
      params.first_id > 65000 || !(params.depth_test_sigmas > 0) ||
      !(params.photometric_margin >= 0) ||
      !(params.weak_fraction > 0 && params.weak_fraction <= 1) || !(params.carry_grey_error >= 0) ||
      !(params.carry_max_failed_fraction >= 0 && params.carry_max_failed_fraction <= 1)) {
    throw std::invalid_argument(
        "motion segmentation: need min_residual_px > 0, depth_sigmas >= 0, relative_residual >= 0, "
        "min_object_pixels >= 1, close_px >= 0, min_overlap in (0, 1], first_id in [1, 65000], "
        "depth_test_sigmas > 0, photometric_margin >= 0, weak_fraction in (0, 1], "
        "carry_grey_error >= 0, carry_max_failed_fraction in [0, 1]");
  }
}

cv::Mat staticFlowFromDepth(const cv::Mat& depth_a, const SE3& T_b_a, const CameraModel& camera,
                            const cv::Mat& fallback) {
  const cv::Size size(camera.width, camera.height);
  CV_Assert(depth_a.type() == CV_32FC1 && depth_a.size() == size && fallback.type() == CV_32FC2 &&
            fallback.size() == size);
  cv::Mat flow = fallback.clone();
  RayTransfer transfer(T_b_a, camera);
  for (int y = 0; y < size.height; ++y) {
    const float* z = depth_a.ptr<float>(y);
    cv::Vec2f* f = flow.ptr<cv::Vec2f>(y);
    transfer.setRow(y);
    for (int x = 0; x < size.width; ++x) {
      if (!(z[x] > 0) || !std::isfinite(z[x])) continue;
      const Vec3 p_b = transfer.point(transfer.ray(x), z[x]);
      if (!(p_b.z() > 1e-3)) continue;
      const Eigen::Vector2d px = transfer.pixel(p_b);
      f[x] = cv::Vec2f(static_cast<float>(px.x() - x), static_cast<float>(px.y() - y));
    }
  }
  return flow;
}

cv::Mat flowFromDepthNoise(const cv::Mat& depth_a, const SE3& T_b_a, const CameraModel& camera,
                           double sigma_a, double sigma_b, double sigma_z0) {
  const cv::Size size(camera.width, camera.height);
  CV_Assert(depth_a.type() == CV_32FC1 && depth_a.size() == size);
  cv::Mat change(size, CV_32FC1, cv::Scalar(std::numeric_limits<float>::infinity()));
  RayTransfer transfer(T_b_a, camera);
  for (int y = 0; y < size.height; ++y) {
    const float* z = depth_a.ptr<float>(y);
    float* c = change.ptr<float>(y);
    transfer.setRow(y);
    for (int x = 0; x < size.width; ++x) {
      if (!(z[x] > 0) || !std::isfinite(z[x])) continue;
      const double sigma_z = sigma_a + sigma_b * (z[x] - sigma_z0) * (z[x] - sigma_z0);
      const double nearer = 1.0 / (1.0 / z[x] + sigma_z / (double(z[x]) * z[x]));
      const Vec3 ray = transfer.ray(x);
      const Vec3 p_b = transfer.point(ray, z[x]), q_b = transfer.point(ray, nearer);
      if (!(p_b.z() > 1e-3) || !(q_b.z() > 1e-3)) continue;
      c[x] = static_cast<float>((transfer.pixel(p_b) - transfer.pixel(q_b)).norm());
    }
  }
  return change;
}

cv::Mat photometricPreference(const cv::Mat& grey_a, const cv::Mat& grey_b, const cv::Mat& measured,
                              const cv::Mat& predicted, int radius) {
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 && grey_a.size() == grey_b.size());
  CV_Assert(measured.type() == CV_32FC2 && predicted.type() == CV_32FC2 &&
            measured.size() == grey_a.size() && predicted.size() == grey_a.size());
  const float kNaN = std::numeric_limits<float>::quiet_NaN();
  cv::Mat a, b;
  grey_a.convertTo(a, CV_32F);
  grey_b.convertTo(b, CV_32F);
  // |b(x + flow) - a(x)|, NaN where x + flow is outside b or the flow is unknown.
  const auto error = [&](const cv::Mat& flow) {
    cv::Mat warped;
    cv::remap(b, warped, flowTargetMap(flow), cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT,
              cv::Scalar(kNaN));
    return cv::Mat(cv::abs(warped - a));
  };
  const cv::Mat difference = error(predicted) - error(measured);
  cv::Mat valid = difference == difference;  // not NaN
  cv::Mat sum = difference.clone();
  sum.setTo(0, ~valid);
  cv::Mat count;
  valid.convertTo(count, CV_32F, 1.0 / 255);
  const cv::Size window(2 * radius + 1, 2 * radius + 1);
  cv::boxFilter(sum, sum, CV_32F, window, cv::Point(-1, -1), false);
  cv::boxFilter(count, count, CV_32F, window, cv::Point(-1, -1), false);
  cv::Mat mean = sum / count;  // NaN where count is 0
  mean.setTo(kNaN, count < 0.5f);
  return mean;
}

cv::Mat landingGreyError(const cv::Mat& grey_a, const cv::Mat& grey_b, const cv::Mat& flow) {
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 && grey_a.size() == grey_b.size());
  CV_Assert(flow.type() == CV_32FC2 && flow.size() == grey_a.size());
  const int W = grey_a.cols, H = grey_a.rows;
  cv::Mat out(grey_a.size(), CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  for (int y = 0; y < H; ++y) {
    const uint8_t* a = grey_a.ptr<uint8_t>(y);
    const cv::Vec2f* f = flow.ptr<cv::Vec2f>(y);
    float* e = out.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const float xf = x + f[x][0], yf = y + f[x][1];
      if (!(xf >= 0.5f && yf >= 0.5f && xf < W - 1.5f && yf < H - 1.5f)) continue;  // or NaN
      e[x] = static_cast<float>(greyErrorNear(a[x], grey_b, static_cast<int>(std::lround(xf)),
                                              static_cast<int>(std::lround(yf))));
    }
  }
  return out;
}

namespace {

// The z-score of the mean of per-pixel z-scores over a (2 radius + 1)^2 window: their sum over
// the square root of their count; NaN where the pixel itself was not judged.
cv::Mat windowZScore(const cv::Mat& score, const cv::Mat& judged, int radius) {
  const cv::Size window(2 * radius + 1, 2 * radius + 1);
  cv::Mat sum, count;
  cv::boxFilter(score, sum, -1, window, cv::Point(-1, -1), false, cv::BORDER_CONSTANT);
  cv::boxFilter(judged, count, -1, window, cv::Point(-1, -1), false, cv::BORDER_CONSTANT);
  cv::Mat out(score.size(), CV_32FC1, cv::Scalar(NAN));
  for (int y = 0; y < score.rows; ++y)
    for (int x = 0; x < score.cols; ++x)
      if (judged.at<float>(y, x) > 0)
        out.at<float>(y, x) = sum.at<float>(y, x) / std::sqrt(count.at<float>(y, x));
  return out;
}

}  // namespace

cv::Mat depthDisagreement(const cv::Mat& depth_a, const cv::Mat& depth_b, const cv::Mat& grey_a,
                          const cv::Mat& grey_b, const cv::Mat& depth_flow, const SE3& T_b_a,
                          const CameraModel& camera, double sigma_a, double sigma_b,
                          double sigma_z0, cv::Mat* occluding_b, double max_grey_error,
                          int radius) {
  const cv::Size size(camera.width, camera.height);
  CV_Assert(depth_a.type() == CV_32FC1 && depth_b.type() == CV_32FC1 && depth_a.size() == size &&
            depth_b.size() == size);
  CV_Assert(depth_flow.empty() || (depth_flow.type() == CV_32FC1 && depth_flow.size() == size));
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 && grey_a.size() == size &&
            grey_b.size() == size);
  CV_Assert(radius >= 0);
  const int W = size.width, H = size.height;
  const auto sigma = [&](double z) { return sigma_a + sigma_b * (z - sigma_z0) * (z - sigma_z0); };
  // Where each pixel of a lands in b if it is static, and its depth there.
  cv::Mat landing(size, CV_32SC2, cv::Scalar(-1, -1));
  cv::Mat z_static(size, CV_32FC1, cv::Scalar(0));
  cv::Mat z_front(size, CV_32FC1, cv::Scalar(INFINITY));  // b's z-buffer of a's static points
  RayTransfer transfer(T_b_a, camera);
  for (int y = 0; y < H; ++y) {
    const float* za = depth_a.ptr<float>(y);
    transfer.setRow(y);
    for (int x = 0; x < W; ++x) {
      if (!(za[x] > 0) || !std::isfinite(za[x])) continue;
      const Vec3 p_b = transfer.point(transfer.ray(x), za[x]);
      if (!(p_b.z() > 1e-3)) continue;
      const Eigen::Vector2d px = transfer.pixel(p_b);
      const int xb = static_cast<int>(std::lround(px.x()));
      const int yb = static_cast<int>(std::lround(px.y()));
      if (!(xb >= 2 && yb >= 2 && xb < W - 2 && yb < H - 2)) continue;
      landing.at<cv::Vec2i>(y, x) = {xb, yb};
      z_static.at<float>(y, x) = static_cast<float>(p_b.z());
      float& front = z_front.at<float>(yb, xb);
      front = std::min(front, static_cast<float>(p_b.z()));
    }
  }
  // One pixel of slack: the splats leave holes that a nearer surface would otherwise fall through.
  cv::erode(z_front, z_front, cv::Mat());
  // b's depth change around a pixel (a quarter of its range over 5 x 5 px): pose errors on
  // slanted surfaces and at depth edges. NaN next to a hole.
  cv::Mat lo_b, hi_b;
  const cv::Mat box = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5));
  cv::erode(depth_b, lo_b, box);
  cv::dilate(depth_b, hi_b, box);
  const auto slope_sigma = [&](int xb, int yb) {
    const float lo = lo_b.at<float>(yb, xb), hi = hi_b.at<float>(yb, xb);
    return lo > 0 ? 0.25 * (hi - lo) : NAN;
  };
  const auto total_sigma = [&](double z_a, double z_b, double s_px) {
    return std::sqrt(sigma(z_a) * sigma(z_a) + sigma(z_b) * sigma(z_b) + s_px * s_px);
  };
  // Per pixel z-score (0 and count 0 where not judged), then window sums.
  cv::Mat score(size, CV_32FC1, cv::Scalar(0)), judged(size, CV_32FC1, cv::Scalar(0));
  for (int y = 0; y < H; ++y) {
    const float* df = depth_flow.empty() ? nullptr : depth_flow.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      const cv::Vec2i land = landing.at<cv::Vec2i>(y, x);
      if (land[0] < 0 || (df && !std::isfinite(df[x]))) continue;
      const int xb = land[0], yb = land[1];
      // A prediction a pose error moved onto another surface (thin poles) compares other depths.
      const int grey_error = greyErrorNear(grey_a.at<uint8_t>(y, x), grey_b, xb, yb);
      if (grey_error > max_grey_error) continue;
      const double s_px = slope_sigma(xb, yb);
      if (std::isnan(s_px)) continue;  // a hole next to the landing point
      const double z_pred = z_static.at<float>(y, x), zb = depth_b.at<float>(yb, xb);
      const double s = total_sigma(z_pred, zb, s_px);
      // Hidden in b behind another static point of a (the scene occludes it): not judged.
      if (z_pred - z_front.at<float>(yb, xb) > 3 * s) continue;
      score.at<float>(y, x) = static_cast<float>((zb - z_pred) / s);
      judged.at<float>(y, x) = 1;
    }
  }
  if (occluding_b) {
    // b's pixels nearer than every static point of a that lands on them: something moved in
    // front (the leading edge of a door swinging towards the camera). No grey check: the
    // occluder's grey is not the occluded point's.
    cv::Mat score_b(size, CV_32FC1, cv::Scalar(0)), judged_b(size, CV_32FC1, cv::Scalar(0));
    for (int yb = 2; yb < H - 2; ++yb) {
      for (int xb = 2; xb < W - 2; ++xb) {
        const double front = z_front.at<float>(yb, xb), zb = depth_b.at<float>(yb, xb);
        if (!std::isfinite(front) || !(zb > 0)) continue;
        const double s_px = slope_sigma(xb, yb);
        if (std::isnan(s_px)) continue;
        score_b.at<float>(yb, xb) = static_cast<float>((front - zb) / total_sigma(front, zb, s_px));
        judged_b.at<float>(yb, xb) = 1;
      }
    }
    *occluding_b = windowZScore(score_b, judged_b, radius);
  }
  return windowZScore(score, judged, radius);
}

cv::Mat MotionSegmenter::segment(const cv::Mat& measured, const cv::Mat& predicted,
                                 const cv::Mat& depth_flow, const cv::Mat& depth_test,
                                 const cv::Mat& photo_test, const cv::Mat& carry_error,
                                 const cv::Mat& occluding) {
  CV_Assert(measured.type() == CV_32FC2 && predicted.type() == CV_32FC2 &&
            measured.size() == predicted.size());
  CV_Assert(depth_flow.empty() ||
            (depth_flow.type() == CV_32FC1 && depth_flow.size() == measured.size()));
  CV_Assert(depth_test.empty() ||
            (depth_test.type() == CV_32FC1 && depth_test.size() == measured.size()));
  CV_Assert(photo_test.empty() ||
            (photo_test.type() == CV_32FC1 && photo_test.size() == measured.size()));
  CV_Assert(carry_error.empty() ||
            (carry_error.type() == CV_32FC1 && carry_error.size() == measured.size()));
  CV_Assert(occluding.empty() ||
            (occluding.type() == CV_32FC1 && occluding.size() == measured.size()));
  const float photo_margin = static_cast<float>(params_.photometric_margin);
  const float depth_z_max = static_cast<float>(params_.depth_test_sigmas);
  const float weak = static_cast<float>(params_.weak_fraction);
  const int W = measured.cols, H = measured.rows;
  const float min_r = static_cast<float>(params_.min_residual_px);
  const float sigmas = static_cast<float>(params_.depth_sigmas);
  const float relative = static_cast<float>(params_.relative_residual);
  const float max_carry_error = static_cast<float>(params_.carry_grey_error);
  constexpr float kEdge = 2;  // px of b's border where the flow is not trusted
  constexpr uint8_t kWeak = 1, kStrong = 2;
  // The evidence that a pixel of a is not explained by the static scene.
  cv::Mat evidence(measured.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < H; ++y) {
    const cv::Vec2f* m = measured.ptr<cv::Vec2f>(y);
    const cv::Vec2f* p = predicted.ptr<cv::Vec2f>(y);
    const float* d = depth_flow.empty() ? nullptr : depth_flow.ptr<float>(y);
    const float* z = depth_test.empty() ? nullptr : depth_test.ptr<float>(y);
    const float* photo = photo_test.empty() ? nullptr : photo_test.ptr<float>(y);
    uint8_t* e = evidence.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      // Comparisons with NaN (not judged) are false.
      const float z_abs = z ? std::abs(z[x]) : 0.f;
      const float du = m[x][0] - p[x][0], dv = m[x][1] - p[x][1];
      const float r2 = du * du + dv * dv;
      const float tolerance =
          min_r + relative * std::hypot(p[x][0], p[x][1]) + (d ? sigmas * d[x] : 0.f);
      const auto photo_above = [&](float margin) { return !photo || !(photo[x] <= margin); };
      const bool flow_strong = r2 > tolerance * tolerance && photo_above(photo_margin);
      const bool flow_weak =
          r2 > weak * weak * tolerance * tolerance && photo_above(weak * photo_margin);
      // The static scene carries the pixel out of b: its measured flow may have found nothing to
      // match (a pole leaving the view), or an object that stays in view (a truck alongside).
      const float xb = x + p[x][0], yb = y + p[x][1];
      const bool in_view = xb >= kEdge && yb >= kEdge && xb < W - 1 - kEdge && yb < H - 1 - kEdge;
      if (z_abs > depth_z_max || (flow_strong && in_view))
        e[x] = kStrong;
      else if (z_abs > weak * depth_z_max || flow_weak)
        e[x] = kWeak;
    }
  }
  // Hysteresis: weak evidence counts where it connects to strong evidence (the slow side of a
  // door near its hinge, the part of a truck leaving the view).
  cv::Mat regions;
  const int n_regions = cv::connectedComponents(evidence > 0, regions, 8, CV_32S);
  std::vector<uint8_t> has_strong(n_regions, 0);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      if (evidence.at<uint8_t>(y, x) == kStrong) has_strong[regions.at<int>(y, x)] = 1;
  cv::Mat moving_a(measured.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      if (has_strong[regions.at<int>(y, x)] && evidence.at<uint8_t>(y, x))
        moving_a.at<uint8_t>(y, x) = 255;
  // Moving pixels of a, carried into b along their measured flow. A region whose flow-only
  // pixels land off their grey values too often is a flow that failed (a pole passing close:
  // carried, its pixels scatter over the background); those pixels stay out. Checked per pixel,
  // the misses inside a large truck's side tore holes in it (large, seed 4: IoU 0.78 -> 0.73).
  // Depth evidence stands on its own: a pose that followed a truck moves the whole ground,
  // whose long flows fail, and the ground test needs to see that.
  const auto flow_only = [&](int y, int x) {
    return depth_test.empty() || !(std::abs(depth_test.at<float>(y, x)) > weak * depth_z_max);
  };
  std::vector<int> checked(n_regions, 0), failed(n_regions, 0);
  if (!carry_error.empty()) {
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const float e = carry_error.at<float>(y, x);
        if (!moving_a.at<uint8_t>(y, x) || std::isnan(e) || !flow_only(y, x)) continue;
        const int r = regions.at<int>(y, x);
        ++checked[r];
        if (e > max_carry_error) ++failed[r];
      }
  }
  std::vector<bool> flow_failed(n_regions);
  for (int r = 0; r < n_regions; ++r)
    flow_failed[r] = failed[r] > params_.carry_max_failed_fraction * checked[r];
  cv::Mat moving_b(measured.size(), CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < H; ++y) {
    const cv::Vec2f* m = measured.ptr<cv::Vec2f>(y);
    const uint8_t* moving = moving_a.ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) {
      if (!moving[x]) continue;
      if (flow_failed[regions.at<int>(y, x)] && flow_only(y, x)) continue;
      const int xb = static_cast<int>(std::lround(x + m[x][0]));
      const int yb = static_cast<int>(std::lround(y + m[x][1]));
      if (xb >= 0 && yb >= 0 && xb < W && yb < H) moving_b.at<uint8_t>(yb, xb) = 255;
    }
  }
  if (!occluding.empty()) moving_b.setTo(255, occluding > depth_z_max);
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

void MotionSegmenter::save(BinaryWriter* out) const {
  out->mat(previous_);
  out->put<int32_t>(next_id_);
}

void MotionSegmenter::load(BinaryReader* in, cv::Size size) {
  cv::Mat previous = in->mat();
  if (!previous.empty() && (previous.type() != CV_16UC1 || previous.size() != size))
    in->fail("bad segmentation mask");
  const int next_id = in->get<int32_t>();
  if (next_id < params_.first_id) in->fail("bad segmentation id");
  previous_ = previous;
  next_id_ = next_id;
}

std::optional<Plane> fitGroundPlane(const cv::Mat& depth, const CameraModel& camera,
                                    const GroundParams& params) {
  std::vector<Vec3> points;
  for (int v = depth.rows / 2; v < depth.rows; v += params.stride_px) {
    for (int u = 0; u < depth.cols; u += params.stride_px) {
      const float z = depth.at<float>(v, u);
      if (z > 0 && z < params.max_range_m)
        points.push_back(unproject(camera, Eigen::Vector2d(u, v), z));
    }
  }
  PlaneRansacParams ransac;
  ransac.inlier_threshold = params.inlier_threshold_m;
  ransac.min_inliers = std::max<int>(3, params.min_inlier_fraction * points.size());
  const double min_cos = std::cos(params.max_tilt_deg * M_PI / 180);
  for (int attempt = 0; attempt < 3 && static_cast<int>(points.size()) >= ransac.min_inliers;
       ++attempt) {
    PlaneFit fit;
    try {
      fit = fitPlaneRansac(points, ransac);
    } catch (const std::invalid_argument&) {
      break;  // no plane gathers enough points
    }
    const Plane& plane = fit.plane;
    // Below the camera: the plane crosses the optical centre's downward vertical (+y) at
    // y = -d / n_y.
    const bool level = std::abs(plane.normal.y()) >= min_cos;
    if (level && -plane.d / plane.normal.y() >= params.min_height_m) return plane;
    std::vector<bool> inlier(points.size(), false);
    for (int i : fit.inliers) inlier[i] = true;
    std::vector<Vec3> rest;
    for (size_t i = 0; i < points.size(); ++i) {
      if (!inlier[i]) rest.push_back(points[i]);
    }
    points = std::move(rest);
  }
  return std::nullopt;
}

cv::Mat planePixels(const cv::Mat& depth, const CameraModel& camera, const Plane& plane,
                    double max_range_m, double threshold_m) {
  // The point at depth z of pixel (u, v) is z r with r = ((u - cx) / fx, (v - cy) / fy, 1), so
  // its distance to the plane is z (n . r) + d, and n . r is linear in u and v.
  const Vec3& n = plane.normal;
  const double du = n.x() / camera.fx, dv = n.y() / camera.fy;
  const double c = n.z() - n.x() * camera.cx / camera.fx - n.y() * camera.cy / camera.fy;
  cv::Mat pixels(depth.size(), CV_8UC1, cv::Scalar(0));
  for (int v = depth.rows / 2; v < depth.rows; ++v) {
    const float* z = depth.ptr<float>(v);
    uint8_t* g = pixels.ptr<uint8_t>(v);
    for (int u = 0; u < depth.cols; ++u) {
      if (z[u] > 0 && z[u] < max_range_m &&
          std::abs(z[u] * (du * u + dv * v + c) + plane.d) < threshold_m)
        g[u] = 255;
    }
  }
  return pixels;
}

}  // namespace radslam
