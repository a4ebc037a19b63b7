#include "mapper/mapper.h"

#include <algorithm>
#include <array>
#include <climits>
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
  if (params.alloc_stride < 1 || !(params.alloc_sigma_range > 0) ||
      !(params.alloc_max_band_voxels > 0))
    throw std::invalid_argument(
        "mapper: alloc_stride must be >= 1, alloc_sigma_range and alloc_max_band_voxels > 0");
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
  field_.reserveBlocks(params_.max_fine_blocks);
  for (int i = 0; i < keyframes_.size(); ++i) allocateFor(keyframes_.entry(i));
}

float Mapper::allocationDepthLimit(const Keyframe& kf) const {
  std::vector<float> valid_depths;
  for (int y = params_.alloc_stride / 2; y < kf.camera.height; y += params_.alloc_stride)
    for (int x = params_.alloc_stride / 2; x < kf.camera.width; x += params_.alloc_stride)
      if (kf.depth.at<float>(y, x) > 0) valid_depths.push_back(kf.depth.at<float>(y, x));
  if (valid_depths.empty()) return 0;
  std::nth_element(valid_depths.begin(), valid_depths.begin() + valid_depths.size() / 2,
                   valid_depths.end());
  return params_.alloc_max_depth_ratio * valid_depths[valid_depths.size() / 2];
}

void Mapper::allocateFor(const KeyframeEntry& entry, bool new_blocks_only) {
  if (!field_.initialized()) return;
  const Keyframe& kf = entry.keyframe;
  const SamplingParams sp = trainer_.samplingFor(field_.geometry().fineVoxelSize());
  const float fine = static_cast<float>(field_.geometry().fineVoxelSize());
  const Eigen::Matrix3f R = entry.T_world_cam.rotation().cast<float>();
  const Eigen::Vector3f t = entry.T_world_cam.translation().cast<float>();
  const cv::Mat& mask = kf.dynamic_mask;
  const int fine_level = field_.numLevels() - 1;
  const int first_new = field_.numBlocks(fine_level);
  const float max_depth = allocationDepthLimit(kf);
  if (!(max_depth > 0)) return;
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
      const float half = std::min(range * sigma, params_.alloc_max_band_voxels * fine);
      const float lo = std::max(sp.near, d - half);
      const float hi = d + half;
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
  if (params_.seed_density > 0) seedSurface(entry, first_new, new_blocks_only, max_depth);
}

void Mapper::seedSurface(const KeyframeEntry& entry, int first_new_block, bool new_blocks_only,
                         float max_depth) {
  // Only untouched lattice points (every channel still 0: never seeded, never trained) are
  // seeded, in any fine block; trained ones are left alone. Density: the 8 lattice points
  // around each pixel's surface point get the seed density, an opaque layer about two voxels
  // thick. Colour: every lattice point that trilinear interpolation reads within kColorBand
  // fine voxels of the surface (in depth) gets the mean colour of the pixels that reach it, as
  // a logit. Seeding the colour on the surface points only blended it with the untrained grey
  // in front of them, where renders stop (a single fr1/rpy keyframe rendered at its own pose at
  // 12 dB). Pixels wider than two voxels on the surface are split into sub-pixels so the layer
  // has no holes. Free space (seed_free_density) is seeded in the new blocks.
  constexpr float kColorBand = 2;  // fine voxels either side of the surface
  const Keyframe& kf = entry.keyframe;
  const CameraModel& cam = kf.camera;
  const int fine = field_.numLevels() - 1;
  const float s = static_cast<float>(field_.voxelSize(fine));
  const float inv = field_.invVoxelSize(fine);
  const int C = field_.channels();
  const Eigen::Matrix3f R = entry.T_world_cam.rotation().cast<float>();
  const Eigen::Vector3f t = entry.T_world_cam.translation().cast<float>();
  const cv::Mat& mask = kf.dynamic_mask;
  // The keyframe's image as the field's colour: its exposure undone (zero unless re-sent).
  float gain[3], offset[3];
  for (int j = 0; j < 3; ++j) {
    gain[j] = static_cast<float>(std::exp(entry.exposure[j]));
    offset[j] = static_cast<float>(entry.exposure[3 + j]);
  }
  // Per lattice point of the blocks reached (a slot each, the new blocks first): colour sums
  // and count, and the surface flag.
  std::vector<int> slot(field_.numBlocks(fine), -1);
  std::vector<int> slot_block;
  for (int b = first_new_block; b < field_.numBlocks(fine); ++b) {
    slot[b] = static_cast<int>(slot_block.size());
    slot_block.push_back(b);
  }
  LargeVector<float> sums(slot_block.size() * Field::kBlockVoxels * 4, 0.f);
  LargeVector<uint8_t> surface(slot_block.size() * Field::kBlockVoxels, 0);
  // Index of lattice point i among the slots' points, -1 when its block is unallocated.
  auto pointIndex = [&](const Eigen::Vector3i& i) -> int64_t {
    const int b = field_.findBlock(fine, blockOf(i.x()), blockOf(i.y()), blockOf(i.z()));
    if (b < 0 || (new_blocks_only && b < first_new_block)) return -1;
    if (slot[b] < 0) {
      slot[b] = static_cast<int>(slot_block.size());
      slot_block.push_back(b);
      sums.resize(slot_block.size() * Field::kBlockVoxels * 4, 0.f);
      surface.resize(slot_block.size() * Field::kBlockVoxels, 0);
    }
    return static_cast<int64_t>(slot[b]) * Field::kBlockVoxels +
           Field::voxelInBlock(localOf(i.x()), localOf(i.y()), localOf(i.z()));
  };
  const int band_steps = static_cast<int>(2 * kColorBand);  // half-voxel steps either side
  // With new_blocks_only, most pixels' bands lie in old blocks: those are skipped on a test of
  // the blocks that the band's bounding box (grown by the pixel and a lattice cell) meets.
  auto reachesNewBlock = [&](int x, int y, float d, float footprint) {
    const Eigen::Vector3f dir = R * Eigen::Vector3f(static_cast<float>((x - cam.cx) / cam.fx),
                                                    static_cast<float>((y - cam.cy) / cam.fy), 1.f);
    const Eigen::Vector3f a = t + (d - kColorBand * s) * dir, b = t + (d + kColorBand * s) * dir;
    const Eigen::Vector3f margin = Eigen::Vector3f::Constant(footprint + s);
    const Eigen::Vector3i lo = ((a.cwiseMin(b) - margin) * inv).array().floor().cast<int>();
    const Eigen::Vector3i hi = ((a.cwiseMax(b) + margin) * inv).array().floor().cast<int>();
    for (int bz = blockOf(lo.z()); bz <= blockOf(hi.z()); ++bz)
      for (int by = blockOf(lo.y()); by <= blockOf(hi.y()); ++by)
        for (int bx = blockOf(lo.x()); bx <= blockOf(hi.x()); ++bx)
          if (field_.findBlock(fine, bx, by, bz) >= first_new_block) return true;
    return false;
  };
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      const float d = kf.depth.at<float>(y, x);
      // Past max_depth nothing was allocated, and the footprints of monocular depth outliers
      // (metres wide) would make the new-block test below walk thousands of blocks each.
      if (!(d > 0) || d > max_depth || !std::isfinite(kf.depth_var.at<float>(y, x)))
        continue;  // (holes' guesses are not seeded)
      if (!mask.empty() && mask.at<uint8_t>(y, x) != 0) continue;
      const float footprint = d / static_cast<float>(std::min(cam.fx, cam.fy));  // m per pixel
      // Pixels much smaller than a voxel: every stride-th one in x and y, at most a voxel
      // apart on the surface, still leaves no hole in the layer (each writes its whole cell).
      const int stride = std::max(1, static_cast<int>(s / footprint));
      if (x % stride != 0 || y % stride != 0) continue;
      if (new_blocks_only && !reachesNewBlock(x, y, d, footprint)) continue;
      float rgb[3];
      if (kf.color.channels() == 3) {
        const cv::Vec3b c = kf.color.at<cv::Vec3b>(y, x);
        rgb[0] = c[2] / 255.f;
        rgb[1] = c[1] / 255.f;
        rgb[2] = c[0] / 255.f;
      } else {
        rgb[0] = rgb[1] = rgb[2] = kf.color.at<uint8_t>(y, x) / 255.f;
      }
      for (int j = 0; j < 3; ++j) rgb[j] = (rgb[j] - offset[j]) / gain[j];
      const int k = std::clamp(static_cast<int>(std::ceil(footprint / (2 * s))), 1, 4);
      for (int sy = 0; sy < k; ++sy)
        for (int sx = 0; sx < k; ++sx) {
          const float u = x + (sx + 0.5f) / k - 0.5f, v = y + (sy + 0.5f) / k - 0.5f;
          const Eigen::Vector3f dir =
              R * Eigen::Vector3f(static_cast<float>((u - cam.cx) / cam.fx),
                                  static_cast<float>((v - cam.cy) / cam.fy), 1.f);
          // Half-voxel steps: a cell met by consecutive steps counts the pixel once.
          Eigen::Vector3i previous = Eigen::Vector3i::Constant(INT32_MIN);
          for (int step = -band_steps; step <= band_steps; ++step) {
            const float z = d + 0.5f * s * step;
            if (!(z > 0)) continue;
            const Eigen::Vector3f p = t + z * dir;
            const Eigen::Vector3i i0 = (p * inv).array().floor().cast<int>();
            const bool same_cell = i0 == previous;
            previous = i0;
            if (same_cell && step != 0) continue;
            for (int c = 0; c < 8; ++c) {
              const int64_t q = pointIndex(i0 + Eigen::Vector3i(c & 1, (c >> 1) & 1, c >> 2));
              if (q < 0) continue;
              if (!same_cell) {
                float* sum = &sums[static_cast<size_t>(q) * 4];
                for (int j = 0; j < 3; ++j) sum[j] += rgb[j];
                sum[3] += 1.f;
              }
              if (step == 0) surface[q] = 1;
            }
          }
        }
    }
  }
  auto logit = [](float c) {
    c = std::clamp(c, 0.02f, 0.98f);
    return std::log(c / (1.f - c));
  };
  // Free space: a lattice point that projects onto a measured depth more than the colour band
  // (plus the cell it starts) behind it. Points behind surfaces, outside the image or over
  // holes stay at the default density.
  const float free_density = static_cast<float>(params_.seed_free_density);
  const Eigen::Matrix3f Rt = R.transpose();
  auto seenThrough = [&](const Eigen::Vector3i& i) {
    const Eigen::Vector3f p = Rt * (i.cast<float>() * s - t);
    if (!(p.z() > 0)) return false;
    const int u = static_cast<int>(std::lround(cam.fx * p.x() / p.z() + cam.cx));
    const int v = static_cast<int>(std::lround(cam.fy * p.y() / p.z() + cam.cy));
    if (u < 0 || v < 0 || u >= cam.width || v >= cam.height) return false;
    if (!mask.empty() && mask.at<uint8_t>(v, u) != 0) return false;
    const float d = kf.depth.at<float>(v, u);
    if (!(d > 0) || !std::isfinite(kf.depth_var.at<float>(v, u))) return false;
    return p.z() < d - (kColorBand + 1) * s;
  };
  const float seed = static_cast<float>(params_.seed_density);
  for (size_t k = 0; k < slot_block.size(); ++k) {
    const int b = slot_block[k];
    const bool is_new = b >= first_new_block;
    const size_t base = k * Field::kBlockVoxels;
    bool any = is_new && free_density < 0;
    for (int v = 0; v < Field::kBlockVoxels && !any; ++v) any = sums[(base + v) * 4 + 3] > 0;
    if (!any) continue;
    float* data = field_.levelData(fine) + static_cast<size_t>(b) * Field::kBlockVoxels * C;
    const Eigen::Vector3i origin = field_.blockIndex(fine, b) * Field::kBlockDim;
    bool changed = false;
    for (int v = 0; v < Field::kBlockVoxels; ++v) {
      float* vox = data + static_cast<size_t>(v) * C;
      bool untouched = true;
      for (int ch = 0; ch < C && untouched; ++ch) untouched = vox[ch] == 0.f;
      if (!untouched) continue;
      const float* sum = &sums[(base + v) * 4];
      if (sum[3] > 0) {
        if (surface[base + v]) vox[0] = seed;
        for (int j = 0; j < 3; ++j) vox[1 + j] = logit(sum[j] / sum[3]);
        changed = true;
      } else if (is_new && free_density < 0) {
        const Eigen::Vector3i i =
            origin + Eigen::Vector3i(v % Field::kBlockDim,
                                     (v / Field::kBlockDim) % Field::kBlockDim,
                                     v / (Field::kBlockDim * Field::kBlockDim));
        if (seenThrough(i)) {
          vox[0] = free_density;
          changed = true;
        }
      }
    }
    if (changed) field_.markChanged(fine, b);
  }
}

KeyframeStore::InsertResult Mapper::addKeyframe(const Keyframe& keyframe) {
  if (retired(keyframe.keyframe_id)) return KeyframeStore::InsertResult::kIgnored;
  bool resent = false;
  KeyframeStore::InsertResult result = keyframes_.insert(keyframe, &resent);
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
  if (!field_.initialized()) {
    initializeField();  // allocates for every stored keyframe
  } else {
    KeyframeEntry& entry = keyframes_.entry(keyframes_.find(keyframe.keyframe_id));
    // A re-sent keyframe (the same image, refined pose and depth) keeps its exposure and what
    // its earlier version seeded: only blocks new to this version are seeded.
    if (!resent) initExposure(&entry);  // before its own blocks and seeds change the field
    allocateFor(entry, resent);
  }
  if (keyframes_.size() > params_.max_keyframes) retireMostRedundant(keyframe.keyframe_id);
  return result;
}

void Mapper::retireMostRedundant(int32_t newest_id) {
  // Pose distance: camera-centre distance relative to the scene depth (fine voxel /
  // fine_voxel_rel, the first keyframe's median depth) plus the rotation angle (rad).
  const double depth = field_.initialized() && params_.fine_voxel_rel > 0
                           ? field_.geometry().fineVoxelSize() / params_.fine_voxel_rel
                           : 1.0;
  auto distance = [&](const SE3& a, const SE3& b) {
    return (a.translation() - b.translation()).norm() / depth +
           a.quaternion().angularDistance(b.quaternion());
  };
  const int gauge = keyframes_.gaugeIndex();
  int victim = -1;
  double victim_distance = INFINITY;
  for (int i = 0; i < keyframes_.size(); ++i) {
    const KeyframeEntry& e = keyframes_.entry(i);
    if (i == gauge || e.keyframe.keyframe_id == newest_id) continue;
    double nearest = INFINITY;
    for (int j = 0; j < keyframes_.size(); ++j)
      if (j != i)
        nearest = std::min(nearest, distance(e.T_world_cam, keyframes_.entry(j).T_world_cam));
    // Of two equally redundant keyframes (a pair), the older goes.
    if (nearest < victim_distance ||
        (nearest == victim_distance && e.arrival < keyframes_.entry(victim).arrival)) {
      victim = i;
      victim_distance = nearest;
    }
  }
  if (victim < 0) return;
  retired_.insert(keyframes_.entry(victim).keyframe.keyframe_id);
  keyframes_.erase(victim);
}

void Mapper::initExposure(KeyframeEntry* entry) const {
  // The gain per channel from the field's render at the keyframe's pose to its image, over
  // well-rendered pixels (weight > 0.9). Seeding then writes the
  // keyframe's colours in the field's terms, so the field keeps one colour scale instead of
  // absorbing each keyframe's exposure where it was seeded.
  const int stride = params_.exposure_init_stride;
  const int index = keyframes_.find(entry->keyframe.keyframe_id);
  if (stride <= 0 || !params_.trainer.refine_exposure || index == keyframes_.gaugeIndex() ||
      field_.empty())
    return;
  const Keyframe& kf = entry->keyframe;
  const CameraModel& cam = kf.camera;
  const MarchParams mp = marchParams();
  std::vector<std::array<float, 6>> pairs;  // render RGB, image RGB
  for (int y = stride / 2; y < cam.height; y += stride)
    for (int x = stride / 2; x < cam.width; x += stride) {
      if (!kf.dynamic_mask.empty() && kf.dynamic_mask.at<uint8_t>(y, x) != 0) continue;
      const Ray ray = makeRay(entry->T_world_cam,
                              Eigen::Vector3d((x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0));
      const RayOutput r = renderer_.march(field_, ray, mp);
      if (!(r.weight > 0.9f)) continue;
      std::array<float, 6> p;
      for (int j = 0; j < 3; ++j) p[j] = r.color[j];
      if (kf.color.channels() == 3) {
        const cv::Vec3b c = kf.color.at<cv::Vec3b>(y, x);
        for (int j = 0; j < 3; ++j) p[3 + j] = c[2 - j] / 255.f;  // BGR
      } else {
        for (int j = 0; j < 3; ++j) p[3 + j] = kf.color.at<uint8_t>(y, x) / 255.f;
      }
      pairs.push_back(p);
    }
  constexpr size_t kMinPixels = 200;
  if (pairs.size() < kMinPixels) return;
  Vec6 x = Vec6::Zero();
  for (int j = 0; j < 3; ++j) {
    // Gain only, as the ratio of the means over pixels whose ratio is within a factor 1.5 of
    // the median one: a regression slope would be biased low by the render's misalignment
    // (regression dilution), an offset is left to training.
    std::vector<float> ratios;
    for (const auto& p : pairs)
      if (p[j] > 0.05f) ratios.push_back(p[3 + j] / p[j]);
    if (ratios.size() < kMinPixels) return;
    std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
    const double median = ratios[ratios.size() / 2];
    double sa = 0, sb = 0;
    for (const auto& p : pairs) {
      if (!(p[j] > 0.05f)) continue;
      const double r = p[3 + j] / p[j];
      if (r > median * 1.5 || r < median / 1.5) continue;
      sa += p[j];
      sb += p[3 + j];
    }
    const double gain = sb / sa;
    // Auto exposure moves brightness by tens of percent between keyframes, not by factors.
    if (!(gain > 0.5 && gain < 2)) return;
    x[j] = std::log(gain);
  }
  entry->exposure = x;
}

void Mapper::skipVersionsAfterRestart() {
  // One version per training step: 2^32 of them are centuries of training.
  constexpr int64_t kVersionsPerRun = int64_t{1} << 32;
  version_floor_ =
      std::max(version_floor_, field_.initialized() ? field_.version() : 0) + kVersionsPerRun;
  if (field_.initialized()) field_.restoreVersion(version_floor_);
}

void Mapper::reset() {
  if (field_.initialized()) version_floor_ = std::max(version_floor_, field_.version());
  retired_.clear();
  field_ = Field();
  keyframes_ = KeyframeStore();
  trainer_.reset();
}

void Mapper::setTrainingThreads(int threads) {
  TrainerParams trainer = params_.trainer;
  trainer.threads = threads;
  trainer_.setParams(trainer);  // validates
  params_.trainer = trainer;
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

FieldUpdate Mapper::makeCatchUp(int64_t since_version, int max_blocks) {
  if (!field_.initialized()) return makeUpdate(since_version);
  return makeFieldCatchUp(&field_, since_version, max_blocks);
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

RenderImages Mapper::render(const SE3& T_world_cam, const CameraModel& camera, int threads,
                            const RollingShutterView& rolling_shutter) const {
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
  return renderer_.render(field_, T_world_cam, camera, marchParams(),
                          threads > 0 ? threads : params_.render_threads, rolling_shutter);
}

}  // namespace radslam
