#include "tracker/object_synthetic.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/camera.h"

namespace radslam {

std::vector<ObjectCorrespondence> syntheticObjectCorrespondences(
    const CameraModel& camera, const RenderedView& view0, int object_id, const SE3& T_world_cam0,
    const SE3& T_world_cam1, const SE3& M_world, int stride, const ObjectNoise& noise,
    std::mt19937_64* rng) {
  validateCamera(camera);
  if (stride < 1) throw std::invalid_argument("syntheticObjectCorrespondences: stride < 1");
  if (view0.depth.type() != CV_32FC1 || view0.instance.type() != CV_16UC1 ||
      view0.depth.size() != view0.instance.size() || view0.depth.cols != camera.width ||
      view0.depth.rows != camera.height)
    throw std::invalid_argument("syntheticObjectCorrespondences: view does not match the camera");
  const SE3 T_cam1_cam0 = T_world_cam1.inverse() * M_world * T_world_cam0;
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<ObjectCorrespondence> out;
  for (int y = 0; y < view0.depth.rows; y += stride) {
    for (int x = 0; x < view0.depth.cols; x += stride) {
      const float z = view0.depth.at<float>(y, x);
      if (view0.instance.at<uint16_t>(y, x) != object_id || !(z > 0)) continue;
      const Vec3 p0 = unproject(camera, Eigen::Vector2d(x, y), z);
      const Vec3 p1 = T_cam1_cam0 * p0;
      if (!(p1.z() > 1e-3)) continue;
      Eigen::Vector2d px1 = project(camera, p1);
      if (px1.x() < -0.5 || px1.y() < -0.5 || px1.x() > camera.width - 0.5 ||
          px1.y() > camera.height - 0.5)
        continue;
      ObjectCorrespondence c;
      const double z_noisy = z + noise.depth_sigma_rel * z * z * gauss(*rng);
      c.p_cam0 = p0 * (std::max(z_noisy, 1e-3) / z);
      c.px1 = px1 + noise.pixel_sigma * Eigen::Vector2d(gauss(*rng), gauss(*rng));
      if (noise.outlier_ratio > 0 && uniform(*rng) < noise.outlier_ratio) {
        const double angle = 2 * M_PI * uniform(*rng);
        c.px1 +=
            noise.outlier_px * uniform(*rng) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      }
      out.push_back(c);
    }
  }
  return out;
}

namespace {

SE3 objectPoseAt(const SyntheticScene& scene, int object_id, int frame) {
  for (const ObjectPoseSample& s : scene.objectPoses(frame))
    if (s.object_id == object_id) return s.T_world_object;
  throw std::invalid_argument("scene '" + scene.config().scene + "' has no object " +
                              std::to_string(object_id));
}

}  // namespace

SE3 syntheticObjectMotion(const SyntheticScene& scene, int object_id, int frame_a, int frame_b) {
  return objectPoseAt(scene, object_id, frame_b) *
         objectPoseAt(scene, object_id, frame_a).inverse();
}

ObjectWindowProblem syntheticObjectWindow(const SyntheticScene& scene, const Joint& joint,
                                          int object_id, int first, int frames, int stride,
                                          const ObjectNoise& noise, std::mt19937_64* rng) {
  if (frames < 2 || first < 0 || stride < 1)
    throw std::invalid_argument("syntheticObjectWindow: need frames >= 2, first >= 0, stride >= 1");
  ObjectWindowProblem p;
  p.joint = joint;
  p.camera = scene.camera();
  p.dt = 1.0 / scene.fps();
  for (int f = 0; f < frames; ++f) p.T_world_cam.push_back(scene.cameraPose(first + f));
  const RenderedView view0 = scene.render(p.T_world_cam[0], p.camera, first);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::vector<Vec3> truth;
  for (int y = 0; y < view0.depth.rows; y += stride) {
    for (int x = 0; x < view0.depth.cols; x += stride) {
      const float z = view0.depth.at<float>(y, x);
      if (view0.instance.at<uint16_t>(y, x) != object_id || !(z > 0)) continue;
      truth.push_back(unproject(p.camera, Eigen::Vector2d(x, y), z));
      const double z_noisy = std::max(z + noise.depth_sigma_rel * z * z * gauss(*rng), 1e-3);
      p.points_cam0.push_back(truth.back() * (z_noisy / z));
    }
  }
  for (int f = 1; f < frames; ++f) {
    const SE3 T_camf_cam0 = p.T_world_cam[f].inverse() *
                            syntheticObjectMotion(scene, object_id, first, first + f) *
                            p.T_world_cam[0];
    for (size_t l = 0; l < truth.size(); ++l) {
      const Vec3 pc = T_camf_cam0 * truth[l];
      if (!(pc.z() > 1e-3)) continue;
      Eigen::Vector2d px = project(p.camera, pc);
      if (px.x() < -0.5 || px.y() < -0.5 || px.x() > p.camera.width - 0.5 ||
          px.y() > p.camera.height - 0.5)
        continue;
      px += noise.pixel_sigma * Eigen::Vector2d(gauss(*rng), gauss(*rng));
      if (noise.outlier_ratio > 0 && uniform(*rng) < noise.outlier_ratio) {
        const double angle = 2 * M_PI * uniform(*rng);
        px += noise.outlier_px * uniform(*rng) * Eigen::Vector2d(std::cos(angle), std::sin(angle));
      }
      p.observations.push_back({static_cast<int>(l), f, px});
    }
  }
  return p;
}

SyntheticObject syntheticObject(const SyntheticScene& scene, int object_id) {
  for (const SyntheticObject& o : scene.objects())
    if (o.object_id == object_id) return o;
  throw std::invalid_argument("scene '" + scene.config().scene + "' has no object " +
                              std::to_string(object_id));
}

}  // namespace radslam
