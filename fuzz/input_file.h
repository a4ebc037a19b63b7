// For targets whose entry point reads a file: the fuzzer's input written to a private file of
// this process under /tmp (created once, rewritten for every input).
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace radslam::fuzz {

/// Writes data to this process's input file (named after `target`) and returns its path.
inline const std::string& writeInputFile(const char* target, const uint8_t* data, size_t size) {
  static const std::string path = [target] {
    std::string pattern = std::string("/tmp/radslam_fuzz_") + target + "_XXXXXX";
    const int fd = mkstemp(pattern.data());
    if (fd < 0) {
      std::perror("fuzz: mkstemp");
      std::abort();
    }
    close(fd);
    return pattern;
  }();
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);
  return path;
}

}  // namespace radslam::fuzz
