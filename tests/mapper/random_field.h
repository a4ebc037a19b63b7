// A test field: a shell of allocated blocks with pseudo-random values, some blocks zeroed.
#pragma once

#include <cstdint>

#include "mapper/field.h"
#include "mapper/volume_renderer.h"

namespace radslam {

inline Field makeRandomField(int levels, int level_ratio, int sh_degree,
                             uint64_t seed = Rng().state) {
  Field field(FieldGeometry::make(0.03, levels, level_ratio, sh_degree, -4.6f));
  Rng rng;
  rng.state = seed;
  for (double x = -0.4; x <= 0.4; x += 0.03)
    for (double y = -0.4; y <= 0.4; y += 0.03)
      for (double z = 0.8; z <= 1.6; z += 0.03)
        if (rng.uniform() < 0.6f) field.allocateAround(Eigen::Vector3f(x, y, z));
  for (int l = 0; l < field.numLevels(); ++l)
    for (int b = 0; b < field.numBlocks(l); ++b) {
      float* data = field.blockData(l, b);
      const bool zero = rng.uniform() < 0.3f;
      for (int i = 0; i < Field::kBlockVoxels * field.channels(); ++i)
        data[i] = zero ? 0.f : (rng.uniform() - 0.5f) * 8.f;
    }
  return field;
}

}  // namespace radslam
