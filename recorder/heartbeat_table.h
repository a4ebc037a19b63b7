// The latest STATUS heartbeat of each process on the bus, aged by the time it
// was received here (not the sender's clock: machines on a LAN need not agree).
// The core of radslam-status, which the launcher reads to supervise a run.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "common/types.h"

namespace radslam {

struct Heartbeat {
  std::string process;
  int32_t pid = 0;
  ProcessState state = ProcessState::kStarting;
  double received_s = 0;  // local monotonic time of the last heartbeat, seconds
  int64_t heartbeats = 0;
  int64_t items_handled = 0;
  double fps = 0;
  std::string last_error;
};

class HeartbeatTable {
 public:
  /// Records one heartbeat received at local time now_s (seconds, monotonic).
  void onStatus(const Status& status, double now_s);

  /// Seconds since the last heartbeat of process (negative when never seen).
  double ageOf(const std::string& process, double now_s) const;

  /// Processes whose last heartbeat is older than silent_after_s and that did not say they
  /// were done (a finished process legitimately falls silent).
  std::vector<std::string> silent(double now_s, double silent_after_s) const;

  /// One line per process, sorted by name:
  /// "NAME PID STATE AGE_S HEARTBEATS ITEMS FPS", AGE_S with one decimal. Meant for scripts
  /// (the launcher reads it); last_error is left out so that a line never holds spaces
  /// beyond its fields.
  std::string table(double now_s) const;

  const std::map<std::string, Heartbeat>& entries() const { return entries_; }

 private:
  std::map<std::string, Heartbeat> entries_;
};

/// "starting", "running", "idle", "done", "error".
const char* processStateName(ProcessState state);

}  // namespace radslam
