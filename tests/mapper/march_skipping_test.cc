// The field's density bounds and zero flags (what the march skips by), and the approximations
// they allow (MarchParams::skip_thickness, max_sample_thickness) against the exact march.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include <gtest/gtest.h>

#include "mapper/field.h"
#include "mapper/ray_kernels.h"
#include "mapper/volume_renderer.h"
#include "tests/mapper/random_field.h"

namespace radslam {
namespace {

using ray_kernels::Corners;

// The level's interpolation at p (channels, bias not added), as the renderer computes it.
void interpolate(const Field& field, int level, const Eigen::Vector3f& p, float* raw) {
  Corners c;
  ray_kernels::locate(field, level, p.data(), &c);
  std::fill(raw, raw + 13, 0.f);
  if (field.channels() == 4) ray_kernels::gather<4>(field.levelData(level), c, raw);
  if (field.channels() == 13) ray_kernels::gather<13>(field.levelData(level), c, raw);
}

// The table entry of the level's sub-block holding p, or -1 when its block is unallocated.
long entryAt(const Field& field, int level, const Eigen::Vector3f& p) {
  const float inv = field.invVoxelSize(level);
  int s[3];
  for (int k = 0; k < 3; ++k) s[k] = static_cast<int>(std::floor(p[k] * inv)) >> Field::kSubShift;
  const int b = field.findBlock(level, s[0] >> 1, s[1] >> 1, s[2] >> 1);
  if (b < 0) return -1;
  return long(b) * Field::kSubBlocks + ((s[0] & 1) | ((s[1] & 1) << 1) | ((s[2] & 1) << 2));
}

TEST(DensityBounds, BoundTheInterpolationAndFlagZeros) {
  for (const int sh : {0, 1}) {
    const Field field = makeRandomField(2, 2, sh);
    Rng rng;
    int checked = 0, zeros = 0;
    for (int i = 0; i < 20000; ++i) {
      const Eigen::Vector3f p((rng.uniform() - 0.5f) * 0.8f, (rng.uniform() - 0.5f) * 0.8f,
                              0.8f + rng.uniform() * 0.8f);
      for (int l = 0; l < field.numLevels(); ++l) {
        const long e = entryAt(field, l, p);
        if (e < 0) continue;
        float raw[13];
        interpolate(field, l, p, raw);
        ASSERT_LE(raw[0], field.densityBounds(l)[e] + 1e-5f) << "level " << l;
        if (field.zeroSubBlocks(l)[e]) {
          ++zeros;
          for (int ch = 0; ch < field.channels(); ++ch) ASSERT_EQ(raw[ch], 0.f) << "level " << l;
        }
        ++checked;
      }
    }
    EXPECT_GT(checked, 10000);
    EXPECT_GT(zeros, 100);
  }
}

TEST(DensityBounds, FollowChangesToTheBlockAndItsLowerNeighbours) {
  Field field(FieldGeometry::make(0.01, 1, 2, 0, -4.6f));
  const int a = field.allocateBlock(0, Eigen::Vector3i(0, 0, 0));
  const int b = field.allocateBlock(0, Eigen::Vector3i(1, 0, 0));
  for (int s = 0; s < Field::kSubBlocks; ++s) {
    EXPECT_EQ(field.densityBounds(0)[a * Field::kSubBlocks + s], 0.f);
    EXPECT_EQ(field.zeroSubBlocks(0)[a * Field::kSubBlocks + s], 1);
  }
  // Voxel (0, 0, 0) of block b is read by the cells of a's sub-block 1 (x half 4..8) too.
  field.blockData(0, b)[0] = 3.f;
  EXPECT_EQ(field.densityBounds(0)[b * Field::kSubBlocks + 0], 3.f);
  EXPECT_EQ(field.densityBounds(0)[a * Field::kSubBlocks + 1], 3.f);
  EXPECT_EQ(field.densityBounds(0)[a * Field::kSubBlocks + 0], 0.f);
  EXPECT_EQ(field.zeroSubBlocks(0)[a * Field::kSubBlocks + 1], 0);
  EXPECT_EQ(field.zeroSubBlocks(0)[a * Field::kSubBlocks + 0], 1);
  // A colour channel alone clears the zero flag; writes through levelData() count once marked.
  field.levelData(0)[(size_t(a) * Field::kBlockVoxels) * field.channels() + 2] = -1.f;
  field.markChanged(0, a);
  EXPECT_EQ(field.zeroSubBlocks(0)[a * Field::kSubBlocks + 0], 0);
  EXPECT_EQ(field.densityBounds(0)[a * Field::kSubBlocks + 0], 0.f);
  // A copy carries the bounds and refreshes on its own.
  Field copy = field;
  copy.blockData(0, b)[0] = 5.f;
  EXPECT_EQ(copy.densityBounds(0)[a * Field::kSubBlocks + 1], 5.f);
  EXPECT_EQ(field.densityBounds(0)[a * Field::kSubBlocks + 1], 3.f);
}

// Fog (low density, as untrained-but-allocated space after a little training) in front of an
// opaque wall at z = 1.4 m with a coloured pattern: what skipping and the adaptive step change.
Field makeFogAndWall() {
  Field field(FieldGeometry::make(0.01, 2, 4, 0, -4.6f));
  for (double x = -0.5; x <= 0.5; x += 0.02)
    for (double y = -0.4; y <= 0.4; y += 0.02)
      for (double z = 0.6; z <= 1.5; z += 0.02) field.allocateAround(Eigen::Vector3f(x, y, z));
  for (int l = 0; l < field.numLevels(); ++l) {
    const double s = field.voxelSize(l);
    for (int b = 0; b < field.numBlocks(l); ++b) {
      float* data = field.blockData(l, b);
      const Eigen::Vector3i base = field.blockIndex(l, b) * Field::kBlockDim;
      for (int v = 0; v < Field::kBlockVoxels; ++v) {
        const Eigen::Vector3d p =
            (base + Eigen::Vector3i(v % 8, (v / 8) % 8, v / 64)).cast<double>() * s;
        float* vox = data + v * field.channels();
        if (l == 0) {
          // Slowly varying fog, from clear (-6) to about 0.05 per fine voxel (-2).
          vox[0] = static_cast<float>(-4 + 2 * std::sin(3 * p.x() + 2 * p.y() + 4 * p.z()));
          for (int k = 0; k < 3; ++k) vox[1 + k] = static_cast<float>(std::cos(2 * p.x() + k));
        } else {
          vox[0] = p.z() > 1.4 ? 12.f : 0.f;
          for (int k = 0; k < 3; ++k)
            vox[1 + k] =
                p.z() > 1.4 ? static_cast<float>(2 * std::sin(20 * p.x() + 7 * p.y() + k)) : 0.f;
        }
      }
    }
  }
  return field;
}

struct Difference {
  double psnr = 0;       // dB, colour
  double max_depth = 0;  // m, where both have a depth
  int depth_validity = 0;
  long samples_exact = 0, samples_fast = 0;
};

Difference compare(const Field& field, const MarchParams& fast) {
  CameraModel cam;
  cam.width = 64;
  cam.height = 48;
  cam.fx = cam.fy = 60;
  cam.cx = 31.5;
  cam.cy = 23.5;
  const VolumeRenderer renderer(Eigen::Vector3f(0.3f, 0.3f, 0.3f));
  MarchParams exact = fast;
  exact.skip_thickness = 0;
  exact.max_sample_thickness = 0;
  Difference d;
  double sq = 0;
  long values = 0;
  for (const SE3& T : {SE3(), SE3(SO3::exp(Vec3(0.05, -0.1, 0.02)), Vec3(0.05, 0.02, 0.1))}) {
    for (int v = 0; v < cam.height; ++v)
      for (int u = 0; u < cam.width; ++u) {
        const Ray ray = makeRay(T, Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1));
        const RayOutput a = renderer.march(field, ray, exact);
        const RayOutput b = renderer.march(field, ray, fast);
        for (int k = 0; k < 3; ++k)
          sq += double(a.color[k] - b.color[k]) * (a.color[k] - b.color[k]);
        values += 3;
        if ((a.depth > 0) != (b.depth > 0)) ++d.depth_validity;
        if (a.depth > 0 && b.depth > 0)
          d.max_depth = std::max(d.max_depth, double(std::abs(a.depth - b.depth)));
        d.samples_exact += a.samples;
        d.samples_fast += b.samples;
      }
  }
  d.psnr = sq > 0 ? 10 * std::log10(values / sq) : INFINITY;
  std::printf(
      "skip %g, adaptive %g/%g: PSNR %.1f dB, max depth difference %.4f m, samples %ld "
      "of %ld\n",
      fast.skip_thickness, fast.max_sample_thickness, fast.max_step_fine, d.psnr, d.max_depth,
      d.samples_fast, d.samples_exact);
  return d;
}

TEST(MarchApproximations, SkipThresholdStaysWithinItsTolerance) {
  const Field field = makeFogAndWall();
  MarchParams fast;
  fast.skip_thickness = 1e-3f;
  const Difference d = compare(field, fast);
  // Skipped sub-blocks absorb < 1e-3 per fine voxel: below what 8-bit colour shows.
  EXPECT_GT(d.psnr, 50) << "PSNR " << d.psnr;
  EXPECT_LT(d.max_depth, 0.01) << "max depth difference " << d.max_depth;
  EXPECT_EQ(d.depth_validity, 0);
  EXPECT_LT(d.samples_fast, d.samples_exact * 0.95) << "nothing skipped";
}

TEST(MarchApproximations, AdaptiveStepStaysWithinItsTolerance) {
  const Field field = makeFogAndWall();
  MarchParams fast;
  fast.max_sample_thickness = 0.05f;
  fast.max_step_fine = 4;
  const Difference d = compare(field, fast);
  EXPECT_GT(d.psnr, 40) << "PSNR " << d.psnr;
  EXPECT_LT(d.max_depth, 0.03) << "max depth difference " << d.max_depth;
  EXPECT_LT(d.samples_fast, d.samples_exact * 0.8) << "steps did not grow";
  // Off, the march is the exact one.
  fast.max_sample_thickness = 0;
  EXPECT_EQ(compare(field, fast).psnr, INFINITY);
}

}  // namespace
}  // namespace radslam
