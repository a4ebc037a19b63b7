#include "mapper/sparse_adam.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include "common/parallel.h"

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
  if (table_beta1_ == params_.beta1 && table_beta2_ == params_.beta2 &&
      table_half_life_ == params_.lr_half_life_steps && table_min_scale_ == params_.lr_min_scale)
    return;
  correction1_.assign(kTable + 1, 1.f);
  correction2_.assign(kTable + 1, 1.f);
  for (int t = 1; t <= kTable; ++t) {
    // The rate's decay rides on the first moment's correction: one table look-up per voxel.
    const double decay = params_.lr_half_life_steps > 0
                             ? std::max(double(params_.lr_min_scale),
                                        std::exp2(-double(t - 1) / params_.lr_half_life_steps))
                             : 1.0;
    correction1_[t] = static_cast<float>(decay / (1.0 - std::pow(double(params_.beta1), t)));
    correction2_[t] = static_cast<float>(1.0 / (1.0 - std::pow(double(params_.beta2), t)));
  }
  table_beta1_ = params_.beta1;
  table_beta2_ = params_.beta2;
  table_half_life_ = params_.lr_half_life_steps;
  table_min_scale_ = params_.lr_min_scale;
}

int64_t SparseAdam::step(Field* field, const std::vector<FieldGradient*>& grads, int threads) {
  resize(*field);
  buildTables();
  const int C = field->channels();
  const int levels = field->numLevels();
  const int buffers = static_cast<int>(grads.size());
  const float b1 = params_.beta1, b2 = params_.beta2;
  FieldGradient& g0 = *grads[0];
  std::vector<int64_t> updated(std::max(1, threads), 0);
  for (int l = 0; l < levels; ++l) {
    // The union of the touched blocks, in the first buffer's list.
    for (int k = 1; k < buffers; ++k)
      for (int b : grads[k]->touched(l)) g0.touch(l, b);
    const std::vector<int>& blocks = g0.touched(l);
    std::vector<uint8_t> changed(blocks.size(), 0);
    const float scale = l + 1 < levels ? params_.coarse_lr_scale : 1.f;
    const float lr_d = params_.lr_density * scale, lr_c = params_.lr_color * scale;
    float* p = field->levelData(l);
    float* m = m_[l].data();
    float* v = v_[l].data();
    int32_t* steps = steps_[l].data();
    const int parts = std::clamp(threads, 1, std::max<int>(1, blocks.size()));
    runOnThreads(parts, [&](int part) {
      std::vector<float*> g(buffers);
      for (int k = 0; k < buffers; ++k) g[k] = grads[k]->data(l);
      int64_t voxels = 0;
      for (size_t i = blocks.size() * part / parts; i < blocks.size() * (part + 1) / parts; ++i) {
        const int b = blocks[i];
        const int64_t voxels_before = voxels;
        // Only the voxels the backward passes wrote; the other buffers' into the first.
        uint64_t* bits = grads[0]->voxelBits(l, b);
        for (int k = 1; k < buffers; ++k) {
          const uint64_t* bits_k = grads[k]->voxelBits(l, b);
          for (int w = 0; w < FieldGradient::kWords; ++w) {
            for (uint64_t word = bits_k[w]; word; word &= word - 1) {
              const size_t o = (size_t(b) * Field::kBlockVoxels + w * 64 +
                                static_cast<size_t>(__builtin_ctzll(word))) *
                               C;
              for (int ch = 0; ch < C; ++ch) {
                g[0][o + ch] += g[k][o + ch];
                g[k][o + ch] = 0.f;
              }
            }
            bits[w] |= bits_k[w];
          }
        }
        for (int w = 0; w < FieldGradient::kWords; ++w) {
          for (uint64_t word = bits[w]; word; word &= word - 1) {
            const size_t voxel = size_t(b) * Field::kBlockVoxels + w * 64 +
                                 static_cast<size_t>(__builtin_ctzll(word));
            const size_t o = voxel * C;
            const int t = ++steps[voxel];
            const float c1 = correction1_[std::min(t, kTable)];
            const float c2 = correction2_[std::min(t, kTable)];
            for (int ch = 0; ch < C; ++ch) {
              const float gi = g[0][o + ch];
              g[0][o + ch] = 0.f;
              m[o + ch] = b1 * m[o + ch] + (1 - b1) * gi;
              v[o + ch] = b2 * v[o + ch] + (1 - b2) * gi * gi;
              const float lr = ch == 0 ? lr_d : lr_c;
              p[o + ch] -= lr * (m[o + ch] * c1) / (std::sqrt(v[o + ch] * c2) + params_.eps);
            }
            ++voxels;
          }
        }
        changed[i] = voxels > voxels_before;
      }
      updated[part] += voxels;  // once: the threads' counters share a cache line
    });
    // Field bookkeeping is not thread-safe; in block order, so that it is deterministic.
    for (size_t i = 0; i < blocks.size(); ++i)
      if (changed[i]) field->markChanged(l, blocks[i]);
  }
  for (FieldGradient* grad : grads) grad->forgetTouched();
  int64_t total = 0;
  for (int64_t u : updated) total += u;
  return total;
}

}  // namespace radslam
