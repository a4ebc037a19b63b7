// Conversions between the plain message structs (common/types.h) and the
// lcm-gen types (lcmtypes/*.lcm). Private to common/*.cc: the generated classes
// are only forward-declared here, and only code linked with radslam_lcmtypes
// (the bus adapter) can call these functions. Everyone else uses encode<T> /
// decode<T> from common/bus.h.
//
// The from*() functions validate everything they read (sizes, enum ranges,
// finiteness, image payloads) before allocating from or trusting it, and return
// false with a message naming the field instead of throwing.
#pragma once

#include <string>

#include <opencv2/core.hpp>

#include "common/types.h"

namespace radslam {

// lcm-gen classes (namespace radslam, from package radslam).
class camera_t;
class control_t;
class field_update_t;
class frame_t;
class header_t;
class image_t;
class keyframe_t;
class objects_t;
class pose_stamped_t;
class pose_t;
class render_request_t;
class render_t;
class status_t;

namespace codec {

/// Largest accepted image side, pixels.
inline constexpr int kMaxImageSide = 16384;
/// Quaternions whose norm is within this of 1 are renormalised, others rejected.
inline constexpr double kQuaternionNormTolerance = 1e-3;

/// Bit set of image_t formats a field accepts (1 << image_t::FORMAT).
enum ImageFormatMask : int {
  kAllowGrey8 = 1 << 0,
  kAllowRgb8 = 1 << 1,
  kAllowUint16 = 1 << 2,
  kAllowFloat32 = 1 << 3,
};

/// cv::Mat -> image_t. Supported types: CV_8UC3 (BGR, sent as RGB8), CV_8UC1
/// (GREY8), CV_16UC1 (UINT16), CV_32FC1 (FLOAT32); an empty Mat is "no image"
/// (width 0). PNG is lossless for all but FLOAT32, JPEG (quality 95) is for
/// 8-bit images only. scale is written to image_t::scale. Throws
/// std::invalid_argument naming `name` for an unsupported type or compression.
void imageToLcm(const cv::Mat& image, WireCompression compression, float scale,
                const std::string& name, image_t* out);
/// image_t -> cv::Mat (RGB8 back to BGR). Checks the side limits, the enums, the
/// payload size against width*height*bytes for RAW, and for PNG/JPEG the size in
/// the compressed header before decoding and the decoded type and size after.
bool imageFromLcm(const image_t& in, const std::string& name, int allowed_formats, cv::Mat* out,
                  std::string* error);

/// Frame depth (CV_32FC1 metres, 0 = invalid) as UINT16 units of `scale`
/// metres: non-positive, non-finite and out-of-range depths become 0.
cv::Mat quantizeDepth(const cv::Mat& depth_m, float scale);

void poseToLcm(const SE3& T, pose_t* out);
/// Rejects non-finite values and quaternions whose norm is off by more than
/// kQuaternionNormTolerance; renormalises the others.
bool poseFromLcm(const pose_t& in, const std::string& name, SE3* out, std::string* error);

void cameraToLcm(const CameraModel& camera, camera_t* out);
bool cameraFromLcm(const camera_t& in, const std::string& name, CameraModel* out,
                   std::string* error);

void headerToLcm(const Header& header, header_t* out);
void headerFromLcm(const header_t& in, Header* out);

// Whole messages. toLcm throws std::invalid_argument for unencodable content
// (unsupported image type, mismatched image sizes, oversize data).
void toLcm(const Frame& msg, frame_t* out);
bool fromLcm(const frame_t& in, Frame* out, std::string* error);
void toLcm(const PoseStamped& msg, pose_stamped_t* out);
bool fromLcm(const pose_stamped_t& in, PoseStamped* out, std::string* error);
void toLcm(const Keyframe& msg, keyframe_t* out);
bool fromLcm(const keyframe_t& in, Keyframe* out, std::string* error);
void toLcm(const ObjectList& msg, objects_t* out);
bool fromLcm(const objects_t& in, ObjectList* out, std::string* error);
void toLcm(const FieldUpdate& msg, field_update_t* out);
bool fromLcm(const field_update_t& in, FieldUpdate* out, std::string* error);
void toLcm(const RenderRequest& msg, render_request_t* out);
bool fromLcm(const render_request_t& in, RenderRequest* out, std::string* error);
void toLcm(const RenderResult& msg, render_t* out);
bool fromLcm(const render_t& in, RenderResult* out, std::string* error);
void toLcm(const Status& msg, status_t* out);
bool fromLcm(const status_t& in, Status* out, std::string* error);
void toLcm(const Control& msg, control_t* out);
bool fromLcm(const control_t& in, Control* out, std::string* error);

}  // namespace codec
}  // namespace radslam
