// A keyframe in the run folder: keyframes/<stamp>.exr (depth and sigma in m, inverse depth and
// its variance, OpenEXR float channels) and keyframes/<stamp>.png (the colour image the mapper
// trains on: undistorted at the tracker's working resolution and, for a rolling-shutter camera,
// as seen at its middle row). The recorder and radslam-bench-tracker --out write the same files.
#pragma once

#include <string>

#include "common/types.h"

namespace radslam {

/// Writes DIR/<stamp>.exr (channels the keyframe has) and DIR/<stamp>.png (when it has a
/// colour image), creating DIR. Throws std::runtime_error naming the file that cannot be
/// written.
void writeKeyframeFiles(const std::string& dir, const Keyframe& keyframe);

}  // namespace radslam
