#include "recorder/run_recorder.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <stdexcept>

#include "common/evaluation.h"
#include "common/keyframe_files.h"

namespace radslam {
namespace {

namespace fs = std::filesystem;

const char* stateName(ProcessState state) {
  switch (state) {
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
  return "?";
}

double valueOf(const Status& status, const std::string& key, double fallback) {
  for (const auto& [k, v] : status.values)
    if (k == key) return v;
  return fallback;
}

std::string jsonEscape(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buffer[8];
      std::snprintf(buffer, sizeof(buffer), "\\u%04x", c);
      out += buffer;
    } else {
      out += c;
    }
  }
  return out;
}

std::string jsonNumber(double value) {
  if (!std::isfinite(value)) return "null";
  std::ostringstream out;
  out << std::setprecision(10) << value;
  return out.str();
}

std::string jsonKey(const std::string& key) {
  std::string out;
  for (char c : key) out += std::isalnum(static_cast<unsigned char>(c)) ? c : '_';
  return out;
}

void writeObjectTracks(const std::string& path, const std::vector<ObjectList>& lists) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error("cannot write " + path);
  out << "# t object_id class_id tx ty tz qx qy qz qw vx vy vz wx wy wz joint parent\n";
  out << std::setprecision(9);
  for (const ObjectList& list : lists) {
    for (const TrackedObject& o : list.objects) {
      const Eigen::Quaterniond q = o.T_world_object.quaternion();
      const Vec3& t = o.T_world_object.translation();
      out << static_cast<double>(list.header.utime) * 1e-6 << ' ' << o.object_id << ' '
          << o.class_id << ' ' << t.x() << ' ' << t.y() << ' ' << t.z() << ' ' << q.x() << ' '
          << q.y() << ' ' << q.z() << ' ' << q.w();
      for (int k = 0; k < 6; ++k) out << ' ' << o.twist[k];
      out << ' ' << static_cast<int>(o.joint_type) << ' ' << o.parent_cluster << '\n';
    }
  }
}

}  // namespace

bool LogGuard::admits(int64_t written, size_t bytes) {
  constexpr int64_t kDiskCheckBytes = 16'000'000;
  if (!why_.empty()) return false;
  std::ostringstream reason;
  if (params_.max_log_mb > 0 &&
      static_cast<double>(written) + static_cast<double>(bytes) > params_.max_log_mb * 1e6) {
    reason << "it reached max_log_mb = " << params_.max_log_mb;
  } else if (written >= next_disk_check_) {
    next_disk_check_ = written + kDiskCheckBytes;
    std::error_code ec;
    const std::filesystem::space_info space = std::filesystem::space(path_, ec);
    if (!ec && static_cast<double>(space.available) < params_.min_free_disk_mb * 1e6)
      reason << "its disk has " << space.available / 1000000
             << " MB left (min_free_disk_mb = " << params_.min_free_disk_mb << ")";
  }
  if (reason.str().empty()) return true;
  why_ = path_ + " stops growing here: " + reason.str();
  std::cerr << "radslam-record: warning: " << why_ << "\n";
  return false;
}

RunRecorder::RunRecorder(RecorderParams params) : params_(std::move(params)) {}

void RunRecorder::onCameraFrame(int64_t) { ++camera_frames_; }

void RunRecorder::onPose(const PoseStamped& pose) { poses_[pose.frame_index] = pose; }

void RunRecorder::onGroundTruth(const PoseStamped& pose) {
  ground_truth_[pose.header.utime] = pose;
}

void RunRecorder::onKeyframe(const Keyframe& keyframe, int64_t recv_utime) {
  ++keyframe_messages_;
  if (keyframe.header.utime > mapper_handled_utime_)
    keyframe_arrival_.emplace(keyframe.header.utime, recv_utime);
  auto it = keyframes_.find(keyframe.keyframe_id);
  if (it != keyframes_.end() && it->second.version > keyframe.version) return;
  if (params_.keyframe_exr_dir.empty() || !params_.export_keyframe_exr) {
    keyframes_[keyframe.keyframe_id] = keyframe;
    return;
  }
  const bool first = it == keyframes_.end();
  Keyframe& kept = keyframes_[keyframe.keyframe_id];  // the pose only: the images go to disk
  kept.header = keyframe.header;
  kept.keyframe_id = keyframe.keyframe_id;
  kept.version = keyframe.version;
  kept.frame_index = keyframe.frame_index;
  kept.T_world_cam = keyframe.T_world_cam;
  if (keyframe.depth.empty()) return;
  try {
    writeKeyframeFiles(params_.keyframe_exr_dir, keyframe);
    if (first) ++exr_written_;
  } catch (const std::exception& e) {
    std::cerr << "radslam-record: warning: keyframe " << keyframe.keyframe_id << ": " << e.what()
              << "\n";
  }
}

void RunRecorder::onObjects(const ObjectList& objects) { objects_.push_back(objects); }

void RunRecorder::onGroundTruthObjects(const ObjectList& objects) {
  ground_truth_objects_.push_back(objects);
}

void RunRecorder::onStatus(const Status& status, int64_t recv_utime) {
  statuses_[status.process] = status;
  if (status.process != "mapper" || status.last_frame_utime <= mapper_handled_utime_) return;
  mapper_handled_utime_ = status.last_frame_utime;
  // The mapper takes keyframes in order: every one up to its last is handled.
  const auto end = keyframe_arrival_.upper_bound(mapper_handled_utime_);
  for (auto it = keyframe_arrival_.begin(); it != end; ++it)
    mapper_lag_s_.push_back(static_cast<double>(recv_utime - it->second) * 1e-6);
  keyframe_arrival_.erase(keyframe_arrival_.begin(), end);
}

std::optional<ProcessState> RunRecorder::processState(const std::string& process) const {
  auto it = statuses_.find(process);
  if (it == statuses_.end()) return std::nullopt;
  return it->second.state;
}

Trajectory RunRecorder::trajectory() const {
  Trajectory out;
  for (const auto& [index, pose] : poses_) {
    if (pose.state != TrackingState::kTracking) continue;
    out.push_back({static_cast<double>(pose.header.utime) * 1e-6, pose.T_world_cam});
  }
  return out;
}

Trajectory RunRecorder::keyframeTrajectory() const {
  Trajectory out;
  for (const auto& [id, keyframe] : keyframes_)
    out.push_back({static_cast<double>(keyframe.header.utime) * 1e-6, keyframe.T_world_cam});
  std::sort(out.begin(), out.end(),
            [](const StampedPose& a, const StampedPose& b) { return a.t < b.t; });
  return out;
}

Trajectory RunRecorder::groundTruth() const {
  Trajectory out;
  for (const auto& [utime, pose] : ground_truth_)
    out.push_back({static_cast<double>(utime) * 1e-6, pose.T_world_cam});
  return out;
}

std::string RunRecorder::progressLine(double wall_s) const {
  std::ostringstream line;
  line << std::fixed << std::setprecision(1) << wall_s << " s | frames " << camera_frames_;
  auto player = statuses_.find("player");
  if (player != statuses_.end()) {
    const double total = valueOf(player->second, "frames_total", -1);
    if (total > 0) line << "/" << static_cast<int64_t>(total);
  }
  line << " | poses " << poses_.size() << " | keyframes " << keyframes_.size();
  for (const auto& [name, status] : statuses_) {
    if (name == "player" || name == "recorder") continue;
    line << " | " << name << " " << std::setprecision(1) << status.fps << " fps";
    if (status.state == ProcessState::kError) line << " ERROR";
  }
  return line.str();
}

void RunRecorder::onMessage(const std::string& channel, int64_t recv_utime, size_t bytes) {
  ChannelTraffic& t = traffic_[channel];
  if (t.messages == 0) t.first_utime = recv_utime;
  ++t.messages;
  t.bytes += static_cast<int64_t>(bytes);
  t.last_utime = recv_utime;
  // Peak rate: the bytes of the last second, kept as a queue (bounded by one second of
  // messages).
  t.recent.emplace_back(recv_utime, bytes);
  t.recent_bytes += static_cast<int64_t>(bytes);
  size_t drop = 0;
  while (drop < t.recent.size() && t.recent[drop].first <= recv_utime - 1000000) {
    t.recent_bytes -= static_cast<int64_t>(t.recent[drop].second);
    ++drop;
  }
  t.recent.erase(t.recent.begin(), t.recent.begin() + static_cast<std::ptrdiff_t>(drop));
  t.max_bytes_in_1s = std::max(t.max_bytes_in_1s, t.recent_bytes);
}

RunRecorder::MapperLag RunRecorder::mapperLag() const {
  MapperLag lag;
  lag.keyframes = static_cast<int>(mapper_lag_s_.size());
  if (mapper_lag_s_.empty()) return lag;
  std::vector<double> sorted = mapper_lag_s_;
  std::sort(sorted.begin(), sorted.end());
  lag.median_s = sorted[sorted.size() / 2];
  lag.max_s = sorted.back();
  return lag;
}

std::string RunRecorder::exportRun(const std::string& out_dir, double wall_s, int64_t log_events,
                                   int64_t log_bytes) const {
  fs::create_directories(out_dir);
  const Trajectory estimate = trajectory();
  const Trajectory keyframe_poses = keyframeTrajectory();
  const Trajectory truth = groundTruth();
  writeTumTrajectory(out_dir + "/trajectory.txt", estimate);
  writeTumTrajectory(out_dir + "/keyframes.txt", keyframe_poses);
  if (!truth.empty()) writeTumTrajectory(out_dir + "/groundtruth.txt", truth);
  if (!objects_.empty()) writeObjectTracks(out_dir + "/objects.txt", objects_);
  if (!ground_truth_objects_.empty())
    writeObjectTracks(out_dir + "/objects_groundtruth.txt", ground_truth_objects_);

  int exr_written = exr_written_;
  if (params_.export_keyframe_exr && params_.keyframe_exr_dir.empty()) {
    for (const auto& [id, keyframe] : keyframes_) {
      if (keyframe.depth.empty()) continue;
      writeKeyframeFiles(out_dir + "/keyframes", keyframe);
      ++exr_written;
    }
  }

  std::string alignment = params_.alignment;
  if (alignment == "auto") alignment = params_.mode == "mono" ? "sim3" : "se3";
  bool evaluated = false;
  TrajectoryErrors errors;
  std::string eval_note = "no ground truth";
  if (!truth.empty() && estimate.size() >= 3) {
    try {
      errors = evaluateTrajectory(estimate, truth, alignment, params_.max_dt_s);
      evaluated = true;
    } catch (const std::exception& e) {
      eval_note = e.what();
    }
  } else if (!truth.empty()) {
    eval_note = "fewer than 3 estimated poses";
  }

  // summary.json
  std::ostringstream json;
  json << "{\n";
  json << "  \"mode\": \"" << jsonEscape(params_.mode) << "\",\n";
  json << "  \"frames\": " << camera_frames_ << ",\n";
  json << "  \"frames_with_pose\": " << estimate.size() << ",\n";
  json << "  \"keyframes\": " << keyframes_.size() << ",\n";
  json << "  \"keyframe_messages\": " << keyframe_messages_ << ",\n";
  json << "  \"wall_s\": " << jsonNumber(wall_s) << ",\n";
  json << "  \"log_events\": " << log_events << ",\n";
  json << "  \"log_bytes\": " << log_bytes << ",\n";
  json << "  \"ate_alignment\": \"" << alignment << "\",\n";
  if (evaluated) {
    json << "  \"ate_rmse_m\": " << jsonNumber(errors.ate_rmse_m) << ",\n";
    json << "  \"ate_matched\": " << errors.matched << ",\n";
    json << "  \"rot_rmse_deg\": " << jsonNumber(errors.rot_rmse_deg) << ",\n";
    json << "  \"rpe_trans_m\": " << jsonNumber(errors.rpe_trans_m) << ",\n";
    json << "  \"rpe_rot_deg\": " << jsonNumber(errors.rpe_rot_deg) << ",\n";
    json << "  \"scale\": " << jsonNumber(errors.scale) << ",\n";
  } else {
    json << "  \"ate_rmse_m\": null,\n";
    json << "  \"evaluation\": \"" << jsonEscape(eval_note) << "\",\n";
  }
  const MapperLag lag = mapperLag();
  if (lag.keyframes > 0) {
    json << "  \"mapper_lag_median_s\": " << jsonNumber(lag.median_s) << ",\n";
    json << "  \"mapper_lag_max_s\": " << jsonNumber(lag.max_s) << ",\n";
  }
  // Without a mapper on the bus, no keyframe is waiting for one.
  const bool with_mapper = statuses_.count("mapper") > 0;
  if (with_mapper)
    json << "  \"mapper_keyframes_unhandled\": " << keyframe_arrival_.size() << ",\n";
  bool first = true;
  json << "  \"processes\": [";
  for (const auto& [name, status] : statuses_) {
    json << (first ? "\"" : ", \"") << jsonEscape(name) << "\"";
    first = false;
  }
  json << "]";
  for (const auto& [name, status] : statuses_) {
    json << ",\n  \"" << jsonKey(name) << "\": {\"fps\": " << jsonNumber(status.fps)
         << ", \"busy_s\": " << jsonNumber(status.busy_s) << ", \"items\": " << status.items_handled
         << ", \"peak_rss_mb\": " << jsonNumber(status.peak_rss_mb) << ", \"state\": \""
         << stateName(status.state) << "\", \"last_error\": \"" << jsonEscape(status.last_error)
         << "\"";
    for (const auto& [key, value] : status.values)
      json << ", \"" << jsonKey(key) << "\": " << jsonNumber(value);
    json << "}";
  }
  // Traffic per channel: mean rate over the channel's active span (at least the 1 s of the peak
  // window: a burst of a few messages within milliseconds is not megabytes per second) and the
  // peak 1 s rate.
  auto meanRate = [](const ChannelTraffic& t) {
    const double span_s = static_cast<double>(t.last_utime - t.first_utime) * 1e-6;
    return static_cast<double>(t.bytes) / std::max(1.0, span_s);
  };
  json << ",\n  \"channels\": {";
  first = true;
  for (const auto& [name, t] : traffic_) {
    json << (first ? "\n" : ",\n") << "    \"" << jsonEscape(name)
         << "\": {\"messages\": " << t.messages << ", \"bytes\": " << t.bytes
         << ", \"mean_bytes_per_s\": " << jsonNumber(meanRate(t))
         << ", \"peak_bytes_per_s\": " << t.max_bytes_in_1s << "}";
    first = false;
  }
  json << "\n  }";
  json << "\n}\n";
  {
    std::ofstream out(out_dir + "/summary.json");
    if (!out) throw std::runtime_error("cannot write " + out_dir + "/summary.json");
    out << json.str();
  }

  // summary.txt: the result table printed at the end of a run.
  std::ostringstream text;
  text << std::fixed;
  text << "radslam run summary (" << params_.mode << ")\n";
  text << "  frames played          " << camera_frames_ << "\n";
  text << "  frames with a pose     " << estimate.size() << "\n";
  text << "  keyframes              " << keyframes_.size() << " (" << exr_written
       << " depth/sigma EXR)\n";
  text << "  wall time              " << std::setprecision(1) << wall_s << " s\n";
  if (evaluated) {
    text << "  ATE RMSE (" << alignment << ")      " << std::setprecision(4) << errors.ate_rmse_m
         << " m over " << errors.matched << " poses\n";
    text << "  orientation error      " << std::setprecision(3) << errors.rot_rmse_deg
         << " deg (rotation-only alignment)\n";
    text << "  RPE                    " << std::setprecision(4) << errors.rpe_trans_m << " m, "
         << std::setprecision(3) << errors.rpe_rot_deg << " deg per frame\n";
  } else {
    text << "  evaluation             " << eval_note << "\n";
  }
  if (with_mapper && (lag.keyframes > 0 || !keyframe_arrival_.empty())) {
    text << "  mapper lag             ";
    if (lag.keyframes > 0)
      text << std::setprecision(1) << "median " << lag.median_s << " s, max " << lag.max_s
           << " s from arrival to handled, " << lag.keyframes << " keyframes";
    if (!keyframe_arrival_.empty())
      text << (lag.keyframes > 0 ? "; " : "") << keyframe_arrival_.size() << " never handled";
    text << "\n";
  }
  if (with_mapper) {
    for (const auto& [key, value] : statuses_.at("mapper").values)
      if (key == "keyframe_psnr_db")
        text << "  map                    " << std::setprecision(2) << value
             << " dB PSNR of the keyframe renders (renders/rgb) against the keyframe images\n";
  }
  text << "  LCM log                " << log_events << " messages, " << std::setprecision(1)
       << static_cast<double>(log_bytes) / 1e6 << " MB\n";
  text << "  process     state      fps      busy s   peak RSS MB\n";
  for (const auto& [name, status] : statuses_) {
    char row[160];
    std::snprintf(row, sizeof(row), "  %-11s %-9s %7.1f %9.1f %11.1f\n", name.c_str(),
                  stateName(status.state), status.fps, status.busy_s, status.peak_rss_mb);
    text << row;
  }
  if (!traffic_.empty()) {
    text << "  channel                 messages        MB   mean MB/s   peak MB/s\n";
    for (const auto& [name, t] : traffic_) {
      char row[200];
      std::snprintf(row, sizeof(row), "  %-22s %9lld %9.1f %11.2f %11.2f\n", name.c_str(),
                    static_cast<long long>(t.messages), static_cast<double>(t.bytes) / 1e6,
                    meanRate(t) / 1e6, static_cast<double>(t.max_bytes_in_1s) / 1e6);
      text << row;
    }
  }
  {
    std::ofstream out(out_dir + "/summary.txt");
    if (!out) throw std::runtime_error("cannot write " + out_dir + "/summary.txt");
    out << text.str();
  }
  return text.str();
}

}  // namespace radslam
