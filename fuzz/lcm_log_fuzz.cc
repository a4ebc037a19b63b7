// libFuzzer target for LogReader (common/lcm_log.h): the input is written as an
// LCM log file and read to its end. Event lengths come from the file, so they
// must be checked against what the file holds before anything is allocated.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "common/lcm_log.h"

namespace {

// One log file per fuzzing process, rewritten for every input.
const std::string& logPath() {
  static const std::string path = [] {
    char pattern[] = "/tmp/radslam_fuzz_lcm_log_XXXXXX";
    const int fd = mkstemp(pattern);
    if (fd < 0) {
      std::perror("lcm_log fuzz: mkstemp");
      std::abort();
    }
    close(fd);
    return std::string(pattern);
  }();
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = logPath();
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);
  try {
    radslam::LogReader reader(path);
    size_t bytes = 0;
    while (auto event = reader.next()) {
      bytes += event->data.size() + event->channel.size();
      // Events are read from the file: they cannot hold more than it does.
      if (bytes > size) {
        std::fprintf(stderr, "lcm_log fuzz: events hold %zu bytes, the file %zu\n", bytes, size);
        std::abort();
      }
    }
  } catch (const std::exception&) {
    // A clear error is an accepted outcome.
  }
  return 0;
}
