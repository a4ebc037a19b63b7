// Training of the field on all keyframes (DESIGN section 4):
//   L = sum over rays of  ||I - I*||^2 + lambda_D (D - D*)^2 / Sigma_D
// with sparse Adam on the voxels and Adam on each keyframe's pose (right perturbation of
// T_world_cam, the gauge keyframe held fixed).
//
/// Depth loss modes:
///  - weighted (default): Sigma_D = the keyframe's depth variance, clamped below at
///    (min_depth_sigma_voxels * fine voxel)^2; pixels with infinite variance get no depth loss.
///  - raw: Sigma_D = (raw_depth_sigma_voxels * fine voxel)^2 for every pixel: unweighted, with
///    the constant chosen relative to the map scale (about one fine voxel) so that the balance
///    between colour and depth is the same in metric and monocular maps.
///  - none: colour only (depth still guides where samples go).
/// Lengths in the parameters are in fine voxels so that they follow the (arbitrary) map scale.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "mapper/field.h"
#include "mapper/keyframe_store.h"
#include "mapper/sparse_adam.h"
#include "mapper/volume_renderer.h"

namespace radslam {

enum class DepthLoss { kWeighted, kRaw, kNone };
/// "weighted", "raw" or "none"; throws std::invalid_argument otherwise.
DepthLoss parseDepthLoss(const std::string& name);
std::string depthLossName(DepthLoss mode);

struct TrainerParams {
  int batch_rays = 4096;
  int patch_size = 2;  // rays come in patch_size^2 pixel patches (cache locality)
  int threads = 1;
  uint64_t seed = 1;
  // Samples per ray (see SamplingParams); lengths in fine voxels.
  int surface_samples = 12;
  int spread_samples = 4;
  int free_samples = 24;
  float sigma_range = 3;
  float sigma_min_voxels = 1;
  float sigma_max_voxels = 16;
  float near_voxels = 5;
  // Loss.
  DepthLoss depth_loss = DepthLoss::kWeighted;
  float lambda_depth = 1;
  float raw_depth_sigma_voxels = 1;
  float min_depth_sigma_voxels = 0.5f;
  float depth_huber = 3;             // Huber threshold on |D - D*| / sigma (0 = plain squares)
  bool train_depthless_rays = true;  // pixels without depth train colour (samples in bounds)
  AdamParams adam;
  // Pose refinement.
  bool refine_poses = true;
  float pose_lr_rot = 2e-4f;           // rad per step
  float pose_lr_trans_voxels = 0.01f;  // fine voxels per step
  int64_t pose_warmup_rays = 5000;     // rays of a keyframe before its pose moves
  /// The pose steps halve every this many steps of the keyframe (0 = constant). Adam's step
  /// does not shrink with the gradient, so at a constant rate the poses wander for as long as
  /// training runs and the views between keyframes lose (fr1/rpy oracle, 6M rays: held-out
  /// 20.83 dB constant, 22.32 dB with 250; docs/mapper.md).
  int64_t pose_lr_half_life_steps = 250;
  /// Weight of the depth term in the pose gradient. The keyframe depths come from the same
  /// bundle adjustment as the poses, and depth residuals are biased by the field's surface
  /// quadrature (a fraction of a voxel), so the photometric term alone drives poses by default.
  float pose_depth_weight = 0;
  // Exposure: per-keyframe affine colour (applyExposure), Adam on its mean gradient per step.
  bool refine_exposure = true;
  float exposure_lr = 1e-3f;         // log gain and offset units per step
  int64_t exposure_warmup_rays = 0;  // rays of a keyframe before its exposure moves
  // Keyframe choice: weight 1 + recency_boost exp(-rays / recency_rays)
  //                           + loss_boost (running loss / mean running loss).
  float recency_boost = 4;
  float recency_rays = 50000;
  float loss_boost = 1;
};

struct TrainStats {
  int rays = 0;
  int64_t samples = 0;    // samples in allocated space
  double loss = 0;        // mean per ray
  double loss_rgb = 0;    // mean per ray
  double loss_depth = 0;  // mean per ray (including lambda_D)
  int64_t voxels_updated = 0;
  int poses_refined = 0;
};

/// The colour keyframe k sees where the field renders c (RGB, [0, 1]): the camera's auto
/// exposure and white balance as an affine map per channel,
///   c'_j = exp(x_j) c_j + x_{3+j},   x = KeyframeEntry::exposure.
/// Consecutive fr1/rpy keyframes differ by gains of 0.86..1.18 and offsets up to 0.1, which
/// one field cannot fit without it.
inline void applyExposure(const float gain[3], const float offset[3], const float c[3],
                          float out[3]) {
  for (int j = 0; j < 3; ++j) out[j] = gain[j] * c[j] + offset[j];
}
/// Backward of applyExposure: given g_out = d loss / d c', sets g_c = d loss / d c and adds
/// d loss / d x to *g_x when not null (gain = exp(x_j), so d c'_j / d x_j = gain_j c_j).
inline void exposureBackward(const float gain[3], const float c[3], const float g_out[3],
                             float g_c[3], Vec6* g_x) {
  for (int j = 0; j < 3; ++j) g_c[j] = g_out[j] * gain[j];
  if (!g_x) return;
  for (int j = 0; j < 3; ++j) {
    (*g_x)[j] += g_out[j] * gain[j] * c[j];
    (*g_x)[3 + j] += g_out[j];
  }
}
/// A render's colour (CV_32FC3 RGB) as seen under exposure x, in place.
void applyExposure(const Vec6& x, cv::Mat* rgb);
/// Exposure of a frame at time t (any unit) between keyframes at times t_a <= t <= t_b: linear
/// interpolation of x (auto exposure drifts smoothly), the nearest one outside.
Vec6 interpolateExposure(double t, double t_a, const Vec6& x_a, double t_b, const Vec6& x_b);

class Trainer {
 public:
  explicit Trainer(const TrainerParams& params = TrainerParams());
  ~Trainer();
  Trainer(const Trainer&) = delete;
  Trainer& operator=(const Trainer&) = delete;
  void setParams(const TrainerParams& params);
  const TrainerParams& params() const { return params_; }

  /// One step: a batch of rays drawn from all keyframes, forward, backward, Adam on the
  /// touched voxels and on the poses. No-op (rays = 0) when the field or the store is empty.
  TrainStats step(Field* field, KeyframeStore* keyframes);

  int64_t steps() const { return steps_; }
  uint64_t rngState() const { return rng_.state; }
  /// Back to the state after construction (no steps, fresh optimiser).
  void reset();
  /// Restores the counters of a checkpoint.
  void restoreState(int64_t steps, uint64_t rng_state);
  SparseAdam& optimizer() { return adam_; }
  const SparseAdam& optimizer() const { return adam_; }

  /// Sampling parameters in metres for a field of this fine voxel size.
  SamplingParams samplingFor(double fine_voxel_size) const;

 private:
  struct ThreadState;
  struct KeyframeView;
  void traceRays(const Field& field, const KeyframeStore& keyframes, ThreadState* ts, int count);
  void traceRay(const Field& field, const VolumeRenderer& renderer, const SamplingParams& sp,
                const KeyframeView& kv, int k, int x, int y, float depth, float var,
                ThreadState* ts) const;

  TrainerParams params_;
  SparseAdam adam_;
  Rng rng_;
  int64_t steps_ = 0;
  std::vector<ThreadState> threads_;
  // Per step: keyframe choice and per-keyframe cached geometry.
  std::vector<double> cdf_;
  std::vector<KeyframeView> views_;
  int gauge_ = -1;
};

}  // namespace radslam
