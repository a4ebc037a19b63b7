// A small trained field from the project's synthetic scene, for the renderer's tests and
// benchmark (no dataset or checkpoint needed).
#pragma once

#include <memory>
#include <vector>

#include "common/types.h"
#include "mapper/mapper.h"

namespace radslam {

struct DemoFieldOptions {
  int width = 160;  // keyframe images, pixels (height = 3/4 width)
  int keyframes = 4;
  int train_steps = 20;
  int batch_rays = 1024;
};

/// A mapper trained on keyframes of the synthetic "room" scene with their true poses and
/// depths; *keyframes (optional) receives the keyframes it was given.
std::unique_ptr<Mapper> makeDemoMapper(const DemoFieldOptions& options,
                                       std::vector<Keyframe>* keyframes = nullptr);

}  // namespace radslam
