#include "mapper/mapper.h"

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <stdexcept>

#include <opencv2/imgproc.hpp>

#include "mapper/field_io.h"

namespace radslam {

double medianDepth(const Keyframe& keyframe) {
  if (keyframe.depth.empty() || keyframe.depth.type() != CV_32FC1) return 0;
  std::vector<float> depths;
  const int step = std::max(1, keyframe.depth.cols / 160);  // about 160 x 120 samples suffice
  for (int y = 0; y < keyframe.depth.rows; y += step)
    for (int x = 0; x < keyframe.depth.cols; x += step) {
      const float d = keyframe.depth.at<float>(y, x);
      if (d > 0 && std::isfinite(d)) depths.push_back(d);
    }
  if (depths.empty()) return 0;
  std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
  return depths[depths.size() / 2];
}

cv::Mat fillDepthHoles(const cv::Mat& depth) {
  CV_Assert(depth.type() == CV_32FC1);
  cv::Mat valid = depth > 0;
  const int holes = static_cast<int>(depth.total()) - cv::countNonZero(valid);
  if (holes == 0 || holes == static_cast<int>(depth.total())) return depth.clone();
  // Grow the valid depths into the holes on a coarse grid (max of valid neighbours), then
  // copy them into the holes at full resolution.
  constexpr int kCell = 8;
  const cv::Size coarse((depth.cols + kCell - 1) / kCell, (depth.rows + kCell - 1) / kCell);
  cv::Mat low(coarse, CV_32FC1, cv::Scalar(0));
  for (int y = 0; y < depth.rows; ++y)
    for (int x = 0; x < depth.cols; ++x) {
      const float d = depth.at<float>(y, x);
      float& l = low.at<float>(y / kCell, x / kCell);
      if (d > 0) l = std::max(l, d);
    }
  for (int iteration = 0; iteration < coarse.width + coarse.height; ++iteration) {
    if (cv::countNonZero(low > 0) == static_cast<int>(low.total())) break;
    cv::Mat grown;
    cv::dilate(low, grown, cv::Mat());
    grown.copyTo(low, low <= 0);
  }
  cv::Mat out = depth.clone();
  for (int y = 0; y < depth.rows; ++y)
    for (int x = 0; x < depth.cols; ++x)
      if (!valid.at<uint8_t>(y, x)) out.at<float>(y, x) = low.at<float>(y / kCell, x / kCell);
  return out;
}

Mapper::Mapper(const MapperParams& params) : params_(params), trainer_(params.trainer) {
  if (params.levels < 1 || params.levels > Field::kMaxLevels || params.level_ratio < 1)
    throw std::invalid_argument("mapper: levels must be 1.." + std::to_string(Field::kMaxLevels) +
                                " and level_ratio >= 1");
  if (params.fine_voxel_size < 0 || !(params.fine_voxel_rel > 0))
    throw std::invalid_argument("mapper: fine_voxel_size must be >= 0 and fine_voxel_rel > 0");
  if (params.sh_degree != 0 && params.sh_degree != 1)
    throw std::invalid_argument("mapper: sh_degree must be 0 or 1");
  if (params.alloc_stride < 1 || !(params.alloc_sigma_range > 0))
    throw std::invalid_argument("mapper: alloc_stride must be >= 1 and alloc_sigma_range > 0");
  if (!(params.render_step_fine > 0) || params.render_threads < 1)
    throw std::invalid_argument("mapper: render_step_fine must be > 0 and render_threads >= 1");
}

void Mapper::initializeField() {
  if (field_.initialized()) return;
  double fine = params_.fine_voxel_size;
  if (fine <= 0) {
    // Scale-aware default: a fixed fraction of the median depth of the first keyframe with
    // depth, so a monocular map of any scale gets the same resolution in pixels.
    for (int i = 0; i < keyframes_.size() && fine <= 0; ++i) {
      const double median = medianDepth(keyframes_.entry(i).keyframe);
      if (median > 0) fine = params_.fine_voxel_rel * median;
    }
  }
  if (fine <= 0) return;  // no depth yet
  field_ = Field(FieldGeometry::make(fine, params_.levels, params_.level_ratio, params_.sh_degree,
                                     static_cast<float>(params_.density_bias)));
  field_.restoreVersion(version_floor_);
  for (int i = 0; i < keyframes_.size(); ++i) allocateFor(keyframes_.entry(i));
}

void Mapper::allocateFor(const KeyframeEntry& entry) {
  if (!field_.initialized()) return;
  const Keyframe& kf = entry.keyframe;
  const SamplingParams sp = trainer_.samplingFor(field_.geometry().fineVoxelSize());
  const float fine = static_cast<float>(field_.geometry().fineVoxelSize());
  const Eigen::Matrix3f R = entry.T_world_cam.rotation().cast<float>();
  const Eigen::Vector3f t = entry.T_world_cam.translation().cast<float>();
  const cv::Mat& mask = kf.dynamic_mask;
  const int fine_level = field_.numLevels() - 1;
  const int first_new = field_.numBlocks(fine_level);
  std::vector<float> valid_depths;
  for (int y = params_.alloc_stride / 2; y < kf.camera.height; y += params_.alloc_stride)
    for (int x = params_.alloc_stride / 2; x < kf.camera.width; x += params_.alloc_stride)
      if (kf.depth.at<float>(y, x) > 0) valid_depths.push_back(kf.depth.at<float>(y, x));
  if (valid_depths.empty()) return;
  std::nth_element(valid_depths.begin(), valid_depths.begin() + valid_depths.size() / 2,
                   valid_depths.end());
  const float max_depth = params_.alloc_max_depth_ratio * valid_depths[valid_depths.size() / 2];
  for (int y = params_.alloc_stride / 2; y < kf.camera.height; y += params_.alloc_stride) {
    for (int x = params_.alloc_stride / 2; x < kf.camera.width; x += params_.alloc_stride) {
      if (field_.numBlocks(fine_level) >= params_.max_fine_blocks) {
        if (!block_budget_warned_) {
          std::cerr << "radslam-mapper: warning: fine block budget (" << params_.max_fine_blocks
                    << ") reached; further surfaces are not allocated\n";
          block_budget_warned_ = true;
        }
        break;
      }
      const float d = kf.depth.at<float>(y, x);
      if (!(d > 0) || d > max_depth) continue;
      if (!mask.empty() && mask.at<uint8_t>(y, x) != 0) continue;
      const float var = kf.depth_var.at<float>(y, x);
      const float sigma = std::clamp(std::sqrt(var), sp.sigma_min, sp.sigma_max);
      // A filled hole (infinite variance) is a guess: a thinner band keeps memory bounded.
      const float range =
          std::isfinite(var) ? params_.alloc_sigma_range : params_.alloc_hole_sigmas;
      const float lo = std::max(sp.near, d - range * sigma);
      const float hi = d + range * sigma;
      const Eigen::Vector3f dir =
          R * Eigen::Vector3f(static_cast<float>((x - kf.camera.cx) / kf.camera.fx),
                              static_cast<float>((y - kf.camera.cy) / kf.camera.fy), 1.f);
      // Steps of 2 fine voxels: allocateAround covers the cell around each point, and blocks
      // are 8 voxels wide, so no block along the segment is missed.
      const int steps = std::max(1, static_cast<int>(std::ceil((hi - lo) / (2 * fine))));
      for (int i = 0; i <= steps; ++i)
        field_.allocateAround(t + (lo + (hi - lo) * i / steps) * dir);
    }
  }
  if (params_.seed_density > 0) seedSurface(entry, first_new);
}

void Mapper::seedSurface(const KeyframeEntry& entry, int first_new_block) {
  // The 8 lattice points around each pixel's surface point, in fine blocks this keyframe has
  // just allocated (trained blocks are left alone), get the seed density and the pixel's
  // colour (as a logit, clamped away from 0 and 1): an opaque layer about two voxels thick.
  // Pixels wider than two voxels on the surface are split into sub-pixels so the layer has
  // no holes.
  const Keyframe& kf = entry.keyframe;
  const CameraModel& cam = kf.camera;
  const int fine = field_.numLevels() - 1;
  const float s = static_cast<float>(field_.voxelSize(fine));
  const float inv = field_.invVoxelSize(fine);
  const int C = field_.channels();
  const Eigen::Matrix3f R = entry.T_world_cam.rotation().cast<float>();
  const Eigen::Vector3f t = entry.T_world_cam.translation().cast<float>();
  const cv::Mat& mask = kf.dynamic_mask;
  auto logit = [](float c) {
    c = std::clamp(c, 0.02f, 0.98f);
    return std::log(c / (1.f - c));
  };
  const float seed = static_cast<float>(params_.seed_density);
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      const float d = kf.depth.at<float>(y, x);
      if (!(d > 0) || !std::isfinite(kf.depth_var.at<float>(y, x))) continue;  // not guesses
      if (!mask.empty() && mask.at<uint8_t>(y, x) != 0) continue;
      float rgb[3];
      if (kf.color.channels() == 3) {
        const cv::Vec3b c = kf.color.at<cv::Vec3b>(y, x);
        rgb[0] = logit(c[2] / 255.f);
        rgb[1] = logit(c[1] / 255.f);
        rgb[2] = logit(c[0] / 255.f);
      } else {
        rgb[0] = rgb[1] = rgb[2] = logit(kf.color.at<uint8_t>(y, x) / 255.f);
      }
      const float footprint = d / static_cast<float>(std::min(cam.fx, cam.fy));  // m per pixel
      const int k = std::clamp(static_cast<int>(std::ceil(footprint / (2 * s))), 1, 4);
      for (int sy = 0; sy < k; ++sy)
        for (int sx = 0; sx < k; ++sx) {
          const float u = x + (sx + 0.5f) / k - 0.5f, v = y + (sy + 0.5f) / k - 0.5f;
          const Eigen::Vector3f p =
              t + R * Eigen::Vector3f(static_cast<float>((u - cam.cx) / cam.fx) * d,
                                      static_cast<float>((v - cam.cy) / cam.fy) * d, d);
          const Eigen::Vector3i i0 = (p * inv).array().floor().cast<int>();
          for (int c = 0; c < 8; ++c) {
            const Eigen::Vector3i i = i0 + Eigen::Vector3i(c & 1, (c >> 1) & 1, c >> 2);
            const int b = field_.findBlock(fine, blockOf(i.x()), blockOf(i.y()), blockOf(i.z()));
            if (b < first_new_block) continue;  // also b < 0
            float* vox = field_.blockData(fine, b) +
                         Field::voxelInBlock(localOf(i.x()), localOf(i.y()), localOf(i.z())) * C;
            vox[0] = seed;
            for (int ch = 0; ch < 3; ++ch) vox[1 + ch] = rgb[ch];
          }
        }
    }
  }
}

KeyframeStore::InsertResult Mapper::addKeyframe(const Keyframe& keyframe) {
  KeyframeStore::InsertResult result = keyframes_.insert(keyframe);
  if (result != KeyframeStore::InsertResult::kIgnored && params_.fill_depth_holes) {
    // Holes get a guessed depth with infinite variance (the store keeps the normalised images).
    Keyframe& kf = keyframes_.entry(keyframes_.find(keyframe.keyframe_id)).keyframe;
    if (!kf.depth.empty()) {
      const cv::Mat holes = kf.depth <= 0;
      if (cv::countNonZero(holes) > 0) {
        kf.depth = fillDepthHoles(kf.depth);
        kf.depth_var.setTo(std::numeric_limits<float>::infinity(), holes & (kf.depth > 0));
      }
    }
  }
  if (result == KeyframeStore::InsertResult::kIgnored) return result;
  if (!field_.initialized())
    initializeField();  // allocates for every stored keyframe
  else
    allocateFor(keyframes_.entry(keyframes_.find(keyframe.keyframe_id)));
  return result;
}

void Mapper::reset() {
  if (field_.initialized()) version_floor_ = std::max(version_floor_, field_.version());
  field_ = Field();
  keyframes_ = KeyframeStore();
  trainer_.reset();
}

TrainStats Mapper::train(int steps) {
  TrainStats stats;
  for (int i = 0; i < steps; ++i) stats = trainer_.step(&field_, &keyframes_);
  return stats;
}

std::vector<RefinedPose> Mapper::takeRefinedPoses() {
  std::vector<RefinedPose> out;
  for (int i = 0; i < keyframes_.size(); ++i) {
    KeyframeEntry& e = keyframes_.entry(i);
    if (!e.pose_refined) continue;
    e.pose_refined = false;
    RefinedPose p;
    p.keyframe_id = e.keyframe.keyframe_id;
    p.version = e.keyframe.version;
    p.header = e.keyframe.header;
    p.T_world_cam = e.T_world_cam;
    out.push_back(p);
  }
  return out;
}

FieldUpdate Mapper::makeUpdate(int64_t since_version, int max_blocks) {
  if (!field_.initialized()) {
    FieldUpdate u;
    u.base_version = since_version;
    u.block_dim = Field::kBlockDim;
    return u;
  }
  return makeFieldUpdate(&field_, since_version, max_blocks);
}

FieldUpdate Mapper::makeSnapshot() {
  if (!field_.initialized()) {
    FieldUpdate u;
    u.is_snapshot = true;
    u.block_dim = Field::kBlockDim;
    return u;
  }
  return makeFieldSnapshot(&field_);
}

SnapshotSender Mapper::makeSnapshotSender(int64_t snapshot_id, int max_blocks) {
  if (!field_.initialized()) throw std::logic_error("makeSnapshotSender: no field yet");
  return SnapshotSender(&field_, snapshot_id, max_blocks);
}

MarchParams Mapper::marchParams() const {
  MarchParams mp;
  mp.step_fine = params_.render_step_fine;
  if (field_.initialized()) {
    const SamplingParams sp = trainer_.samplingFor(field_.geometry().fineVoxelSize());
    mp.near = sp.near;
    mp.far = sp.far;
  }
  return mp;
}

RenderImages Mapper::render(const SE3& T_world_cam, const CameraModel& camera) const {
  if (camera.width <= 0 || camera.height <= 0 || !(camera.fx > 0) || !(camera.fy > 0))
    throw std::invalid_argument("render: camera needs a positive size and focal lengths");
  if (!field_.initialized()) {
    // Nothing mapped yet: background, unknown depth.
    RenderImages out;
    out.color = cv::Mat(camera.height, camera.width, CV_32FC3, cv::Scalar::all(0));
    out.depth = cv::Mat::zeros(camera.height, camera.width, CV_32FC1);
    out.sigma = cv::Mat::zeros(camera.height, camera.width, CV_32FC1);
    out.weight = cv::Mat::zeros(camera.height, camera.width, CV_32FC1);
    return out;
  }
  return renderer_.render(field_, T_world_cam, camera, marchParams(), params_.render_threads);
}

}  // namespace radslam
