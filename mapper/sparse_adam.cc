#include "mapper/sparse_adam.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace radslam {

namespace {
// Past this many steps the bias corrections are 1 to float precision (beta2 = 0.99: 1e-9).
constexpr int kTable = 4096;
}  // namespace

void SparseAdam::resize(const Field& field) {
  const int levels = field.numLevels();
  m_.resize(levels);
  v_.resize(levels);
  steps_.resize(levels);
  for (int l = 0; l < levels; ++l) {
    // The field's reservation, so that growth does not move the moments either.
    const size_t capacity = size_t(field.blockCapacity(l)) * Field::kBlockVoxels;
    m_[l].reserve(capacity * field.channels());
    v_[l].reserve(capacity * field.channels());
    steps_[l].reserve(capacity);
    m_[l].resize(field.levelSize(l), 0.f);
    v_[l].resize(field.levelSize(l), 0.f);
    steps_[l].resize(size_t(field.numBlocks(l)) * Field::kBlockVoxels, 0);
  }
}

void SparseAdam::buildTables() {
  if (table_beta1_ == params_.beta1 && table_beta2_ == params_.beta2) return;
  correction1_.assign(kTable + 1, 1.f);
  correction2_.assign(kTable + 1, 1.f);
  for (int t = 1; t <= kTable; ++t) {
    correction1_[t] = static_cast<float>(1.0 / (1.0 - std::pow(double(params_.beta1), t)));
    correction2_[t] = static_cast<float>(1.0 / (1.0 - std::pow(double(params_.beta2), t)));
  }
  table_beta1_ = params_.beta1;
  table_beta2_ = params_.beta2;
}

int64_t SparseAdam::step(Field* field, FieldGradient* grad) {
  resize(*field);
  buildTables();
  const int C = field->channels();
  const int levels = field->numLevels();
  const float b1 = params_.beta1, b2 = params_.beta2;
  int64_t updated = 0;
  for (int l = 0; l < levels; ++l) {
    const float scale = l + 1 < levels ? params_.coarse_lr_scale : 1.f;
    const float lr_d = params_.lr_density * scale, lr_c = params_.lr_color * scale;
    float* g = grad->data(l);
    float* p = field->levelData(l);
    float* m = m_[l].data();
    float* v = v_[l].data();
    int32_t* steps = steps_[l].data();
    for (int b : grad->touched(l)) {
      // Only the voxels the backward passes wrote.
      const uint64_t* bits = grad->voxelBits(l, b);
      bool changed = false;
      for (int w = 0; w < FieldGradient::kWords; ++w) {
        for (uint64_t word = bits[w]; word; word &= word - 1) {
          const size_t voxel =
              size_t(b) * Field::kBlockVoxels + w * 64 + static_cast<size_t>(__builtin_ctzll(word));
          const size_t o = voxel * C;
          const int t = ++steps[voxel];
          const float c1 = correction1_[std::min(t, kTable)];
          const float c2 = correction2_[std::min(t, kTable)];
          for (int ch = 0; ch < C; ++ch) {
            const float gi = g[o + ch];
            m[o + ch] = b1 * m[o + ch] + (1 - b1) * gi;
            v[o + ch] = b2 * v[o + ch] + (1 - b2) * gi * gi;
            const float lr = ch == 0 ? lr_d : lr_c;
            p[o + ch] -= lr * (m[o + ch] * c1) / (std::sqrt(v[o + ch] * c2) + params_.eps);
            g[o + ch] = 0.f;
          }
          changed = true;
          ++updated;
        }
      }
      if (changed) field->markChanged(l, b);
    }
  }
  grad->forgetTouched();
  return updated;
}

}  // namespace radslam
