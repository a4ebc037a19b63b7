#include "renderer/render_service.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace radslam {
namespace {

bool finite(double v) { return std::isfinite(v); }

// Maps [0, max] to 8 bits through an OpenCV colour map; invalid pixels black.
cv::Mat colorize(const cv::Mat& values, double max_m, int colormap) {
  if (values.empty()) return cv::Mat();
  CV_Assert(values.type() == CV_32FC1);
  cv::Mat valid = (values > 0) & (values < std::numeric_limits<float>::infinity());
  if (max_m <= 0) {
    std::vector<float> v;
    v.reserve(values.total());
    for (int y = 0; y < values.rows; ++y) {
      const float* row = values.ptr<float>(y);
      for (int x = 0; x < values.cols; ++x)
        if (row[x] > 0 && std::isfinite(row[x])) v.push_back(row[x]);
    }
    if (!v.empty()) {
      const size_t k = std::min(v.size() - 1, static_cast<size_t>(0.98 * v.size()));
      std::nth_element(v.begin(), v.begin() + k, v.end());
      max_m = v[k];
    }
    if (!(max_m > 0)) max_m = 1;
  }
  cv::Mat clean;
  values.copyTo(clean);
  clean.setTo(0, ~valid);
  cv::Mat u8;
  clean.convertTo(u8, CV_8UC1, 255.0 / max_m);
  cv::Mat bgr;
  cv::applyColorMap(u8, bgr, colormap);
  bgr.setTo(cv::Scalar::all(0), ~valid);
  return bgr;
}

}  // namespace

std::string validateRenderRequest(const RenderRequest& r) {
  const CameraModel& c = r.camera;
  if (c.width <= 0 || c.height <= 0)
    return "render request " + std::to_string(r.request_id) + ": size " + std::to_string(c.width) +
           "x" + std::to_string(c.height) + " is not positive";
  if (c.width > kMaxRenderSize || c.height > kMaxRenderSize)
    return "render request " + std::to_string(r.request_id) + ": size " + std::to_string(c.width) +
           "x" + std::to_string(c.height) + " exceeds " + std::to_string(kMaxRenderSize);
  if (!finite(c.fx) || !finite(c.fy) || !finite(c.cx) || !finite(c.cy))
    return "render request " + std::to_string(r.request_id) + ": intrinsics are not finite";
  if (c.fx <= 0 || c.fy <= 0)
    return "render request " + std::to_string(r.request_id) + ": focal lengths must be > 0";
  const Mat4 T = r.T_world_cam.matrix();
  if (!T.allFinite())
    return "render request " + std::to_string(r.request_id) + ": pose is not finite";
  if ((r.channels & ~(kRenderColor | kRenderDepth | kRenderSigma)) != 0 || r.channels == 0)
    return "render request " + std::to_string(r.request_id) + ": channels " +
           std::to_string(r.channels) + " are not a non-empty set of colour(1)|depth(2)|sigma(4)";
  return "";
}

RenderResult renderView(const FieldReplica& replica, const RenderRequest& request,
                        const PreviewOptions* preview) {
  RenderResult out;
  out.header.utime = request.header.utime;
  out.request_id = request.request_id;
  out.client = request.client;
  out.field_version = replica.version();
  out.error = validateRenderRequest(request);
  if (!out.error.empty()) return out;
  try {
    CameraModel camera = request.camera;
    camera.distortion.clear();  // renders are pinhole views
    const RenderImages images =
        preview ? replica.renderPreview(request.T_world_cam, camera, preview->march,
                                        preview->refresh_budget_s)
                : replica.render(request.T_world_cam, camera);
    if (request.channels & kRenderColor) out.color = toBgr8(images.color);
    if (request.channels & kRenderDepth) out.depth = images.depth;
    if (request.channels & kRenderSigma) out.sigma = images.sigma;
    out.ok = true;
  } catch (const std::exception& e) {
    out.error = "render request " + std::to_string(request.request_id) + ": " + e.what();
  }
  return out;
}

cv::Mat colorizeDepth(const cv::Mat& depth, double max_m) {
  return colorize(depth, max_m, cv::COLORMAP_TURBO);
}

cv::Mat colorizeSigma(const cv::Mat& sigma, double max_m) {
  return colorize(sigma, max_m, cv::COLORMAP_INFERNO);
}

}  // namespace radslam
