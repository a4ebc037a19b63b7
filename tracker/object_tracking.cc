#include "tracker/object_tracking.h"

#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>

#include "common/camera.h"

namespace radslam {

namespace {

// The residual with the displacement E = Exp(A theta) and J_l(A theta) A precomputed: shared by
// all points of one linearisation.
bool residualAt(const CameraModel& camera, const SE3& T_cam1_joint, const SE3& E,
                const JointBasis& JlA, const Vec3& q_joint, const Eigen::Vector2d& px1,
                Eigen::Vector2d* r, JointJacobian* H_theta) {
  const Vec3 q1 = E * q_joint;  // the point after the displacement, joint frame
  const Vec3 p1 = T_cam1_joint * q1;
  if (!(p1.z() > 1e-6)) return false;
  Eigen::Matrix<double, 2, 3> H_p;
  *r = project(camera, p1, &H_p) - px1;
  if (H_theta) {
    // Exp(A (theta + d)) ~= Exp(J_l(A theta) A d) Exp(A theta), and
    // d(Exp(e) q1)/de = [I, -hat(q1)] for e = (v, w).
    const Eigen::Matrix<double, 2, 3> H_q = H_p * T_cam1_joint.rotation();
    *H_theta = H_q * (JlA.topRows<3>() - hat(q1) * JlA.bottomRows<3>());
  }
  return true;
}

}  // namespace

bool objectReprojectionResidual(const CameraModel& camera, const SE3& T_cam1_joint,
                                const Vec3& q_joint, const Eigen::Vector2d& px1,
                                const JointBasis& A, const JointVector& theta, Eigen::Vector2d* r,
                                JointJacobian* H_theta) {
  const Vec6 xi = A * theta;
  const JointBasis JlA = SE3::leftJacobian(xi) * A;
  return residualAt(camera, T_cam1_joint, SE3::exp(xi), JlA, q_joint, px1, r, H_theta);
}

namespace {

void checkInput(const Joint& joint, const CameraModel& camera, const SE3& T_world_cam0,
                const SE3& T_world_cam1, const std::vector<ObjectCorrespondence>& corr, double dt,
                const ObjectTrackingParams& params, const JointVector* initial) {
  validateCamera(camera);
  if (!(dt > 0)) throw std::invalid_argument("trackObjectMotion: dt must be > 0 s");
  if (static_cast<int>(corr.size()) < std::max(params.min_points, 1))
    throw std::invalid_argument("trackObjectMotion: " + std::to_string(corr.size()) +
                                " correspondences, need at least " +
                                std::to_string(params.min_points));
  if (!(params.huber_px > 0) || !(params.pixel_sigma > 0))
    throw std::invalid_argument("trackObjectMotion: huber_px and pixel_sigma must be > 0");
  if (!T_world_cam0.matrix().allFinite() || !T_world_cam1.matrix().allFinite())
    throw std::invalid_argument("trackObjectMotion: non-finite camera pose");
  for (const ObjectCorrespondence& c : corr)
    if (!c.p_cam0.allFinite() || !c.px1.allFinite())
      throw std::invalid_argument("trackObjectMotion: non-finite correspondence");
  if (initial && initial->size() != joint.dof())
    throw std::invalid_argument("trackObjectMotion: initial has " +
                                std::to_string(initial->size()) + " coordinates, joint has " +
                                std::to_string(joint.dof()));
}

}  // namespace

ObjectMotionEstimate trackObjectMotion(const Joint& joint, const CameraModel& camera,
                                       const SE3& T_world_cam0, const SE3& T_world_cam1,
                                       const std::vector<ObjectCorrespondence>& correspondences,
                                       double dt, const ObjectTrackingParams& params,
                                       const JointVector* initial) {
  checkInput(joint, camera, T_world_cam0, T_world_cam1, correspondences, dt, params, initial);
  const int k = joint.dof();
  const JointBasis& A = joint.basis();
  const SE3 T_joint_cam0 = joint.T_world_joint().inverse() * T_world_cam0;
  const SE3 T_cam1_joint = T_world_cam1.inverse() * joint.T_world_joint();
  std::vector<Vec3> q(correspondences.size());
  for (size_t i = 0; i < q.size(); ++i) q[i] = T_joint_cam0 * correspondences[i].p_cam0;

  ObjectMotionEstimate est;
  est.theta = initial ? *initial : JointVector(JointVector::Zero(k));
  JointMatrix H(k, k);
  JointVector g(k);
  // Builds the Huber-weighted normal equations at theta; returns the robust cost.
  auto linearise = [&](const JointVector& theta, int* inliers, double* inlier_sq) {
    H.setZero();
    g.setZero();
    double cost = 0;
    *inliers = 0;
    *inlier_sq = 0;
    Eigen::Vector2d r;
    JointJacobian J;
    for (size_t i = 0; i < q.size(); ++i) {
      if (!objectReprojectionResidual(camera, T_cam1_joint, q[i], correspondences[i].px1, A, theta,
                                      &r, &J))
        continue;
      const double e = r.norm();
      const double w = e <= params.huber_px ? 1.0 : params.huber_px / e;
      cost += e <= params.huber_px ? 0.5 * e * e : params.huber_px * (e - 0.5 * params.huber_px);
      if (e <= params.huber_px) {
        ++*inliers;
        *inlier_sq += e * e;
      }
      H.noalias() += w * J.transpose() * J;
      g.noalias() += w * J.transpose() * r;
    }
    return cost;
  };

  int inliers = 0;
  double inlier_sq = 0;
  double cost = linearise(est.theta, &inliers, &inlier_sq);
  for (est.iterations = 0; est.iterations < params.max_iterations;) {
    // Levenberg-style damping only when a plain Gauss-Newton step fails to lower the cost.
    double lambda = 0;
    bool improved = false;
    JointVector delta;
    for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
      JointMatrix Hd = H;
      Hd.diagonal() += JointVector::Constant(k, lambda) + 1e-12 * H.diagonal();
      delta = -Hd.ldlt().solve(g);
      if (!delta.allFinite()) break;
      int trial_inliers = 0;
      double trial_sq = 0;
      const JointMatrix H_saved = H;
      const JointVector g_saved = g;
      const double trial = linearise(est.theta + delta, &trial_inliers, &trial_sq);
      if (trial <= cost) {
        est.theta += delta;
        cost = trial;
        inliers = trial_inliers;
        inlier_sq = trial_sq;
        improved = true;
      } else {
        H = H_saved;
        g = g_saved;
        lambda = lambda == 0 ? 1e-4 * H.diagonal().maxCoeff() : 10 * lambda;
      }
    }
    ++est.iterations;
    if (!improved || delta.norm() < params.step_tolerance) {
      est.converged = true;
      break;
    }
  }

  est.motion_world = joint.motionWorld(est.theta);
  est.twist_joint = joint.twist(est.theta, dt);
  est.inliers = inliers;
  est.rms_px = inliers > 0 ? std::sqrt(inlier_sq / inliers) : 0;
  Eigen::LDLT<JointMatrix> ldlt(H);
  est.covariance = params.pixel_sigma * params.pixel_sigma *
                   ldlt.solve(JointMatrix(JointMatrix::Identity(k, k)));
  est.twist_covariance = A * est.covariance * A.transpose() / (dt * dt);
  return est;
}

SE3 initialObjectPose(const Joint& joint, const std::vector<Vec3>& points_world) {
  if (points_world.empty()) throw std::invalid_argument("initialObjectPose: no points");
  Vec3 centroid = Vec3::Zero();
  for (const Vec3& p : points_world) {
    if (!p.allFinite()) throw std::invalid_argument("initialObjectPose: non-finite point");
    centroid += p;
  }
  return SE3(joint.T_world_joint().so3(), centroid / static_cast<double>(points_world.size()));
}

void applyObjectMotion(const ObjectMotionEstimate& estimate, const Joint& joint,
                       TrackedObject* object) {
  object->T_world_object = estimate.motion_world * object->T_world_object;
  object->twist = estimate.twist_joint;
  object->covariance = estimate.twist_covariance;
  object->joint_type = joint.type();
  object->T_world_joint = joint.T_world_joint();
}

MotionError objectMotionError(const SE3& M_est_world, const SE3& M_gt_world,
                              const SE3& T_world_object) {
  const SE3 E = T_world_object.inverse() * M_gt_world.inverse() * M_est_world * T_world_object;
  MotionError err;
  err.translation = E.translation().norm();
  err.rotation = E.so3().log().norm();
  return err;
}

std::vector<ObjectCorrespondence> objectCorrespondencesFromFlow(const CameraModel& camera,
                                                                const cv::Mat& depth,
                                                                const cv::Mat& instance,
                                                                int object_id, const cv::Mat& flow,
                                                                int stride) {
  validateCamera(camera);
  if (depth.type() != CV_32FC1 || flow.type() != CV_32FC2 ||
      (instance.type() != CV_16UC1 && instance.type() != CV_32SC1))
    throw std::invalid_argument(
        "objectCorrespondencesFromFlow: need depth CV_32FC1, instance CV_16UC1 or CV_32SC1, flow "
        "CV_32FC2");
  if (depth.size() != instance.size() || depth.size() != flow.size() ||
      depth.cols != camera.width || depth.rows != camera.height)
    throw std::invalid_argument(
        "objectCorrespondencesFromFlow: image sizes differ from the camera");
  if (stride < 1) throw std::invalid_argument("objectCorrespondencesFromFlow: stride must be >= 1");
  std::vector<ObjectCorrespondence> out;
  for (int y = 0; y < depth.rows; y += stride) {
    for (int x = 0; x < depth.cols; x += stride) {
      const int id =
          instance.type() == CV_16UC1 ? instance.at<uint16_t>(y, x) : instance.at<int32_t>(y, x);
      const float z = depth.at<float>(y, x);
      if (id != object_id || !(z > 0) || !std::isfinite(z)) continue;
      const cv::Vec2f f = flow.at<cv::Vec2f>(y, x);
      const Eigen::Vector2d px1(x + f[0], y + f[1]);
      if (!px1.allFinite() || px1.x() < -0.5 || px1.y() < -0.5 || px1.x() > camera.width - 0.5 ||
          px1.y() > camera.height - 0.5)
        continue;
      out.push_back({unproject(camera, Eigen::Vector2d(x, y), z), px1});
    }
  }
  return out;
}

}  // namespace radslam
