// libFuzzer target for tracker checkpoints (Tracker::loadCheckpoint, tracker/tracker.h): the
// input is written as a checkpoint file and loaded into a tracker; when it loads, the tracker
// tracks the sequence's last frames and finishes, as a resumed radslam-tracker does. A clear
// exception is an accepted outcome; a crash, a sanitizer report, an allocation past libFuzzer's
// limit or a hang is a finding. A refused file must leave the tracker as it was.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "fuzz/tracker_sequence.h"

namespace {

// One checkpoint file per fuzzing process, rewritten for every input.
const std::string& checkpointPath() {
  static const std::string path = [] {
    char pattern[] = "/tmp/radslam_fuzz_tracker_checkpoint_XXXXXX";
    const int fd = mkstemp(pattern);
    if (fd < 0) {
      std::perror("tracker checkpoint fuzz: mkstemp");
      std::abort();
    }
    close(fd);
    return std::string(pattern);
  }();
  return path;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using radslam::fuzz::trackerSequence;
  const std::string& path = checkpointPath();
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) std::abort();
  if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
  std::fclose(f);
  radslam::Tracker tracker(radslam::fuzz::trackerParams());
  try {
    tracker.loadCheckpoint(path);
  } catch (const std::exception&) {
    if (tracker.lastFrameIndex() != -1) {
      std::fprintf(stderr, "tracker checkpoint fuzz: a refused file changed the tracker\n");
      std::abort();
    }
    return 0;
  }
  try {
    for (int i = radslam::fuzz::kCheckpointFrames; i < radslam::fuzz::kSequenceFrames; ++i)
      tracker.process(trackerSequence()[i]);
    tracker.finish();
  } catch (const std::exception&) {
    // A clear error is an accepted outcome.
  }
  return 0;
}
