// Collects what a run publishes (poses, keyframes, objects, statuses, ground
// truth) and exports the run folder: trajectories, keyframe depth and sigma as
// OpenEXR, object tracks, evaluation, summary.json and summary.txt. The core of
// radslam-record; the LCM log itself is written by the bus adapter side.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common/trajectory.h"
#include "common/types.h"

namespace radslam {

struct RecorderParams {
  /// Trajectory alignment for evaluation: "sim3", "se3", "none", or "auto"
  /// (sim3 unless the run says it is metric: mode rgbd or stereo).
  std::string alignment = "auto";
  std::string mode = "mono";  // mono | rgbd | stereo (for "auto" and the summary)
  double max_dt_s = 0.02;     // timestamp association tolerance for evaluation
  bool export_keyframe_exr = true;
  /// Where keyframe EXRs go as keyframes arrive (each newer version overwrites its file), so
  /// that memory stays flat on long runs (only poses are kept) and a killed recorder leaves
  /// them; "" = written by exportRun from the keyframes kept in memory (tests).
  std::string keyframe_exr_dir;
  /// The LCM log stops growing (a warning; the rest of the run folder is still written) past
  /// max_log_mb (0 = no limit) or when the disk holding it has less than min_free_disk_mb
  /// left: a long run at full rate writes about 1.7 MB per frame, and a full disk would cost
  /// every process its final outputs.
  double max_log_mb = 0;
  double min_free_disk_mb = 1024;
};

/// Keeps the LCM log within max_log_mb and away from a full disk: the log ends before the
/// event that would pass the size limit, or at the first check (every 16 MB written) that
/// finds less than min_free_disk_mb free on the log's disk.
class LogGuard {
 public:
  LogGuard(const RecorderParams& params, std::string path)
      : params_(params), path_(std::move(path)) {}
  /// True while an event of `bytes` may be written after `written` bytes; the first refusal
  /// says why on stderr (and in why()), and every later call refuses.
  bool admits(int64_t written, size_t bytes);
  const std::string& why() const { return why_; }

 private:
  RecorderParams params_;
  std::string path_;
  int64_t next_disk_check_ = 0;
  std::string why_;
};

struct ProcessSummary {
  std::string process;
  double fps = 0;
  double busy_s = 0;
  int64_t items = 0;
  double peak_rss_mb = 0;
  std::string state;
  std::string last_error;
  std::vector<std::pair<std::string, double>> values;
};

class RunRecorder {
 public:
  explicit RunRecorder(RecorderParams params);

  void onCameraFrame(int64_t utime);
  void onPose(const PoseStamped& pose);
  void onGroundTruth(const PoseStamped& pose);
  /// recv_utime: when the message arrived (us, wall clock), for the mapper's lag.
  void onKeyframe(const Keyframe& keyframe, int64_t recv_utime);
  void onObjects(const ObjectList& objects);
  void onGroundTruthObjects(const ObjectList& objects);
  void onStatus(const Status& status, int64_t recv_utime);
  /// Traffic accounting: every message seen on the bus (any channel), with its receive time
  /// (us) and encoded size (bytes).
  void onMessage(const std::string& channel, int64_t recv_utime, size_t bytes);

  /// One line for the terminal: frames, rates, keyframes, map state.
  std::string progressLine(double wall_s) const;

  /// Writes the run folder (created if needed); returns summary.txt's text.
  /// log_events/log_bytes describe the LCM log written alongside.
  std::string exportRun(const std::string& out_dir, double wall_s, int64_t log_events,
                        int64_t log_bytes) const;

  int64_t cameraFrames() const { return camera_frames_; }
  /// The state in the latest STATUS of a process, or nullopt when none was seen.
  std::optional<ProcessState> processState(const std::string& process) const;
  Trajectory trajectory() const;
  Trajectory keyframeTrajectory() const;
  Trajectory groundTruth() const;
  /// How long keyframes waited, from their arrival on the bus until a mapper STATUS reported
  /// them handled (its resolution: the STATUS period, 0.5 s by default).
  struct MapperLag {
    int keyframes = 0;  // handled so far
    double median_s = 0, max_s = 0;
  };
  MapperLag mapperLag() const;

 private:
  RecorderParams params_;
  int64_t camera_frames_ = 0;
  std::map<int64_t, PoseStamped> poses_;         // latest per frame index
  std::map<int64_t, PoseStamped> ground_truth_;  // by utime
  std::map<int32_t, Keyframe> keyframes_;        // latest version per id (without images
                                                 // when written on arrival)
  int exr_written_ = 0;                          // keyframe EXRs written on arrival
  int64_t keyframe_messages_ = 0;
  std::vector<ObjectList> objects_;
  std::vector<ObjectList> ground_truth_objects_;
  std::map<std::string, Status> statuses_;  // latest per process
  // Mapper lag: each keyframe's first arrival (us, by its sensor utime) until a mapper STATUS
  // reports it handled (to within the STATUS period), then the arrival-to-handled times (s).
  std::map<int64_t, int64_t> keyframe_arrival_;
  int64_t mapper_handled_utime_ = 0;  // sensor utime of the mapper's last handled keyframe
  std::vector<double> mapper_lag_s_;
  struct ChannelTraffic {
    int64_t messages = 0;
    int64_t bytes = 0;
    int64_t first_utime = 0, last_utime = 0;         // us
    int64_t max_bytes_in_1s = 0;                     // largest sum over a sliding 1 s window
    std::vector<std::pair<int64_t, size_t>> recent;  // (utime, bytes) of the last second
    int64_t recent_bytes = 0;
  };
  std::map<std::string, ChannelTraffic> traffic_;
};

}  // namespace radslam
