// Replica reader in the NICE-SLAM layout: results/frameNNNNNN.jpg,
// results/depthNNNNNN.png, traj.txt, cam_params.json.
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/dataset_internal.h"

namespace radslam::dataset_internal {
namespace {

// Replica is rendered, it has no clock: frames are stamped at NICE-SLAM's 30 Hz.
constexpr double kReplicaRateHz = 30.0;
constexpr double kReplicaDefaultDepthScale = 6553.5;  // depth units per metre
constexpr int kMaxImageSide = 100000;                 // pixels, as readCameraNode

double jsonNumber(const cv::FileNode& camera, const std::string& key, const std::string& path) {
  const cv::FileNode value = camera[key];
  if (value.empty()) throw std::runtime_error(path + ": \"camera\" has no \"" + key + "\"");
  if (!value.isInt() && !value.isReal())
    throw std::runtime_error(path + ": \"camera\".\"" + key + "\" is not a number");
  if (!std::isfinite(value.real()))
    throw std::runtime_error(path + ": \"camera\".\"" + key + "\" is not finite");
  return value.real();
}

class ReplicaDataset : public DatasetReader {
 public:
  explicit ReplicaDataset(const std::string& path) : path_(path) {
    results_ = joinPath(path, "results");
    if (!isDirectory(results_)) throw std::runtime_error(path + ": no results/ folder");
    readCameraParams(path);

    for (const char* extension : {".jpg", ".png"})
      for (const auto& [number, file] : listNumberedFiles(results_, "frame", extension))
        frames_.push_back({number, file, "depth" + file.substr(5, file.size() - 5 - 4) + ".png"});
    std::sort(frames_.begin(), frames_.end(),
              [](const Image& a, const Image& b) { return a.number < b.number; });
    if (frames_.empty()) throw std::runtime_error(results_ + ": no frameNNNNNN.jpg images");
    has_depth_ = !listNumberedFiles(results_, "depth", ".png").empty();

    const std::string traj = joinPath(path, "traj.txt");
    if (isFile(traj)) {
      const std::vector<NumericRow> rows =
          readNumericRows(traj, 16, "4x4 row-major T_world_cam, OpenCV camera axes");
      for (const Image& image : frames_) {
        if (image.number >= static_cast<int64_t>(rows.size())) continue;
        const NumericRow& row = rows[image.number];
        Mat4 T;
        for (int r = 0; r < 4; ++r)
          for (int c = 0; c < 4; ++c) T(r, c) = row.values[4 * r + c];
        if ((T.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).norm() > 1e-6 ||
            std::abs(T.topLeftCorner<3, 3>().determinant() - 1) > 1e-3)
          throw std::runtime_error(traj + ":" + std::to_string(row.line) +
                                   ": not a rigid 4x4 transform");
        ground_truth_.push_back({timeOf(image), SE3(T)});
      }
    }
  }

  std::string name() const override { return "replica:" + path_; }
  size_t size() const override { return frames_.size(); }
  double timestamp(size_t i) const override { return timeOf(frames_.at(i)); }
  const Trajectory& groundTruth() const override { return ground_truth_; }
  bool hasDepth() const override { return has_depth_; }

  std::optional<Frame> frame(size_t i, std::string* error) const override {
    if (i >= frames_.size())
      return frameError(error, name() + ": frame " + std::to_string(i) + " out of range");
    const Image& image = frames_[i];
    Frame frame;
    frame.header.utime = secondsToUtime(timeOf(image));
    frame.frame_index = static_cast<int64_t>(i);
    frame.camera = camera_;
    const cv::Size size(camera_.width, camera_.height);
    if (!loadColorImage(joinPath(results_, image.color), false, size, &frame.color, error))
      return std::nullopt;
    if (has_depth_) {
      if (!loadDepthImage(joinPath(results_, image.depth), 1.0 / depth_scale_, size, &frame.depth,
                          error))
        return std::nullopt;
      frame.depth_wire_scale = 1.0 / depth_scale_;
    }
    return frame;
  }

 private:
  struct Image {
    int64_t number = 0;  // NNNNNN of the file names = row of traj.txt
    std::string color, depth;
  };

  static double timeOf(const Image& image) {
    return static_cast<double>(image.number) / kReplicaRateHz;
  }

  // cam_params.json: {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}, found
  // in results/, in the scene folder or (NICE-SLAM's Replica/) one level up.
  void readCameraParams(const std::string& path) {
    std::string json;
    for (const std::string& candidate :
         {joinPath(results_, "cam_params.json"), joinPath(path, "cam_params.json"),
          joinPath(path, "../cam_params.json")})
      if (json.empty() && isFile(candidate)) json = candidate;
    if (json.empty())
      throw std::runtime_error(path +
                               ": cam_params.json not found (looked in results/, the scene "
                               "folder and one level up)");
    cv::FileStorage storage;
    try {
      storage.open(json, cv::FileStorage::READ | cv::FileStorage::FORMAT_JSON);
    } catch (const cv::Exception& e) {
      throw std::runtime_error(json + ": cannot parse JSON: " + e.err);
    }
    const cv::FileNode camera = storage["camera"];
    if (!storage.isOpened() || !camera.isMap())
      throw std::runtime_error(json + ": expected a \"camera\" object");
    const double width = jsonNumber(camera, "w", json);
    const double height = jsonNumber(camera, "h", json);
    // Checked before the conversion to int, which is undefined out of range.
    if (width < 1 || height < 1 || width > kMaxImageSide || height > kMaxImageSide ||
        width != std::floor(width) || height != std::floor(height))
      throw std::runtime_error(json + ": w and h must be integers in [1, " +
                               std::to_string(kMaxImageSide) + "]");
    camera_.width = static_cast<int>(width);
    camera_.height = static_cast<int>(height);
    camera_.fx = jsonNumber(camera, "fx", json);
    camera_.fy = jsonNumber(camera, "fy", json);
    camera_.cx = jsonNumber(camera, "cx", json);
    camera_.cy = jsonNumber(camera, "cy", json);
    depth_scale_ =
        camera["scale"].empty() ? kReplicaDefaultDepthScale : jsonNumber(camera, "scale", json);
    if (camera_.width < 1 || camera_.height < 1 || camera_.fx <= 0 || camera_.fy <= 0 ||
        !(depth_scale_ > 0))
      throw std::runtime_error(json + ": implausible camera (w, h, fx, fy and scale must be > 0)");
  }

  std::string path_;
  std::string results_;
  CameraModel camera_;  // pinhole: Replica is rendered without distortion
  double depth_scale_ = kReplicaDefaultDepthScale;
  std::vector<Image> frames_;
  bool has_depth_ = false;
  Trajectory ground_truth_;
};

}  // namespace

std::unique_ptr<DatasetReader> openReplica(const std::string& path) {
  return std::make_unique<ReplicaDataset>(path);
}

}  // namespace radslam::dataset_internal
