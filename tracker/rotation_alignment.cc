#include "tracker/rotation_alignment.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/image_sampling.h"

namespace radslam {
namespace {

// Bilinear grey value at (u, v); false outside the pixel centres' hull.
bool sample(const cv::Mat& image, double u, double v, double* value) {
  if (!(u >= 0 && v >= 0 && u <= image.cols - 1.001 && v <= image.rows - 1.001)) return false;
  const int x = static_cast<int>(u);
  const int y = static_cast<int>(v);
  *value = bilinearAt<uint8_t>(image, x, y, u - x, v - y);
  return true;
}

// A pixel of image a with its ray and its row of the inverse compositional Jacobian.
struct TemplatePixel {
  Vec3 ray;
  double grey;
  Eigen::Vector4d jacobian;  // d a(W(x; delta)) / d(delta, beta)
};

std::vector<TemplatePixel> templatePixels(const cv::Mat& a, const CameraModel& camera,
                                          double min_gradient) {
  std::vector<TemplatePixel> pixels;
  for (int v = 1; v + 1 < a.rows; ++v) {
    const uint8_t* up = a.ptr<uint8_t>(v - 1);
    const uint8_t* row = a.ptr<uint8_t>(v);
    const uint8_t* down = a.ptr<uint8_t>(v + 1);
    for (int u = 1; u + 1 < a.cols; ++u) {
      const Eigen::RowVector2d gradient(0.5 * (row[u + 1] - row[u - 1]), 0.5 * (down[u] - up[u]));
      if (gradient.norm() < min_gradient) continue;
      TemplatePixel p;
      p.ray = Vec3((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0);
      p.grey = row[u];
      p.jacobian << (gradient * rotationWarpJacobian(camera, u, v)).transpose(), 1.0;
      pixels.push_back(p);
    }
  }
  return pixels;
}

}  // namespace

ImagePyramid coarsePyramid(const cv::Mat& grey, const CameraModel& camera, int first, int last) {
  if (grey.type() != CV_8UC1 || grey.cols != camera.width || grey.rows != camera.height) {
    throw std::invalid_argument("coarsePyramid: the image must be CV_8UC1 of the camera's size");
  }
  if (first < 0 || last < first || (grey.cols >> last) < 8 || (grey.rows >> last) < 8) {
    throw std::invalid_argument(
        "coarsePyramid: levels " + std::to_string(first) + ".." + std::to_string(last) +
        " do not fit a " + std::to_string(grey.cols) + "x" + std::to_string(grey.rows) + " image");
  }
  ImagePyramid pyramid;
  cv::Mat level = grey;
  CameraModel level_camera = camera;
  for (int i = 0; i <= last; ++i) {
    if (i > 0) {
      const cv::Size half(level.cols / 2, level.rows / 2);
      cv::Mat reduced;
      cv::resize(level, reduced, half, 0, 0, cv::INTER_AREA);
      level_camera = scaleCamera(level_camera, half.width, half.height);
      level = reduced;
    }
    if (i >= first) {
      pyramid.levels.push_back(level);
      pyramid.cameras.push_back(level_camera);
    }
  }
  return pyramid;
}

Eigen::Matrix<double, 2, 3> rotationWarpJacobian(const CameraModel& camera, double u, double v) {
  const double x = (u - camera.cx) / camera.fx;
  const double y = (v - camera.cy) / camera.fy;
  Eigen::Matrix<double, 2, 3> J;
  J << camera.fx * -x * y, camera.fx * (1 + x * x), camera.fx * -y,  //
      camera.fy * -(1 + y * y), camera.fy * x * y, camera.fy * x;
  return J;
}

RotationAlignment alignRotation(const ImagePyramid& a, const ImagePyramid& b, const SO3& R_b_a_init,
                                const RotationAlignmentOptions& options) {
  if (a.levels.empty() || a.levels.size() != b.levels.size()) {
    throw std::invalid_argument("alignRotation: the pyramids must have the same, non-zero levels");
  }
  RotationAlignment result;
  result.R_b_a = R_b_a_init;
  SO3 R_b_a = R_b_a_init;
  double beta = 0;
  for (int level = static_cast<int>(a.levels.size()) - 1; level >= 0; --level) {
    const CameraModel& camera = a.cameras[level];
    const cv::Mat& image_b = b.levels[level];
    const std::vector<TemplatePixel> pixels =
        templatePixels(a.levels[level], camera, options.min_gradient);
    int inliers = 0;
    double inlier_sq = 0;
    for (int iteration = 0; iteration < options.max_iterations; ++iteration) {
      Eigen::Matrix4d H = Eigen::Matrix4d::Zero();
      Eigen::Vector4d g = Eigen::Vector4d::Zero();
      inliers = 0;
      inlier_sq = 0;
      const Mat3 R = R_b_a.matrix();
      for (const TemplatePixel& p : pixels) {
        const Vec3 q = R * p.ray;
        if (!(q.z() > 0)) continue;
        double grey_b;
        if (!sample(image_b, camera.fx * q.x() / q.z() + camera.cx,
                    camera.fy * q.y() / q.z() + camera.cy, &grey_b)) {
          continue;
        }
        const double e = grey_b - p.grey - beta;
        const double w =
            std::abs(e) <= options.huber_scale ? 1.0 : options.huber_scale / std::abs(e);
        if (w == 1.0) {
          ++inliers;
          inlier_sq += e * e;
        }
        // The unknowns are delta and the whole offset: the residual without beta is e + beta.
        H.noalias() += w * p.jacobian * p.jacobian.transpose();
        g.noalias() += w * p.jacobian * (e + beta);
      }
      if (inliers < options.min_inlier_share * static_cast<double>(pixels.size()) || inliers < 16) {
        return result;
      }
      const Eigen::Vector4d step = H.ldlt().solve(g);
      if (!step.allFinite()) return result;
      R_b_a = R_b_a * SO3::exp(-step.head<3>());
      beta = step(3);
      if (step.head<3>().norm() < options.converged_rad) break;
    }
    if (level == 0) {
      result.ok = true;
      result.R_b_a = R_b_a;
      result.brightness_offset = beta;
      result.rms = std::sqrt(inlier_sq / std::max(1, inliers));
      result.pixels = static_cast<int>(pixels.size());
    }
  }
  return result;
}

}  // namespace radslam
