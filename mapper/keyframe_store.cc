#include "mapper/keyframe_store.h"

#include <cmath>
#include <limits>
#include <stdexcept>

#include "common/camera.h"

namespace radslam {

namespace {

std::string name(const Keyframe& kf) {
  return "keyframe " + std::to_string(kf.keyframe_id) + " (version " + std::to_string(kf.version) +
         ")";
}

void checkImage(const Keyframe& kf, const cv::Mat& image, const char* what, int type,
                bool required) {
  if (image.empty()) {
    if (required) throw std::invalid_argument(name(kf) + ": " + what + " image is missing");
    return;
  }
  if (image.type() != type)
    throw std::invalid_argument(name(kf) + ": " + what + " image has the wrong type (" +
                                std::to_string(image.type()) + ", expected " +
                                std::to_string(type) + ")");
  if (image.cols != kf.camera.width || image.rows != kf.camera.height)
    throw std::invalid_argument(name(kf) + ": " + what + " image is " + std::to_string(image.cols) +
                                "x" + std::to_string(image.rows) + ", camera is " +
                                std::to_string(kf.camera.width) + "x" +
                                std::to_string(kf.camera.height));
}

}  // namespace

SE3 canonicalPose(const SE3& T) {
  SE3 out = T;
  for (int i = 0; i < 8; ++i) {
    const SE3 again(out.quaternion(), out.translation());
    if (again.quaternion().coeffs() == out.quaternion().coeffs()) break;
    out = again;
  }
  return out;
}

Keyframe normalizeKeyframe(const Keyframe& kf) {
  try {
    validateCamera(kf.camera);
  } catch (const std::exception& e) {
    throw std::invalid_argument(name(kf) + ": " + e.what());
  }
  bool distorted = kf.camera.type == CameraModel::Type::kEquidistant;
  for (double d : kf.camera.distortion) distorted = distorted || d != 0;
  if (distorted)
    throw std::invalid_argument(name(kf) +
                                ": camera has distortion; the mapper needs undistorted "
                                "pinhole keyframes");
  if (!kf.T_world_cam.translation().allFinite() ||
      !kf.T_world_cam.quaternion().coeffs().allFinite())
    throw std::invalid_argument(name(kf) + ": pose is not finite");
  if (kf.color.empty()) throw std::invalid_argument(name(kf) + ": colour image is missing");
  checkImage(kf, kf.color, "colour", kf.color.channels() == 1 ? CV_8UC1 : CV_8UC3, true);
  checkImage(kf, kf.depth, "depth", CV_32FC1, false);
  checkImage(kf, kf.depth_var, "depth_var", CV_32FC1, false);
  checkImage(kf, kf.inv_depth, "inv_depth", CV_32FC1, false);
  checkImage(kf, kf.inv_depth_var, "inv_depth_var", CV_32FC1, false);
  checkImage(kf, kf.dynamic_mask, "dynamic_mask", CV_8UC1, false);

  Keyframe out = kf;
  out.T_world_cam = canonicalPose(kf.T_world_cam);
  out.color = kf.color.clone();
  out.dynamic_mask = kf.dynamic_mask.clone();
  out.inv_depth = kf.inv_depth.clone();
  out.inv_depth_var = kf.inv_depth_var.clone();
  const int w = kf.camera.width, h = kf.camera.height;
  // Fresh buffers: `out` still shares the caller's images (assigning a MatExpr would write
  // into them).
  out.depth = cv::Mat(h, w, CV_32FC1, cv::Scalar(0));
  out.depth_var = cv::Mat(h, w, CV_32FC1, cv::Scalar(std::numeric_limits<float>::infinity()));
  const float kInf = std::numeric_limits<float>::infinity();
  for (int y = 0; y < h; ++y) {
    float* depth = out.depth.ptr<float>(y);
    float* var = out.depth_var.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      float d = 0, v = kInf;
      if (!kf.depth.empty()) {
        d = kf.depth.at<float>(y, x);
        if (!kf.depth_var.empty()) v = kf.depth_var.at<float>(y, x);
      } else if (!kf.inv_depth.empty()) {
        // First-order propagation: var(z) = var(1/z) z^4.
        const float id = kf.inv_depth.at<float>(y, x);
        d = id > 0 ? 1.f / id : 0.f;
        if (!kf.inv_depth_var.empty()) v = kf.inv_depth_var.at<float>(y, x) * d * d * d * d;
      }
      if (!(d > 0) || !std::isfinite(d)) d = 0;
      if (!(v >= 0) || !std::isfinite(v)) v = kInf;
      depth[x] = d;
      var[x] = v;
    }
  }
  return out;
}

KeyframeStore::InsertResult KeyframeStore::insert(const Keyframe& keyframe, bool* resent) {
  if (resent) *resent = false;
  const int existing = find(keyframe.keyframe_id);
  if (existing >= 0 && entries_[existing].keyframe.version >= keyframe.version)
    return InsertResult::kIgnored;
  KeyframeEntry entry;
  entry.keyframe = normalizeKeyframe(keyframe);
  entry.T_world_cam = entry.keyframe.T_world_cam;
  entry.arrival = arrivals_++;
  const cv::Mat& mask = entry.keyframe.dynamic_mask;
  const int w = keyframe.camera.width, h = keyframe.camera.height;
  entry.pixels.reserve(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      if (mask.empty() || mask.at<uint8_t>(y, x) == 0) entry.pixels.push_back(y * w + x);
  if (existing >= 0) {
    // The tracker's refined pose supersedes the mapper's refinement; statistics restart. The
    // same image (a re-sent keyframe) keeps its exposure as trained.
    const KeyframeEntry& old = entries_[existing];
    if (old.keyframe.header.utime == keyframe.header.utime) {
      if (resent) *resent = true;
      entry.exposure = old.exposure;
      entry.exposure_m = old.exposure_m;
      entry.exposure_v = old.exposure_v;
      entry.exposure_steps = old.exposure_steps;
    }
    entries_[existing] = std::move(entry);
    return InsertResult::kReplaced;
  }
  entries_.push_back(std::move(entry));
  return InsertResult::kAdded;
}

int KeyframeStore::find(int32_t keyframe_id) const {
  for (int i = 0; i < size(); ++i)
    if (entries_[i].keyframe.keyframe_id == keyframe_id) return i;
  return -1;
}

int KeyframeStore::gaugeIndex() const {
  int best = -1;
  for (int i = 0; i < size(); ++i)
    if (best < 0 || entries_[i].keyframe.keyframe_id < entries_[best].keyframe.keyframe_id)
      best = i;
  return best;
}

void KeyframeStore::restore(KeyframeEntry entry) {
  const int existing = find(entry.keyframe.keyframe_id);
  if (existing >= 0)
    entries_[existing] = std::move(entry);
  else
    entries_.push_back(std::move(entry));
}

}  // namespace radslam
