// Volume rendering of the voxel field with analytic gradients (DESIGN section 4).
//
/// Along a ray x(t) = origin + t * dir with samples t_i (increasing) and intervals delta_i:
///   tau_i = sigma_i delta_i,  T_i = exp(-sum_{j<i} tau_j),  w_i = T_i (1 - exp(-tau_i)),
///   colour I* = sum_i w_i c_i + (1 - W) bg,  W = sum_i w_i,
///   depth  D* = sum_i w_i t_i,  variance Var = sum_i w_i (t_i - D*)^2.
/// dir is R_world_cam * (x, y, 1) in camera coordinates, so t is the z-depth of the keyframe
/// depth maps (metres). Backward passes give d loss / d voxel parameters (sparse) and the
/// pieces of d loss / d pose for a right perturbation T_world_cam * Exp(xi), xi = (v, w).
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"
#include "mapper/field.h"

namespace radslam {

/// Deterministic, cheap random numbers (SplitMix64); the state is one integer so that
/// checkpoints can store it.
struct Rng {
  uint64_t state = 0x9E3779B97F4A7C15ull;
  uint64_t next() {
    uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  /// Uniform in [0, 1).
  float uniform() { return static_cast<float>(next() >> 40) * (1.f / 16777216.f); }
  /// Uniform integer in [0, n).
  uint32_t below(uint32_t n) {
    return static_cast<uint32_t>(((next() >> 32) * static_cast<uint64_t>(n)) >> 32);
  }
};

struct Ray {
  Eigen::Vector3f origin = Eigen::Vector3f::Zero();     // world, m
  Eigen::Vector3f dir = Eigen::Vector3f::UnitZ();       // world, R_world_cam * cam_dir
  Eigen::Vector3f view_dir = Eigen::Vector3f::UnitZ();  // world, unit (SH colour)
  Eigen::Vector3f cam_dir = Eigen::Vector3f::UnitZ();   // camera, (x, y, 1)
};
/// The ray of camera direction cam_dir = (x, y, 1) of a camera at T_world_cam.
Ray makeRay(const SE3& T_world_cam, const Eigen::Vector3d& cam_dir);

/// A view through a rolling shutter: pixel (u, v) was exposed exposure_s(v, u) after the
/// pose's time, by a camera turning at omega_cam meanwhile, so its ray is
/// Exp(omega_cam exposure_s) K^-1 (u, v, 1) in the pose's camera (rotation only). Empty
/// exposure times: a global shutter.
struct RollingShutterView {
  Vec3 omega_cam = Vec3::Zero();  // rad/s, camera frame
  cv::Mat exposure_s;             // CV_32FC1 of the camera's size (Undistorter::exposureTimes)
};

struct RayOutput {
  float color[3] = {0, 0, 0};  // RGB, [0, 1]
  float depth = 0;             // D*, m (not normalised by the weight sum)
  float var = 0;               // m^2
  float weight = 0;            // W = 1 - final transmittance
  int samples = 0;             // samples in allocated space
};

/// Upstream gradients d loss / d (I*, D*, Var).
struct RayOutputGrad {
  float color[3] = {0, 0, 0};
  float depth = 0;
  float var = 0;
};

/// Per-ray scratch of the forward pass, reused across rays (no allocation per sample). Plain
/// data: the renderer's kernels fill it, backward and tests read it.
struct RayWorkspace {
  struct Sample {
    float t, delta;
    float dsoftplus;       // sigmoid(raw density): d softplus / d raw
    float sigma;           // density, 1/m
    float transmit;        // T_i
    float decay;           // exp(-tau_i)
    float w;               // weight
    float color[3];        // RGB after the sigmoid
    float raw[1 + 3 * 4];  // interpolated channels (SH needs the coefficients in backward)
  };
  struct Corners {
    int32_t vox[8];  // voxel index into the level's array (block * kBlockVoxels + voxel)
    float frac[3];   // position within the cell, [0, 1)
    uint8_t mask;    // bit c: corner c is allocated
  };
  void reserve(int samples, int levels);
  int size() const { return n; }
  const Sample& sample(int i) const { return samples[i]; }

  std::vector<Sample> samples;   // the n samples in allocated space, in ray order
  std::vector<Corners> corners;  // samples x levels
  int n = 0;
  int levels = 0;
};

/// Dense per-level gradient arrays parallel to the field's parameters, with the blocks touched
/// since the last clear and, per block, a bit per voxel written (the optimiser visits those
/// voxels only).
class FieldGradient {
 public:
  static constexpr int kWords = Field::kBlockVoxels / 64;  // voxel bits per block

  /// Grows the arrays to the field's current blocks (new entries 0).
  void resize(const Field& field);
  float* data(int level) { return grad_[level].data(); }
  const float* data(int level) const { return grad_[level].data(); }
  void touch(int level, int block) {
    uint8_t& flag = touched_flag_[level][block];
    if (!flag) {
      flag = 1;
      touched_[level].push_back(block);
    }
  }
  /// Marks voxel `voxel` (block * kBlockVoxels + index) as written; touch its block too.
  void markVoxel(int level, int voxel) {
    voxel_bits_[level][voxel >> 6] |= uint64_t{1} << (voxel & 63);
  }
  /// The kWords bit words of a block's written voxels.
  uint64_t* voxelBits(int level, int block) {
    return voxel_bits_[level].data() + static_cast<size_t>(block) * kWords;
  }
  const std::vector<int>& touched(int level) const { return touched_[level]; }
  /// Zeroes the touched blocks and forgets them.
  void clear(int channels);
  /// Forgets the touched blocks without zeroing (their gradients are already zero).
  void forgetTouched();
  int numLevels() const { return static_cast<int>(grad_.size()); }

 private:
  std::vector<LargeVector<float>> grad_;
  std::vector<std::vector<uint64_t>> voxel_bits_;
  std::vector<std::vector<uint8_t>> touched_flag_;
  std::vector<std::vector<int>> touched_;
};

/// Sums of a ray's pose gradient in the world frame; poseGradient() turns them into the
/// 6-vector for T_world_cam (v, w).
struct RayPoseGrad {
  Eigen::Vector3f g_pos = Eigen::Vector3f::Zero();   // sum_i dL/dx_i
  Eigen::Vector3f g_tpos = Eigen::Vector3f::Zero();  // sum_i t_i dL/dx_i
  Eigen::Vector3f g_dir = Eigen::Vector3f::Zero();   // dL/d view_dir (SH only)
};
/// d loss / d xi for T_world_cam * Exp(xi), xi = (v, w), given the ray's world-frame sums.
Vec6 poseGradient(const SE3& T_world_cam, const Ray& ray, const RayPoseGrad& g);

/// Where the training samples of a ray go (all lengths in metres along the z-depth).
struct SamplingParams {
  int surface_samples = 12;  // stratified within depth +- sigma_range * sigma
  int spread_samples = 4;    // stratified between near and the surface band
  int free_samples = 24;     // for rays without depth: stratified in the field bounds
  float sigma_range = 3;     // surface band half-width, in depth sigmas
  float sigma_min = 0.02f;   // clamp of the depth sigma (m): about one fine voxel
  float sigma_max = 0.5f;    // m
  float near = 0.05f;        // m
  float far = 100.f;         // m
};

/// Stratified training samples for a ray with a keyframe depth (depth > 0) or without
/// (depth <= 0: samples between max(near, t_enter) and min(far, t_exit)). Writes at most
/// maxSamples(params) values to t and delta (increasing t); returns the count (0 when the ray
/// misses the interval).
int sampleRay(const SamplingParams& params, float depth, float depth_sigma, float t_enter,
              float t_exit, Rng* rng, float* t, float* delta);
int maxSamples(const SamplingParams& params);

/// Options of the render-only path (arbitrary views, no depth prior): deterministic ray
/// marching through allocated space, jumping over unallocated coarse and fine blocks.
struct MarchParams {
  float step_fine = 0.5f;           // step in fine voxels through allocated space
  float near = 0.05f;               // m
  float far = 100.f;                // m
  float min_transmittance = 1e-4f;  // early termination
  /// Empty-space skipping beyond unallocated blocks: a sub-block of Field::kSubDim^3 fine cells
  /// where the field's density bound (Field::densityBounds, all levels summed) gives less than
  /// this optical thickness per fine voxel (sigma * fine voxel size) is stepped over whole,
  /// staying on the sample grid. A skipped sub-block would have absorbed at most this much per
  /// fine voxel travelled in it. 0 = exact march (no skipping).
  float skip_thickness = 0;
  /// Adaptive step: in each sub-block the step grows from step_fine up to max_step_fine fine
  /// voxels while the sub-block's density bound keeps the optical thickness of one step below
  /// this (a step ends at the sub-block's exit at the latest). Exact for a constant field
  /// (transmittance depends on the distance only), approximate where the field varies within
  /// a step. 0 = fixed step.
  float max_sample_thickness = 0;
  float max_step_fine = 4;
  /// Depth and variance normalised by the weight sum W (the depth of the surface hit, not
  /// D* = sum w t); pixels with W < min_weight get depth 0 (unknown) and sigma 0.
  bool normalize_depth = true;
  float min_weight = 0.5f;
};

/// Float images of a render: colour CV_32FC3 RGB in [0, 1], depth/sigma/weight CV_32FC1.
struct RenderImages {
  cv::Mat color;   // RGB
  cv::Mat depth;   // m
  cv::Mat sigma;   // m, sqrt(Var)
  cv::Mat weight;  // W
};

class VolumeRenderer {
 public:
  /// Background colour for rays that leave the field (RGB, [0, 1]); default black.
  explicit VolumeRenderer(Eigen::Vector3f background = Eigen::Vector3f::Zero())
      : background_(background) {}
  const Eigen::Vector3f& background() const { return background_; }

  /// Forward pass at the given samples; keeps what backward needs in ws.
  RayOutput forward(const Field& field, const Ray& ray, const float* t, const float* delta, int n,
                    RayWorkspace* ws) const;
  /// Adds d loss / d parameters to grad (touching the blocks it writes) and, when pose is
  /// non-null, adds the ray's pose-gradient sums: of the same loss, or of the loss whose
  /// upstream gradients are g_pose when given. out is forward()'s result for ws.
  void backward(const Field& field, const Ray& ray, const RayWorkspace& ws, const RayOutput& out,
                const RayOutputGrad& g, FieldGradient* grad, RayPoseGrad* pose,
                const RayOutputGrad* g_pose = nullptr) const;

  /// Render-only: marches the ray through allocated space (see MarchParams).
  RayOutput march(const Field& field, const Ray& ray, const MarchParams& params) const;
  /// Renders a pinhole view (distortion ignored) with `threads` threads; deterministic.
  RenderImages render(const Field& field, const SE3& T_world_cam, const CameraModel& camera,
                      const MarchParams& params, int threads = 1,
                      const RollingShutterView& rolling_shutter = {}) const;

 private:
  Eigen::Vector3f background_;
};

/// Renders a pinhole view (distortion ignored) ray by ray, in square tiles on `threads`
/// threads; march_ray(ray, u, v) gives the output of pixel (u, v). Deterministic: pixels are
/// independent. Throws std::invalid_argument on a camera without positive size and focal
/// lengths, or exposure times of another size.
RenderImages renderPinhole(const SE3& T_world_cam, const CameraModel& camera, int threads,
                           const std::function<RayOutput(const Ray&, int u, int v)>& march_ray,
                           const RollingShutterView& rolling_shutter = {});

/// Entry and exit of a ray in the box [lo, hi] (t may be negative); false when it misses.
bool intersectBox(const Ray& ray, const Eigen::Vector3f& lo, const Eigen::Vector3f& hi,
                  float* t_enter, float* t_exit);

/// Converts a RenderImages colour (RGB float) to CV_8UC3 BGR.
cv::Mat toBgr8(const cv::Mat& rgb);

}  // namespace radslam
