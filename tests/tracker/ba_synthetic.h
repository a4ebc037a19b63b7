// Synthetic dense-BA problems for the tracker tests: random inverse depths per grid pixel,
// ground-truth poses, targets = exact projections (+ optional Gaussian noise).
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "tracker/dense_ba.h"

namespace radslam::test {

struct SyntheticScene {
  CameraModel camera;
  std::vector<SE3> T_world_cam;    // ground truth
  std::vector<cv::Mat> inv_depth;  // ground truth, CV_32FC1
};

inline CameraModel gridCamera(int width, int height, double f) {
  CameraModel cam;
  cam.width = width;
  cam.height = height;
  cam.fx = f;
  cam.fy = f * 1.02;
  cam.cx = 0.5 * (width - 1) + 0.3;
  cam.cy = 0.5 * (height - 1) - 0.2;
  return cam;
}

/// K keyframes moving mostly sideways (spacing `baseline` m along x) with small rotations,
/// looking at depths uniform in [z_min, z_max] m.
inline SyntheticScene makeScene(int K, int width, int height, double f, std::mt19937* rng,
                                double baseline = 0.25, double z_min = 2.0, double z_max = 5.0) {
  SyntheticScene s;
  s.camera = gridCamera(width, height, f);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  std::uniform_real_distribution<double> Z(z_min, z_max);
  for (int k = 0; k < K; ++k) {
    Vec6 xi;
    xi << baseline * k, 0.05 * U(*rng), 0.05 * U(*rng), 0.03 * U(*rng), 0.03 * U(*rng),
        0.03 * U(*rng);
    SE3 T(SO3::exp(xi.tail<3>()), xi.head<3>());
    s.T_world_cam.push_back(T);
    cv::Mat d(height, width, CV_32FC1);
    for (int v = 0; v < height; ++v) {
      for (int u = 0; u < width; ++u) d.at<float>(v, u) = static_cast<float>(1.0 / Z(*rng));
    }
    s.inv_depth.push_back(d);
  }
  return s;
}

/// Replaces the scene's inverse depths by those of the plane n . X = h (world frame), seen by
/// every camera: inverse depth is then affine in the pixel, so the grid's bilinear interpolation
/// (dense BA's depth residual) is exact.
inline void makePlanar(SyntheticScene* s, const Vec3& n_world, double h) {
  const CameraModel& cam = s->camera;
  for (size_t k = 0; k < s->T_world_cam.size(); ++k) {
    const SE3& T = s->T_world_cam[k];
    const Vec3 n_cam = T.so3().inverse() * n_world;
    const double h_cam = h - n_world.dot(T.translation());
    for (int v = 0; v < cam.height; ++v) {
      for (int u = 0; u < cam.width; ++u) {
        const Vec3 ray((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
        s->inv_depth[k].at<float>(v, u) = static_cast<float>(n_cam.dot(ray) / h_cam);
      }
    }
  }
}

/// Edge i -> j with targets from the ground truth plus N(0, sigma^2) noise and weight 1/sigma^2
/// (weight `w` when sigma = 0). Pixels projecting outside j's grid (by more than `margin`)
/// get weight 0, as flow would mark them invalid.
inline DenseBaEdge makeEdge(const SyntheticScene& s, int i, int j, double sigma, double w,
                            std::mt19937* rng, const SE3* T_i_other = nullptr,
                            double margin = 1.0) {
  DenseBaEdge e;
  e.i = i;
  e.j = j;
  const CameraModel& cam = s.camera;
  const SE3 T_world_j = T_i_other ? s.T_world_cam[i] * *T_i_other : s.T_world_cam[j];
  if (T_i_other) e.T_i_other = *T_i_other;
  e.target = cv::Mat(cam.height, cam.width, CV_32FC2);
  e.weight = cv::Mat(cam.height, cam.width, kFlowWeightType);
  std::normal_distribution<double> N(0.0, 1.0);
  const double weight = sigma > 0 ? 1.0 / (sigma * sigma) : w;
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      Eigen::Vector2d r;
      const bool ok =
          denseBaResidual(cam, s.T_world_cam[i], T_world_j, u, v, s.inv_depth[i].at<float>(v, u),
                          Eigen::Vector2d::Zero(), 0.2, &r);
      const Eigen::Vector2d px = -r;
      const bool inside = ok && px.x() > -margin && px.y() > -margin &&
                          px.x() < cam.width - 1 + margin && px.y() < cam.height - 1 + margin;
      const double nu = sigma * N(*rng), nv = sigma * N(*rng);
      e.target.at<cv::Vec2f>(v, u) =
          inside ? cv::Vec2f(static_cast<float>(px.x() + nu), static_cast<float>(px.y() + nv))
                 : cv::Vec2f(0, 0);
      e.weight.at<cv::Vec3f>(v, u) =
          inside ? cv::Vec3f(static_cast<float>(weight), 0, static_cast<float>(weight))
                 : cv::Vec3f(0, 0, 0);
    }
  }
  return e;
}

/// Problem with the ground-truth state and edges between all ordered pairs |i - j| <= reach.
inline DenseBaProblem makeProblem(const SyntheticScene& s, double sigma, std::mt19937* rng,
                                  int reach = 100) {
  DenseBaProblem p;
  p.camera = s.camera;
  const int K = static_cast<int>(s.T_world_cam.size());
  for (int k = 0; k < K; ++k) {
    DenseBaKeyframe kf;
    kf.T_world_cam = s.T_world_cam[k];
    kf.inv_depth = s.inv_depth[k].clone();
    p.keyframes.push_back(kf);
  }
  for (int i = 0; i < K; ++i) {
    for (int j = 0; j < K; ++j) {
      if (i != j && std::abs(i - j) <= reach) p.edges.push_back(makeEdge(s, i, j, sigma, 1.0, rng));
    }
  }
  return p;
}

/// Right-perturbation error e with T_est = T_gt Exp(e).
inline Vec6 poseError(const SE3& T_gt, const SE3& T_est) { return (T_gt.inverse() * T_est).log(); }

inline void perturbPose(SE3* T, double rot, double trans, std::mt19937* rng) {
  std::normal_distribution<double> N(0.0, 1.0);
  Vec6 xi;
  xi << trans * N(*rng), trans * N(*rng), trans * N(*rng), rot * N(*rng), rot * N(*rng),
      rot * N(*rng);
  *T = *T * SE3::exp(xi);
}

inline void perturbDepths(cv::Mat* d, double relative, std::mt19937* rng) {
  std::uniform_real_distribution<double> U(-relative, relative);
  for (int v = 0; v < d->rows; ++v) {
    for (int u = 0; u < d->cols; ++u) d->at<float>(v, u) *= static_cast<float>(1.0 + U(*rng));
  }
}

/// A small problem (3 keyframes, 8x6 grid) exercising everything the assembly handles: duplicate
/// edges, a stereo edge, priors on part of a keyframe with a level prior, zero weights, weights
/// with a cross term (an aperture), outliers for the Huber kernel, a perturbed state.
inline DenseBaProblem richProblem(std::mt19937* rng) {
  test::SyntheticScene s = makeScene(3, 8, 6, 7.0, rng, 0.4);
  DenseBaProblem p = makeProblem(s, 0.0, rng);
  p.edges.erase(p.edges.begin() + 3);                   // drop one pair direction
  p.edges.push_back(makeEdge(s, 0, 2, 0.0, 2.0, rng));  // duplicate of 0 -> 2
  const SE3 T_left_right(SO3(), Vec3(0.12, 0, 0));
  p.edges.push_back(makeEdge(s, 2, -1, 0.0, 0.5, rng, &T_left_right));
  std::uniform_real_distribution<double> U(0, 1);
  for (DenseBaEdge& e : p.edges) {
    for (int q = 0; q < 48; ++q) {
      cv::Vec3f& w = e.weight.at<cv::Vec3f>(q);
      cv::Vec2f& t = e.target.at<cv::Vec2f>(q);
      const double x = U(*rng);
      if (x < 0.1)
        w = cv::Vec3f(0, 0, 0);
      else if (x < 0.15)
        t += cv::Vec2f(4.0f, -3.0f);  // outlier
      else if (x < 0.2)
        w[2] = 0;  // one component only
      else if (x < 0.6)
        w[1] = static_cast<float>(0.9 * (2 * U(*rng) - 1) * std::sqrt(w[0] * w[2]));
      w *= static_cast<float>(0.5 + U(*rng));
    }
  }
  DenseBaKeyframe& kf1 = p.keyframes[1];
  kf1.prior_inv_depth = s.inv_depth[1].clone();
  kf1.prior_inv_depth_var = cv::Mat(6, 8, CV_32FC1, cv::Scalar(-1));
  for (int q = 0; q < 20; ++q) kf1.prior_inv_depth_var.at<float>(q) = 0.01f + 0.001f * q;
  kf1.prior_level_var = 0.002;  // about the mean's variance from its 20 pixels' priors
  // Measured depth on keyframes 0 and 2 (edges into them get depth residuals): a smooth slant
  // that disagrees with the random true depths (so the robust kernel bites), a hole and a depth
  // edge between columns 5 and 6.
  for (int k : {0, 2}) {
    DenseBaKeyframe& kf = p.keyframes[k];
    const double mean = cv::mean(s.inv_depth[k])[0];
    kf.measured_inv_depth.create(6, 8, CV_32FC1);
    kf.measured_inv_depth_var.create(6, 8, CV_32FC1);
    for (int v = 0; v < 6; ++v) {
      for (int u = 0; u < 8; ++u) {
        const double edge = u >= 6 ? 1.3 : 1.0;
        kf.measured_inv_depth.at<float>(v, u) =
            static_cast<float>(mean * edge * (1 + 0.01 * u - 0.005 * v));
        kf.measured_inv_depth_var.at<float>(v, u) = static_cast<float>(0.005 * (1 + 0.1 * u));
      }
    }
    kf.measured_inv_depth_var.at<float>(2, 3) = 0;
  }
  for (int k = 0; k < 3; ++k) {
    perturbPose(&p.keyframes[k].T_world_cam, 0.01, 0.02, rng);
    perturbDepths(&p.keyframes[k].inv_depth, 0.1, rng);
  }
  return p;
}

}  // namespace radslam::test
