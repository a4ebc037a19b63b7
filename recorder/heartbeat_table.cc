#include "recorder/heartbeat_table.h"

#include <cstdio>
#include <sstream>

namespace radslam {

const char* processStateName(ProcessState state) {
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
  return "unknown";
}

void HeartbeatTable::onStatus(const Status& status, double now_s) {
  if (status.process.empty()) return;  // nothing to key it by
  Heartbeat& h = entries_[status.process];
  h.process = status.process;
  h.pid = status.pid;
  h.state = status.state;
  h.received_s = now_s;
  ++h.heartbeats;
  h.items_handled = status.items_handled;
  h.fps = status.fps;
  h.last_error = status.last_error;
}

double HeartbeatTable::ageOf(const std::string& process, double now_s) const {
  auto it = entries_.find(process);
  return it == entries_.end() ? -1.0 : now_s - it->second.received_s;
}

std::vector<std::string> HeartbeatTable::silent(double now_s, double silent_after_s) const {
  std::vector<std::string> out;
  for (const auto& [name, h] : entries_)
    if (h.state != ProcessState::kDone && now_s - h.received_s > silent_after_s)
      out.push_back(name);
  return out;
}

std::string HeartbeatTable::table(double now_s) const {
  std::ostringstream out;
  for (const auto& [name, h] : entries_) {
    char line[256];
    // Names come from the bus: keep the line's field count fixed for readers.
    std::string safe_name = name;
    for (char& c : safe_name)
      if (c == ' ' || c == '\t' || c == '\n') c = '_';
    std::snprintf(line, sizeof(line), "%s %d %s %.1f %lld %lld %.2f\n", safe_name.c_str(), h.pid,
                  processStateName(h.state), now_s - h.received_s,
                  static_cast<long long>(h.heartbeats), static_cast<long long>(h.items_handled),
                  h.fps);
    out << line;
  }
  return out.str();
}

}  // namespace radslam
