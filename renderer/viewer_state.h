// What the web viewer shows: the latest message per channel, kept under one mutex so that the
// bus thread only swaps slots and the HTTP threads only read copies (a slow browser never
// slows the pipeline).
#pragma once

#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/types.h"

namespace radslam {

/// Images the viewer can fetch by name.
enum class ViewerImage { kCamera, kRender, kDepth, kSigma };

class ViewerState {
 public:
  void setCamera(const Frame& frame);
  /// Tracked pose (also refreshed poses of earlier frames, keyed by frame index).
  void addPose(const PoseStamped& pose);
  void addGroundTruth(const PoseStamped& pose);
  /// Tracked moving objects of a frame (channel OBJECTS): their tracks are plotted.
  void addObjects(const ObjectList& objects);
  void addKeyframe(int32_t keyframe_id);
  void setStatus(const Status& status);
  /// The follow view (rendered at the latest pose): BGR colour, depth and sigma (m).
  void setRender(const cv::Mat& bgr, const cv::Mat& depth, const cv::Mat& sigma);
  void setField(int64_t version, size_t blocks, const Eigen::Vector3f& lo,
                const Eigen::Vector3f& hi);
  void setRunEnded(bool ended);

  /// JPEG bytes of an image (colour-mapped depth and sigma); empty when none yet.
  std::vector<uint8_t> imageJpeg(ViewerImage which) const;
  /// Everything else as one JSON object (see renderer/web/viewer.js for the fields).
  std::string stateJson() const;
  /// Latest tracked pose and camera, false when none yet (follow rendering).
  bool latestPose(PoseStamped* pose, CameraModel* camera, int64_t* pose_seq) const;

 private:
  mutable std::mutex mutex_;
  cv::Mat camera_;
  CameraModel camera_model_;
  int64_t camera_frame_ = -1;
  PoseStamped pose_;
  bool has_pose_ = false;
  int64_t pose_seq_ = 0;
  std::map<int64_t, Eigen::Vector3d> trajectory_;    // frame index -> camera centre (world, m)
  std::map<int64_t, Eigen::Vector3d> ground_truth_;  // likewise
  struct ObjectTrack {
    int32_t class_id = 0;
    JointType joint = JointType::kFree;
    std::map<int64_t, Eigen::Vector3d> positions;  // frame index -> object origin (world, m)
  };
  std::map<int32_t, ObjectTrack> objects_;  // by object id
  std::map<int32_t, bool> keyframes_;
  std::map<std::string, Status> status_;
  cv::Mat render_, depth_, sigma_;
  int64_t image_seq_[4] = {0, 0, 0, 0};
  int64_t field_version_ = 0;
  size_t field_blocks_ = 0;
  Eigen::Vector3f bounds_lo_ = Eigen::Vector3f::Zero(), bounds_hi_ = Eigen::Vector3f::Zero();
  bool has_bounds_ = false;
  bool run_ended_ = false;
};

}  // namespace radslam
