// Process figures for the STATUS heartbeat: memory from /proc, busy time,
// wall clock, and a reporter that assembles a Status message (no LCM here).
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "common/types.h"

namespace radslam {

/// Resident set size of this process, MiB (VmRSS of /proc/self/status); 0
/// when /proc is unavailable.
double currentRssMb();
/// Peak resident set size, MiB: VmHWM, raised to any RSS this process has
/// read (the kernel's counters are approximate); 0 when /proc is unavailable.
double peakRssMb();

/// threads when positive, else every core of this machine (at least 1).
int threadsOrEveryCore(int threads);

/// Microseconds since the Unix epoch (system clock), for Status headers.
int64_t wallClockMicros();

/// Accumulates the time spent working (steady clock), so a process can report
/// items per busy second independently of how long it waited for input.
class BusyTimer {
 public:
  /// Starts a busy interval; no effect when one is already running.
  void start();
  /// Ends the running interval and adds it; no effect when none is running.
  void stop();
  bool running() const { return running_; }
  /// Accumulated busy time, seconds, including the running interval.
  double seconds() const;
  void reset();

  /// RAII interval: start() on construction, stop() on destruction.
  class Scope {
   public:
    explicit Scope(BusyTimer& timer) : timer_(timer) { timer_.start(); }
    ~Scope() { timer_.stop(); }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    BusyTimer& timer_;
  };

 private:
  using Clock = std::chrono::steady_clock;
  Clock::duration total_{};
  Clock::time_point started_;
  bool running_ = false;
};

/// Keeps a process's running figures and fills Status messages from them.
class StatusReporter {
 public:
  explicit StatusReporter(std::string process);

  void setState(ProcessState state) { state_ = state; }
  ProcessState state() const { return state_; }
  /// One item (frame, keyframe, render...) done; frame_index/frame_utime are the
  /// last fully handled frame (lock-step acknowledgement), -1 to leave them.
  void itemHandled(int64_t frame_index = -1, int64_t frame_utime = 0);
  void setQueueDepth(int32_t depth) { queue_depth_ = depth; }
  void setError(std::string error) { last_error_ = std::move(error); }
  /// Process-specific figure; replaces the value of an existing key.
  void setValue(const std::string& key, double value);
  /// Time spent working; wrap the work in BusyTimer::Scope(reporter.busy()).
  BusyTimer& busy() { return busy_; }
  int64_t itemsHandled() const { return items_; }

  /// A Status with header.utime = wall clock now, pid, busy_s, fps =
  /// items / busy_s (0 before any busy time), current and peak RSS. The bus
  /// fills header.sender and header.seq when publishing.
  Status make() const;

 private:
  std::string process_;
  ProcessState state_ = ProcessState::kStarting;
  int64_t items_ = 0;
  int64_t last_frame_index_ = -1;
  int64_t last_frame_utime_ = 0;
  int32_t queue_depth_ = 0;
  std::string last_error_;
  std::vector<std::pair<std::string, double>> values_;
  BusyTimer busy_;
};

}  // namespace radslam
