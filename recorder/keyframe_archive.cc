#include "recorder/keyframe_archive.h"

#include <algorithm>
#include <exception>

namespace radslam {

void KeyframeArchive::add(int32_t keyframe_id, int32_t version, int64_t log_offset) {
  auto it = entries_.find(keyframe_id);
  if (it != entries_.end() && it->second.version > version) return;
  entries_[keyframe_id] = {version, log_offset};
}

size_t KeyframeArchive::request(const std::vector<int32_t>& ids) {
  const auto queue = [this](int32_t id) {
    if (std::find(queue_.begin(), queue_.end(), id) == queue_.end()) queue_.push_back(id);
  };
  if (ids.empty()) {
    for (const auto& [id, entry] : entries_) queue(id);
  } else {
    for (int32_t id : ids)
      if (entries_.count(id)) queue(id);
  }
  return queue_.size();
}

std::optional<LogEvent> KeyframeArchive::next(std::string* error) {
  if (queue_.empty()) return std::nullopt;
  const int32_t id = queue_.front();
  queue_.pop_front();
  const Entry& entry = entries_.at(id);
  try {
    LogReader reader(log_path_);
    reader.seek(entry.offset);
    std::optional<LogEvent> event = reader.next();
    if (event) return event;
    *error = log_path_ + ": no event at byte " + std::to_string(entry.offset) + " (keyframe " +
             std::to_string(id) + ")";
  } catch (const std::exception& e) {
    *error = e.what();
  }
  return std::nullopt;
}

}  // namespace radslam
