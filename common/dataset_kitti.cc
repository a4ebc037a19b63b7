// KITTI odometry reader: sequences/XX with image_0 (+ image_1), calib.txt,
// times.txt, and ground truth from ../../poses/XX.txt.
#include <cmath>
#include <filesystem>
#include <map>
#include <stdexcept>

#include "common/dataset_internal.h"

namespace radslam::dataset_internal {
namespace {

// calib.txt rows "P0: 12 numbers" (3x4 row-major projection matrices).
std::map<std::string, std::vector<double>> readKittiCalib(const std::string& path) {
  std::map<std::string, std::vector<double>> matrices;
  for (const TextRow& row : readTextRows(path, false)) {
    std::string key = row.fields[0];
    if (key.empty() || key.back() != ':') continue;
    key.pop_back();
    std::vector<double> values;
    for (size_t k = 1; k < row.fields.size(); ++k) {
      double v = 0;
      if (!parseNumber(row.fields[k], &v))
        throw std::runtime_error(path + ":" + std::to_string(row.line) + ": '" + row.fields[k] +
                                 "' is not a number");
      values.push_back(v);
    }
    matrices[key] = values;
  }
  return matrices;
}

const std::vector<double>& projection(const std::map<std::string, std::vector<double>>& calib,
                                      const std::string& key, const std::string& path) {
  const auto it = calib.find(key);
  if (it == calib.end()) throw std::runtime_error(path + ": no " + key + " line");
  if (it->second.size() != 12 || it->second[0] <= 0 || it->second[5] <= 0)
    throw std::runtime_error(path + ": " + key +
                             " must be 12 numbers (3x4 row-major) with positive focal lengths");
  return it->second;
}

class KittiDataset : public DatasetReader {
 public:
  explicit KittiDataset(const std::string& path) : path_(path) {
    const std::string calib_path = joinPath(path, "calib.txt");
    if (!isFile(calib_path)) throw std::runtime_error(calib_path + ": calibration file not found");
    const auto calib = readKittiCalib(calib_path);
    const std::vector<double>& P0 = projection(calib, "P0", calib_path);
    camera_.fx = P0[0], camera_.cx = P0[2], camera_.fy = P0[5], camera_.cy = P0[6];

    const std::string times_path = joinPath(path, "times.txt");
    if (!isFile(times_path)) throw std::runtime_error(times_path + ": time stamps file not found");
    const std::vector<double> times = readTimes(times_path);

    // times.txt and poses cover the whole sequence; only images on disk are frames.
    const std::string left_dir = joinPath(path, "image_0");
    if (!isDirectory(left_dir)) throw std::runtime_error(path + ": no image_0/ folder");
    for (const auto& [number, file] : listNumberedFiles(left_dir, "", ".png")) {
      if (number >= static_cast<int64_t>(times.size())) continue;
      images_.push_back({number, times[number], file});
    }
    if (images_.empty())
      throw std::runtime_error(left_dir + ": no PNG image with a time stamp in times.txt");

    right_dir_ = joinPath(path, "image_1");
    if (isDirectory(right_dir_)) {
      const std::vector<double>& P1 = projection(calib, "P1", calib_path);
      baseline_m_ = -P1[3] / P1[0];
      // The division overflows for a tiny focal length.
      if (!std::isfinite(baseline_m_) || baseline_m_ <= 0)
        throw std::runtime_error(calib_path + ": P1 gives no finite positive stereo baseline");
    }

    const std::filesystem::path sequence = std::filesystem::absolute(path);
    const std::string poses =
        (sequence.parent_path().parent_path() / "poses" / (sequence.filename().string() + ".txt"))
            .string();
    if (isFile(poses)) {
      const Trajectory all = readKittiTrajectory(poses);
      for (const Image& image : images_)
        if (image.number < static_cast<int64_t>(all.size()))
          ground_truth_.push_back({image.t, all[image.number].T_world_cam});
    }
  }

  std::string name() const override { return "kitti:" + path_; }
  size_t size() const override { return images_.size(); }
  double timestamp(size_t i) const override { return images_.at(i).t; }
  const Trajectory& groundTruth() const override { return ground_truth_; }
  bool hasStereo() const override { return baseline_m_ > 0; }

  std::optional<Frame> frame(size_t i, std::string* error) const override {
    if (i >= images_.size())
      return frameError(error, name() + ": frame " + std::to_string(i) + " out of range");
    const Image& image = images_[i];
    Frame frame;
    frame.header.utime = secondsToUtime(image.t);
    frame.frame_index = static_cast<int64_t>(i);
    if (!loadColorImage(joinPath(joinPath(path_, "image_0"), image.file), true, cv::Size(),
                        &frame.color, error))
      return std::nullopt;
    frame.camera = camera_;
    frame.camera.width = frame.color.cols;
    frame.camera.height = frame.color.rows;
    if (hasStereo()) {
      // KITTI's pairs are already rectified.
      if (!loadColorImage(joinPath(right_dir_, image.file), true, frame.color.size(), &frame.right,
                          error))
        return std::nullopt;
      frame.baseline_m = baseline_m_;
    }
    return frame;
  }

 private:
  struct Image {
    int64_t number = 0;  // index in the sequence (row of times.txt and poses)
    double t = 0;        // s
    std::string file;
  };

  std::string path_;
  std::string right_dir_;
  CameraModel camera_;  // pinhole; size filled from each image
  double baseline_m_ = 0;
  std::vector<Image> images_;
  Trajectory ground_truth_;
};

}  // namespace

std::unique_ptr<DatasetReader> openKitti(const std::string& path) {
  return std::make_unique<KittiDataset>(path);
}

}  // namespace radslam::dataset_internal
