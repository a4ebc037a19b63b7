// Training: the field fits a synthetic room (PSNR on the training views), dynamic pixels are
// never trained on, new keyframes are favoured, threads and depth-loss modes work, and the
// optimiser's step on several threads' gradients equals its step on their sum.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "common/synthetic.h"
#include "mapper/mapper.h"
#include "mapper/sparse_adam.h"

namespace radslam {
namespace {

// PSNR of an RGB float render against a BGR 8-bit image, dB.
double psnr(const cv::Mat& bgr8, const cv::Mat& rgb) {
  cv::Mat ref;
  bgr8.convertTo(ref, CV_32FC3, 1 / 255.0);
  cv::cvtColor(ref, ref, cv::COLOR_BGR2RGB);
  cv::Mat d = ref - rgb;
  const cv::Scalar s = cv::mean(d.mul(d));
  return 10 * std::log10(3 / (s[0] + s[1] + s[2]));
}

Keyframe keyframeOf(const SyntheticScene& scene, int frame, int id) {
  const Frame f = scene.frame(frame);
  Keyframe kf;
  kf.header = f.header;
  kf.keyframe_id = id;
  kf.frame_index = frame;
  kf.T_world_cam = scene.cameraPose(frame);
  kf.camera = f.camera;
  kf.color = f.color;
  kf.depth = f.depth;
  kf.depth_var = cv::Mat(f.depth.size(), CV_32FC1, cv::Scalar(1e-4));  // 1 cm
  return kf;
}

SyntheticScene smallRoom(int frames) {
  SyntheticConfig config;
  config.scene = "room";
  config.frames = frames;
  config.width = 160;
  config.height = 120;
  config.stereo = false;
  return SyntheticScene::make(config);
}

// Stated target: >= 28 dB mean PSNR on the 6 training views of the synthetic room at 160x120
// after 100 steps of 4096 rays (about 70 passes over the pixels), rendered by the render-only
// ray marcher (not the training sampler). Measured: about 30 dB.
TEST(Trainer, FitsASyntheticRoom) {
  const SyntheticScene scene = smallRoom(60);
  Mapper mapper;
  std::vector<Keyframe> keyframes;
  for (int i = 0; i < 6; ++i) {
    keyframes.push_back(keyframeOf(scene, i * 10, i));
    ASSERT_EQ(mapper.addKeyframe(keyframes.back()), KeyframeStore::InsertResult::kAdded);
  }
  ASSERT_TRUE(mapper.field().initialized());
  // Scale-aware default: 1% of the median depth.
  EXPECT_NEAR(mapper.field().geometry().fineVoxelSize(),
              0.01 * medianDepth(mapper.keyframes().entry(0).keyframe), 1e-9);
  double before = 0;
  for (const Keyframe& kf : keyframes)
    before += psnr(kf.color, mapper.render(kf.T_world_cam, kf.camera).color);
  TrainStats first = mapper.train(1), last;
  for (int i = 0; i < 99; ++i) last = mapper.train(1);
  EXPECT_LT(last.loss, first.loss);
  double sum = 0, worst = 1e9;
  for (const Keyframe& kf : keyframes) {
    const double p = psnr(kf.color, mapper.render(kf.T_world_cam, kf.camera).color);
    sum += p;
    worst = std::min(worst, p);
  }
  const double mean = sum / keyframes.size();
  std::printf(
      "PSNR on training views: %.2f dB before training (seeded), %.2f dB after (worst "
      "%.2f); loss %.3f -> %.3f\n",
      before / keyframes.size(), mean, worst, first.loss, last.loss);
  EXPECT_GE(mean, 28.0);
  EXPECT_GT(mean, before / keyframes.size());
  // Rendered depth matches the keyframe depth where the surface is hit.
  const RenderImages r = mapper.render(keyframes[0].T_world_cam, keyframes[0].camera);
  double err = 0;
  int n = 0;
  for (int y = 0; y < r.depth.rows; ++y)
    for (int x = 0; x < r.depth.cols; ++x)
      if (r.depth.at<float>(y, x) > 0) {
        err += std::abs(r.depth.at<float>(y, x) - keyframes[0].depth.at<float>(y, x));
        ++n;
      }
  EXPECT_GT(n, r.depth.total() * 9 / 10);
  EXPECT_LT(err / n, 2 * mapper.field().geometry().fineVoxelSize());
}

// A fronto-parallel textured plane seen by one keyframe.
Keyframe planeKeyframe(bool masked_half_magenta) {
  Keyframe kf;
  kf.keyframe_id = 0;
  kf.camera.width = 64;
  kf.camera.height = 48;
  kf.camera.fx = kf.camera.fy = 50;
  kf.camera.cx = 31.5;
  kf.camera.cy = 23.5;
  kf.color = cv::Mat(48, 64, CV_8UC3, cv::Scalar(40, 160, 90));
  kf.depth = cv::Mat(48, 64, CV_32FC1, cv::Scalar(2.0));
  kf.depth_var = cv::Mat(48, 64, CV_32FC1, cv::Scalar(1e-4));
  kf.dynamic_mask = cv::Mat::zeros(48, 64, CV_8UC1);
  if (masked_half_magenta) {
    kf.dynamic_mask.colRange(32, 64).setTo(255);
    kf.color.colRange(32, 64).setTo(cv::Scalar(255, 0, 255));
  }
  return kf;
}

TEST(Trainer, NeverTrainsOnDynamicPixels) {
  Mapper mapper;
  mapper.addKeyframe(planeKeyframe(true));
  mapper.train(60);
  const Keyframe kf = planeKeyframe(false);
  const RenderImages r = mapper.render(kf.T_world_cam, kf.camera);
  // Left half: trained towards the static colour (RGB 90, 160, 40).
  const cv::Vec3f left = r.color.at<cv::Vec3f>(24, 10);
  EXPECT_NEAR(left[1], 160 / 255.0, 0.05);
  // Right half: a moving object; never seen, so never magenta (R and B high, G low).
  for (int x = 34; x < 64; x += 3) {
    const cv::Vec3f c = r.color.at<cv::Vec3f>(24, x);
    EXPECT_FALSE(c[0] > 0.7 && c[2] > 0.7 && c[1] < 0.3) << "x " << x;
  }
  // A fully masked keyframe gives no rays at all.
  Mapper empty;
  Keyframe all = planeKeyframe(false);
  all.dynamic_mask.setTo(255);
  empty.addKeyframe(planeKeyframe(false));  // fixes the field geometry
  empty.keyframes().clear();
  empty.addKeyframe(all);
  EXPECT_EQ(empty.train(1).rays, 0);
}

TEST(Trainer, FavoursNewKeyframes) {
  const SyntheticScene scene = smallRoom(40);
  Mapper mapper;
  for (int i = 0; i < 3; ++i) mapper.addKeyframe(keyframeOf(scene, i * 10, i));
  mapper.train(40);
  mapper.addKeyframe(keyframeOf(scene, 35, 3));
  mapper.train(1);
  // One step after it arrived, the new keyframe got more rays than any old one in that step:
  // compare the ray counts of this step.
  const int64_t new_rays = mapper.keyframes().entry(3).rays_trained;
  const int64_t old_total = mapper.keyframes().entry(0).rays_trained;
  EXPECT_GT(new_rays, 4096 / 4);  // more than a uniform share
  EXPECT_GT(old_total, 0);
}

TEST(Trainer, ThreadsGiveTheSameQuality) {
  const SyntheticScene scene = smallRoom(30);
  MapperParams params;
  params.trainer.threads = 2;
  params.trainer.batch_rays = 1024;
  Mapper mapper(params);
  for (int i = 0; i < 3; ++i) mapper.addKeyframe(keyframeOf(scene, i * 10, i));
  const TrainStats first = mapper.train(1);
  const TrainStats last = mapper.train(40);
  EXPECT_EQ(last.rays, params.trainer.batch_rays);
  EXPECT_LT(last.loss, first.loss);
  // Deterministic for a given thread count.
  Mapper again(params);
  for (int i = 0; i < 3; ++i) again.addKeyframe(keyframeOf(scene, i * 10, i));
  again.train(41);
  EXPECT_TRUE(again.field().sameContent(mapper.field()));
}

// Random gradients on random voxels of every block (about a third of them), summed into *sum.
void addRandomGradient(const Field& field, std::mt19937* rng, FieldGradient* grad,
                       FieldGradient* sum) {
  std::uniform_real_distribution<float> value(-1.f, 1.f);
  const int C = field.channels();
  for (int l = 0; l < field.numLevels(); ++l) {
    for (int b = 0; b < field.numBlocks(l); ++b) {
      for (int i = 0; i < Field::kBlockVoxels; ++i) {
        if ((*rng)() % 3 != 0) continue;
        const int voxel = b * Field::kBlockVoxels + i;
        for (FieldGradient* g : {grad, sum}) {
          g->touch(l, b);
          g->markVoxel(l, voxel);
        }
        for (int ch = 0; ch < C; ++ch) {
          const float x = value(*rng);
          grad->data(l)[size_t(voxel) * C + ch] = x;
          sum->data(l)[size_t(voxel) * C + ch] += x;
        }
      }
    }
  }
}

TEST(SparseAdam, AStepOnSeveralBuffersEqualsTheStepOnTheirSum) {
  Field reference(FieldGeometry::make(0.05, 2, 4, 0, -4.6f));
  for (int i = 0; i < 12; ++i) {
    reference.allocateBlock(0, Eigen::Vector3i(i % 3, i / 3, 0));
    reference.allocateBlock(1, Eigen::Vector3i(i % 4, i / 4, 1));
  }
  Field on_one_thread = reference, on_two_threads = reference;
  SparseAdam adam_sum, adam_one, adam_two;
  std::mt19937 rng(7);
  for (int step = 0; step < 3; ++step) {
    // Three buffers (training threads), each marking its own random voxels, and a copy.
    FieldGradient sum, buffers[2][3];
    sum.resize(reference);
    for (int k = 0; k < 3; ++k) {
      buffers[0][k].resize(reference);
      addRandomGradient(reference, &rng, &buffers[0][k], &sum);
      buffers[1][k] = buffers[0][k];
    }
    const int64_t updated = adam_sum.step(&reference, &sum);
    EXPECT_GT(updated, 0);
    EXPECT_EQ(adam_one.step(&on_one_thread, {&buffers[0][0], &buffers[0][1], &buffers[0][2]}, 1),
              updated);
    EXPECT_EQ(adam_two.step(&on_two_threads, {&buffers[1][0], &buffers[1][1], &buffers[1][2]}, 2),
              updated);
    // The sum is taken in buffer order on any number of threads: the same floats.
    EXPECT_TRUE(on_one_thread.sameContent(reference)) << "step " << step;
    EXPECT_TRUE(on_two_threads.sameContent(reference)) << "step " << step;
    // Every buffer is left zeroed, with nothing touched.
    for (int copy = 0; copy < 2; ++copy) {
      for (const FieldGradient& g : buffers[copy]) {
        for (int l = 0; l < reference.numLevels(); ++l) {
          EXPECT_TRUE(g.touched(l).empty());
          for (size_t i = 0; i < reference.levelSize(l); ++i) ASSERT_EQ(g.data(l)[i], 0.f);
        }
      }
    }
  }
}

TEST(SparseAdam, EachVoxelsRateHalvesEveryHalfLifeOfItsOwnSteps) {
  Field field(FieldGeometry::make(0.05, 2, 4, 0, -4.6f));
  const int block = field.allocateBlock(1, Eigen::Vector3i(0, 0, 0));
  AdamParams params;
  params.lr_half_life_steps = 10;
  params.lr_min_scale = 0.25f;
  SparseAdam adam(params);
  const int C = field.channels();
  const int first = block * Field::kBlockVoxels, second = first + 1;
  // A constant gradient makes Adam's step exactly the rate (bias-corrected moments g and g^2).
  auto expectedStep = [&](int t) {
    return params.lr_density * std::max(0.25, std::exp2(-(t - 1) / 10.0));
  };
  for (int step = 1; step <= 50; ++step) {
    FieldGradient grad;
    grad.resize(field);
    grad.touch(1, block);
    grad.data(1)[size_t(first) * C] = 1.f;
    grad.markVoxel(1, first);
    if (step > 20) {  // the second voxel joins late: its own count starts at 1
      grad.data(1)[size_t(second) * C] = 1.f;
      grad.markVoxel(1, second);
    }
    const float before_first = field.levelData(1)[size_t(first) * C];
    const float before_second = field.levelData(1)[size_t(second) * C];
    adam.step(&field, &grad);
    EXPECT_NEAR(before_first - field.levelData(1)[size_t(first) * C], expectedStep(step), 1e-5)
        << "step " << step;
    EXPECT_NEAR(before_second - field.levelData(1)[size_t(second) * C],
                step > 20 ? expectedStep(step - 20) : 0.0, 1e-5)
        << "step " << step;
  }
}

TEST(Trainer, DepthLossModes) {
  EXPECT_EQ(parseDepthLoss("weighted"), DepthLoss::kWeighted);
  EXPECT_EQ(parseDepthLoss("raw"), DepthLoss::kRaw);
  EXPECT_EQ(parseDepthLoss("none"), DepthLoss::kNone);
  EXPECT_THROW(parseDepthLoss("l1"), std::invalid_argument);
  for (DepthLoss mode : {DepthLoss::kWeighted, DepthLoss::kRaw, DepthLoss::kNone}) {
    MapperParams params;
    params.trainer.depth_loss = mode;
    Mapper mapper(params);
    mapper.addKeyframe(planeKeyframe(false));
    const TrainStats s = mapper.train(5);
    if (mode == DepthLoss::kNone)
      EXPECT_EQ(s.loss_depth, 0.0);
    else
      EXPECT_GT(s.loss_depth, 0.0);
  }
}

}  // namespace
}  // namespace radslam
