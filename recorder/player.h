// Plays a frame source (dataset or live camera) in sensor time: the core of
// radslam-play, independent of the bus (frames go to callbacks).
#pragma once

#include <cstdint>
#include <functional>
#include <string>

#include "common/dataset.h"
#include "common/types.h"

namespace radslam {

struct PlayerParams {
  /// Playback speed relative to sensor time (1 = real time); 0 = as fast as possible.
  double rate = 1.0;
  /// Lock-step: frame k+1 is sent only after ack_process has acknowledged frame k.
  bool lockstep = false;
  std::string ack_process = "tracker";
  double ack_timeout_s = 30.0;  // then lock-step is abandoned with a warning
  int start = 0;                // first frame index
  int end = -1;                 // one past the last frame index; -1 = to the end
  int stride = 1;
  /// Plays [start, end) this many times (long-run tests), every other time backwards so that
  /// the motion stays continuous: frame indices go on counting and sensor times go on by one
  /// frame interval across each turn (loop k starts k times the duration plus an interval in).
  int loops = 1;
  /// Image encoding on the wire: "raw" (fastest: about 1 MB per 640x480 RGB-D
  /// frame), "png" (lossless, about 3x smaller, ~40 ms per frame to encode) or
  /// "jpeg" (colour only; depth then goes as PNG).
  std::string color_compression = "raw";
  /// Depth quantisation on the wire, metres per unit; 0 = lossless float32;
  /// negative = the dataset's own depth step (lossless for 16-bit depth PNGs).
  double depth_wire_scale = -1;
  bool ground_truth = true;  // publish GROUND_TRUTH / GROUND_TRUTH_OBJECTS
  /// log: at rate 0, at most this many MB per second (0 = no limit): a log replayed as fast as
  /// the disk reads overruns its receivers' socket buffers (a 528 MB fr1/rpy run log lost most
  /// of its FIELD updates in `radslam view --rate 0`).
  double log_max_mb_per_s = 20;
};

/// What the player does with its output; the bus adapter in play_main.cc wires
/// these to channels, tests to vectors.
struct PlayerSinks {
  std::function<void(const Frame&)> frame;
  std::function<void(const PoseStamped&)> ground_truth;
  std::function<void(const ObjectList&)> ground_truth_objects;
  /// Blocks until frame_index is acknowledged or timeout_s passes; returns
  /// whether it was acknowledged. Needed only in lock-step mode.
  std::function<bool(int64_t frame_index, double timeout_s)> wait_for_ack;
  /// Lock-step, after each acknowledgement: a frame index to play again from (the
  /// acknowledging process resumed from a checkpoint older than the frames sent), or -1. Its
  /// acknowledgements count from there on. Optional.
  std::function<int64_t()> take_rewind;
  /// Polled between frames; true ends playback early (Ctrl-C, CONTROL STOP).
  std::function<bool()> should_stop;
  /// Called after each frame with (frames sent, frames planned).
  std::function<void(int64_t, int64_t)> progress;
};

struct PlayerStats {
  int64_t frames_sent = 0;
  int64_t frames_skipped = 0;  // unreadable frames (warned)
  int64_t acks_missed = 0;
  int64_t rewinds = 0;  // plays again from an earlier frame (take_rewind)
  double wall_s = 0;
};

class Player {
 public:
  Player(PlayerParams params, PlayerSinks sinks);

  /// Plays frames [start, end) with the stride of a dataset.
  PlayerStats play(const DatasetReader& dataset);
  /// Plays an OpenCV VideoCapture device until should_stop() or the stream ends.
  /// Frames are stamped with the wall clock; intrinsics come from `camera`.
  PlayerStats playCamera(int device, const CameraModel& camera);

 private:
  void waitUntil(double sensor_t, double first_sensor_t, double wall_start_s) const;
  void applyWireHints(Frame* frame) const;
  void acknowledge(int64_t frame_index, PlayerStats* stats);

  PlayerParams params_;
  PlayerSinks sinks_;
};

}  // namespace radslam
