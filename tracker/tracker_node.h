// The tracker process's parameters (YAML loading and validation) and bus wiring: CAMERA in;
// POSE, KEYFRAME and STATUS out; CONTROL for stop and reset. The core (tracker/tracker.h)
// knows nothing of the bus.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "common/bus.h"
#include "common/process_stats.h"
#include "tracker/tracker.h"

namespace radslam {

/// TrackerParams from the "tracker" section of a YAML file ("" = defaults), then "key=value"
/// overrides. Every field is read; unknown keys are an error (std::runtime_error naming the
/// file and the keys). *dump (optional) receives the values in force as YAML.
/// Every frame allocates and frees images of a few hundred kB; by default glibc maps them afresh
/// and the page faults cost ~15% of the tracker's CPU time (measured): keep them mapped. Call
/// once at the start of a tracker executable.
void keepImageAllocationsMapped();

TrackerParams loadTrackerParams(const std::string& yaml_path,
                                const std::vector<std::string>& overrides = {},
                                std::string* dump = nullptr, std::string* source = nullptr);

struct TrackerNodeOptions {
  /// Frames waiting to be processed beyond this are dropped, oldest first, with a counted
  /// warning (lock-step playback never queues more than one).
  int max_queue = 4;
  double status_period_s = 0.5;  // heartbeat (~2 Hz) besides the per-frame acknowledgement
  /// Exit after this long without a frame once at least one was processed (0 = never); for
  /// file:// replays whose end the bus reports anyway.
  double idle_exit_s = 0;
  /// Checkpoint written every checkpoint_period_s (after a frame) and after re-publishing
  /// keyframes, when both are set: what a restarted tracker resumes from.
  std::string checkpoint_path;
  double checkpoint_period_s = 0;
};

/// Runs a Tracker on the bus until a stop is requested (SIGINT/SIGTERM through common/cli.h,
/// or CONTROL STOP for "" or "tracker"), or a file:// log ends. Then it processes the frames
/// still queued, calls finish(), publishes the final keyframes and refreshed poses and a DONE
/// status.
class TrackerNode {
 public:
  /// Subscribes to CAMERA and CONTROL on `bus`. Throws std::invalid_argument on bad params.
  TrackerNode(Bus* bus, TrackerParams params, TrackerNodeOptions options = {});

  /// Continues from a checkpoint of an earlier run of this tracker (restart after a crash):
  /// frames up to the checkpoint's last are skipped, and the player is asked (CONTROL REWIND,
  /// repeated until the next frame arrives) to play again from the one after it. Throws
  /// std::runtime_error naming the file.
  void resume(const std::string& checkpoint);

  /// The loop; returns the process exit code (0).
  int run();

  /// Figures (also for tests).
  int64_t framesProcessed() const { return processed_; }
  int64_t framesDropped() const { return dropped_; }
  int64_t framesRejected() const { return rejected_; }

 private:
  void onFrame(const Frame& frame);
  void onControl(const Control& control);
  void processQueued();
  void handle(const Frame& frame);
  void publish(const TrackerOutput& output);
  /// Paced: a keyframe is megabytes of UDP fragments.
  void publishKeyframes(const std::vector<Keyframe>& keyframes);
  void publishStatus(ProcessState state);
  bool checkpointing() const {
    return !options_.checkpoint_path.empty() && options_.checkpoint_period_s > 0;
  }
  void saveCheckpoint();
  void finish();

  Bus* bus_;
  TrackerParams params_;
  TrackerNodeOptions options_;
  std::unique_ptr<Tracker> tracker_;
  StatusReporter reporter_;
  std::deque<Frame> queue_;
  int64_t last_index_ = -1;
  int64_t processed_ = 0, dropped_ = 0, rejected_ = 0;
  bool reset_requested_ = false;
  bool republish_requested_ = false;  // CONTROL REPUBLISH: keyframes again
  bool republish_all_ = false;        // ... every one, else republish_ids_
  std::vector<int> republish_ids_;
  // Keyframes being re-published, one per kRepublishGapMs between frames (a burst would
  // overrun the receive buffers, the tracker's own included: it loses CAMERA frames).
  std::deque<Keyframe> republish_queue_;
  std::chrono::steady_clock::time_point last_republish_;
  TrackerStats last_stats_;
  std::chrono::steady_clock::time_point last_checkpoint_;
  // After resume(): the frame the player is asked to play again from (-1: none pending), the
  // request's token and when it was last sent.
  int64_t rewind_from_ = -1;
  std::string rewind_token_;
  std::chrono::steady_clock::time_point last_rewind_request_;
};

}  // namespace radslam
