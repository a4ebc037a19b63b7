// Standard LCM log files (the format lcm-logger writes and lcm-logplayer
// replays), behind plain types so callers need no LCM headers.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace radslam {

struct LogEvent {
  int64_t utime = 0;  // receive time recorded in the log, microseconds
  std::string channel;
  std::vector<uint8_t> data;
};

class LogReader {
 public:
  /// Throws std::runtime_error naming the file when it cannot be opened.
  explicit LogReader(const std::string& path);
  ~LogReader();
  /// Next event, or nullopt at the end. A truncated last event also ends it; so
  /// does a corrupt one (invalid lengths), with a warning on stderr. Lengths are
  /// checked against the bytes left in the file before anything is allocated.
  std::optional<LogEvent> next();
  /// The next event is read from this byte offset (as LogWriter::position() gave it).
  void seek(int64_t offset);
  /// Byte offsets where the last event next() returned starts and ends (0 before the first):
  /// past the end of the last one, a log holds at most the torn tail a killed writer left.
  int64_t lastEventStart() const;
  int64_t lastEventEnd() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

class LogWriter {
 public:
  /// Creates (truncates) the file; throws std::runtime_error when it cannot.
  explicit LogWriter(const std::string& path);
  /// Continues the log at path: cuts it after its last complete event and appends, the event
  /// numbers going on from there (a recorder restarted in its run folder). The counts start at
  /// what the log holds; read_back (when given) gets each event it holds and the byte offset
  /// where it starts, from the one pass that counts them. Throws std::runtime_error when it
  /// cannot.
  static LogWriter append(
      const std::string& path,
      const std::function<void(const LogEvent& event, int64_t offset)>& read_back = {});
  LogWriter(LogWriter&&) noexcept;
  ~LogWriter();
  void write(int64_t utime, const std::string& channel, const uint8_t* data, size_t size);
  /// Pushes buffered events to the kernel so a killed process leaves them.
  void flush();
  int64_t eventsWritten() const { return events_; }
  /// Byte offset in the file where the next event starts.
  int64_t position() const;
  int64_t bytesWritten() const { return bytes_; }

 private:
  LogWriter(const std::string& path, int64_t events, int64_t bytes);  // appends
  struct Impl;
  std::unique_ptr<Impl> impl_;
  int64_t events_ = 0;
  int64_t bytes_ = 0;
};

}  // namespace radslam
