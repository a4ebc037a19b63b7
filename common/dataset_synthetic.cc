// Reader of radslam's own synthetic format (written by the synthetic generator):
//   camera.yaml    width height fx fy cx cy baseline_m depth_scale (m per uint16 unit)
//   times.txt      one time (s) per frame
//   rgb/%06d.png   BGR; right/%06d.png, depth/%06d.png, instance/%06d.png,
//                  class/%06d.png optional (depth, instance, class uint16)
//   groundtruth.txt  TUM format T_world_cam, one per frame
//   objects.txt    optional "t object_id class_id tx ty tz qx qy qz qw" (T_world_object)
//   classes.yaml   optional sequence "classes" of {id, name, dynamic, joint, parent}
#include <cmath>
#include <cstdio>
#include <set>
#include <stdexcept>

#include "common/dataset_internal.h"

namespace radslam::dataset_internal {
namespace {

std::string numberedFile(const std::string& dir, size_t i) {
  char name[32];
  std::snprintf(name, sizeof(name), "%06zu.png", i);
  return joinPath(dir, name);
}

std::vector<ObjectPoseSample> readObjects(const std::string& path) {
  std::vector<ObjectPoseSample> samples;
  for (const NumericRow& row :
       readNumericRows(path, 10, "t object_id class_id tx ty tz qx qy qz qw")) {
    const std::vector<double>& v = row.values;
    const std::string at = path + ":" + std::to_string(row.line) + ": ";
    if (v[1] != std::floor(v[1]) || v[2] != std::floor(v[2]) || std::abs(v[1]) > 2e9 ||
        std::abs(v[2]) > 2e9)
      throw std::runtime_error(at + "object_id and class_id must be integers");
    const Eigen::Quaterniond q(v[9], v[6], v[7], v[8]);
    if (q.norm() < 1e-6 || !std::isfinite(q.squaredNorm()))
      throw std::runtime_error(at + "quaternion norm is zero or overflows");
    ObjectPoseSample sample;
    sample.t = v[0];
    sample.object_id = static_cast<int32_t>(v[1]);
    sample.class_id = static_cast<int32_t>(v[2]);
    sample.T_world_object = SE3(q, Vec3(v[3], v[4], v[5]));
    samples.push_back(sample);
  }
  return samples;
}

std::vector<SemanticClass> readClasses(const std::string& path) {
  cv::FileStorage storage = openYaml(path);
  const cv::FileNode list = storage["classes"];
  if (!list.isSeq()) throw std::runtime_error(path + ": expected a sequence 'classes'");
  std::vector<SemanticClass> classes;
  std::set<int32_t> ids;
  std::set<std::string> names;
  for (const cv::FileNode& node : list) {
    const std::string at = path + ": class " + std::to_string(classes.size()) + ": ";
    if (!node.isMap() || !node["id"].isInt() || !node["name"].isString())
      throw std::runtime_error(at + "needs an integer 'id' and a string 'name'");
    SemanticClass c;
    c.id = static_cast<int32_t>(static_cast<int>(node["id"]));
    c.name = node["name"].string();
    // real() of a string node is DBL_MAX: check the type before converting.
    const cv::FileNode dynamic = node["dynamic"];
    if (!dynamic.empty() && !dynamic.isInt())
      throw std::runtime_error(at + "'dynamic' must be 0 or 1");
    c.dynamic = !dynamic.empty() && static_cast<int>(dynamic) != 0;
    const std::string joint = node["joint"].empty() ? "free" : node["joint"].string();
    if (joint == "free") {
      c.joint = JointType::kFree;
    } else if (joint == "planar") {
      c.joint = JointType::kPlanar;
    } else if (joint == "revolute") {
      c.joint = JointType::kRevolute;
    } else {
      throw std::runtime_error(at + "unknown joint '" + joint + "' (free, planar, revolute)");
    }
    c.parent = node["parent"].empty() ? "" : node["parent"].string();
    if (c.name.empty() || !ids.insert(c.id).second || !names.insert(c.name).second)
      throw std::runtime_error(at + "empty or repeated name or id ('" + c.name + "', " +
                               std::to_string(c.id) + ")");
    classes.push_back(c);
  }
  for (const SemanticClass& c : classes)
    if (!c.parent.empty() && names.count(c.parent) == 0)
      throw std::runtime_error(path + ": class '" + c.name + "' has unknown parent '" + c.parent +
                               "'");
  return classes;
}

class SyntheticDataset : public DatasetReader {
 public:
  explicit SyntheticDataset(const std::string& path) : path_(path) {
    const std::string yaml = joinPath(path, "camera.yaml");
    cv::FileStorage storage = openYaml(yaml);
    camera_ = readCameraNode(storage.root(), yaml);
    const cv::FileNode baseline = storage["baseline_m"];
    const cv::FileNode scale = storage["depth_scale"];
    baseline_m_ = baseline.isInt() || baseline.isReal() ? baseline.real() : 0.0;
    depth_scale_ = scale.isInt() || scale.isReal() ? scale.real() : 0.0;

    const std::string times = joinPath(path, "times.txt");
    if (!isFile(times)) throw std::runtime_error(times + ": time stamps file not found");
    times_ = readTimes(times);
    if (times_.empty()) throw std::runtime_error(times + ": no frames");

    has_right_ = isDirectory(joinPath(path, "right"));
    has_depth_ = isDirectory(joinPath(path, "depth"));
    has_instance_ = isDirectory(joinPath(path, "instance"));
    has_class_ = isDirectory(joinPath(path, "class"));
    if (has_right_ && !(baseline_m_ > 0))
      throw std::runtime_error(yaml + ": right/ exists but baseline_m is missing or not positive");
    if (has_depth_ && !(depth_scale_ > 0))
      throw std::runtime_error(yaml + ": depth/ exists but depth_scale is missing or not positive");

    const std::string gt = joinPath(path, "groundtruth.txt");
    if (isFile(gt)) ground_truth_ = readTumTrajectory(gt);
    const std::string objects = joinPath(path, "objects.txt");
    if (isFile(objects)) objects_ = readObjects(objects);
    const std::string classes = joinPath(path, "classes.yaml");
    if (isFile(classes)) classes_ = readClasses(classes);
  }

  std::string name() const override { return "synthetic:" + path_; }
  size_t size() const override { return times_.size(); }
  double timestamp(size_t i) const override { return times_.at(i); }
  const Trajectory& groundTruth() const override { return ground_truth_; }
  std::vector<ObjectPoseSample> objectGroundTruth() const override { return objects_; }
  std::vector<SemanticClass> classes() const override { return classes_; }
  bool hasDepth() const override { return has_depth_; }
  bool hasStereo() const override { return has_right_; }

  std::optional<Frame> frame(size_t i, std::string* error) const override {
    if (i >= times_.size())
      return frameError(error, name() + ": frame " + std::to_string(i) + " out of range");
    Frame frame;
    frame.header.utime = secondsToUtime(times_[i]);
    frame.frame_index = static_cast<int64_t>(i);
    frame.camera = camera_;
    const cv::Size size(camera_.width, camera_.height);
    if (!loadColorImage(numberedFile(joinPath(path_, "rgb"), i), false, size, &frame.color, error))
      return std::nullopt;
    if (has_right_) {
      if (!loadColorImage(numberedFile(joinPath(path_, "right"), i), false, size, &frame.right,
                          error))
        return std::nullopt;
      frame.baseline_m = baseline_m_;
    }
    if (has_depth_) {
      if (!loadDepthImage(numberedFile(joinPath(path_, "depth"), i), depth_scale_, size,
                          &frame.depth, error))
        return std::nullopt;
      frame.depth_wire_scale = depth_scale_;
    }
    if (has_instance_ && !loadUint16Image(numberedFile(joinPath(path_, "instance"), i), size,
                                          &frame.instance, error))
      return std::nullopt;
    if (has_class_ &&
        !loadUint16Image(numberedFile(joinPath(path_, "class"), i), size, &frame.class_id, error))
      return std::nullopt;
    return frame;
  }

 private:
  std::string path_;
  CameraModel camera_;
  double baseline_m_ = 0;   // m
  double depth_scale_ = 0;  // m per depth unit
  std::vector<double> times_;
  bool has_right_ = false, has_depth_ = false, has_instance_ = false, has_class_ = false;
  Trajectory ground_truth_;
  std::vector<ObjectPoseSample> objects_;
  std::vector<SemanticClass> classes_;
};

}  // namespace

std::unique_ptr<DatasetReader> openSynthetic(const std::string& path) {
  return std::make_unique<SyntheticDataset>(path);
}

}  // namespace radslam::dataset_internal
