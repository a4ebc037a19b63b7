// TUM RGB-D reader: rgb.txt / depth.txt / associations.txt, groundtruth.txt.
#include <algorithm>
#include <filesystem>
#include <stdexcept>

#include "common/dataset_internal.h"

namespace radslam::dataset_internal {
namespace {

constexpr double kTumDepthMetresPerUnit = 1.0 / 5000.0;  // TUM depth PNG: 5000 units per metre
constexpr double kMaxRgbDepthGapS = 0.02;                // as TUM's associate.py

struct StampedFile {
  double t = 0;      // s
  std::string file;  // relative to the sequence folder
};

struct TumEntry {
  double t = 0;  // colour time stamp, s
  std::string rgb;
  std::string depth;   // "" in monocular sequences
  double t_depth = 0;  // s
};

// "t file" rows of an index (rgb.txt, depth.txt) or, when the index is absent,
// the folder's PNGs: TUM names every image by its time stamp.
std::vector<StampedFile> readImageList(const std::string& root, const std::string& index,
                                       const std::string& folder) {
  std::vector<StampedFile> files;
  const std::string index_path = joinPath(root, index);
  if (isFile(index_path)) {
    for (const TextRow& row : readTextRows(index_path, false)) {
      StampedFile file;
      if (row.fields.size() < 2 || !parseNumber(row.fields[0], &file.t))
        throw std::runtime_error(index_path + ":" + std::to_string(row.line) +
                                 ": expected 'timestamp filename'");
      file.file = row.fields[1];
      files.push_back(file);
    }
    return files;
  }
  const std::string dir = joinPath(root, folder);
  if (!isDirectory(dir)) return files;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    StampedFile file;
    if (entry.path().extension() != ".png" || !parseNumber(entry.path().stem().string(), &file.t))
      continue;
    file.file = folder + "/" + entry.path().filename().string();
    files.push_back(file);
  }
  std::sort(files.begin(), files.end(),
            [](const StampedFile& a, const StampedFile& b) { return a.t < b.t; });
  return files;
}

// "t_rgb rgb/x.png t_depth depth/y.png" (either order of the two pairs).
std::vector<TumEntry> readAssociations(const std::string& path) {
  std::vector<TumEntry> entries;
  for (const TextRow& row : readTextRows(path, false)) {
    double t_first = 0, t_second = 0;
    if (row.fields.size() < 4 || !parseNumber(row.fields[0], &t_first) ||
        !parseNumber(row.fields[2], &t_second))
      throw std::runtime_error(path + ":" + std::to_string(row.line) +
                               ": expected 't_rgb rgb_file t_depth depth_file'");
    const bool depth_first =
        row.fields[1].rfind("depth", 0) == 0 && row.fields[3].rfind("rgb", 0) == 0;
    if (depth_first) {
      entries.push_back({t_second, row.fields[3], row.fields[1], t_first});
    } else {
      entries.push_back({t_first, row.fields[1], row.fields[3], t_second});
    }
  }
  return entries;
}

// The Kinect colour camera of freiburg1 and 2 has a rolling shutter. Its readout is not
// published; 25 ms is where the tracker's orientation error on fr1/rpy is lowest, between
// 20 and 30 ms (docs/tracker.md, "Rolling shutter").
constexpr double kKinectReadoutS = 0.025;

// Intrinsics are not part of the TUM files: camera.yaml, else the calibration
// the TUM site gives for the sensor named in the folder name (freiburg1/2/3).
CameraModel tumCamera(const std::string& path) {
  const std::string yaml = joinPath(path, "camera.yaml");
  if (isFile(yaml)) {
    cv::FileStorage storage = openYaml(yaml);
    return readCameraNode(storage.root(), yaml);
  }
  const std::string absolute = std::filesystem::absolute(path).string();
  const size_t at = absolute.rfind("freiburg");
  const char sensor = at == std::string::npos || at + 8 >= absolute.size() ? '?' : absolute[at + 8];
  CameraModel camera;
  camera.width = 640;
  camera.height = 480;
  if (sensor == '1') {
    camera.type = CameraModel::Type::kRadTan;
    camera.fx = 517.3, camera.fy = 516.5, camera.cx = 318.6, camera.cy = 255.3;
    camera.distortion = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
    camera.readout_s = kKinectReadoutS;
  } else if (sensor == '2') {
    camera.type = CameraModel::Type::kRadTan;
    camera.fx = 520.9, camera.fy = 521.0, camera.cx = 325.1, camera.cy = 249.7;
    camera.distortion = {0.2312, -0.7849, -0.0033, -0.0001, 0.9172};
    camera.readout_s = kKinectReadoutS;
  } else if (sensor == '3') {
    // fr3 images are already undistorted.
    camera.fx = 535.4, camera.fy = 539.2, camera.cx = 320.1, camera.cy = 247.6;
  } else {
    throw std::runtime_error(path +
                             ": cannot tell the TUM camera: the folder name contains no "
                             "freiburg1/2/3 and there is no camera.yaml (keys width height fx fy "
                             "cx cy, optional k1 k2 p1 p2 k3)");
  }
  return camera;
}

class TumDataset : public DatasetReader {
 public:
  explicit TumDataset(const std::string& path) : path_(path), camera_(tumCamera(path)) {
    const std::string associations = joinPath(path, "associations.txt");
    if (isFile(associations)) {
      entries_ = readAssociations(associations);
      has_depth_ = true;
    } else {
      const std::vector<StampedFile> rgb = readImageList(path, "rgb.txt", "rgb");
      const std::vector<StampedFile> depth = readImageList(path, "depth.txt", "depth");
      has_depth_ = !depth.empty();
      if (!has_depth_) {
        for (const StampedFile& f : rgb) entries_.push_back({f.t, f.file, "", f.t});
      } else {
        std::vector<double> t_rgb, t_depth;
        for (const StampedFile& f : rgb) t_rgb.push_back(f.t);
        for (const StampedFile& f : depth) t_depth.push_back(f.t);
        for (const auto& [i, j] : associateTimes(t_rgb, t_depth, kMaxRgbDepthGapS))
          entries_.push_back({rgb[i].t, rgb[i].file, depth[j].file, depth[j].t});
        if (entries_.empty() && !rgb.empty())
          throw std::runtime_error(path + ": no colour image has a depth image within 20 ms");
      }
    }
    if (entries_.empty())
      throw std::runtime_error(path +
                               ": no colour images (no associations.txt, no rgb.txt and no PNG "
                               "in rgb/)");
    const std::string gt = joinPath(path, "groundtruth.txt");
    if (isFile(gt)) ground_truth_ = readTumTrajectory(gt);
  }

  std::string name() const override { return "tum:" + path_; }
  size_t size() const override { return entries_.size(); }
  double timestamp(size_t i) const override { return entries_.at(i).t; }
  const Trajectory& groundTruth() const override { return ground_truth_; }
  bool hasDepth() const override { return has_depth_; }

  std::optional<Frame> frame(size_t i, std::string* error) const override {
    if (i >= entries_.size())
      return frameError(error, name() + ": frame " + std::to_string(i) + " out of range");
    const TumEntry& entry = entries_[i];
    Frame frame;
    frame.header.utime = secondsToUtime(entry.t);
    frame.frame_index = static_cast<int64_t>(i);
    frame.camera = camera_;
    const cv::Size size(camera_.width, camera_.height);
    if (!loadColorImage(joinPath(path_, entry.rgb), false, size, &frame.color, error))
      return std::nullopt;
    if (has_depth_) {
      if (!loadDepthImage(joinPath(path_, entry.depth), kTumDepthMetresPerUnit, size, &frame.depth,
                          error))
        return std::nullopt;
      frame.depth_wire_scale = kTumDepthMetresPerUnit;  // lossless: the source's quantisation
      frame.depth_time_offset_s = entry.t_depth - entry.t;
    }
    return frame;
  }

 private:
  std::string path_;
  CameraModel camera_;
  std::vector<TumEntry> entries_;
  bool has_depth_ = false;
  Trajectory ground_truth_;
};

}  // namespace

std::unique_ptr<DatasetReader> openTum(const std::string& path) {
  return std::make_unique<TumDataset>(path);
}

}  // namespace radslam::dataset_internal
