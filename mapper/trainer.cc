#include "mapper/trainer.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/parallel.h"

namespace radslam {

DepthLoss parseDepthLoss(const std::string& name) {
  if (name == "weighted") return DepthLoss::kWeighted;
  if (name == "raw") return DepthLoss::kRaw;
  if (name == "none") return DepthLoss::kNone;
  throw std::invalid_argument("depth loss mode '" + name + "': expected weighted, raw or none");
}

std::string depthLossName(DepthLoss mode) {
  switch (mode) {
    case DepthLoss::kWeighted:
      return "weighted";
    case DepthLoss::kRaw:
      return "raw";
    case DepthLoss::kNone:
      return "none";
  }
  return "?";
}

// Per-step view of a keyframe for the ray loop: the pose as floats and the images.
struct Trainer::KeyframeView {
  Eigen::Matrix3f R;  // R_world_cam
  Eigen::Vector3f t;  // camera centre, world
  float fx, fy, cx, cy;
  int width, height;
  const uint8_t* mask;  // dynamic mask, nullptr when none
  const uint8_t* color;
  int color_channels;
  size_t color_step;
  const float* depth;
  const float* depth_var;
  const int32_t* pixels;
  uint32_t num_pixels;
  bool refine_pose;
  float gain[3], offset[3];  // exposure (applyExposure)
  bool refine_exposure;
};

struct Trainer::ThreadState {
  FieldGradient grad;
  RayWorkspace ws;
  Rng rng;
  std::vector<float> t, delta;
  std::vector<Vec6> pose_grad;      // per keyframe
  std::vector<Vec6> exposure_grad;  // per keyframe
  std::vector<int> kf_rays;
  std::vector<double> kf_loss;
  double loss_rgb = 0, loss_depth = 0;
  int64_t samples = 0;
  int rays = 0;
};

Trainer::Trainer(const TrainerParams& params) { setParams(params); }
Trainer::~Trainer() = default;

void Trainer::setParams(const TrainerParams& params) {
  if (params.batch_rays <= 0 || params.threads <= 0 || params.surface_samples <= 0 ||
      params.spread_samples < 0 || params.free_samples < 0 || params.pose_lr_half_life_steps < 0 ||
      params.adam.lr_half_life_steps < 0 ||
      !(params.adam.lr_min_scale > 0 && params.adam.lr_min_scale <= 1))
    throw std::invalid_argument(
        "trainer: batch_rays, threads and surface_samples must be > 0, other sample counts, "
        "pose_lr_half_life_steps and lr_half_life_steps >= 0, lr_min_scale in (0, 1]");
  params_ = params;
  adam_.setParams(params.adam);
  if (steps_ == 0) rng_.state = params.seed;
}

void Trainer::reset() {
  steps_ = 0;
  rng_.state = params_.seed;
  adam_ = SparseAdam(params_.adam);
  threads_.clear();
}

void Trainer::restoreState(int64_t steps, uint64_t rng_state) {
  steps_ = steps;
  rng_.state = rng_state;
}

SamplingParams Trainer::samplingFor(double fine_voxel_size) const {
  const float s = static_cast<float>(fine_voxel_size);
  SamplingParams sp;
  sp.surface_samples = params_.surface_samples;
  sp.spread_samples = params_.spread_samples;
  sp.free_samples = params_.free_samples;
  sp.sigma_range = params_.sigma_range;
  sp.sigma_min = params_.sigma_min_voxels * s;
  sp.sigma_max = params_.sigma_max_voxels * s;
  sp.near = params_.near_voxels * s;
  sp.far = 1e5f * s;
  return sp;
}

void applyExposure(const Vec6& x, cv::Mat* rgb) {
  CV_Assert(rgb->type() == CV_32FC3);
  float gain[3], offset[3];
  for (int j = 0; j < 3; ++j) {
    gain[j] = static_cast<float>(std::exp(x[j]));
    offset[j] = static_cast<float>(x[3 + j]);
  }
  for (int y = 0; y < rgb->rows; ++y) {
    cv::Vec3f* row = rgb->ptr<cv::Vec3f>(y);
    for (int x0 = 0; x0 < rgb->cols; ++x0) {
      float out[3];
      applyExposure(gain, offset, &row[x0][0], out);
      row[x0] = cv::Vec3f(out[0], out[1], out[2]);
    }
  }
}

Vec6 interpolateExposure(double t, double t_a, const Vec6& x_a, double t_b, const Vec6& x_b) {
  if (t <= t_a || !(t_b > t_a)) return x_a;
  if (t >= t_b) return x_b;
  const double s = (t - t_a) / (t_b - t_a);
  return (1 - s) * x_a + s * x_b;
}

void Trainer::traceRays(const Field& field, const KeyframeStore& keyframes, ThreadState* ts,
                        int count) {
  const VolumeRenderer renderer;
  const SamplingParams sp = samplingFor(field.geometry().fineVoxelSize());
  const int nk = keyframes.size();
  ts->pose_grad.assign(nk, Vec6::Zero());
  ts->exposure_grad.assign(nk, Vec6::Zero());
  ts->kf_rays.assign(nk, 0);
  ts->kf_loss.assign(nk, 0.0);
  ts->loss_rgb = ts->loss_depth = 0;
  ts->samples = 0;
  ts->rays = 0;
  ts->t.resize(maxSamples(sp));
  ts->delta.resize(maxSamples(sp));
  // Rays come in small pixel patches: neighbouring rays read and write mostly the same voxels,
  // so the caches serve them (scattered rays miss on every voxel).
  const int P = params_.patch_size;
  int traced = 0;
  for (int attempt = 0; traced < count && attempt < 4 * count; ++attempt) {
    const double u = ts->rng.uniform() * cdf_.back();
    const int k =
        std::min<int>(nk - 1, std::upper_bound(cdf_.begin(), cdf_.end(), u) - cdf_.begin());
    const KeyframeView& kv = views_[k];
    if (kv.num_pixels == 0) continue;
    const int32_t anchor = kv.pixels[ts->rng.below(kv.num_pixels)];
    const int x0 = anchor % kv.width - static_cast<int>(ts->rng.below(P));
    const int y0 = anchor / kv.width - static_cast<int>(ts->rng.below(P));
    for (int py = 0; py < P * P && traced < count; ++py) {
      const int x = x0 + py % P, y = y0 + py / P;
      if (x < 0 || y < 0 || x >= kv.width || y >= kv.height) continue;
      const int pix = y * kv.width + x;
      if (kv.mask && kv.mask[pix]) continue;
      const float depth = kv.depth[pix];
      const float var = kv.depth_var[pix];
      if (!(depth > 0) && !params_.train_depthless_rays) continue;
      ++traced;
      traceRay(field, renderer, sp, kv, k, x, y, depth, var, ts);
    }
  }
}

void Trainer::traceRay(const Field& field, const VolumeRenderer& renderer, const SamplingParams& sp,
                       const KeyframeView& kv, int k, int x, int y, float depth, float var,
                       ThreadState* ts) const {
  const float fine = static_cast<float>(field.geometry().fineVoxelSize());
  const float raw_var = std::pow(params_.raw_depth_sigma_voxels * fine, 2.f);
  const float min_var = std::pow(params_.min_depth_sigma_voxels * fine, 2.f);
  const float lambda = params_.lambda_depth;
  const Eigen::Vector3f lo = field.boundsMin(), hi = field.boundsMax();
  float target[3];
  const uint8_t* c = kv.color + y * kv.color_step + x * kv.color_channels;
  if (kv.color_channels == 3) {
    target[0] = c[2] * (1.f / 255.f);  // BGR -> RGB
    target[1] = c[1] * (1.f / 255.f);
    target[2] = c[0] * (1.f / 255.f);
  } else {
    target[0] = target[1] = target[2] = c[0] * (1.f / 255.f);
  }
  Ray ray;
  ray.cam_dir = Eigen::Vector3f((x - kv.cx) / kv.fx, (y - kv.cy) / kv.fy, 1.f);
  ray.origin = kv.t;
  ray.dir = kv.R * ray.cam_dir;
  ray.view_dir = ray.dir.normalized();
  float t_enter = 0, t_exit = -1;
  intersectBox(ray, lo, hi, &t_enter, &t_exit);
  const int n = sampleRay(sp, depth, std::sqrt(var), t_enter, t_exit, &ts->rng, ts->t.data(),
                          ts->delta.data());
  const RayOutput out = renderer.forward(field, ray, ts->t.data(), ts->delta.data(), n, &ts->ws);
  RayOutputGrad g;
  double loss_rgb = 0, loss_depth = 0;
  float seen[3], g_seen[3];
  applyExposure(kv.gain, kv.offset, out.color, seen);
  for (int ch = 0; ch < 3; ++ch) {
    const float e = seen[ch] - target[ch];
    loss_rgb += e * e;
    g_seen[ch] = 2 * e;
  }
  exposureBackward(kv.gain, out.color, g_seen, g.color,
                   kv.refine_exposure ? &ts->exposure_grad[k] : nullptr);
  // Infinite variance marks a depth that is no measurement (a filled hole): sampling only.
  if (depth > 0 && std::isfinite(var) && params_.depth_loss != DepthLoss::kNone) {
    const float sigma2 = params_.depth_loss == DepthLoss::kRaw ? raw_var : std::max(var, min_var);
    if (std::isfinite(sigma2)) {
      // Huber on the normalised residual r = e / sigma: quadratic up to huber sigmas, then
      // linear, so depth discontinuities (a small pose error moves them) do not dominate.
      const float e = out.depth - depth;
      const float r = e / std::sqrt(sigma2);
      const float k = params_.depth_huber;
      if (k <= 0 || std::abs(r) <= k) {
        loss_depth = lambda * r * r;
        g.depth = 2 * lambda * e / sigma2;
      } else {
        loss_depth = lambda * (2 * k * std::abs(r) - k * k);
        g.depth = 2 * lambda * k * (r > 0 ? 1.f : -1.f) / std::sqrt(sigma2);
      }
    }
  }
  ts->loss_rgb += loss_rgb;
  ts->loss_depth += loss_depth;
  ts->kf_loss[k] += loss_rgb + loss_depth;
  ++ts->kf_rays[k];
  ++ts->rays;
  ts->samples += out.samples;
  if (out.samples == 0) return;
  if (kv.refine_pose) {
    RayPoseGrad pg;
    RayOutputGrad g_pose = g;
    g_pose.depth *= params_.pose_depth_weight;
    renderer.backward(field, ray, ts->ws, out, g, &ts->grad, &pg, &g_pose);
    // x_i = T (t_i d_c): d/dv = R, d/dw = -R hat(t_i d_c) (see poseGradient).
    const Eigen::Vector3f a = kv.R.transpose() * pg.g_pos;
    const Eigen::Vector3f b = ray.cam_dir.cross(kv.R.transpose() * pg.g_tpos) +
                              ray.cam_dir.normalized().cross(kv.R.transpose() * pg.g_dir);
    ts->pose_grad[k].head<3>() += a.cast<double>();
    ts->pose_grad[k].tail<3>() += b.cast<double>();
  } else {
    renderer.backward(field, ray, ts->ws, out, g, &ts->grad, nullptr);
  }
}

TrainStats Trainer::step(Field* field, KeyframeStore* keyframes) {
  TrainStats stats;
  const int nk = keyframes->size();
  if (!field->initialized() || field->empty() || nk == 0) return stats;
  const double fine = field->geometry().fineVoxelSize();

  // Keyframe choice: favour new keyframes and badly fitted ones.
  double mean_loss = 0;
  int measured = 0;
  for (int i = 0; i < nk; ++i)
    if (keyframes->entry(i).loss_ema > 0) {
      mean_loss += keyframes->entry(i).loss_ema;
      ++measured;
    }
  mean_loss = measured > 0 ? mean_loss / measured : 0;
  cdf_.resize(nk);
  views_.resize(nk);
  gauge_ = keyframes->gaugeIndex();
  double total = 0;
  for (int i = 0; i < nk; ++i) {
    const KeyframeEntry& e = keyframes->entry(i);
    const double loss_term = e.loss_ema > 0 && mean_loss > 0 ? e.loss_ema / mean_loss : 1.0;
    total += 1.0 +
             params_.recency_boost * std::exp(-double(e.rays_trained) / params_.recency_rays) +
             params_.loss_boost * loss_term;
    cdf_[i] = total;
    KeyframeView& v = views_[i];
    v.R = e.T_world_cam.rotation().cast<float>();
    v.t = e.T_world_cam.translation().cast<float>();
    const CameraModel& cam = e.keyframe.camera;
    v.fx = static_cast<float>(cam.fx);
    v.fy = static_cast<float>(cam.fy);
    v.cx = static_cast<float>(cam.cx);
    v.cy = static_cast<float>(cam.cy);
    v.width = cam.width;
    v.height = cam.height;
    v.mask = e.keyframe.dynamic_mask.empty() ? nullptr : e.keyframe.dynamic_mask.ptr<uint8_t>();
    v.color = e.keyframe.color.data;
    v.color_channels = e.keyframe.color.channels();
    v.color_step = e.keyframe.color.step[0];
    v.depth = e.keyframe.depth.ptr<float>();
    v.depth_var = e.keyframe.depth_var.ptr<float>();
    v.pixels = e.pixels.data();
    v.num_pixels = static_cast<uint32_t>(e.pixels.size());
    v.refine_pose =
        params_.refine_poses && i != gauge_ && e.rays_trained >= params_.pose_warmup_rays;
    v.refine_exposure =
        params_.refine_exposure && i != gauge_ && e.rays_trained >= params_.exposure_warmup_rays;
    for (int j = 0; j < 3; ++j) {
      v.gain[j] = static_cast<float>(std::exp(e.exposure[j]));
      v.offset[j] = static_cast<float>(e.exposure[3 + j]);
    }
  }

  // Rays, split over threads; each thread has its own gradient buffers and random stream.
  const int nt = params_.threads;
  threads_.resize(nt);
  for (ThreadState& ts : threads_) {
    ts.grad.resize(*field);
    ts.rng.state = rng_.next();
  }
  const int batch = params_.batch_rays;
  runOnThreads(nt, [&](int k) {
    traceRays(*field, *keyframes, &threads_[k], batch * (k + 1) / nt - batch * k / nt);
  });
  std::vector<FieldGradient*> grads;
  for (ThreadState& ts : threads_) grads.push_back(&ts.grad);
  stats.voxels_updated = adam_.step(field, grads, nt);

  // Statistics, per-keyframe running losses and ray counts.
  std::vector<double> kf_loss(nk, 0.0);
  std::vector<int> kf_rays(nk, 0);
  std::vector<Vec6> pose_grad(nk, Vec6::Zero()), exposure_grad(nk, Vec6::Zero());
  for (const ThreadState& ts : threads_) {
    stats.rays += ts.rays;
    stats.samples += ts.samples;
    stats.loss_rgb += ts.loss_rgb;
    stats.loss_depth += ts.loss_depth;
    for (int i = 0; i < nk; ++i) {
      kf_loss[i] += ts.kf_loss[i];
      kf_rays[i] += ts.kf_rays[i];
      pose_grad[i] += ts.pose_grad[i];
      exposure_grad[i] += ts.exposure_grad[i];
    }
  }
  if (stats.rays > 0) {
    stats.loss_rgb /= stats.rays;
    stats.loss_depth /= stats.rays;
    stats.loss = stats.loss_rgb + stats.loss_depth;
  }
  for (int i = 0; i < nk; ++i) {
    KeyframeEntry& e = keyframes->entry(i);
    if (kf_rays[i] == 0) continue;
    const double loss = kf_loss[i] / kf_rays[i];
    e.loss_ema = e.loss_ema > 0 ? 0.9 * e.loss_ema + 0.1 * loss : loss;
    e.rays_trained += kf_rays[i];
    constexpr double b1 = 0.9, b2 = 0.99, eps = 1e-12;
    if (views_[i].refine_exposure) {
      // Adam on the exposure, on the mean gradient over this keyframe's rays.
      const Vec6 g = exposure_grad[i] / kf_rays[i];
      e.exposure_m = b1 * e.exposure_m + (1 - b1) * g;
      e.exposure_v = b2 * e.exposure_v + (1 - b2) * g.cwiseProduct(g);
      ++e.exposure_steps;
      const double c1 = 1.0 / (1.0 - std::pow(b1, double(e.exposure_steps)));
      const double c2 = 1.0 / (1.0 - std::pow(b2, double(e.exposure_steps)));
      for (int j = 0; j < 6; ++j)
        e.exposure[j] -=
            params_.exposure_lr * (e.exposure_m[j] * c1) / (std::sqrt(e.exposure_v[j] * c2) + eps);
    }
    if (!views_[i].refine_pose) continue;
    // Adam on the pose; the gradient is the mean over this keyframe's rays.
    const Vec6 g = pose_grad[i] / kf_rays[i];
    e.pose_m = b1 * e.pose_m + (1 - b1) * g;
    e.pose_v = b2 * e.pose_v + (1 - b2) * g.cwiseProduct(g);
    ++e.pose_steps;
    const double c1 = 1.0 / (1.0 - std::pow(b1, double(e.pose_steps)));
    const double c2 = 1.0 / (1.0 - std::pow(b2, double(e.pose_steps)));
    const double decay =
        params_.pose_lr_half_life_steps > 0
            ? std::exp2(-double(e.pose_steps - 1) / double(params_.pose_lr_half_life_steps))
            : 1.0;
    Vec6 xi;
    for (int j = 0; j < 6; ++j) {
      const double lr = decay * (j < 3 ? params_.pose_lr_trans_voxels * fine : params_.pose_lr_rot);
      xi[j] = -lr * (e.pose_m[j] * c1) / (std::sqrt(e.pose_v[j] * c2) + eps);
    }
    e.T_world_cam = canonicalPose(e.T_world_cam * SE3::exp(xi));
    e.pose_refined = true;
    ++stats.poses_refined;
  }
  ++steps_;
  return stats;
}

}  // namespace radslam
