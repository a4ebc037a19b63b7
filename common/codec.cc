// Whole messages between the plain structs and the lcm-gen types.
#include "common/codec.h"

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include <radslam/camera_t.hpp>
#include <radslam/control_t.hpp>
#include <radslam/field_block_t.hpp>
#include <radslam/field_update_t.hpp>
#include <radslam/frame_t.hpp>
#include <radslam/header_t.hpp>
#include <radslam/image_t.hpp>
#include <radslam/keyframe_t.hpp>
#include <radslam/object_t.hpp>
#include <radslam/objects_t.hpp>
#include <radslam/pose_stamped_t.hpp>
#include <radslam/pose_t.hpp>
#include <radslam/render_request_t.hpp>
#include <radslam/render_t.hpp>
#include <radslam/status_t.hpp>

namespace radslam {
namespace codec {
namespace {

bool fail(std::string* error, const std::string& message) {
  *error = message;
  return false;
}

void covarianceToLcm(const Mat6& cov, double* out) {
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) out[6 * r + c] = cov(r, c);  // row-major
  }
}

bool covarianceFromLcm(const double* in, const std::string& name, Mat6* out, std::string* error) {
  for (int i = 0; i < 36; ++i) {
    if (!std::isfinite(in[i])) return fail(error, name + ": covariance is not finite");
  }
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) (*out)(r, c) = in[6 * r + c];
  }
  return true;
}

// LCM strings are NUL-terminated on the wire: one holding a NUL decodes, but
// cannot be encoded again (a process echoing it, as the renderer echoes a
// request's client, would fail to publish).
bool checkText(const std::string& text, const std::string& name, std::string* error) {
  if (text.find('\0') != std::string::npos) return fail(error, name + " contains a NUL byte");
  return true;
}

bool checkHeader(const header_t& in, std::string* error) {
  return checkText(in.sender, "header.sender", error);
}

// Depths consumers use as numbers (0 or negative = invalid): a NaN or infinity
// would spread through every estimate computed from them. Variances may be +inf
// (the tracker's "unknown"), never NaN or -inf.
enum class FloatRule { kFinite, kVariance };
bool checkFloatImage(const cv::Mat& image, FloatRule rule, const std::string& name,
                     std::string* error) {
  if (image.empty() || image.type() != CV_32FC1) return true;
  for (int r = 0; r < image.rows; ++r) {
    const float* row = image.ptr<float>(r);
    for (int c = 0; c < image.cols; ++c) {
      const float v = row[c];
      if (std::isfinite(v) || (rule == FloatRule::kVariance && v > 0)) continue;
      return fail(error, name + ": pixel (" + std::to_string(c) + ", " + std::to_string(r) +
                             ") is " + std::to_string(v) +
                             (rule == FloatRule::kVariance ? " (finite or +inf expected)"
                                                           : " (finite expected)"));
    }
  }
  return true;
}

int32_t checkedCount(size_t n, const std::string& name) {
  if (n > static_cast<size_t>(INT32_MAX)) {
    throw std::invalid_argument(name + ": " + std::to_string(n) + " elements do not fit a message");
  }
  return static_cast<int32_t>(n);
}

std::string sizeText(const cv::Mat& m) {
  return std::to_string(m.cols) + "x" + std::to_string(m.rows);
}

// Sender side: images of one message share a size and a type.
void requireType(const cv::Mat& m, int type, const std::string& name) {
  if (!m.empty() && m.type() != type) {
    throw std::invalid_argument(name + " must be " + cv::typeToString(type) + ", not " +
                                cv::typeToString(m.type()));
  }
}

void requireSameSize(const cv::Mat& ref, const std::string& ref_name, const cv::Mat& m,
                     const std::string& name) {
  if (!ref.empty() && !m.empty() && ref.size() != m.size()) {
    throw std::invalid_argument(name + " is " + sizeText(m) + " but " + ref_name + " is " +
                                sizeText(ref));
  }
}

// Receiver side: every non-empty image of a message has the size of the first
// non-empty one, and the camera (when it states a size) agrees, so consumers can
// index one with another's pixel coordinates.
bool checkSameSize(const std::vector<std::pair<const cv::Mat*, const char*>>& images,
                   const CameraModel* camera, std::string* error) {
  const cv::Mat* ref = nullptr;
  const char* ref_name = nullptr;
  for (const auto& [image, name] : images) {
    if (image->empty()) continue;
    if (!ref) {
      ref = image;
      ref_name = name;
    } else if (image->size() != ref->size()) {
      return fail(error, std::string(name) + " is " + sizeText(*image) + " but " + ref_name +
                             " is " + sizeText(*ref));
    }
  }
  if (ref && camera && camera->width > 0 &&
      (camera->width != ref->cols || camera->height != ref->rows)) {
    return fail(error, "camera is " + std::to_string(camera->width) + "x" +
                           std::to_string(camera->height) + " but " + ref_name + " is " +
                           sizeText(*ref));
  }
  return true;
}

WireCompression compressionOf(const image_t& image) {
  if (image.width == 0) return WireCompression::kRaw;
  return static_cast<WireCompression>(image.compression);
}

}  // namespace

// ---- Frame ----------------------------------------------------------------

void toLcm(const Frame& msg, frame_t* out) {
  if (!msg.color.empty() && !msg.right.empty() && msg.color.type() != msg.right.type()) {
    throw std::invalid_argument("Frame.right must have the type of Frame.color");
  }
  requireSameSize(msg.color, "Frame.color", msg.right, "Frame.right");
  requireType(msg.depth, CV_32FC1, "Frame.depth");
  requireSameSize(msg.color, "Frame.color", msg.depth, "Frame.depth");
  requireType(msg.instance, CV_16UC1, "Frame.instance");
  requireSameSize(msg.color, "Frame.color", msg.instance, "Frame.instance");
  requireType(msg.class_id, CV_16UC1, "Frame.class_id");
  requireSameSize(msg.color, "Frame.color", msg.class_id, "Frame.class_id");
  if (!std::isfinite(msg.depth_wire_scale) || msg.depth_wire_scale < 0) {
    throw std::invalid_argument("Frame.depth_wire_scale must be finite and >= 0");
  }
  if (!(std::abs(msg.depth_time_offset_s) < 1)) {
    throw std::invalid_argument("Frame.depth_time_offset_s must be below 1 s in magnitude");
  }
  headerToLcm(msg.header, &out->header);
  out->frame_index = msg.frame_index;
  cameraToLcm(msg.camera, &out->camera);
  imageToLcm(msg.color, msg.color_compression, 0.0f, "Frame.color", &out->color);
  imageToLcm(msg.right, msg.color_compression, 0.0f, "Frame.right", &out->right);
  out->baseline_m = msg.baseline_m;
  out->depth_time_offset_s = msg.depth_time_offset_s;
  const float depth_scale = static_cast<float>(msg.depth_wire_scale);
  if (msg.depth.empty()) {
    imageToLcm(cv::Mat(), WireCompression::kRaw, 0.0f, "Frame.depth", &out->depth);
  } else if (msg.depth_wire_scale > 0) {
    if (!(depth_scale > 0)) throw std::invalid_argument("Frame.depth_wire_scale underflows float");
    // Depth is never JPEG: lossless PNG unless the sender chose raw images.
    const WireCompression depth_compression = msg.color_compression == WireCompression::kRaw
                                                  ? WireCompression::kRaw
                                                  : WireCompression::kPng;
    imageToLcm(quantizeDepth(msg.depth, depth_scale), depth_compression, depth_scale, "Frame.depth",
               &out->depth);
  } else {
    imageToLcm(msg.depth, WireCompression::kRaw, 0.0f, "Frame.depth", &out->depth);
  }
  imageToLcm(msg.instance, WireCompression::kPng, 0.0f, "Frame.instance", &out->instance);
  imageToLcm(msg.class_id, WireCompression::kPng, 0.0f, "Frame.class_id", &out->class_id);
}

bool fromLcm(const frame_t& in, Frame* out, std::string* error) {
  Frame f;
  if (!checkHeader(in.header, error)) return false;
  headerFromLcm(in.header, &f.header);
  f.frame_index = in.frame_index;
  if (!cameraFromLcm(in.camera, "camera", &f.camera, error)) return false;
  if (!imageFromLcm(in.color, "color", kAllowGrey8 | kAllowRgb8, &f.color, error)) return false;
  if (!imageFromLcm(in.right, "right", kAllowGrey8 | kAllowRgb8, &f.right, error)) return false;
  if (!f.color.empty() && !f.right.empty() && f.color.type() != f.right.type()) {
    return fail(error, "right has another pixel format than color");
  }
  if (!std::isfinite(in.baseline_m)) return fail(error, "baseline_m is not finite");
  f.baseline_m = in.baseline_m;
  if (!(std::abs(in.depth_time_offset_s) < 1))
    return fail(error, "depth_time_offset_s is not below 1 s in magnitude");
  f.depth_time_offset_s = in.depth_time_offset_s;
  cv::Mat depth;
  if (!imageFromLcm(in.depth, "depth", kAllowUint16 | kAllowFloat32, &depth, error)) return false;
  if (depth.type() == CV_16UC1) {
    if (!(in.depth.scale > 0)) return fail(error, "depth: UINT16 depth needs a scale > 0");
    depth.convertTo(f.depth, CV_32F, static_cast<double>(in.depth.scale));
    f.depth_wire_scale = static_cast<double>(in.depth.scale);
  } else {
    f.depth = depth;
  }
  // Also after scaling: a huge UINT16 scale overflows float.
  if (!checkFloatImage(f.depth, FloatRule::kFinite, "depth", error)) return false;
  if (!imageFromLcm(in.instance, "instance", kAllowUint16, &f.instance, error)) return false;
  if (!imageFromLcm(in.class_id, "class_id", kAllowUint16, &f.class_id, error)) return false;
  if (!checkSameSize({{&f.color, "color"},
                      {&f.right, "right"},
                      {&f.depth, "depth"},
                      {&f.instance, "instance"},
                      {&f.class_id, "class_id"}},
                     &f.camera, error)) {
    return false;
  }
  f.color_compression = compressionOf(in.color);
  *out = std::move(f);
  return true;
}

// ---- PoseStamped ------------------------------------------------------------

void toLcm(const PoseStamped& msg, pose_stamped_t* out) {
  headerToLcm(msg.header, &out->header);
  out->frame_index = msg.frame_index;
  out->state = static_cast<int8_t>(msg.state);
  out->is_keyframe = msg.is_keyframe ? 1 : 0;
  poseToLcm(msg.T_world_cam, &out->T_world_cam);
  covarianceToLcm(msg.covariance, out->covariance);
}

bool fromLcm(const pose_stamped_t& in, PoseStamped* out, std::string* error) {
  PoseStamped p;
  if (!checkHeader(in.header, error)) return false;
  headerFromLcm(in.header, &p.header);
  p.frame_index = in.frame_index;
  if (in.state < pose_stamped_t::INITIALIZING || in.state > pose_stamped_t::GROUND_TRUTH) {
    return fail(error, "unknown tracking state " + std::to_string(in.state));
  }
  p.state = static_cast<TrackingState>(in.state);
  p.is_keyframe = in.is_keyframe != 0;
  if (!poseFromLcm(in.T_world_cam, "T_world_cam", &p.T_world_cam, error)) return false;
  if (!covarianceFromLcm(in.covariance, "T_world_cam", &p.covariance, error)) return false;
  *out = std::move(p);
  return true;
}

// ---- Keyframe ---------------------------------------------------------------

void toLcm(const Keyframe& msg, keyframe_t* out) {
  requireType(msg.inv_depth, CV_32FC1, "Keyframe.inv_depth");
  requireType(msg.inv_depth_var, CV_32FC1, "Keyframe.inv_depth_var");
  requireType(msg.depth, CV_32FC1, "Keyframe.depth");
  requireType(msg.depth_var, CV_32FC1, "Keyframe.depth_var");
  requireType(msg.dynamic_mask, CV_8UC1, "Keyframe.dynamic_mask");
  const cv::Mat* ref = &msg.color;
  for (const cv::Mat* m : {&msg.inv_depth, &msg.inv_depth_var, &msg.depth, &msg.depth_var}) {
    if (ref->empty()) ref = m;
  }
  requireSameSize(*ref, "Keyframe images", msg.color, "Keyframe.color");
  requireSameSize(*ref, "Keyframe images", msg.inv_depth, "Keyframe.inv_depth");
  requireSameSize(*ref, "Keyframe images", msg.inv_depth_var, "Keyframe.inv_depth_var");
  requireSameSize(*ref, "Keyframe images", msg.depth, "Keyframe.depth");
  requireSameSize(*ref, "Keyframe images", msg.depth_var, "Keyframe.depth_var");
  requireSameSize(*ref, "Keyframe images", msg.dynamic_mask, "Keyframe.dynamic_mask");
  headerToLcm(msg.header, &out->header);
  out->keyframe_id = msg.keyframe_id;
  out->version = msg.version;
  out->frame_index = msg.frame_index;
  poseToLcm(msg.T_world_cam, &out->T_world_cam);
  covarianceToLcm(msg.covariance, out->covariance);
  cameraToLcm(msg.camera, &out->camera);
  // Colour and mask compress well losslessly; float maps go raw (exact).
  imageToLcm(msg.color, WireCompression::kPng, 0.0f, "Keyframe.color", &out->color);
  imageToLcm(msg.inv_depth, WireCompression::kRaw, 0.0f, "Keyframe.inv_depth", &out->inv_depth);
  imageToLcm(msg.inv_depth_var, WireCompression::kRaw, 0.0f, "Keyframe.inv_depth_var",
             &out->inv_depth_var);
  imageToLcm(msg.depth, WireCompression::kRaw, 0.0f, "Keyframe.depth", &out->depth);
  imageToLcm(msg.depth_var, WireCompression::kRaw, 0.0f, "Keyframe.depth_var", &out->depth_var);
  imageToLcm(msg.dynamic_mask, WireCompression::kPng, 0.0f, "Keyframe.dynamic_mask",
             &out->dynamic_mask);
}

bool fromLcm(const keyframe_t& in, Keyframe* out, std::string* error) {
  Keyframe k;
  if (!checkHeader(in.header, error)) return false;
  headerFromLcm(in.header, &k.header);
  k.keyframe_id = in.keyframe_id;
  k.version = in.version;
  k.frame_index = in.frame_index;
  if (!poseFromLcm(in.T_world_cam, "T_world_cam", &k.T_world_cam, error)) return false;
  if (!covarianceFromLcm(in.covariance, "T_world_cam", &k.covariance, error)) return false;
  if (!cameraFromLcm(in.camera, "camera", &k.camera, error)) return false;
  if (!imageFromLcm(in.color, "color", kAllowGrey8 | kAllowRgb8, &k.color, error) ||
      !imageFromLcm(in.inv_depth, "inv_depth", kAllowFloat32, &k.inv_depth, error) ||
      !imageFromLcm(in.inv_depth_var, "inv_depth_var", kAllowFloat32, &k.inv_depth_var, error) ||
      !imageFromLcm(in.depth, "depth", kAllowFloat32, &k.depth, error) ||
      !imageFromLcm(in.depth_var, "depth_var", kAllowFloat32, &k.depth_var, error) ||
      !imageFromLcm(in.dynamic_mask, "dynamic_mask", kAllowGrey8, &k.dynamic_mask, error)) {
    return false;
  }
  // inv_depth and inv_depth_var may hold NaN/inf where BA has no estimate; the
  // metric maps the mapper trains on may not.
  if (!checkFloatImage(k.depth, FloatRule::kFinite, "depth", error) ||
      !checkFloatImage(k.depth_var, FloatRule::kVariance, "depth_var", error)) {
    return false;
  }
  if (!checkSameSize({{&k.color, "color"},
                      {&k.inv_depth, "inv_depth"},
                      {&k.inv_depth_var, "inv_depth_var"},
                      {&k.depth, "depth"},
                      {&k.depth_var, "depth_var"},
                      {&k.dynamic_mask, "dynamic_mask"}},
                     &k.camera, error)) {
    return false;
  }
  *out = std::move(k);
  return true;
}

// ---- ObjectList -------------------------------------------------------------

void toLcm(const ObjectList& msg, objects_t* out) {
  headerToLcm(msg.header, &out->header);
  out->frame_index = msg.frame_index;
  out->num_objects = checkedCount(msg.objects.size(), "ObjectList.objects");
  out->objects.resize(msg.objects.size());
  for (size_t i = 0; i < msg.objects.size(); ++i) {
    const TrackedObject& o = msg.objects[i];
    object_t& l = out->objects[i];
    l.object_id = o.object_id;
    l.class_id = o.class_id;
    l.class_name = o.class_name;
    poseToLcm(o.T_world_object, &l.T_world_object);
    for (int j = 0; j < 6; ++j) l.twist[j] = o.twist[j];
    l.joint_type = static_cast<int8_t>(o.joint_type);
    poseToLcm(o.T_world_joint, &l.T_world_joint);
    l.parent_cluster = o.parent_cluster;
    covarianceToLcm(o.covariance, l.covariance);
  }
}

bool fromLcm(const objects_t& in, ObjectList* out, std::string* error) {
  ObjectList list;
  if (!checkHeader(in.header, error)) return false;
  headerFromLcm(in.header, &list.header);
  list.frame_index = in.frame_index;
  list.objects.resize(in.objects.size());
  for (size_t i = 0; i < in.objects.size(); ++i) {
    const object_t& l = in.objects[i];
    TrackedObject& o = list.objects[i];
    const std::string name = "objects[" + std::to_string(i) + "]";
    o.object_id = l.object_id;
    o.class_id = l.class_id;
    if (!checkText(l.class_name, name + ".class_name", error)) return false;
    o.class_name = l.class_name;
    if (!poseFromLcm(l.T_world_object, name + ".T_world_object", &o.T_world_object, error)) {
      return false;
    }
    for (int j = 0; j < 6; ++j) {
      if (!std::isfinite(l.twist[j])) return fail(error, name + ".twist is not finite");
      o.twist[j] = l.twist[j];
    }
    if (l.joint_type < object_t::FREE || l.joint_type > object_t::REVOLUTE) {
      return fail(error, name + ": unknown joint type " + std::to_string(l.joint_type));
    }
    o.joint_type = static_cast<JointType>(l.joint_type);
    if (!poseFromLcm(l.T_world_joint, name + ".T_world_joint", &o.T_world_joint, error)) {
      return false;
    }
    o.parent_cluster = l.parent_cluster;
    if (!covarianceFromLcm(l.covariance, name, &o.covariance, error)) return false;
  }
  *out = std::move(list);
  return true;
}

// ---- FieldUpdate ------------------------------------------------------------

void toLcm(const FieldUpdate& msg, field_update_t* out) {
  headerToLcm(msg.header, &out->header);
  out->version = msg.version;
  out->base_version = msg.base_version;
  out->is_snapshot = msg.is_snapshot ? 1 : 0;
  out->snapshot_id = msg.snapshot_id;
  out->chunk_index = msg.chunk_index;
  out->chunk_count = msg.chunk_count;
  out->layout = msg.layout;
  out->num_levels = checkedCount(msg.voxel_size.size(), "FieldUpdate.voxel_size");
  out->voxel_size = msg.voxel_size;
  out->block_dim = msg.block_dim;
  out->num_blocks = checkedCount(msg.blocks.size(), "FieldUpdate.blocks");
  out->blocks.resize(msg.blocks.size());
  for (size_t i = 0; i < msg.blocks.size(); ++i) {
    const FieldBlock& b = msg.blocks[i];
    field_block_t& l = out->blocks[i];
    l.level = b.level;
    l.bx = b.index.x();
    l.by = b.index.y();
    l.bz = b.index.z();
    l.size = checkedCount(b.data.size(), "FieldUpdate.blocks.data");
    l.data = b.data;
  }
}

bool fromLcm(const field_update_t& in, FieldUpdate* out, std::string* error) {
  if (!checkHeader(in.header, error) || !checkText(in.layout, "layout", error)) return false;
  FieldUpdate u;
  headerFromLcm(in.header, &u.header);
  u.version = in.version;
  u.base_version = in.base_version;
  u.is_snapshot = in.is_snapshot != 0;
  if (in.chunk_count < 1 || in.chunk_index < 0 || in.chunk_index >= in.chunk_count) {
    return fail(error, "chunk " + std::to_string(in.chunk_index) + " of " +
                           std::to_string(in.chunk_count) + " is invalid");
  }
  u.snapshot_id = in.snapshot_id;
  u.chunk_index = in.chunk_index;
  u.chunk_count = in.chunk_count;
  u.layout = in.layout;
  for (double v : in.voxel_size) {
    if (!std::isfinite(v) || v <= 0) return fail(error, "voxel_size must be finite and > 0");
  }
  u.voxel_size = in.voxel_size;
  if (in.block_dim < 0 || (in.block_dim == 0 && !in.blocks.empty())) {
    return fail(error, "block_dim " + std::to_string(in.block_dim) + " is invalid");
  }
  u.block_dim = in.block_dim;
  u.blocks.resize(in.blocks.size());
  for (size_t i = 0; i < in.blocks.size(); ++i) {
    const field_block_t& l = in.blocks[i];
    if (l.level < 0 || l.level >= in.num_levels) {
      return fail(error, "blocks[" + std::to_string(i) + "]: level " + std::to_string(l.level) +
                             " outside [0, " + std::to_string(in.num_levels) + ")");
    }
    FieldBlock& b = u.blocks[i];
    b.level = l.level;
    b.index = Eigen::Vector3i(l.bx, l.by, l.bz);
    b.data = l.data;
  }
  *out = std::move(u);
  return true;
}

// ---- RenderRequest / RenderResult -----------------------------------------

void toLcm(const RenderRequest& msg, render_request_t* out) {
  headerToLcm(msg.header, &out->header);
  out->request_id = msg.request_id;
  out->client = msg.client;
  poseToLcm(msg.T_world_cam, &out->T_world_cam);
  cameraToLcm(msg.camera, &out->camera);
  out->channels = msg.channels;
}

bool fromLcm(const render_request_t& in, RenderRequest* out, std::string* error) {
  RenderRequest r;
  if (!checkHeader(in.header, error) || !checkText(in.client, "client", error)) return false;
  headerFromLcm(in.header, &r.header);
  r.request_id = in.request_id;
  r.client = in.client;
  if (!poseFromLcm(in.T_world_cam, "T_world_cam", &r.T_world_cam, error)) return false;
  if (!cameraFromLcm(in.camera, "camera", &r.camera, error)) return false;
  const int32_t known = kRenderColor | kRenderDepth | kRenderSigma;
  if ((in.channels & ~known) != 0) {
    return fail(error, "channels " + std::to_string(in.channels) + " has unknown bits");
  }
  r.channels = in.channels;
  *out = std::move(r);
  return true;
}

void toLcm(const RenderResult& msg, render_t* out) {
  requireType(msg.depth, CV_32FC1, "RenderResult.depth");
  requireType(msg.sigma, CV_32FC1, "RenderResult.sigma");
  const cv::Mat& ref = msg.color.empty() ? msg.depth : msg.color;
  requireSameSize(ref, "RenderResult images", msg.depth, "RenderResult.depth");
  requireSameSize(ref, "RenderResult images", msg.sigma, "RenderResult.sigma");
  headerToLcm(msg.header, &out->header);
  out->request_id = msg.request_id;
  out->client = msg.client;
  out->ok = msg.ok ? 1 : 0;
  out->error = msg.error;
  out->field_version = msg.field_version;
  imageToLcm(msg.color, WireCompression::kPng, 0.0f, "RenderResult.color", &out->color);
  imageToLcm(msg.depth, WireCompression::kRaw, 0.0f, "RenderResult.depth", &out->depth);
  imageToLcm(msg.sigma, WireCompression::kRaw, 0.0f, "RenderResult.sigma", &out->sigma);
}

bool fromLcm(const render_t& in, RenderResult* out, std::string* error) {
  RenderResult r;
  if (!checkHeader(in.header, error) || !checkText(in.client, "client", error) ||
      !checkText(in.error, "error", error)) {
    return false;
  }
  headerFromLcm(in.header, &r.header);
  r.request_id = in.request_id;
  r.client = in.client;
  r.ok = in.ok != 0;
  r.error = in.error;
  r.field_version = in.field_version;
  if (!imageFromLcm(in.color, "color", kAllowGrey8 | kAllowRgb8, &r.color, error) ||
      !imageFromLcm(in.depth, "depth", kAllowFloat32, &r.depth, error) ||
      !imageFromLcm(in.sigma, "sigma", kAllowFloat32, &r.sigma, error)) {
    return false;
  }
  if (!checkSameSize({{&r.color, "color"}, {&r.depth, "depth"}, {&r.sigma, "sigma"}}, nullptr,
                     error)) {
    return false;
  }
  *out = std::move(r);
  return true;
}

// ---- Status / Control -------------------------------------------------------

void toLcm(const Status& msg, status_t* out) {
  headerToLcm(msg.header, &out->header);
  out->process = msg.process;
  out->pid = msg.pid;
  out->state = static_cast<int8_t>(msg.state);
  out->last_frame_index = msg.last_frame_index;
  out->last_frame_utime = msg.last_frame_utime;
  out->items_handled = msg.items_handled;
  out->busy_s = msg.busy_s;
  out->fps = msg.fps;
  out->queue_depth = msg.queue_depth;
  out->rss_mb = msg.rss_mb;
  out->peak_rss_mb = msg.peak_rss_mb;
  out->last_error = msg.last_error;
  out->num_values = checkedCount(msg.values.size(), "Status.values");
  out->keys.clear();
  out->values.clear();
  for (const auto& [key, value] : msg.values) {
    out->keys.push_back(key);
    out->values.push_back(value);
  }
}

bool fromLcm(const status_t& in, Status* out, std::string* error) {
  Status s;
  if (!checkHeader(in.header, error) || !checkText(in.process, "process", error) ||
      !checkText(in.last_error, "last_error", error)) {
    return false;
  }
  for (size_t i = 0; i < in.keys.size(); ++i) {
    if (!checkText(in.keys[i], "keys[" + std::to_string(i) + "]", error)) return false;
  }
  headerFromLcm(in.header, &s.header);
  s.process = in.process;
  s.pid = in.pid;
  if (in.state < status_t::STARTING || in.state > status_t::ERROR) {
    return fail(error, "unknown process state " + std::to_string(in.state));
  }
  s.state = static_cast<ProcessState>(in.state);
  s.last_frame_index = in.last_frame_index;
  s.last_frame_utime = in.last_frame_utime;
  s.items_handled = in.items_handled;
  s.busy_s = in.busy_s;
  s.fps = in.fps;
  s.queue_depth = in.queue_depth;
  s.rss_mb = in.rss_mb;
  s.peak_rss_mb = in.peak_rss_mb;
  s.last_error = in.last_error;
  s.values.reserve(in.keys.size());
  for (size_t i = 0; i < in.keys.size(); ++i) s.values.emplace_back(in.keys[i], in.values[i]);
  *out = std::move(s);
  return true;
}

void toLcm(const Control& msg, control_t* out) {
  headerToLcm(msg.header, &out->header);
  out->command = static_cast<int8_t>(msg.command);
  out->target = msg.target;
  out->argument = msg.argument;
}

bool fromLcm(const control_t& in, Control* out, std::string* error) {
  Control c;
  if (!checkHeader(in.header, error) || !checkText(in.target, "target", error) ||
      !checkText(in.argument, "argument", error)) {
    return false;
  }
  headerFromLcm(in.header, &c.header);
  if (in.command < control_t::STOP || in.command > control_t::REWIND) {
    return fail(error, "unknown control command " + std::to_string(in.command));
  }
  c.command = static_cast<ControlCommand>(in.command);
  c.target = in.target;
  c.argument = in.argument;
  *out = std::move(c);
  return true;
}

}  // namespace codec
}  // namespace radslam
