// libFuzzer target for LogReader (common/lcm_log.h): the input is written as an
// LCM log file and read to its end. Event lengths come from the file, so they
// must be checked against what the file holds before anything is allocated.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "common/lcm_log.h"
#include "fuzz/input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string& path = radslam::fuzz::writeInputFile("lcm_log", data, size);
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
