#include "mapper/mapping_eval.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/alignment.h"
#include "common/evaluation.h"
#include "common/exr_io.h"

namespace radslam {

double psnr(const cv::Mat& reference_bgr8, const cv::Mat& rendered_rgb) {
  if (reference_bgr8.type() != CV_8UC3 || rendered_rgb.type() != CV_32FC3 ||
      reference_bgr8.size() != rendered_rgb.size())
    throw std::invalid_argument(
        "psnr: expected a CV_8UC3 reference and a CV_32FC3 render of "
        "the same size");
  cv::Mat ref;
  reference_bgr8.convertTo(ref, CV_32FC3, 1 / 255.0);
  cv::cvtColor(ref, ref, cv::COLOR_BGR2RGB);
  const cv::Mat d = ref - rendered_rgb;
  const cv::Scalar s = cv::mean(d.mul(d));
  const double mse = (s[0] + s[1] + s[2]) / 3;
  return 10 * std::log10(1 / std::max(mse, 1e-12));
}

DepthError& DepthError::operator+=(const DepthError& o) {
  sum_abs += o.sum_abs;
  pixels += o.pixels;
  valid += o.valid;
  for (int b = 0; b < kBins; ++b) {
    bin_abs[b] += o.bin_abs[b];
    bin_signed[b] += o.bin_signed[b];
    bin_pixels[b] += o.bin_pixels[b];
  }
  return *this;
}

DepthError depthError(const cv::Mat& rendered, const cv::Mat& reference) {
  if (rendered.type() != CV_32FC1 || reference.type() != CV_32FC1 ||
      rendered.size() != reference.size())
    throw std::invalid_argument("depthError: expected two CV_32FC1 images of the same size");
  DepthError e;
  for (int y = 0; y < reference.rows; ++y) {
    const float* r = reference.ptr<float>(y);
    const float* d = rendered.ptr<float>(y);
    for (int x = 0; x < reference.cols; ++x) {
      if (!(r[x] > 0) || !std::isfinite(r[x])) continue;
      ++e.valid;
      if (!(d[x] > 0) || !std::isfinite(d[x])) continue;
      const double error = double(d[x]) - r[x];
      const int bin = std::min(DepthError::kBins - 1, static_cast<int>(r[x]));
      e.sum_abs += std::abs(error);
      ++e.pixels;
      e.bin_abs[bin] += std::abs(error);
      e.bin_signed[bin] += error;
      ++e.bin_pixels[bin];
    }
  }
  return e;
}

std::optional<SE3> poseAt(const Trajectory& trajectory, double t, double max_gap_s) {
  const auto after = std::lower_bound(trajectory.begin(), trajectory.end(), t,
                                      [](const StampedPose& p, double v) { return p.t < v; });
  if (after == trajectory.end()) return std::nullopt;
  if (after->t == t) return after->T_world_cam;
  if (after == trajectory.begin()) return std::nullopt;
  const StampedPose& a = *std::prev(after);
  const StampedPose& b = *after;
  if (b.t - a.t > max_gap_s) return std::nullopt;
  const double s = (t - a.t) / (b.t - a.t);
  const Eigen::Quaterniond q =
      a.T_world_cam.quaternion().slerp(s, b.T_world_cam.quaternion()).normalized();
  const Vec3 p = (1 - s) * a.T_world_cam.translation() + s * b.T_world_cam.translation();
  return SE3(q, p);
}

cv::Mat sensorDepthVariance(const cv::Mat& depth, int foreground_edge_px) {
  CV_Assert(depth.type() == CV_32FC1 && foreground_edge_px >= 0);
  // The depth range of each 3x3 neighbourhood over valid pixels (invalid ones neither raise
  // the maximum nor lower the minimum).
  cv::Mat valid = depth > 0;
  cv::Mat hi, lo, for_min;
  cv::dilate(depth, hi, cv::Mat());
  depth.copyTo(for_min);
  for_min.setTo(1e9, ~valid);
  cv::erode(for_min, lo, cv::Mat());
  // The deepest depth within the foreground edge band (invalid pixels are 0).
  cv::Mat deepest;
  if (foreground_edge_px > 0)
    cv::dilate(depth, deepest,
               cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * foreground_edge_px + 1,
                                                                  2 * foreground_edge_px + 1)));
  cv::Mat var(depth.size(), CV_32FC1);
  for (int y = 0; y < depth.rows; ++y) {
    const float* z = depth.ptr<float>(y);
    const float* h = hi.ptr<float>(y);
    const float* l = lo.ptr<float>(y);
    float* v = var.ptr<float>(y);
    for (int x = 0; x < depth.cols; ++x) {
      if (!(z[x] > 0) || !std::isfinite(z[x]) ||
          (!deepest.empty() && deepest.at<float>(y, x) > 1.1f * z[x])) {
        v[x] = INFINITY;
        continue;
      }
      const float sigma = 0.0012f + 0.0019f * (z[x] - 0.4f) * (z[x] - 0.4f) + 0.5f * (h[x] - l[x]);
      v[x] = sigma * sigma;
    }
  }
  return var;
}

TrackerRun readTrackerRun(const std::string& dir) {
  namespace fs = std::filesystem;
  TrackerRun run;
  for (const char* name : {"trajectory.txt", "keyframes.txt"})
    if (!fs::is_regular_file(fs::path(dir) / name))
      throw std::runtime_error("tracker run " + dir + ": " + name + " is missing");
  run.trajectory = readTumTrajectory((fs::path(dir) / "trajectory.txt").string());
  const Trajectory keyframes = readTumTrajectory((fs::path(dir) / "keyframes.txt").string());
  if (keyframes.empty())
    throw std::runtime_error("tracker run " + dir + ": keyframes.txt lists no keyframe");
  for (const StampedPose& p : keyframes) {
    const std::string stem = stampFileName(std::llround(p.t * 1e6));
    const std::string exr = (fs::path(dir) / "keyframes" / (stem + ".exr")).string();
    if (!fs::is_regular_file(exr))
      throw std::runtime_error("tracker run " + dir + ": " + exr + " (keyframe depth) is missing");
    TrackerKeyframe kf;
    kf.t = p.t;
    kf.T_world_cam = p.T_world_cam;
    kf.depth = readExrChannel(exr, "depth");
    kf.sigma = readExrChannel(exr, "sigma");
    if (kf.depth.size() != kf.sigma.size())
      throw std::runtime_error(exr + ": depth and sigma channels differ in size");
    const std::string png = (fs::path(dir) / "keyframes" / (stem + ".png")).string();
    if (fs::is_regular_file(png)) {
      kf.color = cv::imread(png, cv::IMREAD_COLOR);
      if (kf.color.size() != kf.depth.size())
        throw std::runtime_error(png + ": not a colour image of the depth's size " +
                                 std::to_string(kf.depth.cols) + "x" +
                                 std::to_string(kf.depth.rows));
    }
    run.keyframes.push_back(std::move(kf));
  }
  return run;
}

Sim3 alignToGroundTruth(const Trajectory& estimate, const Trajectory& ground_truth, double scale,
                        double max_gap_s, SO3* camera_offset) {
  std::vector<Vec3> src, dst;
  std::vector<SO3> src_r, dst_r;
  for (const StampedPose& p : estimate) {
    const std::optional<SE3> gt = poseAt(ground_truth, p.t, max_gap_s);
    if (!gt) continue;
    src.push_back(p.T_world_cam.translation());
    dst.push_back(gt->translation());
    src_r.push_back(p.T_world_cam.so3());
    dst_r.push_back(gt->so3());
  }
  if (src.size() < 3)
    throw std::invalid_argument("alignToGroundTruth: fewer than 3 poses have ground truth");
  SO3 R;
  if (camera_offset) {
    const WorldAndCameraRotation fit = alignRotationsWithCameraOffset(src_r, dst_r);
    R = fit.world;
    *camera_offset = fit.camera;
  } else {
    R = alignRotationOnly(src_r, dst_r);
  }
  if (!(scale > 0)) scale = alignUmeyama(src, dst, true).scale();
  Vec3 mean_src = Vec3::Zero(), mean_dst = Vec3::Zero();
  for (size_t i = 0; i < src.size(); ++i) {
    mean_src += src[i];
    mean_dst += dst[i];
  }
  mean_src /= double(src.size());
  mean_dst /= double(src.size());
  return Sim3(R, mean_dst - scale * (R * mean_src), scale);
}

}  // namespace radslam
