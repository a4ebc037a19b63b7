// The tiny sequence and tracker settings shared by the tracker checkpoint fuzz target and its
// seed (write_seeds.cc): a checkpoint written after the first frames, loaded, then tracking
// goes on with the next ones.
#pragma once

#include <vector>

#include "common/synthetic.h"
#include "tracker/tracker.h"

namespace radslam::fuzz {

constexpr int kCheckpointFrames = 8;  // frames before the seed's checkpoint
constexpr int kSequenceFrames = 10;

inline const std::vector<Frame>& trackerSequence() {
  static const std::vector<Frame> frames = [] {
    SyntheticConfig config;
    config.scene = "car";  // street at 10 Hz: keyframes in few frames, and a moving car
    config.width = 48;
    config.height = 32;
    config.frames = kSequenceFrames;
    const SyntheticScene scene = SyntheticScene::make(config);
    std::vector<Frame> out;
    for (int i = 0; i < kSequenceFrames; ++i) out.push_back(scene.frame(i));
    return out;
  }();
  return frames;
}

inline TrackerParams trackerParams() {
  TrackerParams params;
  params.mode = "rgbd";
  params.window_size = 2;
  return params;
}

}  // namespace radslam::fuzz
