#include "tracker/object_tracker.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/image_sampling.h"

namespace radslam {

std::vector<DynamicClass> parseDynamicClasses(const std::string& spec) {
  std::vector<DynamicClass> classes;
  std::set<int> seen;
  std::stringstream items(spec);
  std::string item;
  while (std::getline(items, item, ',')) {
    item.erase(0, item.find_first_not_of(" \t"));
    item.erase(item.find_last_not_of(" \t") + 1);
    if (item.empty()) continue;
    const std::string where = "dynamic class '" + item + "': ";
    std::vector<std::string> fields;
    std::stringstream parts(item);
    std::string field;
    while (std::getline(parts, field, ':')) fields.push_back(field);
    if (fields.size() < 2 || fields.size() > 3)
      throw std::invalid_argument(where + "expected ID:JOINT[:PARENT]");
    auto parseId = [&](const std::string& text, const char* what) {
      size_t used = 0;
      int id = 0;
      try {
        id = std::stoi(text, &used);
      } catch (const std::exception&) {
        used = 0;
      }
      if (used != text.size() || used == 0 || id < 1 || id > 65535)
        throw std::invalid_argument(where + what + " must be an integer in 1..65535");
      return id;
    };
    DynamicClass dc;
    dc.class_id = parseId(fields[0], "the class id");
    if (fields[1] == "free") {
      dc.joint = JointType::kFree;
    } else if (fields[1] == "planar") {
      dc.joint = JointType::kPlanar;
    } else if (fields[1] == "revolute") {
      dc.joint = JointType::kRevolute;
    } else {
      throw std::invalid_argument(where + "joint must be free, planar or revolute");
    }
    if (fields.size() == 3) dc.parent_class = parseId(fields[2], "the parent class id");
    if (dc.joint == JointType::kPlanar && dc.parent_class < 0)
      throw std::invalid_argument(where + "a planar joint needs the parent class whose plane");
    if (dc.parent_class == dc.class_id)
      throw std::invalid_argument(where + "a class cannot be its own parent");
    if (!seen.insert(dc.class_id).second) throw std::invalid_argument(where + "class listed twice");
    classes.push_back(dc);
  }
  for (const DynamicClass& dc : classes) {
    if (dc.parent_class >= 0 && seen.count(dc.parent_class))
      throw std::invalid_argument("dynamic class " + std::to_string(dc.class_id) +
                                  ": its parent class " + std::to_string(dc.parent_class) +
                                  " is dynamic; parents are static");
  }
  return classes;
}

namespace {

void checkMask(const cv::Mat& mask, const char* name, const CameraModel& camera) {
  if (mask.empty()) return;
  if (mask.type() != CV_16UC1 || mask.cols != camera.width || mask.rows != camera.height) {
    throw std::invalid_argument(std::string("object tracker: ") + name +
                                " mask must be CV_16UC1 of the working size " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
}

Vec3 centroidOf(const std::vector<Vec3>& points) {
  Vec3 sum = Vec3::Zero();
  for (const Vec3& p : points) sum += p;
  return sum / static_cast<double>(points.size());
}

}  // namespace

ObjectTracker::ObjectTracker(ObjectTrackerParams params, const CameraModel& camera,
                             const FlowOptions& flow_options)
    : params_(std::move(params)), camera_(camera), flow_([&] {
        FlowOptions f = flow_options;
        f.warp_smoothing_px = params_.flow_warp_smoothing_px;
        return f;
      }()) {
  validateCamera(camera_);
  if (params_.stride < 1 || params_.min_points < params_.tracking.min_points ||
      !(params_.max_depth_m > 0) || params_.hinge_min_motions < 2 ||
      !(params_.hinge_min_angle > 0) ||
      !(params_.flat_fraction > 0 && params_.flat_fraction <= 1) || !(params_.static_speed >= 0) ||
      !(params_.static_angular_speed >= 0) || params_.static_frames < 1 ||
      params_.mask_dilation_px < 0 || params_.window_frames < 1 || params_.window_points < 1) {
    throw std::invalid_argument(
        "object tracker: need stride >= 1, min_points >= tracking.min_points, max_depth_m > 0, "
        "hinge_min_motions >= 2, hinge_min_angle > 0, flat_fraction in (0, 1], static speeds >= 0, "
        "static_frames >= 1, mask_dilation_px >= 0, window_frames >= 1, window_points >= 1");
  }
}

const DynamicClass* ObjectTracker::dynamicClass(int class_id) const {
  for (const DynamicClass& dc : params_.classes)
    if (dc.class_id == class_id) return &dc;
  return nullptr;
}

std::map<int, ObjectTracker::InstanceInfo> ObjectTracker::dynamicInstances(
    const cv::Mat& instance, const cv::Mat& class_id) const {
  std::map<int, InstanceInfo> out;
  if (instance.empty() || class_id.empty()) return out;
  for (int y = 0; y < instance.rows; ++y) {
    const uint16_t* ids = instance.ptr<uint16_t>(y);
    const uint16_t* cls = class_id.ptr<uint16_t>(y);
    for (int x = 0; x < instance.cols; ++x) {
      if (ids[x] == 0 || !dynamicClass(cls[x])) continue;
      InstanceInfo& info = out[ids[x]];
      info.class_id = cls[x];
      ++info.pixels;
    }
  }
  return out;
}

cv::Mat ObjectTracker::movingMask(const cv::Mat& instance, const cv::Mat& class_id) const {
  checkMask(instance, "instance", camera_);
  checkMask(class_id, "class", camera_);
  if (class_id.empty() || params_.classes.empty()) return {};
  cv::Mat mask(class_id.size(), CV_8UC1, cv::Scalar(0));
  bool any = false;
  for (int y = 0; y < class_id.rows; ++y) {
    const uint16_t* cls = class_id.ptr<uint16_t>(y);
    const uint16_t* ids = instance.empty() ? nullptr : instance.ptr<uint16_t>(y);
    uint8_t* m = mask.ptr<uint8_t>(y);
    for (int x = 0; x < class_id.cols; ++x) {
      if (!dynamicClass(cls[x])) continue;
      if (ids) {
        // Without an instance id a pixel of a dynamic class cannot be proven still.
        const auto it = objects_.find(ids[x]);
        if (ids[x] != 0 && it != objects_.end() && it->second.is_static) continue;
      }
      m[x] = 255;
      any = true;
    }
  }
  if (!any) return {};
  if (params_.mask_dilation_px > 0) {
    const int k = 2 * params_.mask_dilation_px + 1;
    cv::dilate(mask, mask, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(k, k)));
  }
  return mask;
}

std::vector<Vec3> ObjectTracker::objectPoints(const ObjectFrame& frame, int instance_id) const {
  std::vector<Vec3> points;
  for (int y = 0; y < frame.depth.rows; y += params_.stride) {
    for (int x = 0; x < frame.depth.cols; x += params_.stride) {
      const float z = frame.depth.at<float>(y, x);
      if (frame.instance.at<uint16_t>(y, x) != instance_id || !(z > 0) || z > params_.max_depth_m)
        continue;
      points.push_back(frame.T_world_cam * unproject(camera_, Eigen::Vector2d(x, y), z));
    }
  }
  return points;
}

bool ObjectTracker::flatPlane(const std::vector<Vec3>& points_world, Plane* plane) const {
  try {
    const PlaneFit fit = fitPlaneRansac(points_world, params_.plane);
    if (fit.inliers.size() < params_.flat_fraction * points_world.size()) return false;
    *plane = fit.plane;
    return true;
  } catch (const std::invalid_argument&) {
    return false;  // too few points
  }
}

bool ObjectTracker::estimateJoint(const DynamicClass& dc, const ObjectFrame& frame,
                                  const std::vector<Vec3>& points_world, Joint* joint) const {
  const Vec3 centroid = centroidOf(points_world);
  *joint = Joint(JointType::kFree, SE3(SO3(), centroid));
  if (dc.joint == JointType::kFree) return true;
  if (dc.joint == JointType::kRevolute) return false;  // the hinge comes from the motion
  // Planar: the parent plane by RANSAC on the parent class's pixels of this frame.
  std::vector<Vec3> parent;
  const int step = 2 * params_.stride;
  for (int y = 0; y < frame.depth.rows; y += step) {
    for (int x = 0; x < frame.depth.cols; x += step) {
      const float z = frame.depth.at<float>(y, x);
      if (frame.class_id.at<uint16_t>(y, x) != dc.parent_class || !(z > 0) ||
          z > params_.max_depth_m)
        continue;
      parent.push_back(frame.T_world_cam * unproject(camera_, Eigen::Vector2d(x, y), z));
    }
  }
  if (static_cast<int>(parent.size()) < std::max(3, params_.plane.min_inliers)) return false;
  try {
    const PlaneFit fit = fitPlaneRansac(parent, params_.plane);
    // Up = against the camera's y axis (image down): the plane normal points away from the
    // ground side, so that the joint frame does not flip between objects.
    const Vec3 up = -(frame.T_world_cam.rotation() * Vec3::UnitY());
    *joint = Joint(JointType::kPlanar, planeJointFrame(fit.plane, centroid, up));
    return true;
  } catch (const std::invalid_argument&) {
    return false;
  }
}

void ObjectTracker::ObjectState::resetWindow() {
  window_T_world_cam.clear();
  window_utime.clear();
  window_theta.clear();
  window_points.clear();
}

void ObjectTracker::refineInWindow(ObjectState* state, const ObjectFrame& frame,
                                   const std::vector<ObjectCorrespondence>& correspondences,
                                   const cv::Mat& flow, ObjectMotionEstimate* estimate) const {
  ObjectState& s = *state;
  // A frame the object was not tracked in breaks the window.
  if (!s.window_utime.empty() && s.window_utime.back() != previous_.header.utime) s.resetWindow();
  if (s.window_T_world_cam.empty()) {
    s.window_T_world_cam.push_back(previous_.T_world_cam);
    s.window_utime.push_back(previous_.header.utime);
  }
  // Points measured before follow the flow while they stay on the object.
  const int id = s.object.object_id;
  for (ObjectState::WindowPoint& w : s.window_points) {
    if (!w.alive) continue;
    const Eigen::Vector2d& last = w.px.back();
    // Bilinear in the flow.
    const int x0 = static_cast<int>(std::floor(last.x())),
              y0 = static_cast<int>(std::floor(last.y()));
    w.alive = x0 >= 0 && y0 >= 0 && x0 + 1 < flow.cols && y0 + 1 < flow.rows;
    if (!w.alive) continue;
    const cv::Vec2f f = bilinearAt<cv::Vec2f>(flow, x0, y0, static_cast<float>(last.x() - x0),
                                              static_cast<float>(last.y() - y0));
    const Eigen::Vector2d next = last + Eigen::Vector2d(f[0], f[1]);
    const int xn = static_cast<int>(std::lround(next.x()));
    const int yn = static_cast<int>(std::lround(next.y()));
    w.alive = next.allFinite() && xn >= 0 && yn >= 0 && xn < camera_.width && yn < camera_.height &&
              frame.instance.at<uint16_t>(yn, xn) == id;
    if (w.alive) w.px.push_back(next);
  }
  s.window_T_world_cam.push_back(frame.T_world_cam);
  s.window_utime.push_back(frame.header.utime);
  s.window_theta.push_back(estimate->theta);
  const int anchor = static_cast<int>(s.window_T_world_cam.size()) - 2;
  const size_t step =
      std::max<size_t>(1, correspondences.size() / std::max(1, params_.window_points));
  for (size_t i = 0; i < correspondences.size(); i += step)
    s.window_points.push_back({anchor, correspondences[i].p_cam0, {correspondences[i].px1}, true});
  // Slide: the oldest frame leaves with the points measured in it.
  while (static_cast<int>(s.window_T_world_cam.size()) > params_.window_frames) {
    s.window_T_world_cam.erase(s.window_T_world_cam.begin());
    s.window_utime.erase(s.window_utime.begin());
    s.window_theta.erase(s.window_theta.begin());
    std::vector<ObjectState::WindowPoint> kept;
    for (ObjectState::WindowPoint& w : s.window_points) {
      if (w.anchor == 0) continue;
      --w.anchor;
      kept.push_back(std::move(w));
    }
    s.window_points = std::move(kept);
  }
  ObjectWindowProblem problem;
  problem.joint = s.joint;
  problem.camera = camera_;
  problem.T_world_cam = s.window_T_world_cam;
  const int n = static_cast<int>(problem.T_world_cam.size());
  problem.dt = (s.window_utime.back() - s.window_utime.front()) * 1e-6 / (n - 1);
  for (const ObjectState::WindowPoint& w : s.window_points) {
    const int landmark = static_cast<int>(problem.points_cam0.size());
    problem.points_cam0.push_back(w.p_anchor);
    problem.anchor_frame.push_back(w.anchor);
    for (size_t j = 0; j < w.px.size(); ++j)
      problem.observations.push_back({landmark, w.anchor + 1 + static_cast<int>(j), w.px[j]});
  }
  ObjectWindowResult r;
  try {
    r = solveObjectWindow(problem, params_.window, &s.window_theta);
  } catch (const std::invalid_argument&) {
    return;  // degenerate window (e.g. time stamps out of order): the frame-to-frame estimate
  }
  const int k = s.joint.dof();
  s.window_theta = r.theta;
  estimate->theta = r.theta.back();
  estimate->motion_world = r.motion_world.back();
  estimate->twist_joint = r.twist_joint.back();
  estimate->covariance = r.covariance.bottomRightCorner(k, k);
  estimate->twist_covariance = r.twist_covariance.back();
}

void ObjectTracker::updateObject(ObjectState* state, const DynamicClass& dc,
                                 const ObjectFrame& frame,
                                 const std::vector<ObjectCorrespondence>& correspondences,
                                 const cv::Mat& flow, double dt) {
  const JointVector* initial =
      state->last_theta.size() == state->joint.dof() ? &state->last_theta : nullptr;
  ObjectMotionEstimate est =
      trackObjectMotion(state->joint, camera_, previous_.T_world_cam, frame.T_world_cam,
                        correspondences, dt, params_.tracking, initial);
  if (params_.window_frames > 1) refineInWindow(state, frame, correspondences, flow, &est);
  applyObjectMotion(est, state->joint, &state->object);
  state->last_motion_world = est.motion_world;
  state->last_dt = dt;
  state->last_theta = est.theta;
  if (dc.joint == JointType::kRevolute && !state->joint_final) {
    // Free-tracked motions since the first frame give the hinge once they turn enough.
    state->motions.push_back(state->object.T_world_object * state->T_world_object_first.inverse());
    if (static_cast<int>(state->motions.size()) >= params_.hinge_min_motions) {
      // A flat object's hinge comes from its planes once they have turned enough; where this
      // frame's points are not flat (noisy stereo depth), from the motions.
      std::vector<Vec3> points;
      if (!state->first_plane.normal.isZero())
        points = objectPoints(frame, state->object.object_id);
      Plane plane;
      try {
        const Hinge hinge = !points.empty() && flatPlane(points, &plane)
                                ? hingeFromPlanes(state->first_plane, plane, centroidOf(points),
                                                  params_.hinge_min_angle)
                                : hingeFromMotions(state->motions, params_.hinge_min_angle);
        state->joint = Joint(JointType::kRevolute, hingeJointFrame(hinge));
        state->joint_final = true;
        state->last_theta = JointVector();
        state->resetWindow();  // its displacements are in the free joint's coordinates
      } catch (const std::invalid_argument&) {
        // Not enough rotation yet.
      }
    }
  }
  const Vec6& xi = state->object.twist;
  const bool still = xi.head<3>().norm() < params_.static_speed &&
                     xi.tail<3>().norm() < params_.static_angular_speed;
  state->still_frames = still ? state->still_frames + 1 : 0;
  state->is_static = state->still_frames >= params_.static_frames;
}

cv::Mat ObjectTracker::flowPrediction(const ObjectFrame& frame, double dt) const {
  const cv::Mat& depth = previous_.depth;
  cv::Mat flow(depth.size(), CV_32FC2);
  std::vector<float> fx, fy;
  const SE3 T_cam_world = frame.T_world_cam.inverse();
  constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 0; y < depth.rows; ++y) {
    const float* z = depth.ptr<float>(y);
    const uint16_t* ids = previous_.instance.ptr<uint16_t>(y);
    cv::Vec2f* f = flow.ptr<cv::Vec2f>(y);
    for (int x = 0; x < depth.cols; ++x) {
      f[x] = cv::Vec2f(kNan, kNan);
      if (!(z[x] > 0)) continue;
      Vec3 p = previous_.T_world_cam * unproject(camera_, Eigen::Vector2d(x, y), z[x]);
      const auto it = objects_.find(ids[x]);
      if (it != objects_.end() && it->second.last_dt > 0) {
        // Constant velocity: the last motion scaled to this frame's interval.
        const ObjectState& s = it->second;
        p = SE3::exp(dt / s.last_dt * s.last_motion_world.log()) * p;
      }
      const Vec3 q = T_cam_world * p;
      if (!(q.z() > 1e-6)) continue;
      const Eigen::Vector2d px = project(camera_, q);
      f[x] = cv::Vec2f(static_cast<float>(px.x() - x), static_cast<float>(px.y() - y));
      fx.push_back(f[x][0]);
      fy.push_back(f[x][1]);
    }
  }
  // Pixels without depth take the median flow (the warp smooths the field anyway).
  auto median = [](std::vector<float>& v) {
    if (v.empty()) return 0.f;
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  const cv::Vec2f fill(median(fx), median(fy));
  for (int y = 0; y < flow.rows; ++y) {
    cv::Vec2f* f = flow.ptr<cv::Vec2f>(y);
    for (int x = 0; x < flow.cols; ++x) {
      if (!std::isfinite(f[x][0])) f[x] = fill;
    }
  }
  return flow;
}

ObjectList ObjectTracker::track(const ObjectFrame& frame) {
  checkMask(frame.instance, "instance", camera_);
  checkMask(frame.class_id, "class", camera_);
  if (frame.grey.type() != CV_8UC1 || frame.grey.cols != camera_.width ||
      frame.grey.rows != camera_.height)
    throw std::invalid_argument("object tracker: grey image must be CV_8UC1 of the working size");
  if (!frame.depth.empty() &&
      (frame.depth.type() != CV_32FC1 || frame.depth.size() != frame.grey.size()))
    throw std::invalid_argument("object tracker: depth must be CV_32FC1 of the working size");

  ObjectList out;
  out.header = frame.header;
  out.frame_index = frame.frame_index;
  const bool usable = !frame.depth.empty() && !frame.instance.empty() && !frame.class_id.empty();
  if (!usable || params_.classes.empty()) {
    has_previous_ = false;
    return out;
  }
  const std::map<int, InstanceInfo> now = dynamicInstances(frame.instance, frame.class_id);
  const double dt = has_previous_ ? (frame.header.utime - previous_.header.utime) * 1e-6 : 0;

  cv::Mat flow;
  const int min_pixels = params_.min_points * params_.stride * params_.stride;
  for (const auto& [id, info] : now) {
    if (info.pixels < min_pixels) continue;
    const DynamicClass& dc = *dynamicClass(info.class_id);
    auto it = objects_.find(id);
    if (it != objects_.end() && has_previous_ && dt > 0) {
      // Seen in the previous frame too: its displacement from the flow of its points.
      if (flow.empty()) {
        // Warped by the predicted flow: the flow of a turning door or a near car varies fast
        // across the object, and started coarse DIS measures it short.
        flow =
            flow_.compute(previous_.grey, frame.grey, flowPrediction(frame, dt), WarmStart::kWarp);
      }
      std::vector<ObjectCorrespondence> c = objectCorrespondencesFromFlow(
          camera_, previous_.depth, previous_.instance, id, flow, params_.stride);
      // Points whose flow lands off the object (occlusion, flow bleeding over the silhouette)
      // would pull it towards the background; far points are too noisy.
      const int instance_id = id;  // (a structured binding cannot be captured in C++17)
      c.erase(std::remove_if(c.begin(), c.end(),
                             [&](const ObjectCorrespondence& m) {
                               if (m.p_cam0.z() > params_.max_depth_m) return true;
                               const int x = static_cast<int>(std::lround(m.px1.x()));
                               const int y = static_cast<int>(std::lround(m.px1.y()));
                               return x < 0 || y < 0 || x >= camera_.width || y >= camera_.height ||
                                      frame.instance.at<uint16_t>(y, x) != instance_id;
                             }),
              c.end());
      if (static_cast<int>(c.size()) >= params_.min_points) {
        ObjectState& state = it->second;
        if (!state.joint_final && dc.joint == JointType::kPlanar) {
          Joint planar;
          const std::vector<Vec3> points = objectPoints(previous_, id);
          if (!points.empty() && estimateJoint(dc, previous_, points, &planar)) {
            state.joint = planar;
            state.joint_final = true;
            state.last_theta = JointVector();
            state.resetWindow();
          }
        }
        try {
          updateObject(&state, dc, frame, c, flow, dt);
          out.objects.push_back(state.object);
        } catch (const std::invalid_argument&) {
          // Degenerate points (e.g. all behind the camera): the object is not seen this frame.
        }
        continue;
      }
    }
    if (it != objects_.end()) continue;  // known, but too few points this frame
    // A new object: its joint and pose from this frame's depth.
    const std::vector<Vec3> points = objectPoints(frame, id);
    if (static_cast<int>(points.size()) < params_.min_points) continue;
    ObjectState state;
    state.joint_final = estimateJoint(dc, frame, points, &state.joint);
    state.object.object_id = id;
    state.object.class_id = info.class_id;
    state.object.T_world_object = initialObjectPose(state.joint, points);
    state.object.joint_type = state.joint.type();
    state.object.T_world_joint = state.joint.T_world_joint();
    state.object.parent_cluster = dc.parent_class;
    state.object.covariance = Mat6::Identity() * 1e6;  // no velocity measured yet
    state.T_world_object_first = state.object.T_world_object;
    if (dc.joint == JointType::kRevolute) flatPlane(points, &state.first_plane);
    out.objects.push_back(state.object);
    objects_.emplace(id, std::move(state));
  }
  previous_ = frame;
  previous_.grey = frame.grey.clone();
  has_previous_ = true;
  return out;
}

namespace {

void putJointVector(BinaryWriter* w, const JointVector& theta) {
  w->put<int32_t>(static_cast<int32_t>(theta.size()));
  for (int i = 0; i < theta.size(); ++i) w->put(theta[i]);
}

JointVector getJointVector(BinaryReader* r) {
  const int n = r->get<int32_t>();
  if (n < 0 || n > 6) r->fail("bad joint coordinates");
  JointVector theta(n);
  for (int i = 0; i < n; ++i) theta[i] = r->get<double>();
  return theta;
}

JointType getJointType(BinaryReader* r) {
  const int8_t type = r->get<int8_t>();
  if (type < 0 || type > static_cast<int8_t>(JointType::kRevolute)) r->fail("bad joint type");
  return static_cast<JointType>(type);
}

}  // namespace

void ObjectTracker::save(BinaryWriter* out) const {
  BinaryWriter& w = *out;
  w.put<uint32_t>(objects_.size());
  for (const auto& [instance, state] : objects_) {
    w.put<int32_t>(instance);
    const TrackedObject& o = state.object;
    w.put(o.object_id);
    w.put(o.class_id);
    w.str(o.class_name);
    w.se3(o.T_world_object);
    w.matrix(o.twist);
    w.put(o.joint_type);
    w.se3(o.T_world_joint);
    w.put(o.parent_cluster);
    w.matrix(o.covariance);
    w.put(state.joint.type());
    w.se3(state.joint.T_world_joint());
    w.put<uint8_t>(state.joint_final);
    w.se3(state.T_world_object_first);
    w.matrix(state.first_plane.normal);
    w.put(state.first_plane.d);
    w.put<uint32_t>(state.motions.size());
    for (const SE3& M : state.motions) w.se3(M);
    putJointVector(&w, state.last_theta);
    w.se3(state.last_motion_world);
    w.put(state.last_dt);
    w.put<int32_t>(state.still_frames);
    w.put<uint8_t>(state.is_static);
    w.put<uint32_t>(state.window_T_world_cam.size());
    for (size_t f = 0; f < state.window_T_world_cam.size(); ++f) {
      w.se3(state.window_T_world_cam[f]);
      w.put<int64_t>(state.window_utime[f]);
    }
    w.put<uint32_t>(state.window_theta.size());
    for (const JointVector& theta : state.window_theta) putJointVector(&w, theta);
    w.put<uint32_t>(state.window_points.size());
    for (const ObjectState::WindowPoint& point : state.window_points) {
      w.put<int32_t>(point.anchor);
      w.matrix(point.p_anchor);
      w.put<uint32_t>(point.px.size());
      for (const Eigen::Vector2d& px : point.px) w.matrix(px);
      w.put<uint8_t>(point.alive);
    }
  }
  w.put<uint8_t>(has_previous_);
  w.header(previous_.header);
  w.put<int64_t>(previous_.frame_index);
  for (const cv::Mat* m :
       {&previous_.grey, &previous_.depth, &previous_.instance, &previous_.class_id})
    w.mat(*m);
  w.se3(previous_.T_world_cam);
}

void ObjectTracker::load(BinaryReader* in) {
  BinaryReader& r = *in;
  std::map<int, ObjectState> objects;
  const uint32_t count = r.count(64);
  for (uint32_t i = 0; i < count; ++i) {
    const int instance = r.get<int32_t>();
    ObjectState& state = objects[instance];
    TrackedObject& o = state.object;
    o.object_id = r.get<int32_t>();
    o.class_id = r.get<int32_t>();
    o.class_name = r.str();
    o.T_world_object = r.se3();
    r.matrix(&o.twist);
    o.joint_type = getJointType(&r);
    o.T_world_joint = r.se3();
    o.parent_cluster = r.get<int32_t>();
    r.matrix(&o.covariance);
    const JointType joint_type = getJointType(&r);
    state.joint = Joint(joint_type, r.se3());
    state.joint_final = r.get<uint8_t>() != 0;
    state.T_world_object_first = r.se3();
    r.matrix(&state.first_plane.normal);
    state.first_plane.d = r.get<double>();
    state.motions.resize(r.count(56));
    for (SE3& M : state.motions) M = r.se3();
    state.last_theta = getJointVector(&r);
    state.last_motion_world = r.se3();
    state.last_dt = r.get<double>();
    state.still_frames = r.get<int32_t>();
    state.is_static = r.get<uint8_t>() != 0;
    const uint32_t frames = r.count(64);
    for (uint32_t f = 0; f < frames; ++f) {
      state.window_T_world_cam.push_back(r.se3());
      state.window_utime.push_back(r.get<int64_t>());
    }
    state.window_theta.resize(r.count(4));
    for (JointVector& theta : state.window_theta) theta = getJointVector(&r);
    state.window_points.resize(r.count(33));
    for (ObjectState::WindowPoint& point : state.window_points) {
      point.anchor = r.get<int32_t>();
      r.matrix(&point.p_anchor);
      point.px.resize(r.count(16));
      for (Eigen::Vector2d& px : point.px) r.matrix(&px);
      point.alive = r.get<uint8_t>() != 0;
      if (point.anchor < 0 || point.anchor + point.px.size() >= frames)
        r.fail("object tracker: window point outside its window");
    }
    if (frames > 0 && state.window_theta.size() + 1 != frames)
      r.fail("object tracker: window of " + std::to_string(frames) + " frames with " +
             std::to_string(state.window_theta.size()) + " displacements");
  }
  ObjectFrame previous;
  const bool has_previous = r.get<uint8_t>() != 0;
  previous.header = r.header();
  previous.frame_index = r.get<int64_t>();
  for (cv::Mat* m : {&previous.grey, &previous.depth, &previous.instance, &previous.class_id})
    *m = r.mat();
  previous.T_world_cam = r.se3();
  const cv::Size size(camera_.width, camera_.height);
  const auto fits = [&](const cv::Mat& m, int type) {
    return m.empty() || (m.size() == size && m.type() == type);
  };
  if (!fits(previous.grey, CV_8UC1) || !fits(previous.depth, CV_32FC1) ||
      !fits(previous.instance, CV_16UC1) || !fits(previous.class_id, CV_16UC1) ||
      (has_previous && previous.grey.empty()))
    r.fail("object tracker: previous frame's images of a wrong size or type");
  objects_ = std::move(objects);
  has_previous_ = has_previous;
  previous_ = std::move(previous);
}

}  // namespace radslam
