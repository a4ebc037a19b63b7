#include "common/lcm_log.h"

#include <sys/stat.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <stdexcept>
#include <string>

#include <lcm/lcm-cpp.hpp>

namespace radslam {

namespace {

// LCM log event header (lcm eventlog format, big endian): magic, event number,
// time stamp (us), channel length, data length; then channel and data bytes.
constexpr uint32_t kEventMagic = 0xEDA1DA01;
constexpr size_t kEventHeaderBytes = 4 + 8 + 8 + 4 + 4;
// lcm's own reader rejects channel names of 1000 bytes and more.
constexpr int64_t kMaxChannelBytes = 999;

uint64_t bigEndian(const uint8_t* p, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | p[i];
  return v;
}

}  // namespace

// Reads the file itself rather than through lcm::LogFile: lcm 1.3.1 allocates
// the data length a header claims before reading, so a corrupt header of a few
// bytes makes it allocate up to 2 GiB. Here lengths are checked against the
// bytes left in the file first.
struct LogReader::Impl {
  std::string path;
  FILE* file = nullptr;
  int64_t file_bytes = 0;
  int64_t event_start = 0, event_end = 0;  // of the last event returned
  bool warned = false;

  ~Impl() {
    if (file) std::fclose(file);
  }

  // Ends the log at a corrupt event, saying why once (a truncated last event,
  // as a killed logger leaves, ends it silently).
  std::nullopt_t corrupt(int64_t offset, const std::string& what) {
    if (!warned) {
      std::fprintf(stderr, "radslam: warning: LCM log '%s': %s at byte %lld; reading stops\n",
                   path.c_str(), what.c_str(), static_cast<long long>(offset));
      warned = true;
    }
    return std::nullopt;
  }
};

LogReader::LogReader(const std::string& path) : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  impl_->file = std::fopen(path.c_str(), "rb");
  struct stat info {};
  if (!impl_->file || fstat(fileno(impl_->file), &info) != 0 || !S_ISREG(info.st_mode)) {
    throw std::runtime_error("cannot open LCM log '" + path + "' (not a readable regular file)");
  }
  impl_->file_bytes = static_cast<int64_t>(info.st_size);
}

LogReader::~LogReader() = default;

std::optional<LogEvent> LogReader::next() {
  FILE* f = impl_->file;
  // Like lcm, resynchronise on the magic word after garbage between events.
  uint32_t magic = 0;
  int c = 0;
  while ((c = std::fgetc(f)) != EOF) {
    magic = (magic << 8) | static_cast<uint32_t>(c);
    if (magic == kEventMagic) break;
  }
  if (c == EOF) return std::nullopt;
  const int64_t start = static_cast<int64_t>(std::ftell(f)) - 4;
  uint8_t header[kEventHeaderBytes - 4];
  if (std::fread(header, 1, sizeof(header), f) != sizeof(header)) return std::nullopt;
  const int64_t offset = static_cast<int64_t>(std::ftell(f));
  const int64_t bytes_left = impl_->file_bytes - offset;
  LogEvent out;
  out.utime = static_cast<int64_t>(bigEndian(header + 8, 8));
  const auto channel_bytes = static_cast<int32_t>(bigEndian(header + 16, 4));
  const auto data_bytes = static_cast<int32_t>(bigEndian(header + 20, 4));
  if (channel_bytes <= 0 || channel_bytes > kMaxChannelBytes) {
    return impl_->corrupt(offset, "channel length " + std::to_string(channel_bytes) +
                                      " outside [1, " + std::to_string(kMaxChannelBytes) + "]");
  }
  if (data_bytes < 0) {
    return impl_->corrupt(offset, "negative data length " + std::to_string(data_bytes));
  }
  if (static_cast<int64_t>(channel_bytes) + data_bytes > bytes_left) {
    // The log may still be growing (a recorder writing it): look again once.
    struct stat info {};
    if (fstat(fileno(f), &info) == 0) impl_->file_bytes = static_cast<int64_t>(info.st_size);
    if (static_cast<int64_t>(channel_bytes) + data_bytes > impl_->file_bytes - offset) {
      return std::nullopt;  // truncated last event
    }
  }
  out.channel.resize(static_cast<size_t>(channel_bytes));
  out.data.resize(static_cast<size_t>(data_bytes));
  if (std::fread(out.channel.data(), 1, out.channel.size(), f) != out.channel.size() ||
      std::fread(out.data.data(), 1, out.data.size(), f) != out.data.size()) {
    return std::nullopt;  // the file shrank while being read
  }
  impl_->event_start = start;
  impl_->event_end = static_cast<int64_t>(std::ftell(f));
  return out;
}

int64_t LogReader::lastEventStart() const { return impl_->event_start; }
int64_t LogReader::lastEventEnd() const { return impl_->event_end; }

void LogReader::seek(int64_t offset) {
  if (std::fseek(impl_->file, static_cast<long>(offset), SEEK_SET) != 0)
    throw std::runtime_error("LCM log '" + impl_->path + "': cannot seek to byte " +
                             std::to_string(offset));
}

struct LogWriter::Impl {
  Impl(const std::string& path, const char* mode) : log(path, mode) {}
  lcm::LogFile log;
};

LogWriter::LogWriter(const std::string& path) : impl_(std::make_unique<Impl>(path, "w")) {
  if (!impl_->log.good()) throw std::runtime_error("cannot create LCM log '" + path + "'");
}

LogWriter LogWriter::append(
    const std::string& path,
    const std::function<void(const LogEvent& event, int64_t offset)>& read_back) {
  int64_t events = 0, bytes = 0, end = 0;
  {
    LogReader reader(path);
    while (auto event = reader.next()) {
      ++events;
      bytes += static_cast<int64_t>(event->data.size());
      if (read_back) read_back(*event, reader.lastEventStart());
    }
    end = reader.lastEventEnd();
  }
  std::error_code error;
  std::filesystem::resize_file(path, static_cast<uintmax_t>(end), error);
  if (error)
    throw std::runtime_error("cannot cut LCM log '" + path +
                             "' after its last complete event: " + error.message());
  return LogWriter(path, events, bytes);
}

LogWriter::LogWriter(const std::string& path, int64_t events, int64_t bytes)
    : impl_(std::make_unique<Impl>(path, "a")), events_(events), bytes_(bytes) {
  // Appends go to the end whatever the position; ftell (position()) needs it there too.
  FILE* f = impl_->log.getFilePtr();
  if (!impl_->log.good() || !f || std::fseek(f, 0, SEEK_END) != 0)
    throw std::runtime_error("cannot append to LCM log '" + path + "'");
}

LogWriter::LogWriter(LogWriter&&) noexcept = default;

LogWriter::~LogWriter() {
  if (impl_) flush();
}

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

int64_t LogWriter::position() const {
  FILE* f = impl_->log.getFilePtr();
  return f ? static_cast<int64_t>(std::ftell(f)) : -1;
}

void LogWriter::flush() {
  if (FILE* f = impl_->log.getFilePtr()) std::fflush(f);
}

}  // namespace radslam
