// libFuzzer target for decode<T> (common/bus.h), T = RADSLAM_FUZZ_MESSAGE. The
// input is the LCM bytes of one message, as a subscriber receives them.
//
// Checked beyond "no crash, no sanitizer report": decode() returns an error
// text whenever it rejects, and a message it accepts re-encodes and decodes
// again (the decoder accepts only what the sender side can carry).
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <vector>

#include "common/bus.h"
#include "common/types.h"

#ifndef RADSLAM_FUZZ_MESSAGE
#error "RADSLAM_FUZZ_MESSAGE must name the message struct to decode"
#endif

namespace {

[[noreturn]] void failCheck(const char* what, const std::string& detail) {
  std::fprintf(stderr, "decode fuzz: %s: %s\n", what, detail.c_str());
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using Message = radslam::RADSLAM_FUZZ_MESSAGE;
  Message msg;
  std::string error;
  if (!radslam::decode<Message>(data, size, &msg, &error)) {
    if (error.empty()) failCheck("rejected without an error message", "");
    return 0;
  }
  std::vector<uint8_t> bytes;
  try {
    bytes = radslam::encode<Message>(msg);
  } catch (const std::exception& e) {
    failCheck("a decoded message does not encode again", e.what());
  }
  Message again;
  if (!radslam::decode<Message>(bytes.data(), bytes.size(), &again, &error)) {
    failCheck("a re-encoded message does not decode", error);
  }
  return 0;
}
