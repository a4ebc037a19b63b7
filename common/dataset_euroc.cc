// EuRoC ASL reader (mav0/cam0, optional cam1 rectified for stereo, ground truth).
#include <cmath>
#include <functional>
#include <stdexcept>

#include <Eigen/Core>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>

#include "common/dataset_internal.h"

namespace radslam::dataset_internal {
namespace {

constexpr double kMaxStereoGapS = 0.002;  // EuRoC's cameras are hardware-triggered together
constexpr int kMaxImageSide = 100000;     // pixels, as readCameraNode

struct EurocCamera {
  CameraModel model;  // raw (distorted) camera
  SE3 T_body_cam;     // sensor.yaml T_BS
  std::vector<int64_t> stamps_ns;
  std::vector<std::string> files;  // relative to data_dir
  std::string data_dir;
};

// All numbers under root[key], nested sequences flattened ("data: [...]").
std::vector<double> readNumberList(const cv::FileNode& node, const std::string& key,
                                   const std::string& path) {
  const cv::FileNode list = key.empty() ? node : node[key];
  if (list.empty()) throw std::runtime_error(path + ": missing key '" + key + "'");
  std::vector<double> values;
  // Depth-first, keeping the order of the elements.
  std::function<void(const cv::FileNode&)> visit = [&](const cv::FileNode& n) {
    if (n.isSeq()) {
      for (const cv::FileNode& child : n) visit(child);
    } else if (n.isInt() || n.isReal()) {
      // YAML has .nan and .inf: calibration must be finite.
      if (!std::isfinite(n.real()))
        throw std::runtime_error(path + ": key '" + key + "' holds a non-finite number");
      values.push_back(n.real());
    } else {
      throw std::runtime_error(path + ": key '" + key + "' must hold only numbers");
    }
  };
  visit(list);
  return values;
}

SE3 readTbs(const cv::FileNode& root, const std::string& path) {
  const cv::FileNode node = root["T_BS"];
  if (node.empty()) throw std::runtime_error(path + ": missing key 'T_BS'");
  // EuRoC: a map {cols, rows, data: [16]}; also accept a bare list of 16 or 4x4.
  const std::vector<double> v =
      node.isMap() ? readNumberList(node, "data", path) : readNumberList(node, "", path);
  if (v.size() != 16)
    throw std::runtime_error(path + ": T_BS must hold 16 numbers (4x4 row-major), has " +
                             std::to_string(v.size()));
  Mat4 T;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) T(r, c) = v[4 * r + c];
  const Mat3 R = T.topLeftCorner<3, 3>();
  if ((T.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).norm() > 1e-6 ||
      (R.transpose() * R - Mat3::Identity()).norm() > 1e-3)
    throw std::runtime_error(path + ": T_BS is not a rigid transform");
  return SE3(T);
}

EurocCamera readEurocCamera(const std::string& dir) {
  EurocCamera camera;
  const std::string yaml = joinPath(dir, "sensor.yaml");
  cv::FileStorage storage = openYaml(yaml);
  const cv::FileNode root = storage.root();

  const std::string model =
      root["camera_model"].empty() ? "pinhole" : root["camera_model"].string();
  if (model != "pinhole")
    throw std::runtime_error(yaml + ": camera_model '" + model + "' is not supported (pinhole)");
  const std::vector<double> intrinsics = readNumberList(root, "intrinsics", yaml);
  const std::vector<double> resolution = readNumberList(root, "resolution", yaml);
  if (intrinsics.size() != 4 || intrinsics[0] <= 0 || intrinsics[1] <= 0)
    throw std::runtime_error(yaml + ": intrinsics must be [fu, fv, cu, cv] with fu, fv > 0");
  if (resolution.size() != 2 || resolution[0] < 1 || resolution[1] < 1 ||
      resolution[0] > kMaxImageSide || resolution[1] > kMaxImageSide ||
      resolution[0] != std::floor(resolution[0]) || resolution[1] != std::floor(resolution[1]))
    throw std::runtime_error(yaml + ": resolution must be [width, height], integers in [1, " +
                             std::to_string(kMaxImageSide) + "]");
  CameraModel& m = camera.model;
  m.width = static_cast<int>(resolution[0]);
  m.height = static_cast<int>(resolution[1]);
  m.fx = intrinsics[0], m.fy = intrinsics[1], m.cx = intrinsics[2], m.cy = intrinsics[3];

  const std::string distortion =
      root["distortion_model"].empty() ? "none" : root["distortion_model"].string();
  if (distortion == "radial-tangential" || distortion == "radtan") {
    m.type = CameraModel::Type::kRadTan;
    m.distortion = readNumberList(root, "distortion_coefficients", yaml);
    if (m.distortion.size() != 4 && m.distortion.size() != 5)
      throw std::runtime_error(yaml + ": radial-tangential needs 4 or 5 distortion_coefficients");
  } else if (distortion == "equidistant" || distortion == "fisheye") {
    m.type = CameraModel::Type::kEquidistant;
    m.distortion = readNumberList(root, "distortion_coefficients", yaml);
    if (m.distortion.size() != 4)
      throw std::runtime_error(yaml + ": equidistant needs 4 distortion_coefficients");
  } else if (distortion != "none") {
    throw std::runtime_error(yaml + ": unknown distortion_model '" + distortion +
                             "' (radial-tangential, equidistant or none)");
  }
  camera.T_body_cam = readTbs(root, yaml);

  const std::string csv = joinPath(dir, "data.csv");
  for (const TextRow& row : readTextRows(csv, true)) {
    int64_t stamp = 0;
    if (row.fields.size() < 2 || !parseInteger(row.fields[0], &stamp))
      throw std::runtime_error(csv + ":" + std::to_string(row.line) +
                               ": expected 'timestamp_ns,filename'");
    camera.stamps_ns.push_back(stamp);
    camera.files.push_back(row.fields[1]);
  }
  camera.data_dir = joinPath(dir, "data");
  return camera;
}

cv::Mat toCv(const CameraModel& m) {
  return (cv::Mat_<double>(3, 3) << m.fx, 0, m.cx, 0, m.fy, m.cy, 0, 0, 1);
}

// Ground truth mav0/state_groundtruth_estimate0/data.csv rows:
// t_ns, p_RS_R (x y z, m), q_RS (w x y z), ... giving T_world_body.
Trajectory readEurocGroundTruth(const std::string& csv, const SE3& T_body_cam) {
  Trajectory trajectory;
  for (const TextRow& row : readTextRows(csv, true)) {
    int64_t stamp = 0;
    double v[7] = {0, 0, 0, 0, 0, 0, 0};
    bool ok = row.fields.size() >= 8 && parseInteger(row.fields[0], &stamp);
    for (int k = 0; ok && k < 7; ++k) ok = parseNumber(row.fields[1 + k], &v[k]);
    const Eigen::Quaterniond q(v[3], v[4], v[5], v[6]);
    // A norm that overflows would normalise to a zero rotation.
    if (!ok || q.norm() < 1e-6 || !std::isfinite(q.squaredNorm()))
      throw std::runtime_error(csv + ":" + std::to_string(row.line) +
                               ": expected 'timestamp_ns, px, py, pz, qw, qx, qy, qz, ...'");
    const SE3 T_world_body(q, Vec3(v[0], v[1], v[2]));
    trajectory.push_back({static_cast<double>(stamp) * 1e-9, T_world_body * T_body_cam});
  }
  return trajectory;
}

class EurocDataset : public DatasetReader {
 public:
  explicit EurocDataset(const std::string& path) : path_(path) {
    const std::string mav0 = joinPath(path, "mav0");
    if (!isDirectory(mav0)) throw std::runtime_error(path + ": no mav0/ folder (EuRoC layout)");
    left_ = readEurocCamera(joinPath(mav0, "cam0"));
    camera_ = left_.model;
    SE3 T_body_cam = left_.T_body_cam;

    const std::string cam1 = joinPath(mav0, "cam1");
    stereo_ = isFile(joinPath(cam1, "sensor.yaml")) && isFile(joinPath(cam1, "data.csv"));
    if (stereo_) {
      right_ = readEurocCamera(cam1);
      T_body_cam = T_body_cam * setUpRectification(path);
      std::vector<double> t_left, t_right;
      for (int64_t s : left_.stamps_ns) t_left.push_back(static_cast<double>(s) * 1e-9);
      for (int64_t s : right_.stamps_ns) t_right.push_back(static_cast<double>(s) * 1e-9);
      for (const auto& [i, j] : associateTimes(t_left, t_right, kMaxStereoGapS))
        frames_.push_back({left_.stamps_ns[i], left_.files[i], right_.files[j]});
    } else {
      for (size_t i = 0; i < left_.stamps_ns.size(); ++i)
        frames_.push_back({left_.stamps_ns[i], left_.files[i], ""});
    }
    if (frames_.empty())
      throw std::runtime_error(path + ": mav0/cam0/data.csv lists no images" +
                               (stereo_ ? std::string(" with a cam1 partner") : ""));

    const std::string tum_gt = joinPath(path, "groundtruth.txt");
    const std::string euroc_gt = joinPath(mav0, "state_groundtruth_estimate0/data.csv");
    if (isFile(tum_gt)) {
      ground_truth_ = readTumTrajectory(tum_gt);
    } else if (isFile(euroc_gt)) {
      ground_truth_ = readEurocGroundTruth(euroc_gt, T_body_cam);
    }
  }

  std::string name() const override { return "euroc:" + path_; }
  size_t size() const override { return frames_.size(); }
  double timestamp(size_t i) const override {
    return static_cast<double>(frames_.at(i).stamp_ns) * 1e-9;
  }
  const Trajectory& groundTruth() const override { return ground_truth_; }
  bool hasStereo() const override { return stereo_; }

  std::optional<Frame> frame(size_t i, std::string* error) const override {
    if (i >= frames_.size())
      return frameError(error, name() + ": frame " + std::to_string(i) + " out of range");
    const StereoFiles& files = frames_[i];
    Frame frame;
    frame.header.utime = (files.stamp_ns + 500) / 1000;
    frame.frame_index = static_cast<int64_t>(i);
    frame.camera = camera_;
    const cv::Size size(left_.model.width, left_.model.height);
    if (!loadColorImage(joinPath(left_.data_dir, files.left), true, size, &frame.color, error))
      return std::nullopt;
    if (stereo_) {
      cv::Mat right;
      if (!loadColorImage(joinPath(right_.data_dir, files.right), true, size, &right, error))
        return std::nullopt;
      cv::Mat left_rectified;
      cv::remap(frame.color, left_rectified, left_map_[0], left_map_[1], cv::INTER_LINEAR);
      cv::remap(right, frame.right, right_map_[0], right_map_[1], cv::INTER_LINEAR);
      frame.color = left_rectified;
      frame.baseline_m = baseline_m_;
    }
    return frame;
  }

 private:
  struct StereoFiles {
    int64_t stamp_ns = 0;
    std::string left, right;
  };

  // EuRoC's cameras are not rectified: rectify both to a common pinhole camera
  // (zero disparity at infinity, only valid pixels) and return T_cam0_rect.
  SE3 setUpRectification(const std::string& path) {
    const CameraModel& m0 = left_.model;
    const CameraModel& m1 = right_.model;
    if (m0.width != m1.width || m0.height != m1.height)
      throw std::runtime_error(path + ": cam0 and cam1 resolutions differ");
    if ((m0.type == CameraModel::Type::kEquidistant) !=
        (m1.type == CameraModel::Type::kEquidistant))
      throw std::runtime_error(path + ": cam0 and cam1 distortion models differ");
    // stereoRectify wants R, T with p_cam1 = R p_cam0 + T.
    const SE3 T_cam1_cam0 = right_.T_body_cam.inverse() * left_.T_body_cam;
    cv::Mat R, T, R0, R1, P0, P1, Q;
    cv::eigen2cv(T_cam1_cam0.rotation(), R);
    cv::eigen2cv(T_cam1_cam0.translation(), T);
    const cv::Size size(m0.width, m0.height);
    const cv::Mat K0 = toCv(m0), K1 = toCv(m1);
    const cv::Mat D0(m0.distortion, true), D1(m1.distortion, true);
    if (T_cam1_cam0.translation().norm() < 1e-6)
      throw std::runtime_error(path + ": cam0 and cam1 have the same position (no baseline)");
    if (m0.type == CameraModel::Type::kEquidistant) {
      cv::fisheye::stereoRectify(K0, D0, K1, D1, size, R, T, R0, R1, P0, P1, Q,
                                 cv::CALIB_ZERO_DISPARITY, size, 0.0, 1.0);
      cv::fisheye::initUndistortRectifyMap(K0, D0, R0, P0, size, CV_16SC2, left_map_[0],
                                           left_map_[1]);
      cv::fisheye::initUndistortRectifyMap(K1, D1, R1, P1, size, CV_16SC2, right_map_[0],
                                           right_map_[1]);
    } else {
      cv::stereoRectify(K0, D0, K1, D1, size, R, T, R0, R1, P0, P1, Q, cv::CALIB_ZERO_DISPARITY,
                        0.0, size);
      cv::initUndistortRectifyMap(K0, D0, R0, P0, size, CV_16SC2, left_map_[0], left_map_[1]);
      cv::initUndistortRectifyMap(K1, D1, R1, P1, size, CV_16SC2, right_map_[0], right_map_[1]);
    }
    // P1 = [f 0 cx -f*b; 0 f cy 0; 0 0 1 0] for a horizontal pair with cam1 on the right.
    if (std::abs(P1.at<double>(1, 3)) > std::abs(P1.at<double>(0, 3)) || P1.at<double>(0, 3) >= 0)
      throw std::runtime_error(path +
                               ": cam1 is not to the right of cam0; only horizontal "
                               "stereo pairs are supported");
    baseline_m_ = -P1.at<double>(0, 3) / P1.at<double>(0, 0);
    camera_ = CameraModel();
    camera_.width = m0.width;
    camera_.height = m0.height;
    camera_.fx = P0.at<double>(0, 0);
    camera_.fy = P0.at<double>(1, 1);
    camera_.cx = P0.at<double>(0, 2);
    camera_.cy = P0.at<double>(1, 2);
    // p_rect = R0 p_cam0, so T_cam0_rect rotates by R0^T.
    Mat3 R0_eigen;
    cv::cv2eigen(R0, R0_eigen);
    return SE3(SO3(Mat3(R0_eigen.transpose())), Vec3::Zero());
  }

  std::string path_;
  EurocCamera left_, right_;
  bool stereo_ = false;
  CameraModel camera_;  // raw cam0, or the rectified pinhole left camera in stereo
  double baseline_m_ = 0;
  cv::Mat left_map_[2], right_map_[2];
  std::vector<StereoFiles> frames_;
  Trajectory ground_truth_;
};

}  // namespace

std::unique_ptr<DatasetReader> openEuroc(const std::string& path) {
  return std::make_unique<EurocDataset>(path);
}

}  // namespace radslam::dataset_internal
