// libFuzzer target for tracker checkpoints (Tracker::loadCheckpoint, tracker/tracker.h): the
// input is written as a checkpoint file and loaded into a tracker; when it loads, the tracker
// tracks the sequence's last frames and finishes, as a resumed radslam-tracker does. A clear
// exception is an accepted outcome; a crash, a sanitizer report, an allocation past libFuzzer's
// limit or a hang is a finding. A refused file must leave the tracker as it was.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

#include "fuzz/input_file.h"
#include "fuzz/tracker_sequence.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using radslam::fuzz::trackerSequence;
  const std::string& path = radslam::fuzz::writeInputFile("tracker_checkpoint", data, size);
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
