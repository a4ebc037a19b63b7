// All keyframes the mapper trains on (no window), with their refined poses, pose optimiser
// state and training statistics. A keyframe re-sent with a higher version replaces the old one
// in place; an equal or lower version is ignored.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"

namespace radslam {

struct KeyframeEntry {
  Keyframe keyframe;  // as received; its images are validated and normalised (see insert)
  /// Pose used for training and rendering: the received pose, then refined by the mapper.
  SE3 T_world_cam;
  bool pose_refined = false;  // changed by the mapper since takeRefinedPoses()
  // Adam state of the pose (tangent (v, w) of a right perturbation).
  Vec6 pose_m = Vec6::Zero();
  Vec6 pose_v = Vec6::Zero();
  int64_t pose_steps = 0;
  /// Colour model of this keyframe's camera (auto exposure and white balance, see
  /// applyExposure in mapper/trainer.h): log gains (R, G, B), then offsets (R, G, B); zero =
  /// the field's own colour. The gauge keyframe keeps zero, which fixes the field's colours.
  Vec6 exposure = Vec6::Zero();
  Vec6 exposure_m = Vec6::Zero();  // its Adam state
  Vec6 exposure_v = Vec6::Zero();
  int64_t exposure_steps = 0;
  // Training statistics for choosing keyframes.
  double loss_ema = 0;       // running mean loss per ray (0 = not measured yet)
  int64_t rays_trained = 0;  // rays drawn from this keyframe since it (last) arrived
  int64_t arrival = 0;       // insertion counter, also bumped on replacement
  /// Trainable pixels (y * width + x): inside the image and not on a moving object.
  std::vector<int32_t> pixels;
};

class KeyframeStore {
 public:
  enum class InsertResult { kAdded, kReplaced, kIgnored };

  /// Validates and stores a keyframe. Colour must be CV_8UC3 (BGR) or CV_8UC1 of the camera's
  /// size; depth and depth_var CV_32FC1 of that size or empty (then derived from inv_depth
  /// and inv_depth_var when those exist); dynamic_mask CV_8UC1 or empty. Non-finite or
  /// negative depths become 0 (unknown), bad variances become infinite (no depth weight).
  /// Throws std::invalid_argument naming the keyframe and what is wrong. The images are
  /// deep-copied. A replacement of the same image (same header time) keeps its exposure; the
  /// rest restarts. *resent (when given) says whether it was such a replacement.
  InsertResult insert(const Keyframe& keyframe, bool* resent = nullptr);

  int size() const { return static_cast<int>(entries_.size()); }
  KeyframeEntry& entry(int i) { return entries_[i]; }
  const KeyframeEntry& entry(int i) const { return entries_[i]; }
  /// Index of the keyframe with this id, -1 if none.
  int find(int32_t keyframe_id) const;
  /// The gauge: the keyframe with the smallest id (its pose is never refined); -1 if empty.
  int gaugeIndex() const;
  void clear() { entries_.clear(); }
  void erase(int i) { entries_.erase(entries_.begin() + i); }
  /// Appends an entry as is (checkpoint loading); replaces one with the same id.
  void restore(KeyframeEntry entry);
  int64_t arrivals() const { return arrivals_; }
  void setArrivals(int64_t n) { arrivals_ = n; }

 private:
  std::vector<KeyframeEntry> entries_;
  int64_t arrivals_ = 0;
};

/// The same pose with a quaternion that SE3's constructor leaves bit-for-bit unchanged
/// (normalising a unit quaternion can move its last bit): checkpoints store quaternions, and a
/// reloaded pose must equal the saved one exactly.
SE3 canonicalPose(const SE3& T);

/// Checks a keyframe and returns the normalised copy insert() stores (exposed for tests).
Keyframe normalizeKeyframe(const Keyframe& keyframe);

}  // namespace radslam
