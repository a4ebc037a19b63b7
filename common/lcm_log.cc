#include "common/lcm_log.h"

#include <cstdio>
#include <stdexcept>

#include <lcm/lcm-cpp.hpp>

namespace radslam {

struct LogReader::Impl {
  explicit Impl(const std::string& path) : log(path, "r") {}
  lcm::LogFile log;
};

LogReader::LogReader(const std::string& path) : impl_(std::make_unique<Impl>(path)) {
  if (!impl_->log.good()) throw std::runtime_error("cannot open LCM log '" + path + "'");
}

LogReader::~LogReader() = default;

std::optional<LogEvent> LogReader::next() {
  const lcm::LogEvent* event = impl_->log.readNextEvent();
  if (!event) return std::nullopt;
  LogEvent out;
  out.utime = event->timestamp;
  out.channel = event->channel;
  const auto* bytes = static_cast<const uint8_t*>(event->data);
  out.data.assign(bytes, bytes + event->datalen);
  return out;
}

struct LogWriter::Impl {
  explicit Impl(const std::string& path) : log(path, "w") {}
  lcm::LogFile log;
};

LogWriter::LogWriter(const std::string& path) : impl_(std::make_unique<Impl>(path)) {
  if (!impl_->log.good()) throw std::runtime_error("cannot create LCM log '" + path + "'");
}

LogWriter::~LogWriter() { flush(); }

void LogWriter::write(int64_t utime, const std::string& channel, const uint8_t* data, size_t size) {
  lcm::LogEvent event;
  event.eventnum = events_;
  event.timestamp = utime;
  event.channel = channel;
  event.datalen = static_cast<int32_t>(size);
  event.data = const_cast<uint8_t*>(data);  // LogFile only reads it
  if (impl_->log.writeEvent(&event) != 0) throw std::runtime_error("cannot write LCM log event");
  ++events_;
  bytes_ += static_cast<int64_t>(size);
}

void LogWriter::flush() {
  if (FILE* f = impl_->log.getFilePtr()) std::fflush(f);
}

}  // namespace radslam
