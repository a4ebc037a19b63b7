// The baked single-level copy of a field (PreviewField): the same field as the levels summed
// (up to bfloat16 rounding), kept current by refresh() as blocks change, within a budget, and
// rebuilt when the field is replaced.
#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "mapper/field.h"
#include "mapper/preview_field.h"
#include "mapper/volume_renderer.h"
#include "tests/mapper/random_field.h"

namespace radslam {
namespace {

CameraModel testCamera() {
  CameraModel cam;
  cam.width = 64;
  cam.height = 48;
  cam.fx = cam.fy = 60;
  cam.cx = 31.5;
  cam.cy = 23.5;
  return cam;
}

const SE3 kViews[] = {SE3(), SE3(SO3::exp(Vec3(0.05, -0.1, 0.02)), Vec3(0.05, 0.02, 0.1))};

// The exact fixed-step march, which samples where the baked march does.
MarchParams exactMarch() {
  MarchParams mp;
  mp.step_fine = 0.5f;
  mp.min_transmittance = 1e-4f;
  return mp;
}

double colorPsnr(const cv::Mat& a, const cv::Mat& b) {
  const double mse = cv::norm(a, b, cv::NORM_L2SQR) / (a.total() * a.channels());
  return mse > 0 ? 10 * std::log10(1 / mse) : INFINITY;
}

bool sameRender(const RenderImages& a, const RenderImages& b) {
  return cv::norm(a.color, b.color, cv::NORM_INF) == 0 &&
         cv::norm(a.depth, b.depth, cv::NORM_INF) == 0 &&
         cv::norm(a.sigma, b.sigma, cv::NORM_INF) == 0;
}

RenderImages renderBaked(const PreviewField& preview, const Field& field, const SE3& T) {
  return preview.render(field, T, testCamera(), exactMarch(), Eigen::Vector3f(0.3f, 0.3f, 0.3f));
}

TEST(PreviewField, RendersTheSumOfLevelsUpToBfloat16) {
  // Coarse levels of ratio 2 and 4 (sub-blocks spanning several coarse cells, or part of one),
  // RGB and SH colour, and a single level.
  struct Case {
    int levels, ratio, sh;
  };
  for (const Case c : {Case{2, 2, 0}, Case{2, 4, 0}, Case{3, 2, 1}, Case{1, 2, 0}}) {
    SCOPED_TRACE("levels " + std::to_string(c.levels) + " ratio " + std::to_string(c.ratio) +
                 " sh " + std::to_string(c.sh));
    const Field field = makeRandomField(c.levels, c.ratio, c.sh);
    PreviewField preview(0.f);  // nothing skipped: the same samples as the exact march
    EXPECT_EQ(preview.refresh(field), 0);
    const VolumeRenderer renderer(Eigen::Vector3f(0.3f, 0.3f, 0.3f));
    for (const SE3& T : kViews) {
      const RenderImages exact = renderer.render(field, T, testCamera(), exactMarch());
      const RenderImages baked = renderBaked(preview, field, T);
      EXPECT_GT(colorPsnr(exact.color, baked.color), 40.0);
      int both = 0, close = 0;
      for (int v = 0; v < exact.depth.rows; ++v)
        for (int u = 0; u < exact.depth.cols; ++u) {
          const float a = exact.depth.at<float>(v, u), b = baked.depth.at<float>(v, u);
          if (a > 0 && b > 0) {
            ++both;
            close += std::abs(a - b) < 0.01f;
          }
        }
      EXPECT_GT(both, static_cast<int>(exact.depth.total() / 20));
      EXPECT_GT(close, 0.95 * both);
    }
  }
}

TEST(PreviewField, RefreshRebakesWhatChangedBlocksReach) {
  Field field = makeRandomField(2, 4, 0);
  PreviewField preview(0.05f);
  preview.refresh(field);
  const RenderImages before = renderBaked(preview, field, kViews[0]);
  // A coarse block (it reaches up to 6^3 fine blocks), a fine block, and a new block.
  for (const int level : {0, 1}) {
    float* data = field.blockData(level, field.numBlocks(level) / 2);
    for (int i = 0; i < Field::kBlockVoxels * field.channels(); ++i) data[i] += 2.f;
  }
  field.allocateAround(Eigen::Vector3f(0.9f, 0.f, 1.2f));
  // Unchanged until refreshed; then as a copy baked from scratch.
  EXPECT_TRUE(sameRender(before, renderBaked(preview, field, kViews[0])));
  EXPECT_EQ(preview.refresh(field), 0);
  PreviewField fresh(0.05f);
  fresh.refresh(field);
  for (const SE3& T : kViews)
    EXPECT_TRUE(sameRender(renderBaked(fresh, field, T), renderBaked(preview, field, T)));
  EXPECT_FALSE(sameRender(before, renderBaked(preview, field, kViews[0])));
  EXPECT_EQ(fresh.bytes(), preview.bytes());
}

TEST(PreviewField, BudgetedRefreshesConvergeOldestFirst) {
  Field field = makeRandomField(2, 4, 0);
  PreviewField preview(0.05f);
  // A budget too small for more than a batch: stale blocks stay, and later calls finish them.
  int stale = preview.refresh(field, 1e-9);
  EXPECT_GT(stale, 0);
  int calls = 1;
  while (stale > 0 && calls < 100000) {
    const int left = preview.refresh(field, 1e-9);
    EXPECT_LT(left, stale);
    stale = left;
    ++calls;
  }
  EXPECT_EQ(stale, 0);
  EXPECT_GT(calls, 2);
  PreviewField fresh(0.05f);
  fresh.refresh(field);
  EXPECT_TRUE(
      sameRender(renderBaked(fresh, field, kViews[1]), renderBaked(preview, field, kViews[1])));
}

TEST(PreviewField, AReplacedFieldIsBakedAnew) {
  Field field = makeRandomField(2, 4, 0, 1);
  PreviewField preview(0.05f);
  preview.refresh(field);
  // As a snapshot replaces a replica: other blocks under the same ids, fewer or more of them.
  for (const uint64_t seed : {7u, 11u}) {
    field = makeRandomField(2, 4, 0, seed);
    preview.refresh(field);
    PreviewField fresh(0.05f);
    fresh.refresh(field);
    EXPECT_TRUE(
        sameRender(renderBaked(fresh, field, kViews[0]), renderBaked(preview, field, kViews[0])));
  }
  // Another geometry.
  field = makeRandomField(2, 2, 1, 3);
  preview.refresh(field);
  PreviewField fresh(0.05f);
  fresh.refresh(field);
  EXPECT_TRUE(
      sameRender(renderBaked(fresh, field, kViews[0]), renderBaked(preview, field, kViews[0])));
}

TEST(PreviewField, JumpsThroughFreeSpaceWithoutMissingABlock) {
  // Single fine blocks scattered through a 4 m box, several blocks apart: rays cross free space
  // in the grid's long jumps, from several views, and must hit what the exact march hits.
  Field field(FieldGeometry::make(0.03, 1, 2, 0, -4.6f));
  Rng rng;
  for (int i = 0; i < 60; ++i) {
    const int b = field.allocateBlock(0, Eigen::Vector3i(static_cast<int>(rng.uniform() * 16) - 8,
                                                         static_cast<int>(rng.uniform() * 16) - 8,
                                                         static_cast<int>(rng.uniform() * 16) + 2));
    float* data = field.blockData(0, b);
    for (int v = 0; v < Field::kBlockVoxels; ++v) {
      data[v * field.channels()] = 6.f + rng.uniform();
      for (int ch = 1; ch < field.channels(); ++ch) data[v * field.channels() + ch] = rng.uniform();
    }
  }
  PreviewField preview(0.05f);
  preview.refresh(field);
  CameraModel wide = testCamera();
  wide.fx = wide.fy = 25;
  const VolumeRenderer renderer(Eigen::Vector3f(0.3f, 0.3f, 0.3f));
  int hits = 0, mismatched = 0;
  for (int k = 0; k < 6; ++k) {
    const SE3 T(SO3::exp(Vec3(0.3 * k, -0.2 * k, 0.1)), Vec3(0.2 * k - 0.5, 0.1 * k, -0.5));
    const RenderImages exact = renderer.render(field, T, wide, exactMarch());
    const RenderImages baked =
        preview.render(field, T, wide, exactMarch(), Eigen::Vector3f(0.3f, 0.3f, 0.3f));
    for (int v = 0; v < exact.depth.rows; ++v)
      for (int u = 0; u < exact.depth.cols; ++u) {
        const bool a = exact.depth.at<float>(v, u) > 0, b = baked.depth.at<float>(v, u) > 0;
        hits += a;
        mismatched += a != b;
      }
  }
  EXPECT_GT(hits, 6 * 64 * 48 / 20);
  EXPECT_LE(mismatched, hits / 200);  // rays grazing an edge
}

TEST(PreviewField, AMarchStartsWhereAskedAndReportsItsFirstSample) {
  const Field field = makeRandomField(2, 2, 0);
  PreviewField preview(0.05f);
  preview.refresh(field);
  const MarchParams live = exactMarch();
  const Eigen::Vector3f bg(0.3f, 0.3f, 0.3f);
  const float block = static_cast<float>(field.voxelSize(1)) * Field::kBlockDim;
  const CameraModel cam = testCamera();
  int hit = 0, missed = 0;
  for (int v = 0; v < cam.height; v += 3)
    for (int u = 0; u < cam.width; u += 3) {
      const Ray ray =
          makeRay(kViews[1], Eigen::Vector3d((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1));
      float first = 0;
      const RayOutput whole = preview.march(field, ray, live, bg, -INFINITY, &first);
      if (first == INFINITY) {
        EXPECT_EQ(whole.samples, 0);
        ++missed;
        continue;
      }
      ++hit;
      // From a block before the first sample: the same samples; from past it: fewer.
      const RayOutput near = preview.march(field, ray, live, bg, first - block);
      EXPECT_NEAR(near.color[0], whole.color[0], 1e-3f);
      EXPECT_NEAR(near.depth, whole.depth, 1e-3f);
      EXPECT_NEAR(near.samples, whole.samples, 1);
      float later = 0;
      const RayOutput past = preview.march(field, ray, live, bg, first + 0.1f, &later);
      EXPECT_LT(past.samples, whole.samples);
      EXPECT_GE(later, first + 0.1f);
    }
  EXPECT_GT(hit, 20);
  EXPECT_GT(missed, 0);
}

TEST(PreviewField, TwoPassRenderMatchesTheRayByRayMarch) {
  // render() starts the rays between every second pixel near their neighbours' first sample:
  // on the random field and on scattered single blocks (edges everywhere), it must give what
  // marching every ray whole gives, but for the odd ray at a structure's edge.
  MarchParams live = exactMarch();
  live.max_sample_thickness = 0.05f;
  const Eigen::Vector3f bg(0.3f, 0.3f, 0.3f);
  Field scattered(FieldGeometry::make(0.03, 1, 2, 0, -4.6f));
  Rng rng;
  for (int i = 0; i < 60; ++i) {
    const int b =
        scattered.allocateBlock(0, Eigen::Vector3i(static_cast<int>(rng.uniform() * 8) - 4,
                                                   static_cast<int>(rng.uniform() * 8) - 4,
                                                   static_cast<int>(rng.uniform() * 16) + 2));
    float* data = scattered.blockData(0, b);
    for (int k = 0; k < Field::kBlockVoxels * scattered.channels(); ++k)
      data[k] = k % scattered.channels() == 0 ? 6.f : rng.uniform();
  }
  Field random_field = makeRandomField(2, 2, 0);
  for (const Field* field : {&random_field, &scattered}) {
    PreviewField preview(0.05f);
    preview.refresh(*field);
    const CameraModel cam = testCamera();
    for (const SE3& T : kViews) {
      const RenderImages two_pass = preview.render(*field, T, cam, live, bg);
      const RenderImages whole = renderPinhole(T, cam, 1, [&](const Ray& ray, int, int) {
        return preview.march(*field, ray, live, bg);
      });
      int hits = 0, mismatched = 0;
      for (int v = 0; v < cam.height; ++v)
        for (int u = 0; u < cam.width; ++u) {
          const float a = whole.depth.at<float>(v, u), b = two_pass.depth.at<float>(v, u);
          hits += a > 0;
          mismatched += (a > 0) != (b > 0);
          if (a > 0 && b > 0) {
            EXPECT_NEAR(a, b, 0.01f);
          }
        }
      EXPECT_GT(hits, static_cast<int>(cam.width * cam.height / 20));
      EXPECT_LE(mismatched, hits / 100);
      EXPECT_GT(colorPsnr(whole.color, two_pass.color), 40.0);
    }
  }
}

TEST(PreviewField, ThinSubBlocksAreNotStored) {
  const Field field = makeRandomField(2, 4, 0);
  PreviewField all(0.f), thick(1.f);
  all.refresh(field);
  thick.refresh(field);
  const size_t per_sub = PreviewField::kPointsPerSub * field.channels() * sizeof(uint16_t);
  EXPECT_EQ(all.bytes(), size_t(field.numBlocks(1)) * Field::kSubBlocks * per_sub);
  EXPECT_LT(thick.bytes(), all.bytes());
  EXPECT_GT(thick.bytes(), 0u);
}

}  // namespace
}  // namespace radslam
