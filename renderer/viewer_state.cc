#include "renderer/viewer_state.h"

#include <cmath>
#include <cstdio>
#include <sstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/alignment.h"
#include "common/process_stats.h"
#include "renderer/render_service.h"

namespace radslam {
namespace {

// Trajectory points sent to the browser at most (subsampled evenly).
constexpr size_t kMaxPlotPoints = 2000;

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\u%04x", c);
      out += buf;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

std::string num(double v) {
  if (!std::isfinite(v)) return "null";
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.9g", v);
  return buf;
}

std::string plotPoints(const std::map<int64_t, Eigen::Vector3d>& points) {
  std::string out = "[";
  const size_t step = points.size() / kMaxPlotPoints + 1;
  size_t i = 0;
  for (auto it = points.begin(); it != points.end(); ++it, ++i) {
    // Keep the last point so the plot ends where the camera is.
    if (i % step != 0 && std::next(it) != points.end()) continue;
    if (out.size() > 1) out += ",";
    out += "[" + num(it->second.x()) + "," + num(it->second.z()) + "]";
  }
  return out + "]";
}

// Ground truth in the estimate's world: the similarity that best maps its camera centres onto
// the tracked ones of the same frames (monocular scale and the world frame are arbitrary; the
// evaluation aligns the same way), or as it is while that is not determined (fewer than 3
// shared frames, or all at one point).
std::map<int64_t, Eigen::Vector3d> alignedGroundTruth(
    const std::map<int64_t, Eigen::Vector3d>& ground_truth,
    const std::map<int64_t, Eigen::Vector3d>& trajectory) {
  std::vector<Vec3> src, dst;
  for (const auto& [frame, p] : ground_truth) {
    const auto it = trajectory.find(frame);
    if (it == trajectory.end()) continue;
    src.push_back(p);
    dst.push_back(it->second);
  }
  if (src.size() < 3) return ground_truth;
  Sim3 T_est_gt;
  try {
    T_est_gt = alignUmeyama(src, dst, true);
  } catch (const std::invalid_argument&) {
    return ground_truth;
  }
  std::map<int64_t, Eigen::Vector3d> aligned;
  for (const auto& [frame, p] : ground_truth) aligned[frame] = T_est_gt * p;
  return aligned;
}

const char* stateName(ProcessState s) {
  switch (s) {
    case ProcessState::kStarting:
      return "starting";
    case ProcessState::kRunning:
      return "running";
    case ProcessState::kIdle:
      return "idle";
    case ProcessState::kDone:
      return "done";
    case ProcessState::kError:
      return "error";
  }
  return "unknown";
}

}  // namespace

void ViewerState::setCamera(const Frame& frame) {
  cv::Mat copy = frame.color.clone();
  std::lock_guard<std::mutex> lock(mutex_);
  camera_ = copy;
  camera_model_ = frame.camera;
  camera_frame_ = frame.frame_index;
  ++image_seq_[static_cast<int>(ViewerImage::kCamera)];
}

void ViewerState::addPose(const PoseStamped& pose) {
  std::lock_guard<std::mutex> lock(mutex_);
  trajectory_[pose.frame_index] = pose.T_world_cam.translation();
  if (!has_pose_ || pose.frame_index >= pose_.frame_index) {
    pose_ = pose;
    has_pose_ = true;
    ++pose_seq_;
  }
}

void ViewerState::addGroundTruth(const PoseStamped& pose) {
  std::lock_guard<std::mutex> lock(mutex_);
  ground_truth_[pose.frame_index] = pose.T_world_cam.translation();
}

void ViewerState::addObjects(const ObjectList& objects) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const TrackedObject& o : objects.objects) {
    ObjectTrack& track = objects_[o.object_id];
    track.class_id = o.class_id;
    track.joint = o.joint_type;
    track.positions[objects.frame_index] = o.T_world_object.translation();
  }
}

void ViewerState::addKeyframe(int32_t keyframe_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  keyframes_[keyframe_id] = true;
}

void ViewerState::setStatus(const Status& status) {
  std::lock_guard<std::mutex> lock(mutex_);
  status_[status.process.empty() ? status.header.sender : status.process] = status;
}

void ViewerState::setRender(const cv::Mat& bgr, const cv::Mat& depth, const cv::Mat& sigma) {
  std::lock_guard<std::mutex> lock(mutex_);
  render_ = bgr;
  depth_ = depth;
  sigma_ = sigma;
  for (ViewerImage i : {ViewerImage::kRender, ViewerImage::kDepth, ViewerImage::kSigma})
    ++image_seq_[static_cast<int>(i)];
}

void ViewerState::setField(int64_t version, size_t blocks, const Eigen::Vector3f& lo,
                           const Eigen::Vector3f& hi) {
  std::lock_guard<std::mutex> lock(mutex_);
  field_version_ = version;
  field_blocks_ = blocks;
  has_bounds_ = lo.allFinite() && hi.allFinite() && (hi.array() >= lo.array()).all();
  if (has_bounds_) {
    bounds_lo_ = lo;
    bounds_hi_ = hi;
  }
}

void ViewerState::setRunEnded(bool ended) {
  std::lock_guard<std::mutex> lock(mutex_);
  run_ended_ = ended;
}

std::vector<uint8_t> ViewerState::imageJpeg(ViewerImage which) const {
  cv::Mat image;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    switch (which) {
      case ViewerImage::kCamera:
        image = camera_;
        break;
      case ViewerImage::kRender:
        image = render_;
        break;
      case ViewerImage::kDepth:
        image = depth_;
        break;
      case ViewerImage::kSigma:
        image = sigma_;
        break;
    }
  }
  // Encoding happens outside the lock: the mats are never written in place, only replaced.
  if (image.empty()) return {};
  if (which == ViewerImage::kDepth) image = colorizeDepth(image);
  if (which == ViewerImage::kSigma) image = colorizeSigma(image);
  std::vector<uint8_t> bytes;
  cv::imencode(".jpg", image, bytes, {cv::IMWRITE_JPEG_QUALITY, 85});
  return bytes;
}

bool ViewerState::latestPose(PoseStamped* pose, CameraModel* camera, int64_t* pose_seq) const {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!has_pose_ || camera_model_.width <= 0) return false;
  *pose = pose_;
  *camera = camera_model_;
  *pose_seq = pose_seq_;
  return true;
}

std::string ViewerState::stateJson() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::ostringstream o;
  char wall[32];
  std::snprintf(wall, sizeof(wall), "%.3f", wallClockMicros() * 1e-6);
  o << "{\"wall_s\":" << wall;
  o << ",\"run_ended\":" << (run_ended_ ? "true" : "false");
  o << ",\"field\":{\"version\":" << field_version_ << ",\"blocks\":" << field_blocks_;
  if (has_bounds_) {
    o << ",\"bounds\":[" << num(bounds_lo_.x()) << "," << num(bounds_lo_.y()) << ","
      << num(bounds_lo_.z()) << "," << num(bounds_hi_.x()) << "," << num(bounds_hi_.y()) << ","
      << num(bounds_hi_.z()) << "]";
  }
  o << "},\"keyframes\":" << keyframes_.size();
  o << ",\"frame_index\":" << camera_frame_;
  const CameraModel& c = camera_model_;
  o << ",\"camera\":{\"width\":" << c.width << ",\"height\":" << c.height << ",\"fx\":" << num(c.fx)
    << ",\"fy\":" << num(c.fy) << ",\"cx\":" << num(c.cx) << ",\"cy\":" << num(c.cy) << "}";
  if (has_pose_) {
    const Eigen::Vector3d t = pose_.T_world_cam.translation();
    const Eigen::Quaterniond q = pose_.T_world_cam.quaternion();
    o << ",\"pose\":{\"frame_index\":" << pose_.frame_index << ",\"t\":[" << num(t.x()) << ","
      << num(t.y()) << "," << num(t.z()) << "],\"q\":[" << num(q.x()) << "," << num(q.y()) << ","
      << num(q.z()) << "," << num(q.w()) << "]}";
  }
  o << ",\"trajectory\":" << plotPoints(trajectory_);
  o << ",\"ground_truth\":" << plotPoints(alignedGroundTruth(ground_truth_, trajectory_));
  o << ",\"objects\":[";
  for (auto it = objects_.begin(); it != objects_.end(); ++it) {
    if (it != objects_.begin()) o << ",";
    o << "{\"id\":" << it->first << ",\"class\":" << it->second.class_id << ",\"joint\":\""
      << jointTypeName(it->second.joint) << "\",\"track\":" << plotPoints(it->second.positions)
      << "}";
  }
  o << "]";
  o << ",\"images\":{\"camera\":" << image_seq_[0] << ",\"render\":" << image_seq_[1]
    << ",\"depth\":" << image_seq_[2] << ",\"sigma\":" << image_seq_[3] << "}";
  o << ",\"status\":[";
  bool first = true;
  const int64_t now = wallClockMicros();
  for (const auto& [name, s] : status_) {
    if (!first) o << ",";
    first = false;
    o << "{\"process\":" << jsonString(name) << ",\"state\":\"" << stateName(s.state)
      << "\",\"fps\":" << num(s.fps) << ",\"items\":" << s.items_handled
      << ",\"frame\":" << s.last_frame_index << ",\"queue\":" << s.queue_depth
      << ",\"rss_mb\":" << num(s.rss_mb) << ",\"age_s\":" << num((now - s.header.utime) * 1e-6)
      << ",\"last_error\":" << jsonString(s.last_error) << "}";
  }
  o << "]}";
  return o.str();
}

}  // namespace radslam
