// Volume rendering: forward pass against a slow reference, analytic gradients against central
// finite differences (voxel parameters and keyframe pose), render-only marching.
#include "mapper/volume_renderer.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "mapper/ray_kernels.h"

namespace radslam {
namespace {

// A field with smooth values (so that finite differences of the pose rarely straddle a kink of
// the trilinear interpolation) around a region 0.7..1.3 m in front of the camera.
Field makeField(int sh_degree, const SE3& T_world_cam) {
  Field field(FieldGeometry::make(0.02, 2, 4, sh_degree, -4.6f));
  for (double x = -0.2; x <= 0.2; x += 0.01)
    for (double y = -0.2; y <= 0.2; y += 0.01)
      for (double z = 0.7; z <= 1.3; z += 0.01)
        field.allocateAround((T_world_cam * Vec3(x, y, z)).cast<float>());
  for (int l = 0; l < field.numLevels(); ++l) {
    const double s = field.voxelSize(l);
    for (int b = 0; b < field.numBlocks(l); ++b) {
      float* data = field.blockData(l, b);
      const Eigen::Vector3i base = field.blockIndex(l, b) * Field::kBlockDim;
      for (int v = 0; v < Field::kBlockVoxels; ++v) {
        const Vec3 p = (base + Eigen::Vector3i(v % 8, (v / 8) % 8, v / 64)).cast<double>() * s;
        const Vec3 q = T_world_cam.inverse() * p;  // camera frame
        float* vox = data + v * field.channels();
        // Level 0 carries a density bump around z = 1 m, level 1 a smaller residual.
        const double bump = std::exp(-std::pow((q.z() - 1.0) / 0.06, 2));
        vox[0] = static_cast<float>(l == 0 ? 7 * bump - 1 : 0.8 * std::sin(9 * p.x() + 4 * p.z()));
        for (int ch = 1; ch < field.channels(); ++ch)
          vox[ch] = static_cast<float>(0.6 * std::sin(5 * p.x() + 3 * ch * p.y() - 2 * p.z() + ch) /
                                       (l + 1));
      }
    }
  }
  return field;
}

SE3 testPose() { return SE3(SO3::exp(Vec3(0.3, -0.2, 0.5)), Vec3(0.4, -0.3, 1.1)); }

struct Samples {
  std::vector<float> t, delta;
};
Samples fixedSamples(int n, float lo, float hi) {
  Samples s;
  for (int i = 0; i < n; ++i) s.t.push_back(lo + (hi - lo) * (i + 0.37f) / n);
  for (int i = 0; i + 1 < n; ++i) s.delta.push_back(s.t[i + 1] - s.t[i]);
  s.delta.push_back((hi - lo) / n);
  return s;
}

enum class LossKind { kColor, kDepth, kVariance, kAll };
const float kTargetColor[3] = {0.2f, 0.55f, 0.7f};
constexpr float kTargetDepth = 1.03f;

double lossOf(const RayOutput& o, LossKind kind) {
  double color = 0;
  for (int k = 0; k < 3; ++k) color += std::pow(o.color[k] - kTargetColor[k], 2);
  const double depth = std::pow(o.depth - kTargetDepth, 2);
  switch (kind) {
    case LossKind::kColor:
      return color;
    case LossKind::kDepth:
      return depth;
    case LossKind::kVariance:
      return o.var;
    case LossKind::kAll:
      return color + 3 * depth + 5 * o.var;
  }
  return 0;
}
RayOutputGrad gradOf(const RayOutput& o, LossKind kind) {
  RayOutputGrad g;
  const bool all = kind == LossKind::kAll;
  if (kind == LossKind::kColor || all)
    for (int k = 0; k < 3; ++k) g.color[k] = 2 * (o.color[k] - kTargetColor[k]);
  if (kind == LossKind::kDepth || all) g.depth = (all ? 3 : 1) * 2 * (o.depth - kTargetDepth);
  if (kind == LossKind::kVariance || all) g.var = all ? 5 : 1;
  return g;
}

class GradientTest : public ::testing::TestWithParam<std::tuple<int, LossKind>> {};

TEST_P(GradientTest, VoxelParametersMatchFiniteDifferences) {
  const auto [sh, kind] = GetParam();
  const SE3 T = testPose();
  Field field = makeField(sh, T);
  const VolumeRenderer renderer(Eigen::Vector3f(0.1f, 0.2f, 0.3f));
  const Ray ray = makeRay(T, Vec3(0.05, -0.04, 1));
  const Samples s = fixedSamples(24, 0.85f, 1.2f);
  RayWorkspace ws;
  const RayOutput out = renderer.forward(field, ray, s.t.data(), s.delta.data(), 24, &ws);
  ASSERT_EQ(out.samples, 24);
  ASSERT_GT(out.weight, 0.3f);
  ASSERT_LT(out.weight, 0.999f);
  FieldGradient grad;
  grad.resize(field);
  renderer.backward(field, ray, ws, out, gradOf(out, kind), &grad, nullptr);

  int checked = 0;
  for (int l = 0; l < field.numLevels(); ++l) {
    // The parameters with the largest gradients of each channel, and some of the smallest.
    const size_t size = field.levelSize(l);
    std::vector<size_t> order;
    for (size_t i = 0; i < size; ++i)
      if (grad.data(l)[i] != 0) order.push_back(i);
    ASSERT_FALSE(order.empty());
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) {
      return std::abs(grad.data(l)[a]) > std::abs(grad.data(l)[b]);
    });
    std::vector<size_t> pick(order.begin(), order.begin() + std::min<size_t>(12, order.size()));
    for (size_t k = order.size() / 2; k < order.size(); k += std::max<size_t>(1, order.size() / 8))
      pick.push_back(order[k]);
    // Every touched block must be listed.
    for (size_t i : order) {
      const int block = static_cast<int>(i / (Field::kBlockVoxels * field.channels()));
      const auto& touched = grad.touched(l);
      ASSERT_NE(std::find(touched.begin(), touched.end(), block), touched.end());
    }
    const double scale = std::abs(grad.data(l)[order[0]]);
    for (size_t i : pick) {
      float& p = field.levelData(l)[i];
      const float saved = p;
      const float eps = 1e-2f;
      p = saved + eps;
      const double lp =
          lossOf(renderer.forward(field, ray, s.t.data(), s.delta.data(), 24, &ws), kind);
      p = saved - eps;
      const double lm =
          lossOf(renderer.forward(field, ray, s.t.data(), s.delta.data(), 24, &ws), kind);
      p = saved;
      const double fd = (lp - lm) / (2 * eps);
      const double an = grad.data(l)[i];
      EXPECT_NEAR(an, fd, 2e-3 * scale + 2e-2 * std::abs(fd))
          << "level " << l << " param " << i << " channel " << i % field.channels();
      ++checked;
    }
  }
  EXPECT_GT(checked, 20);
}

TEST_P(GradientTest, PoseMatchesFiniteDifferences) {
  const auto [sh, kind] = GetParam();
  const SE3 T = testPose();
  const Field field = makeField(sh, T);
  const VolumeRenderer renderer;
  const Vec3 cam_dir(0.05, -0.04, 1);
  const Samples s = fixedSamples(24, 0.85f, 1.2f);
  RayWorkspace ws;
  const Ray ray = makeRay(T, cam_dir);
  const RayOutput out = renderer.forward(field, ray, s.t.data(), s.delta.data(), 24, &ws);
  FieldGradient grad;
  grad.resize(field);
  RayPoseGrad pg;
  renderer.backward(field, ray, ws, out, gradOf(out, kind), &grad, &pg);
  const Vec6 an = poseGradient(T, ray, pg);
  Vec6 fd;
  for (int j = 0; j < 6; ++j) {
    const double eps = 2e-4;
    Vec6 xi = Vec6::Zero();
    xi[j] = eps;
    const double lp = lossOf(renderer.forward(field, makeRay(T * SE3::exp(xi), cam_dir), s.t.data(),
                                              s.delta.data(), 24, &ws),
                             kind);
    const double lm = lossOf(renderer.forward(field, makeRay(T * SE3::exp(-xi), cam_dir),
                                              s.t.data(), s.delta.data(), 24, &ws),
                             kind);
    fd[j] = (lp - lm) / (2 * eps);
  }
  ASSERT_GT(an.norm(), 1e-3);
  EXPECT_LT((an - fd).norm(), 0.03 * an.norm() + 1e-4)
      << "analytic " << an.transpose() << "\nnumeric  " << fd.transpose();
}

INSTANTIATE_TEST_SUITE_P(Losses, GradientTest,
                         ::testing::Combine(::testing::Values(0, 1),
                                            ::testing::Values(LossKind::kColor, LossKind::kDepth,
                                                              LossKind::kVariance,
                                                              LossKind::kAll)));

TEST(VolumeRenderer, ForwardMatchesSlowReference) {
  for (int sh : {0, 1}) {
    const SE3 T = testPose();
    const Field field = makeField(sh, T);
    const Eigen::Vector3f bg(0.3f, 0.1f, 0.9f);
    const VolumeRenderer renderer(bg);
    const Ray ray = makeRay(T, Vec3(-0.11, 0.07, 1));
    const Samples s = fixedSamples(40, 0.6f, 1.5f);  // also crosses the field's border
    RayWorkspace ws;
    const RayOutput out = renderer.forward(field, ray, s.t.data(), s.delta.data(), 40, &ws);
    double transmit = 1, W = 0, D = 0, M2 = 0, color[3] = {0, 0, 0};
    for (size_t i = 0; i < s.t.size(); ++i) {
      const Eigen::Vector3f p = ray.origin + s.t[i] * ray.dir;
      const Field::Value v = field.query(p, ray.view_dir);
      if (!v.occupied) continue;
      const double w = transmit * (1 - std::exp(-double(v.density) * s.delta[i]));
      transmit *= std::exp(-double(v.density) * s.delta[i]);
      W += w;
      D += w * s.t[i];
      M2 += w * s.t[i] * s.t[i];
      for (int k = 0; k < 3; ++k) color[k] += w * v.color[k];
    }
    EXPECT_NEAR(out.weight, W, 1e-5);
    EXPECT_NEAR(out.depth, D, 1e-5);
    EXPECT_NEAR(out.var, M2 - D * D * (2 - W), 1e-5);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(out.color[k], color[k] + (1 - W) * bg[k], 1e-5);
  }
}

TEST(VolumeRenderer, MarchFindsAnOpaqueSlabAndSkipsEmptySpace) {
  // An opaque, red slab z in [2.0, 2.1] m (world) over allocated blocks; camera at the origin
  // looking along +z.
  Field field(FieldGeometry::make(0.02, 2, 4, 0, -4.6f));
  for (double x = -1; x <= 1; x += 0.05)
    for (double y = -1; y <= 1; y += 0.05)
      for (double z = 1.9; z <= 2.2; z += 0.02) field.allocateAround(Eigen::Vector3f(x, y, z));
  const int fine = field.numLevels() - 1;
  for (int b = 0; b < field.numBlocks(0); ++b)
    for (int v = 0; v < Field::kBlockVoxels; ++v) field.blockData(0, b)[v * field.channels()] = -10;
  for (int b = 0; b < field.numBlocks(fine); ++b) {
    float* data = field.blockData(fine, b);
    const Eigen::Vector3i base = field.blockIndex(fine, b) * Field::kBlockDim;
    for (int v = 0; v < Field::kBlockVoxels; ++v) {
      const double z = (base.z() + v / 64) * field.voxelSize(fine);
      float* vox = data + v * field.channels();
      vox[0] = (z >= 2.0 - 1e-6 && z <= 2.1 + 1e-6) ? 20.f : -20.f;
      vox[1] = 5;
      vox[2] = -5;
      vox[3] = -5;
    }
  }
  CameraModel cam;
  cam.width = 40;
  cam.height = 30;
  cam.fx = cam.fy = 40;
  cam.cx = 19.5;
  cam.cy = 14.5;
  const VolumeRenderer renderer;
  MarchParams params;
  const RenderImages img = renderer.render(field, SE3(), cam, params, 2);
  const RenderImages img1 = renderer.render(field, SE3(), cam, params, 1);
  EXPECT_EQ(cv::norm(img.color, img1.color, cv::NORM_INF), 0) << "threads change the result";
  for (int v = 0; v < cam.height; ++v)
    for (int u = 0; u < cam.width; ++u) {
      EXPECT_NEAR(img.depth.at<float>(v, u), 2.0, 0.02) << u << "," << v;
      EXPECT_GT(img.weight.at<float>(v, u), 0.99f);
      EXPECT_LT(img.sigma.at<float>(v, u), 0.02f);
      EXPECT_GT(img.color.at<cv::Vec3f>(v, u)[0], 0.95f);
      EXPECT_LT(img.color.at<cv::Vec3f>(v, u)[1], 0.05f);
    }
  // A ray that never meets allocated space renders the background with depth 0.
  const Ray miss = makeRay(SE3(), Vec3(0, 0, -1));
  const RayOutput out = renderer.march(field, miss, params);
  EXPECT_EQ(out.weight, 0.f);
  EXPECT_EQ(out.depth, 0.f);
  EXPECT_EQ(out.samples, 0);
}

TEST(SampleRay, ConcentratesAroundTheDepthAndStaysSorted) {
  SamplingParams params;
  Rng rng;
  std::vector<float> t(maxSamples(params)), delta(maxSamples(params));
  const int n = sampleRay(params, 2.0f, 0.05f, 0.f, 10.f, &rng, t.data(), delta.data());
  ASSERT_EQ(n, params.surface_samples + params.spread_samples);
  int in_band = 0;
  for (int i = 0; i < n; ++i) {
    if (i > 0) {
      EXPECT_GT(t[i], t[i - 1]);
    }
    EXPECT_GT(delta[i], 0);
    if (std::abs(t[i] - 2.0f) <= 3 * 0.05f) ++in_band;
  }
  EXPECT_EQ(in_band, params.surface_samples);
  // Without depth: inside the given interval.
  const int m = sampleRay(params, 0.f, 0.f, 1.f, 3.f, &rng, t.data(), delta.data());
  ASSERT_EQ(m, params.free_samples);
  for (int i = 0; i < m; ++i) {
    EXPECT_GE(t[i], 1.f);
    EXPECT_LE(t[i], 3.f);
  }
  EXPECT_EQ(sampleRay(params, 0.f, 0.f, 5.f, 3.f, &rng, t.data(), delta.data()), 0);
}

TEST(Field, AllocationLookupAndBounds) {
  Field field(FieldGeometry::make(0.01, 2, 4, 0, -4.6f));
  EXPECT_TRUE(field.empty());
  EXPECT_GT(field.allocateAround(Eigen::Vector3f(-0.005f, 0.32f, 1.0f)), 0);
  // Coarse voxel 4 cm, block 32 cm: the point lies in block (-1, 1, 3) at level 0.
  EXPECT_GE(field.findBlock(0, -1, 1, 3), 0);
  EXPECT_EQ(field.findBlock(0, 5, 5, 5), -1);
  EXPECT_TRUE(field.query(Eigen::Vector3f(-0.005f, 0.32f, 1.0f)).occupied);
  EXPECT_FALSE(field.query(Eigen::Vector3f(3, 3, 3)).occupied);
  // Far away allocations regrow the dense index; earlier blocks stay found.
  field.allocateAround(Eigen::Vector3f(40, -30, 20));
  EXPECT_GE(field.findBlock(0, -1, 1, 3), 0);
  EXPECT_TRUE(field.query(Eigen::Vector3f(40, -30, 20)).occupied);
  EXPECT_LE(field.boundsMin().x(), -0.005f);
  EXPECT_GE(field.boundsMax().x(), 40.f);
  EXPECT_THROW(field.allocateBlock(0, Eigen::Vector3i(1 << 21, 0, 0)), std::out_of_range);
  EXPECT_THROW(Field(FieldGeometry{{0.01, 0.03}, 0, 0.f}), std::invalid_argument);
  EXPECT_THROW(Field(FieldGeometry{{0.04, 0.01}, 2, 0.f}), std::invalid_argument);
}

}  // namespace
}  // namespace radslam

namespace radslam {
namespace {

TEST(FastMath, ExpSoftplusSigmoidMatchLibm) {
  double worst_exp = 0, worst_sp = 0, worst_sig = 0;
  for (float x = -80.f; x <= 80.f; x += 0.0137f) {
    worst_exp = std::max(worst_exp, std::abs(fastExp(x) / std::exp(double(x)) - 1));
    const double sp = std::log1p(std::exp(double(x)));
    worst_sp = std::max(worst_sp, std::abs(softplus(x) - sp) / std::max(sp, 1e-30));
    float s, g;
    softplusAndSigmoid(x, &s, &g);
    EXPECT_EQ(s, softplus(x));
    worst_sig = std::max(worst_sig, std::abs(g - 1 / (1 + std::exp(-double(x)))));
  }
  EXPECT_LT(worst_exp, 1e-6);
  EXPECT_LT(worst_sp, 2e-6);
  EXPECT_LT(worst_sig, 1e-6);
  EXPECT_EQ(fastExp(-1000.f), fastExp(-87.f));  // clamped, no denormal garbage
  EXPECT_GT(fastExp(-87.f), 0.f);
}

TEST(FastMath, ExpRoundsTheExponentAsNearbyint) {
  // fastExp's power of two: the float-adder rounding equals std::nearbyint (ties to even) over
  // the whole clamped range, including the ties x log2 e = k + 1/2.
  int checked = 0;
  for (float y = -126.f; y <= 127.f; y += 0.125f) {
    const float r = (y + 12582912.f) - 12582912.f;
    ASSERT_EQ(r, std::nearbyint(y)) << y;
    ++checked;
  }
  EXPECT_GT(checked, 2000);
  // And exp itself against a copy that rounds with std::nearbyint.
  for (float x = -90.f; x <= 90.f; x += 0.00731f) {
    const float xc = std::clamp(x, -87.f, 88.f);
    const float r = std::nearbyint(xc * 1.44269504089f);
    const float f = (xc - r * 0.693145751953125f) - r * 1.428606765330187e-06f;
    float q = 1.f / 720;
    for (const float c : {1.f / 120, 1.f / 24, 1.f / 6, 0.5f, 1.f, 1.f}) q = q * f + c;
    ASSERT_EQ(fastExp(x), std::ldexp(q, static_cast<int>(r))) << x;
  }
}

// ---- The render-only march against the plain per-sample march it replaces ----

// One sample at a time, every lookup from scratch: the definition the batched, cached march
// must reproduce bit for bit.
RayOutput referenceMarch(const Field& field, const Ray& ray, const MarchParams& params,
                         const Eigen::Vector3f& bg) {
  using namespace ray_kernels;
  RayOutput out;
  const int C = field.channels(), NB = field.colorBasis();
  float t0, t1;
  if (!intersectBox(ray, field.boundsMin(), field.boundsMax(), &t0, &t1)) t1 = -1;
  t0 = std::max(t0, params.near);
  t1 = std::min(t1, params.far);
  const int fine = field.numLevels() - 1;
  const float basis[4] = {1.f, ray.view_dir.x(), ray.view_dir.y(), ray.view_dir.z()};
  const float step = params.step_fine * static_cast<float>(field.voxelSize(fine));
  const float coarse_edge = static_cast<float>(field.voxelSize(0)) * Field::kBlockDim;
  const float fine_edge = static_cast<float>(field.voxelSize(fine)) * Field::kBlockDim;
  const float nudge = 1e-3f * step;
  float transmit = 1.f, color[3] = {0, 0, 0};
  double s0 = 0, s1 = 0, s2 = 0;
  for (float t = t0; t < t1 && transmit > params.min_transmittance;) {
    const float p[3] = {ray.origin.x() + t * ray.dir.x(), ray.origin.y() + t * ray.dir.y(),
                        ray.origin.z() + t * ray.dir.z()};
    const int cb[3] = {static_cast<int>(std::floor(p[0] / coarse_edge)),
                       static_cast<int>(std::floor(p[1] / coarse_edge)),
                       static_cast<int>(std::floor(p[2] / coarse_edge))};
    if (field.findBlock(0, cb[0], cb[1], cb[2]) < 0) {
      t = std::max(t + nudge, cubeExit(ray, cb, coarse_edge) + nudge);
      continue;
    }
    Corners corners[Field::kMaxLevels];
    locate(field, fine, p, &corners[fine]);
    if (!(corners[fine].mask & 1u)) {
      // The fine block of the cell's corner 0, found as locate() found it.
      const float inv = field.invVoxelSize(fine);
      int fb[3];
      for (int k = 0; k < 3; ++k) fb[k] = blockOf(static_cast<int>(std::floor(p[k] * inv)));
      t = std::max(t + nudge, cubeExit(ray, fb, fine_edge) + nudge);
      continue;
    }
    float raw[13] = {};
    for (int i = 0; i < fine + 1; ++i) {
      const int l = i == 0 ? fine : i - 1;  // fine first, then coarse to fine
      if (l != fine) locate(field, l, p, &corners[l]);
      if (C == 4) gather<4>(field.levelData(l), corners[l], raw);
      if (C == 13) gather<13>(field.levelData(l), corners[l], raw);
    }
    const float sigma = softplus(field.densityBias() + raw[0]) * field.densityScale();
    float c[3];
    if (NB == 1) shade<1>(raw, basis, c);
    if (NB == 4) shade<4>(raw, basis, c);
    const float decay = fastExp(-sigma * step);
    const float w = transmit * (1.f - decay);
    transmit *= decay;
    s0 += w;
    s1 += double(w) * t;
    s2 += double(w) * t * t;
    for (int k = 0; k < 3; ++k) color[k] += w * c[k];
    ++out.samples;
    t += step;
  }
  const float W = static_cast<float>(s0);
  for (int k = 0; k < 3; ++k) out.color[k] = color[k] + (1.f - W) * bg[k];
  out.weight = W;
  if (params.normalize_depth) {
    if (W >= params.min_weight && W > 0) {
      out.depth = static_cast<float>(s1 / s0);
      out.var = static_cast<float>(std::max(0.0, s2 / s0 - (s1 / s0) * (s1 / s0)));
    }
  } else {
    out.depth = static_cast<float>(s1);
    out.var = static_cast<float>(std::max(0.0, s2 - s1 * s1 * (2.0 - s0)));
  }
  return out;
}

// A shell of allocated blocks with holes (the fine level is sparser than the coarse ones)
// and pseudo-random parameters: thin and opaque regions, so that rays skip blocks, cross
// block borders, saturate and stop.
Field makeShellField(int levels, int sh_degree) {
  Field field(FieldGeometry::make(0.03, levels, 2, sh_degree, -4.6f));
  Rng rng;
  for (double x = -0.6; x <= 0.6; x += 0.03)
    for (double y = -0.5; y <= 0.5; y += 0.03)
      for (double z = 0.8; z <= 1.6; z += 0.03) {
        const double r = std::hypot(x, y, z - 1.4);
        if (r > 0.35 && r < 0.55 && rng.uniform() < 0.7f)
          field.allocateAround(Eigen::Vector3f(x, y, z));
      }
  for (int l = 0; l < field.numLevels(); ++l)
    for (size_t i = 0; i < field.levelSize(l); ++i)
      field.levelData(l)[i] = (rng.uniform() - 0.5f) * (i % field.channels() == 0 ? 9.f : 4.f);
  return field;
}

// makeShellField with every other fine block and some coarse blocks zeroed (never trained):
// the march composites sub-blocks that read zeros at every level without sampling them.
Field makeShellFieldWithZeros(int levels, int sh_degree) {
  Field field = makeShellField(levels, sh_degree);
  Rng rng;
  for (int l = 0; l < field.numLevels(); ++l)
    for (int b = 0; b < field.numBlocks(l); ++b)
      if (rng.uniform() < (l + 1 == field.numLevels() ? 0.5f : 0.7f))
        std::fill_n(field.blockData(l, b), Field::kBlockVoxels * field.channels(), 0.f);
  return field;
}

void expectSameOutput(const RayOutput& a, const RayOutput& b, const std::string& what) {
  for (int k = 0; k < 3; ++k) EXPECT_EQ(a.color[k], b.color[k]) << what;
  EXPECT_EQ(a.depth, b.depth) << what;
  EXPECT_EQ(a.var, b.var) << what;
  EXPECT_EQ(a.weight, b.weight) << what;
  EXPECT_EQ(a.samples, b.samples) << what;
}

TEST(VolumeRenderer, MarchEqualsThePerSampleReferenceBitwise) {
  CameraModel cam;
  cam.width = 40;
  cam.height = 30;
  cam.fx = cam.fy = 30;
  cam.cx = 19.5;
  cam.cy = 14.5;
  const Eigen::Vector3f bg(0.2f, 0.4f, 0.6f);
  const VolumeRenderer renderer(bg);
  MarchParams preview;
  preview.step_fine = 1;
  preview.min_transmittance = 0.01f;
  MarchParams unnormalized;
  unnormalized.normalize_depth = false;
  const SE3 poses[] = {SE3(), SE3(SO3::exp(Vec3(0.1, -0.2, 0.05)), Vec3(0.1, 0.05, 1.3)),
                       SE3(SO3::exp(Vec3(0, 1.4, 0)), Vec3(-1.2, 0.1, 1.2))};
  int hits = 0, stops = 0;
  for (const auto& [levels, sh, zeros] :
       {std::tuple{2, 0, false}, {3, 1, false}, {1, 0, false}, {2, 0, true}, {2, 1, true}}) {
    const Field field = zeros ? makeShellFieldWithZeros(levels, sh) : makeShellField(levels, sh);
    for (const MarchParams& params : {MarchParams(), preview, unnormalized}) {
      for (const SE3& T : poses) {
        const RenderImages img = renderer.render(field, T, cam, params, 1);
        const RenderImages img2 = renderer.render(field, T, cam, params, 3);
        for (int v = 0; v < cam.height; ++v)
          for (int u = 0; u < cam.width; ++u) {
            const Ray ray = makeRay(T, Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1));
            const RayOutput ref = referenceMarch(field, ray, params, bg);
            const std::string what = "levels " + std::to_string(levels) + " pixel " +
                                     std::to_string(u) + "," + std::to_string(v);
            expectSameOutput(renderer.march(field, ray, params), ref, what);
            const cv::Vec3f c = img.color.at<cv::Vec3f>(v, u);
            for (int k = 0; k < 3; ++k) ASSERT_EQ(c[k], ref.color[k]) << what;
            ASSERT_EQ(img.depth.at<float>(v, u), ref.depth) << what;
            ASSERT_EQ(img.weight.at<float>(v, u), ref.weight) << what;
            ASSERT_EQ(img.sigma.at<float>(v, u), std::sqrt(std::max(0.f, ref.var))) << what;
            ASSERT_EQ(cv::norm(img.color, img2.color, cv::NORM_INF), 0) << "threads differ";
            hits += ref.samples > 0;
            stops += ref.weight > 1 - params.min_transmittance - 1e-6f;
          }
      }
    }
  }
  // The scenes exercise both rays through the shell and rays stopped in it.
  EXPECT_GT(hits, 1000);
  EXPECT_GT(stops, 300);
}

// A rolling-shutter view turns each pixel's camera ray by the camera's rotation until the
// pixel's exposure; without exposure times the rays are the pinhole's.
TEST(RenderPinhole, RollingShutterTurnsEachPixelsRay) {
  CameraModel cam;
  cam.width = 12;
  cam.height = 9;
  cam.fx = cam.fy = 10;
  cam.cx = 5.5;
  cam.cy = 4;
  const SE3 T_world_cam(SO3::exp(Vec3(0.1, -0.2, 0.3)), Vec3(1, 2, 3));
  RollingShutterView view;
  view.omega_cam = Vec3(0.5, -2.0, 0.8);
  view.exposure_s = cv::Mat(cam.height, cam.width, CV_32FC1);
  for (int v = 0; v < cam.height; ++v) view.exposure_s.row(v).setTo(0.004 * (v - 4));  // s
  for (const bool rolling : {false, true}) {
    const RenderImages image = renderPinhole(
        T_world_cam, cam, 2,
        [&](const Ray& ray, int u, int v) {
          Eigen::Vector3d expected((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1);
          if (rolling) expected = SO3::exp(view.omega_cam * (0.004 * (v - 4))) * expected;
          const Ray reference = makeRay(T_world_cam, expected);
          RayOutput out;
          out.depth = (ray.dir - reference.dir).norm() + (ray.origin - reference.origin).norm();
          return out;
        },
        rolling ? view : RollingShutterView());
    double worst = 0;
    cv::minMaxLoc(image.depth, nullptr, &worst);
    EXPECT_LT(worst, 1e-6) << (rolling ? "rolling" : "global");
  }
  view.exposure_s = cv::Mat(3, 3, CV_32FC1, cv::Scalar(0));
  EXPECT_THROW(renderPinhole(
                   T_world_cam, cam, 1, [](const Ray&, int, int) { return RayOutput(); }, view),
               std::invalid_argument);
}

}  // namespace
}  // namespace radslam
