// Readers of the datasets radslam plays: TUM RGB-D, EuRoC ASL, KITTI odometry,
// Replica (NICE-SLAM layout) and radslam's own synthetic format.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/trajectory.h"
#include "common/types.h"

namespace radslam {

/// Ground-truth pose of one moving object at one time (synthetic scenes).
struct ObjectPoseSample {
  double t = 0;  // s
  int32_t object_id = 0;
  int32_t class_id = 0;
  SE3 T_world_object;
};

/// Semantic class description (synthetic scenes; also the config's class table).
struct SemanticClass {
  int32_t id = 0;
  std::string name;
  bool dynamic = false;
  JointType joint = JointType::kFree;
  std::string parent;  // name of the static parent class ("" if none)
};

class DatasetReader {
 public:
  virtual ~DatasetReader() = default;
  /// Human-readable name, e.g. "tum:/path/to/rgbd_dataset_freiburg1_rpy".
  virtual std::string name() const = 0;
  virtual size_t size() const = 0;
  /// Sensor time of frame i, seconds on the dataset's clock.
  virtual double timestamp(size_t i) const = 0;
  /// Loads frame i (header.utime, frame_index = i, camera and images filled).
  /// Returns std::nullopt and fills *error (naming the file and what is wrong)
  /// when a file is missing or corrupt: the caller skips the frame with a warning.
  virtual std::optional<Frame> frame(size_t i, std::string* error) const = 0;
  /// Camera-to-world ground truth at the dataset's own stamps (may be empty).
  virtual const Trajectory& groundTruth() const = 0;
  virtual std::vector<ObjectPoseSample> objectGroundTruth() const { return {}; }
  virtual std::vector<SemanticClass> classes() const { return {}; }
  virtual bool hasDepth() const { return false; }
  virtual bool hasStereo() const { return false; }
};

/// Opens "KIND:PATH" with KIND one of tum, euroc, kitti, replica, synthetic.
/// Throws std::runtime_error with a clear message (missing folder, missing
/// index file, bad calibration) when the dataset cannot be read.
std::unique_ptr<DatasetReader> openDataset(const std::string& spec);

}  // namespace radslam
