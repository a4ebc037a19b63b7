#include "tracker/frontend.h"

#include "tracker/dense_ba.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace radslam {
namespace {

std::string sizeText(int w, int h) { return std::to_string(w) + "x" + std::to_string(h); }

std::string describe(const cv::Mat& m) {
  if (m.empty()) return "empty";
  return sizeText(m.cols, m.rows) + " " + cv::typeToString(m.type());
}

bool isDistorted(const CameraModel& cam) {
  if (cam.type == CameraModel::Type::kEquidistant) return true;
  if (cam.type == CameraModel::Type::kPinhole) return false;
  return std::any_of(cam.distortion.begin(), cam.distortion.end(), [](double k) { return k != 0; });
}

bool finiteAll(const cv::Mat& m) { return cv::checkRange(m, true, nullptr, -1e30, 1e30); }

}  // namespace

GridGeometry makeGridGeometry(const CameraModel& working, int cell) {
  if (cell < 1) throw std::invalid_argument("grid cell must be >= 1, got " + std::to_string(cell));
  if (working.width <= 0 || working.height <= 0 || working.width % cell != 0 ||
      working.height % cell != 0) {
    throw std::invalid_argument("working size " + sizeText(working.width, working.height) +
                                " is not a positive multiple of the grid cell " +
                                std::to_string(cell));
  }
  GridGeometry g;
  g.cell = cell;
  g.working = working;
  g.grid = scaleCamera(working, working.width / cell, working.height / cell);
  return g;
}

cv::Size workingSize(int input_width, int input_height, int working_width, int cell) {
  if (cell < 1) throw std::invalid_argument("grid cell must be >= 1, got " + std::to_string(cell));
  if (input_width < 2 * cell || input_height < 2 * cell) {
    throw std::invalid_argument("input size " + sizeText(input_width, input_height) +
                                " is smaller than two grid cells of " + std::to_string(cell) +
                                " px");
  }
  int w = working_width <= 0 ? input_width : std::min(working_width, input_width);
  w = std::max(2 * cell, w / cell * cell);
  const double h_exact = static_cast<double>(w) * input_height / input_width;
  int h = static_cast<int>(std::lround(h_exact / cell)) * cell;
  h = std::max(2 * cell, h);
  return {w, h};
}

ImagePreparer::ImagePreparer(const CameraModel& input, int working_width, int cell,
                             double readout_s)
    : input_(input) {
  validateCamera(input);
  const cv::Size work = workingSize(input.width, input.height, working_width, cell);
  // Halve with INTER_AREA while the result stays at least the working size: the remap that
  // follows then downsamples by less than 2 and does not alias.
  CameraModel source = input;
  while (source.width / 2 >= work.width && source.height / 2 >= work.height) {
    source = scaleCamera(source, source.width / 2, source.height / 2);
    prescale_ *= 2;
  }
  prescaled_size_ = cv::Size(source.width, source.height);
  distorted_ = isDistorted(input);
  source.readout_s = readout_s;
  undistorter_ = std::make_unique<Undistorter>(source, work.width, work.height);
  geometry_ = makeGridGeometry(undistorter_->target(), cell);
}

cv::Mat ImagePreparer::rollingShutterMap(const Vec3& omega_cam) const {
  return undistorter_->rollingShutterMap(omega_cam, geometry_.cell);
}

bool ImagePreparer::matches(const CameraModel& c) const {
  return c.width == input_.width && c.height == input_.height && c.type == input_.type &&
         c.fx == input_.fx && c.fy == input_.fy && c.cx == input_.cx && c.cy == input_.cy &&
         c.distortion == input_.distortion && c.readout_s == input_.readout_s;
}

cv::Mat ImagePreparer::resample(const cv::Mat& image, bool nearest,
                                const cv::Mat& source_map) const {
  cv::Mat src = image;
  if (prescale_ > 1) {
    cv::Mat reduced;
    cv::resize(src, reduced, prescaled_size_, 0, 0,
               nearest ? cv::INTER_NEAREST_EXACT : cv::INTER_AREA);
    src = reduced;
  }
  if (!source_map.empty()) {
    return undistorter_->apply(src, nearest ? cv::INTER_NEAREST : cv::INTER_LINEAR, source_map);
  }
  if (nearest) return undistorter_->apply(src, cv::INTER_NEAREST);
  // Without distortion apply() is a plain resize: INTER_AREA averages instead of aliasing.
  return undistorter_->apply(src, distorted_ ? cv::INTER_LINEAR : cv::INTER_AREA);
}

PreparedImage ImagePreparer::prepare(const Frame& frame, bool want_color,
                                     const Vec3& omega_cam) const {
  validateFrame(frame);
  if (!matches(frame.camera)) {
    throw std::invalid_argument("frame camera " +
                                sizeText(frame.camera.width, frame.camera.height) +
                                " differs from the camera this preparer was built for");
  }
  PreparedImage out;
  out.source_map = rollingShutterMap(omega_cam);
  const cv::Mat& map = out.source_map;
  out.grey = resample(toGrey(frame.color), false, map);
  if (want_color) out.color = resample(frame.color, false, map);
  if (!frame.right.empty()) out.right_grey = resample(toGrey(frame.right), false, map);
  if (!frame.depth.empty()) {
    // Nearest neighbour: averaging depths across an edge would invent surfaces.
    out.depth = resample(frame.depth, true, map);
  }
  if (!frame.instance.empty()) out.instance = resample(frame.instance, true, map);
  if (!frame.class_id.empty()) out.class_id = resample(frame.class_id, true, map);
  return out;
}

cv::Mat ImagePreparer::prepareGrey(const Frame& frame, const Vec3& omega_cam) const {
  return resample(toGrey(frame.color), false, rollingShutterMap(omega_cam));
}

cv::Mat ImagePreparer::prepareColor(const cv::Mat& color, const PreparedImage& image) const {
  return resample(color, false, image.source_map);
}

void validateFrame(const Frame& frame) {
  const CameraModel& cam = frame.camera;
  const std::string where = "frame " + std::to_string(frame.frame_index) + ": ";
  if (frame.color.empty()) throw std::invalid_argument(where + "empty colour image");
  if (frame.color.type() != CV_8UC3 && frame.color.type() != CV_8UC1) {
    throw std::invalid_argument(where + "colour image is " + describe(frame.color) +
                                ", expected 8UC3 or 8UC1");
  }
  if (!(cam.fx > 0) || !(cam.fy > 0) || !std::isfinite(cam.fx) || !std::isfinite(cam.fy) ||
      !std::isfinite(cam.cx) || !std::isfinite(cam.cy)) {
    throw std::invalid_argument(
        where + "intrinsics are not finite and positive (fx=" + std::to_string(cam.fx) +
        " fy=" + std::to_string(cam.fy) + " cx=" + std::to_string(cam.cx) +
        " cy=" + std::to_string(cam.cy) + ")");
  }
  for (double k : cam.distortion) {
    if (!std::isfinite(k)) throw std::invalid_argument(where + "non-finite distortion coefficient");
  }
  if (frame.color.cols != cam.width || frame.color.rows != cam.height) {
    throw std::invalid_argument(where + "colour image is " + describe(frame.color) +
                                " but the intrinsics are for " + sizeText(cam.width, cam.height));
  }
  try {
    validateCamera(cam);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(where + e.what());
  }
  if (!frame.right.empty()) {
    if (frame.right.type() != frame.color.type() || frame.right.size() != frame.color.size()) {
      throw std::invalid_argument(where + "right image is " + describe(frame.right) +
                                  ", expected the colour image's " + describe(frame.color));
    }
    if (!(frame.baseline_m > 0) || !std::isfinite(frame.baseline_m)) {
      throw std::invalid_argument(where + "right image with baseline " +
                                  std::to_string(frame.baseline_m) + " m (must be > 0)");
    }
  }
  if (!frame.depth.empty()) {
    if (frame.depth.type() != CV_32FC1 || frame.depth.size() != frame.color.size()) {
      throw std::invalid_argument(where + "depth image is " + describe(frame.depth) +
                                  ", expected 32FC1 " + sizeText(cam.width, cam.height));
    }
    if (!finiteAll(frame.depth)) throw std::invalid_argument(where + "depth image has NaN or inf");
    if (!(std::abs(frame.depth_time_offset_s) < 1)) {
      throw std::invalid_argument(where + "depth time offset " +
                                  std::to_string(frame.depth_time_offset_s) +
                                  " s (must be below 1 s in magnitude)");
    }
  }
  for (const auto& [mask, name] :
       {std::pair<const cv::Mat*, const char*>{&frame.instance, "instance"},
        {&frame.class_id, "class"}}) {
    if (!mask->empty() && (mask->type() != CV_16UC1 || mask->size() != frame.color.size())) {
      throw std::invalid_argument(where + name + " mask is " + describe(*mask) +
                                  ", expected 16UC1 " + sizeText(cam.width, cam.height));
    }
  }
}

namespace {

FlowMotion flowMotion(const cv::Mat& target, const cv::Mat& weight, const CameraModel* grid,
                      const Mat3& R_b_a, const cv::Mat& leaning) {
  CV_Assert(target.type() == CV_32FC2 && weight.type() == kFlowWeightType &&
            target.size() == weight.size());
  CV_Assert(leaning.empty() || (leaning.type() == CV_8UC1 && leaning.size() == target.size()));
  double sum = 0, sum_rotation = 0, sum_parallax = 0;
  int n = 0;
  for (int v = 0; v < target.rows; ++v) {
    const cv::Vec2f* t = target.ptr<cv::Vec2f>(v);
    const cv::Vec3f* w = weight.ptr<cv::Vec3f>(v);
    const uint8_t* l = leaning.empty() ? nullptr : leaning.ptr<uint8_t>(v);
    for (int u = 0; u < target.cols; ++u) {
      if (!(w[u][0] > 0 || w[u][2] > 0 || (l && l[u]))) continue;
      const double du = t[u][0] - u, dv = t[u][1] - v;
      if (!std::isfinite(du) || !std::isfinite(dv)) continue;
      sum += std::sqrt(du * du + dv * dv);
      ++n;
      if (!grid) continue;
      // Where the pixel would go under the rotation alone (a point at infinity).
      const Vec3 ray((u - grid->cx) / grid->fx, (v - grid->cy) / grid->fy, 1.0);
      const Vec3 q = R_b_a * ray;
      if (!(q.z() > 1e-6)) continue;
      const double qu = grid->fx * q.x() / q.z() + grid->cx;
      const double qv = grid->fy * q.y() / q.z() + grid->cy;
      sum_rotation += std::hypot(qu - u, qv - v);
      sum_parallax += std::hypot(t[u][0] - qu, t[u][1] - qv);
    }
  }
  FlowMotion m;
  m.valid_fraction = target.total() > 0 ? static_cast<double>(n) / target.total() : 0;
  m.mean_flow_px = n > 0 ? sum / n : 0;
  if (grid) {
    m.mean_rotation_px = n > 0 ? sum_rotation / n : 0;
    m.mean_parallax_px = n > 0 ? sum_parallax / n : 0;
  }
  return m;
}

}  // namespace

FlowMotion measureFlowMotion(const cv::Mat& target, const cv::Mat& weight) {
  return flowMotion(target, weight, nullptr, Mat3::Identity(), cv::Mat());
}

FlowMotion measureFlowMotion(const cv::Mat& target, const cv::Mat& weight, const CameraModel& grid,
                             const Mat3& R_b_a, const cv::Mat& leaning) {
  return flowMotion(target, weight, &grid, R_b_a, leaning);
}

bool isNewKeyframe(const FlowMotion& m, const KeyframePolicy& policy) {
  if (m.valid_fraction < policy.min_valid_fraction) return true;
  if (m.mean_parallax_px < 0 || m.mean_rotation_px < 0) return m.mean_flow_px > policy.flow_px;
  return m.mean_parallax_px > policy.flow_px || m.mean_rotation_px > policy.rotation_px;
}

cv::Mat toGrey(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

}  // namespace radslam
