// Keyframes re-published from the recorder's own log, for a mapper that (re)starts when the
// tracker can no longer answer (it has finished): where the latest version of each keyframe
// lies in the log, and those events read back on request. No bus: radslam-record publishes
// what next() returns.
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "common/lcm_log.h"

namespace radslam {

class KeyframeArchive {
 public:
  explicit KeyframeArchive(std::string log_path) : log_path_(std::move(log_path)) {}

  /// A KEYFRAME event was written at this byte offset of the log (LogWriter::position() before
  /// the write); an older version of the id is forgotten.
  void add(int32_t keyframe_id, int32_t version, int64_t log_offset);
  /// Queues ids for next() (empty = every keyframe known; unknown ids are skipped, ids queued
  /// already are not queued twice). Returns how many are queued now.
  size_t request(const std::vector<int32_t>& ids);
  bool pending() const { return !queue_.empty(); }
  size_t size() const { return entries_.size(); }
  /// The next queued keyframe's event, read from the log; nullopt with *error when it cannot
  /// be read (the keyframe stays known, only this request is dropped).
  std::optional<LogEvent> next(std::string* error);

 private:
  struct Entry {
    int32_t version = 0;
    int64_t offset = 0;
  };
  std::string log_path_;
  std::map<int32_t, Entry> entries_;
  std::deque<int32_t> queue_;
};

}  // namespace radslam
