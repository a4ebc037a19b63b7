#include "common/process_stats.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <fstream>
#include <sstream>
#include <thread>

namespace radslam {
namespace {

// A "Name:   1234 kB" line of /proc/self/status, in MiB; 0 when absent.
double procStatusMb(const std::string& name) {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.compare(0, name.size() + 1, name + ":") != 0) continue;
    std::istringstream fields(line.substr(name.size() + 1));
    double kb = 0;
    if (fields >> kb) return kb / 1024.0;
  }
  return 0.0;
}

// Largest RSS this process has read, MiB: keeps peakRssMb() >= every
// currentRssMb() already returned.
std::atomic<double> g_largest_rss_mb{0.0};

}  // namespace

double currentRssMb() {
  const double rss = procStatusMb("VmRSS");
  double seen = g_largest_rss_mb.load();
  while (rss > seen && !g_largest_rss_mb.compare_exchange_weak(seen, rss)) {
  }
  return rss;
}

// The kernel's RSS counters are approximate (per-CPU), and VmHWM is only
// updated when memory is unmapped, so it can trail VmRSS slightly.
double peakRssMb() {
  return std::max({procStatusMb("VmHWM"), currentRssMb(), g_largest_rss_mb.load()});
}

int threadsOrEveryCore(int threads) {
  if (threads > 0) return threads;
  return static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

int64_t wallClockMicros() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

void BusyTimer::start() {
  if (running_) return;
  started_ = Clock::now();
  running_ = true;
}

void BusyTimer::stop() {
  if (!running_) return;
  total_ += Clock::now() - started_;
  running_ = false;
}

double BusyTimer::seconds() const {
  Clock::duration d = total_;
  if (running_) d += Clock::now() - started_;
  return std::chrono::duration<double>(d).count();
}

void BusyTimer::reset() {
  total_ = Clock::duration::zero();
  running_ = false;
}

StatusReporter::StatusReporter(std::string process) : process_(std::move(process)) {}

void StatusReporter::itemHandled(int64_t frame_index, int64_t frame_utime) {
  ++items_;
  if (frame_index >= 0) {
    last_frame_index_ = frame_index;
    last_frame_utime_ = frame_utime;
  }
}

void StatusReporter::setValue(const std::string& key, double value) {
  for (auto& [k, v] : values_) {
    if (k == key) {
      v = value;
      return;
    }
  }
  values_.emplace_back(key, value);
}

Status StatusReporter::make() const {
  Status s;
  s.header.utime = wallClockMicros();
  s.process = process_;
  s.pid = static_cast<int32_t>(::getpid());
  s.state = state_;
  s.last_frame_index = last_frame_index_;
  s.last_frame_utime = last_frame_utime_;
  s.items_handled = items_;
  s.busy_s = busy_.seconds();
  s.fps = s.busy_s > 0 ? static_cast<double>(items_) / s.busy_s : 0.0;
  s.queue_depth = queue_depth_;
  s.rss_mb = currentRssMb();
  s.peak_rss_mb = peakRssMb();
  s.last_error = last_error_;
  s.values = values_;
  return s;
}

}  // namespace radslam
