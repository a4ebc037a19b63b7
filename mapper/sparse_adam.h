// Sparse ("lazy") Adam on the voxel parameters: only voxels with a gradient in this step are
// updated; each voxel keeps its own step counter for the bias correction, and moments exist
// for every allocated voxel but decay only when the voxel is touched.
#pragma once

#include <cstdint>
#include <vector>

#include "mapper/field.h"
#include "mapper/volume_renderer.h"

namespace radslam {

struct AdamParams {
  float lr_density = 0.3f;      // raw density units per step
  float lr_color = 0.05f;       // raw colour units per step
  float coarse_lr_scale = 1.f;  // multiplies the learning rates of every level but the finest
  // Each voxel's rates halve every lr_half_life_steps of its own steps (0 = constant), down to
  // lr_min_scale x (the decay stops at 4096 steps in any case): a voxel that new keyframes
  // reach starts at the full rate. fr1/rpy oracle, 6M rays: keyframes / held out 25.00 /
  // 22.32 dB constant, 25.32 / 22.81 dB with 250 (docs/mapper.md).
  int lr_half_life_steps = 250;
  float lr_min_scale = 0.1f;
  float beta1 = 0.9f;
  float beta2 = 0.99f;
  float eps = 1e-8f;
};

class SparseAdam {
 public:
  explicit SparseAdam(const AdamParams& params = AdamParams()) : params_(params) {}
  void setParams(const AdamParams& params) { params_ = params; }
  const AdamParams& params() const { return params_; }

  /// Grows the state to the field's blocks (new voxels start at zero moments, step 0).
  void resize(const Field& field);
  /// One step on every voxel grad marked as written (FieldGradient::markVoxel); marks
  /// those blocks changed in the field and leaves grad zeroed with no touched blocks. Returns
  /// the number of voxels updated.
  int64_t step(Field* field, FieldGradient* grad) { return step(field, {grad}, 1); }
  /// The same on the sum of several buffers (one per training thread; at least one), over
  /// every voxel marked in any of them, with the blocks split over `threads` threads: summing
  /// only the marked voxels where they are updated costs far less than merging whole blocks
  /// first, and the sum is in buffer order whatever `threads` is.
  int64_t step(Field* field, const std::vector<FieldGradient*>& grads, int threads);

  // State, for checkpoints: per level, parallel to the field's parameters (steps per voxel).
  std::vector<LargeVector<float>>& firstMoments() { return m_; }
  std::vector<LargeVector<float>>& secondMoments() { return v_; }
  std::vector<LargeVector<int32_t>>& steps() { return steps_; }
  const std::vector<LargeVector<float>>& firstMoments() const { return m_; }
  const std::vector<LargeVector<float>>& secondMoments() const { return v_; }
  const std::vector<LargeVector<int32_t>>& steps() const { return steps_; }

 private:
  void buildTables();

  AdamParams params_;
  std::vector<LargeVector<float>> m_, v_;
  std::vector<LargeVector<int32_t>> steps_;
  // 1 / (1 - beta^t), t = 0..kTable; the first also times the rate's decay at step t.
  std::vector<float> correction1_, correction2_;
  float table_beta1_ = -1, table_beta2_ = -1;
  int table_half_life_ = -1;
  float table_min_scale_ = -1;
};

}  // namespace radslam
