#include "common/camera.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>

#include "common/image_sampling.h"

namespace radslam {
namespace {

std::string sizeString(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

bool allZero(const std::vector<double>& values) {
  return std::all_of(values.begin(), values.end(), [](double v) { return v == 0.0; });
}

// Fisheye (equidistant) input: the pinhole camera of size target whose every
// pixel centre maps inside the source image. The border of the source is
// undistorted densely and the largest axis-aligned rectangle inside it kept;
// OpenCV's fisheye::estimateNewCameraMatrixForUndistortRectify looks only at the
// four edge midpoints and does not guarantee this.
cv::Matx33d innerPinholeForFisheye(const CameraModel& cam, const cv::Size& target) {
  constexpr int kSamplesPerSide = 64;
  const double w = cam.width - 1.0, h = cam.height - 1.0;  // outermost pixel centres
  std::vector<cv::Point2d> left, right, top, bottom;
  for (int i = 0; i < kSamplesPerSide; ++i) {
    const double f = static_cast<double>(i) / (kSamplesPerSide - 1);
    left.emplace_back(0.0, f * h);
    right.emplace_back(w, f * h);
    top.emplace_back(f * w, 0.0);
    bottom.emplace_back(f * w, h);
  }
  const cv::Matx33d K = cameraMatrix(cam);
  const cv::Mat D(cam.distortion, true);
  const auto undistort = [&](const std::vector<cv::Point2d>& in) {
    std::vector<cv::Point2d> out;
    cv::fisheye::undistortPoints(in, out, K, D);
    return out;
  };
  const double inf = std::numeric_limits<double>::infinity();
  double x_min = -inf, x_max = inf, y_min = -inf, y_max = inf;
  for (const cv::Point2d& p : undistort(left)) x_min = std::max(x_min, p.x);
  for (const cv::Point2d& p : undistort(right)) x_max = std::min(x_max, p.x);
  for (const cv::Point2d& p : undistort(top)) y_min = std::max(y_min, p.y);
  for (const cv::Point2d& p : undistort(bottom)) y_max = std::min(y_max, p.y);
  if (!(std::isfinite(x_min) && std::isfinite(x_max) && std::isfinite(y_min) &&
        std::isfinite(y_max) && x_max > x_min && y_max > y_min)) {
    throw std::invalid_argument(
        "Undistorter: the equidistant camera's field of view cannot be mapped to a pinhole "
        "image (too wide or bad coefficients)");
  }
  // Target pixel centres 0 and size-1 land on the rectangle's edges.
  const double fx = (target.width - 1.0) / (x_max - x_min);
  const double fy = (target.height - 1.0) / (y_max - y_min);
  return cv::Matx33d(fx, 0, -fx * x_min, 0, fy, -fy * y_min, 0, 0, 1);
}

}  // namespace

Eigen::Vector2d project(const CameraModel& cam, const Vec3& p_cam,
                        Eigen::Matrix<double, 2, 3>* H_point) {
  const double z_inv = 1.0 / p_cam.z();
  const double x = p_cam.x() * z_inv, y = p_cam.y() * z_inv;
  if (H_point) {
    *H_point << cam.fx * z_inv, 0.0, -cam.fx * x * z_inv, 0.0, cam.fy * z_inv, -cam.fy * y * z_inv;
  }
  return Eigen::Vector2d(cam.fx * x + cam.cx, cam.fy * y + cam.cy);
}

Vec3 unproject(const CameraModel& cam, const Eigen::Vector2d& px, double depth) {
  return Vec3((px.x() - cam.cx) / cam.fx * depth, (px.y() - cam.cy) / cam.fy * depth, depth);
}

CameraModel scaleCamera(const CameraModel& cam, int new_width, int new_height) {
  if (cam.width <= 0 || cam.height <= 0) {
    throw std::invalid_argument("scaleCamera: camera size " + sizeString(cam.width, cam.height) +
                                " is not positive");
  }
  if (new_width <= 0 || new_height <= 0) {
    throw std::invalid_argument("scaleCamera: target size " + sizeString(new_width, new_height) +
                                " is not positive");
  }
  const double sx = static_cast<double>(new_width) / cam.width;
  const double sy = static_cast<double>(new_height) / cam.height;
  CameraModel out = cam;
  out.width = new_width;
  out.height = new_height;
  out.fx = cam.fx * sx;
  out.fy = cam.fy * sy;
  out.cx = (cam.cx + 0.5) * sx - 0.5;
  out.cy = (cam.cy + 0.5) * sy - 0.5;
  return out;
}

cv::Matx33d cameraMatrix(const CameraModel& cam) {
  return cv::Matx33d(cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
}

void validateCamera(const CameraModel& cam) {
  if (cam.width <= 0 || cam.height <= 0) {
    throw std::invalid_argument("camera: image size " + sizeString(cam.width, cam.height) +
                                " is not positive");
  }
  if (!(std::isfinite(cam.fx) && std::isfinite(cam.fy) && cam.fx > 0 && cam.fy > 0)) {
    throw std::invalid_argument("camera: focal lengths fx=" + std::to_string(cam.fx) +
                                " fy=" + std::to_string(cam.fy) + " must be finite and > 0");
  }
  if (!(std::isfinite(cam.cx) && std::isfinite(cam.cy))) {
    throw std::invalid_argument("camera: principal point is not finite");
  }
  if (!(cam.readout_s >= 0 && cam.readout_s < 1)) {
    throw std::invalid_argument("camera: rolling shutter readout " + std::to_string(cam.readout_s) +
                                " s is not in [0, 1)");
  }
  for (double k : cam.distortion) {
    if (!std::isfinite(k)) throw std::invalid_argument("camera: distortion coefficient not finite");
  }
  const size_t n = cam.distortion.size();
  switch (cam.type) {
    case CameraModel::Type::kPinhole:
      if (!allZero(cam.distortion)) {
        throw std::invalid_argument(
            "camera: pinhole model with non-zero distortion coefficients (use RadTan)");
      }
      break;
    case CameraModel::Type::kRadTan:
      if (n != 0 && n != 4 && n != 5) {
        throw std::invalid_argument(
            "camera: RadTan needs 4 or 5 coefficients (k1 k2 p1 p2 [k3]), got " +
            std::to_string(n));
      }
      break;
    case CameraModel::Type::kEquidistant:
      if (n != 4) {
        throw std::invalid_argument("camera: Equidistant needs 4 coefficients (k1 k2 k3 k4), got " +
                                    std::to_string(n));
      }
      break;
    default:
      throw std::invalid_argument("camera: unknown model type " +
                                  std::to_string(static_cast<int>(cam.type)));
  }
}

Undistorter::Undistorter(const CameraModel& source, int target_width, int target_height)
    : source_(source) {
  validateCamera(source);
  if (target_width <= 0 || target_height <= 0) {
    throw std::invalid_argument("Undistorter: target size " +
                                sizeString(target_width, target_height) + " is not positive");
  }
  const bool distorted = source.type == CameraModel::Type::kEquidistant ||
                         (source.type == CameraModel::Type::kRadTan && !allZero(source.distortion));
  if (!distorted) {
    target_ = scaleCamera(source, target_width, target_height);
    target_.type = CameraModel::Type::kPinhole;
    target_.distortion.clear();
    target_.readout_s = 0;  // a rolling shutter is undone by rollingShutterMap, if at all
    pure_resize_ = true;
  } else {
    makeDistortedMaps(target_width, target_height);
  }
  if (source.readout_s > 0) {
    // A camera turning at 3 rad/s over half a 40 ms readout carries rays about 0.06 f (at most
    // half the image: beyond, no real camera's maps need it).
    source_pad_ = static_cast<int>(std::ceil(
        std::min(0.06 * std::max(target_.fx, 1.0), 0.5 * std::max(source.width, source.height))));
    // Bounds the maps below (two floats per padded pixel, about 256 MB at the limit).
    constexpr double kMaxPaddedPixels = 32e6;
    const double padded_pixels =
        (source.width + 2.0 * source_pad_) * (source.height + 2.0 * source_pad_);
    if (padded_pixels > kMaxPaddedPixels)
      throw std::invalid_argument("Undistorter: a rolling-shutter camera of " +
                                  sizeString(source.width, source.height) + " needs maps of " +
                                  std::to_string(static_cast<long long>(padded_pixels)) +
                                  " pixels, more than the 32M supported");
    cv::Mat map_x, map_y;
    sourcePixels(source_pad_, &map_x, &map_y);
    cv::merge(std::vector<cv::Mat>{map_x, map_y}, padded_source_);
  }
}

void Undistorter::makeDistortedMaps(int target_width, int target_height) {
  const CameraModel& source = source_;
  const cv::Size target_size(target_width, target_height);
  // RadTan: alpha = 0, only valid pixels in the output.
  const cv::Matx33d K_new =
      source.type == CameraModel::Type::kRadTan
          ? cv::getOptimalNewCameraMatrix(cameraMatrix(source), cv::Mat(source.distortion, true),
                                          cv::Size(source.width, source.height), 0.0, target_size)
          : innerPinholeForFisheye(source, target_size);
  target_.width = target_width;
  target_.height = target_height;
  target_.type = CameraModel::Type::kPinhole;
  target_.fx = K_new(0, 0);
  target_.fy = K_new(1, 1);
  target_.cx = K_new(0, 2);
  target_.cy = K_new(1, 2);
  target_.distortion.clear();
  sourcePixels(0, &map_x_, &map_y_);
  cv::convertMaps(map_x_, map_y_, map_fixed_, map_interp_, CV_16SC2);
}

cv::Vec2f Undistorter::paddedSource(double u, double v) const {
  const double x = std::clamp(u + source_pad_, 0.0, padded_source_.cols - 1.001);
  const double y = std::clamp(v + source_pad_, 0.0, padded_source_.rows - 1.001);
  const int x0 = static_cast<int>(x);
  const int y0 = static_cast<int>(y);
  return bilinearAt<cv::Vec2f>(padded_source_, x0, y0, static_cast<float>(x - x0),
                               static_cast<float>(y - y0));
}

cv::Mat Undistorter::rollingShutterMap(const Vec3& omega_cam, int step) const {
  if (source_.readout_s <= 0 || omega_cam.isZero()) return cv::Mat();
  if (step < 1) throw std::invalid_argument("Undistorter::rollingShutterMap: step must be >= 1");
  const CameraModel& cam = target_;
  // Exp(-omega dt) of every source row, interpolated between rows below; the table reaches a
  // quarter of the image beyond each border, where the padded map sends rays turned in.
  const int rows = source_.height;
  const int margin = rows / 4 + 1;
  std::vector<Mat3> row_rotation(rows + 2 * margin);
  for (int i = 0; i < static_cast<int>(row_rotation.size()); ++i) {
    const double dt =
        (static_cast<double>(i - margin) / std::max(1, rows - 1) - 0.5) * source_.readout_s;
    row_rotation[i] = SO3::exp(-dt * omega_cam).matrix();
  }
  // The displacement from the global-shutter source pixel varies slowly across the image: it
  // is solved at the centres of step x step blocks and interpolated (cv::resize's pixel-centre
  // convention).
  const cv::Size coarse((cam.width + step - 1) / step, (cam.height + step - 1) / step);
  cv::Mat shift(coarse, CV_32FC2);
  for (int j = 0; j < coarse.height; ++j) {
    for (int i = 0; i < coarse.width; ++i) {
      const double u = step * i + (step - 1) / 2.0;
      const double v = step * j + (step - 1) / 2.0;
      const Vec3 ray((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
      const cv::Vec2f global_shutter = paddedSource(u, v);
      // The source row decides when the ray was seen, and the rotation since the middle row
      // decides which row sees it: a fixed point, reached in a few steps (the rotation over a
      // readout is small).
      cv::Vec2f source = global_shutter;
      for (int iteration = 0; iteration < 3; ++iteration) {
        const double table_row =
            std::clamp(source[1] + static_cast<double>(margin), 0.0, row_rotation.size() - 1.001);
        const int row = static_cast<int>(table_row);
        const double a = table_row - row;
        const Vec3 seen = (1 - a) * (row_rotation[row] * ray) + a * (row_rotation[row + 1] * ray);
        if (!(seen.z() > 0)) break;
        source = paddedSource(cam.fx * seen.x() / seen.z() + cam.cx,
                              cam.fy * seen.y() / seen.z() + cam.cy);
      }
      shift.at<cv::Vec2f>(j, i) = source - global_shutter;
    }
  }
  cv::Mat map;
  cv::resize(shift, map, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_LINEAR);
  map += padded_source_(cv::Rect(source_pad_, source_pad_, cam.width, cam.height));
  return map;
}

cv::Mat Undistorter::apply(const cv::Mat& image, int interpolation,
                           const cv::Mat& source_map) const {
  if (source_map.empty()) return apply(image, interpolation);
  if (image.cols != source_.width || image.rows != source_.height ||
      source_map.type() != CV_32FC2 || source_map.cols != target_.width ||
      source_map.rows != target_.height) {
    throw std::invalid_argument("Undistorter::apply: image " + sizeString(image.cols, image.rows) +
                                " or map does not fit the camera " +
                                sizeString(source_.width, source_.height));
  }
  cv::Mat out;
  const bool nearest =
      interpolation == cv::INTER_NEAREST || interpolation == cv::INTER_NEAREST_EXACT;
  cv::remap(image, out, source_map, cv::noArray(), nearest ? cv::INTER_NEAREST : cv::INTER_LINEAR,
            cv::BORDER_REPLICATE);
  return out;
}

cv::Mat Undistorter::exposureTimes() const {
  if (source_.readout_s <= 0) return cv::Mat();
  const cv::Mat source =
      padded_source_(cv::Rect(source_pad_, source_pad_, target_.width, target_.height));
  cv::Mat times(target_.height, target_.width, CV_32FC1);
  const double scale = source_.readout_s / std::max(1, source_.height - 1);
  for (int v = 0; v < times.rows; ++v) {
    const cv::Vec2f* s = source.ptr<cv::Vec2f>(v);
    float* t = times.ptr<float>(v);
    for (int u = 0; u < times.cols; ++u)
      t[u] = static_cast<float>(s[u][1] * scale - 0.5 * source_.readout_s);
  }
  return times;
}

void Undistorter::sourcePixels(int pad, cv::Mat* map_x, cv::Mat* map_y) const {
  if (pad < 0) throw std::invalid_argument("Undistorter::sourcePixels: pad must be >= 0");
  const cv::Size size(target_.width + 2 * pad, target_.height + 2 * pad);
  if (pure_resize_) {
    // The pixel-centre convention of scaleCamera and cv::resize.
    const double sx = static_cast<double>(source_.width) / target_.width;
    const double sy = static_cast<double>(source_.height) / target_.height;
    map_x->create(size, CV_32FC1);
    map_y->create(size, CV_32FC1);
    for (int y = 0; y < size.height; ++y) {
      float* mx = map_x->ptr<float>(y);
      float* my = map_y->ptr<float>(y);
      for (int x = 0; x < size.width; ++x) {
        mx[x] = static_cast<float>((x - pad + 0.5) * sx - 0.5);
        my[x] = static_cast<float>((y - pad + 0.5) * sy - 0.5);
      }
    }
    return;
  }
  const cv::Matx33d K = cameraMatrix(source_);
  const cv::Mat D(source_.distortion, true);
  CameraModel padded = target_;
  padded.cx += pad;
  padded.cy += pad;
  const cv::Matx33d K_padded = cameraMatrix(padded);
  if (source_.type == CameraModel::Type::kRadTan) {
    cv::initUndistortRectifyMap(K, D, cv::Matx33d::eye(), K_padded, size, CV_32FC1, *map_x, *map_y);
  } else {
    cv::fisheye::initUndistortRectifyMap(K, D, cv::Matx33d::eye(), K_padded, size, CV_32FC1, *map_x,
                                         *map_y);
  }
}

cv::Mat Undistorter::apply(const cv::Mat& image, int interpolation) const {
  if (image.empty()) throw std::invalid_argument("Undistorter::apply: empty image");
  if (image.cols != source_.width || image.rows != source_.height) {
    throw std::invalid_argument("Undistorter::apply: image is " +
                                sizeString(image.cols, image.rows) + " but the camera is " +
                                sizeString(source_.width, source_.height));
  }
  cv::Mat out;
  if (pure_resize_) {
    if (target_.width == source_.width && target_.height == source_.height) return image.clone();
    // INTER_NEAREST in cv::resize picks floor(dst * scale), off the pixel-centre
    // convention of scaleCamera; the _EXACT variant samples the nearest centre.
    const int resize_interpolation =
        interpolation == cv::INTER_NEAREST ? cv::INTER_NEAREST_EXACT : interpolation;
    cv::resize(image, out, cv::Size(target_.width, target_.height), 0, 0, resize_interpolation);
    return out;
  }
  // Edge pixels may sample up to ~1 px past the outermost source pixel centre:
  // replicate rather than blend with black.
  if (interpolation == cv::INTER_NEAREST || interpolation == cv::INTER_NEAREST_EXACT) {
    cv::remap(image, out, map_x_, map_y_, cv::INTER_NEAREST, cv::BORDER_REPLICATE);
  } else {
    cv::remap(image, out, map_fixed_, map_interp_, interpolation, cv::BORDER_REPLICATE);
  }
  return out;
}

cv::Mat rotateDepth(const cv::Mat& depth, const CameraModel& camera, const Mat3& R_colour_depth) {
  cv::Mat out(depth.size(), CV_32FC1, cv::Scalar(0));
  const Mat3 R_depth_colour = R_colour_depth.transpose();
  // The colour pixel's ray in the depth camera, linear in x along a row.
  const Vec3 ray_step = R_depth_colour.col(0) / camera.fx;
  const double max_x = depth.cols - 0.5, max_y = depth.rows - 0.5;
  for (int y = 0; y < depth.rows; ++y) {
    float* z_out = out.ptr<float>(y);
    const Vec3 ray_start =
        R_depth_colour * Vec3(-camera.cx / camera.fx, (y - camera.cy) / camera.fy, 1.0);
    for (int x = 0; x < depth.cols; ++x) {
      const Vec3 ray = ray_start + x * ray_step;
      if (!(ray.z() > 0)) continue;
      // The depth pixel it crosses (nearest; the comparisons also reject NaN).
      const double inv_z = 1.0 / ray.z();
      const double xd = camera.fx * ray.x() * inv_z + camera.cx;
      const double yd = camera.fy * ray.y() * inv_z + camera.cy;
      if (!(xd >= -0.5 && yd >= -0.5 && xd < max_x && yd < max_y)) continue;
      const float z = depth.at<float>(static_cast<int>(yd + 0.5), static_cast<int>(xd + 0.5));
      // The depth pixel's point lies on the ray at (z / ray.z) ray; the colour camera's own ray
      // has z = 1, so that scale is its z there.
      if (z > 0) z_out[x] = static_cast<float>(z * inv_z);
    }
  }
  return out;
}

}  // namespace radslam
