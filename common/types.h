// Plain C++ counterparts of the bus messages (lcmtypes/). Core classes take and
// return these; only common/bus.cc converts them to and from LCM.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"

namespace radslam {

struct Header {
  int64_t utime = 0;  // sensor time, microseconds on the dataset's clock
  int64_t seq = 0;
  std::string sender;
};

struct CameraModel {
  enum class Type : int8_t { kPinhole = 0, kRadTan = 1, kEquidistant = 2 };
  int width = 0;   // pixels
  int height = 0;  // pixels
  Type type = Type::kPinhole;
  double fx = 0, fy = 0, cx = 0, cy = 0;  // pixels
  // RadTan: k1 k2 p1 p2 [k3]; Equidistant: k1 k2 k3 k4.
  std::vector<double> distortion;
  // Rolling shutter: s from the exposure of the first row to that of the last (0: global
  // shutter, every row at once).
  double readout_s = 0;
};

/// How an image travels on the bus.
enum class WireCompression : int8_t { kRaw = 0, kPng = 1, kJpeg = 2 };

/// Channel CAMERA. Images are OpenCV matrices:
///  color: CV_8UC3 (BGR, OpenCV order) or CV_8UC1;
///  right: same type as color, rectified; empty when absent;
///  depth: CV_32FC1 metres, 0 = invalid; empty when absent;
///  instance, class_id: CV_16UC1; empty when absent.
struct Frame {
  Header header;
  int64_t frame_index = 0;
  CameraModel camera;
  cv::Mat color;
  cv::Mat right;
  double baseline_m = 0;
  cv::Mat depth;
  // s, the depth image's time stamp minus the colour image's (TUM's Kinect: up to 20 ms, either
  // way); below 1 s in magnitude.
  double depth_time_offset_s = 0;
  cv::Mat instance;
  cv::Mat class_id;
  // Wire encoding hints (not part of the data): colour compression, and the
  // depth quantisation in metres per unit (0 = send float32 losslessly).
  WireCompression color_compression = WireCompression::kRaw;
  double depth_wire_scale = 0;
};

enum class TrackingState : int8_t { kInitializing = 0, kTracking = 1, kLost = 2, kGroundTruth = 3 };

/// "initializing", "tracking", "lost" or "ground_truth".
inline const char* trackingStateName(TrackingState state) {
  switch (state) {
    case TrackingState::kInitializing:
      return "initializing";
    case TrackingState::kTracking:
      return "tracking";
    case TrackingState::kLost:
      return "lost";
    case TrackingState::kGroundTruth:
      return "ground_truth";
  }
  return "unknown";
}

/// Channels POSE and GROUND_TRUTH.
struct PoseStamped {
  Header header;
  int64_t frame_index = 0;
  TrackingState state = TrackingState::kTracking;
  bool is_keyframe = false;
  SE3 T_world_cam;
  // Covariance of xi = (v, w), right perturbation: T_world_cam * Exp(xi).
  Mat6 covariance = Mat6::Zero();
};

/// Channel KEYFRAME. Images at keyframe resolution; float images CV_32FC1.
struct Keyframe {
  Header header;
  int32_t keyframe_id = 0;
  int32_t version = 0;
  int64_t frame_index = 0;
  SE3 T_world_cam;
  Mat6 covariance = Mat6::Zero();  // as PoseStamped::covariance
  CameraModel camera;
  cv::Mat color;          // CV_8UC3 BGR or CV_8UC1
  cv::Mat inv_depth;      // 1/m
  cv::Mat inv_depth_var;  // 1/m^2
  cv::Mat depth;          // m, 0 = unknown
  cv::Mat depth_var;      // m^2
  cv::Mat dynamic_mask;   // CV_8UC1, 255 = moving object; may be empty
};

enum class JointType : int8_t { kFree = 0, kPlanar = 1, kRevolute = 2 };

/// "free", "planar" or "revolute".
inline const char* jointTypeName(JointType type) {
  switch (type) {
    case JointType::kPlanar:
      return "planar";
    case JointType::kRevolute:
      return "revolute";
    case JointType::kFree:
      return "free";
  }
  return "unknown";
}

struct TrackedObject {
  int32_t object_id = 0;
  int32_t class_id = 0;
  std::string class_name;
  SE3 T_world_object;
  Vec6 twist = Vec6::Zero();  // (v, w) in the joint frame, m/s and rad/s
  JointType joint_type = JointType::kFree;
  SE3 T_world_joint;  // z = plane normal or hinge axis
  int32_t parent_cluster = -1;
  Mat6 covariance = Mat6::Zero();
};

/// Channels OBJECTS and GROUND_TRUTH_OBJECTS.
struct ObjectList {
  Header header;
  int64_t frame_index = 0;
  std::vector<TrackedObject> objects;
};

struct FieldBlock {
  int8_t level = 0;
  Eigen::Vector3i index = Eigen::Vector3i::Zero();
  std::vector<uint8_t> data;
};

/// Channel FIELD.
struct FieldUpdate {
  Header header;
  int64_t version = 0;
  int64_t base_version = 0;
  bool is_snapshot = false;
  // Snapshots travel in chunks (mapper/field_io.h): chunk_index of chunk_count, one snapshot_id.
  int64_t snapshot_id = 0;
  int32_t chunk_index = 0;
  int32_t chunk_count = 1;
  std::string layout;
  std::vector<double> voxel_size;  // m, per level
  int32_t block_dim = 0;
  std::vector<FieldBlock> blocks;
};

enum RenderChannel : int32_t { kRenderColor = 1, kRenderDepth = 2, kRenderSigma = 4 };

/// Channel RENDER_REQUEST.
struct RenderRequest {
  Header header;
  int64_t request_id = 0;
  std::string client;
  SE3 T_world_cam;
  CameraModel camera;
  int32_t channels = kRenderColor | kRenderDepth;
};

/// Channel RENDER.
struct RenderResult {
  Header header;
  int64_t request_id = 0;
  std::string client;
  bool ok = false;
  std::string error;
  int64_t field_version = 0;
  cv::Mat color;  // CV_8UC3 BGR
  cv::Mat depth;  // CV_32FC1 m
  cv::Mat sigma;  // CV_32FC1 m
};

enum class ProcessState : int8_t { kStarting = 0, kRunning = 1, kIdle = 2, kDone = 3, kError = 4 };

/// Channel STATUS.
struct Status {
  Header header;  // utime: wall clock
  std::string process;
  int32_t pid = 0;
  ProcessState state = ProcessState::kStarting;
  int64_t last_frame_index = -1;
  int64_t last_frame_utime = 0;
  int64_t items_handled = 0;
  double busy_s = 0;
  double fps = 0;
  int32_t queue_depth = 0;
  double rss_mb = 0;
  double peak_rss_mb = 0;
  std::string last_error;
  std::vector<std::pair<std::string, double>> values;
};

enum class ControlCommand : int8_t {
  kStop = 0,
  kSave = 1,
  kReset = 2,
  kSnapshot = 3,
  kRepublish = 4,
  kRewind = 5
};

/// Channel CONTROL.
struct Control {
  Header header;
  ControlCommand command = ControlCommand::kStop;
  std::string target;  // process name, "" = all
  std::string argument;
};

}  // namespace radslam
