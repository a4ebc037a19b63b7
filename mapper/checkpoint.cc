// Mapper checkpoints: one little-endian binary file.
//   "RSMAPCK\0", u32 format version
//   u8 initialised; geometry (u32 levels, f64 voxel sizes, i32 sh degree, f32 bias)
//   i64 field version; per level: u32 blocks, then per block i32 x 3 index, i64 version and
//   u8 changed flag, and the level's
//   parameters, Adam first and second moments (f32) and per-voxel step counts (i32)
//   i64 trainer steps, u64 random state
//   i64 keyframe arrivals, u32 keyframes, each: ids and header, received and refined poses,
//   covariance, camera, pose Adam state, exposure and its Adam state (format 2), statistics,
//   then its images (may be empty)
// Written through common/binary_io.h: a crash never leaves a half-written checkpoint.
#include <cstring>
#include <stdexcept>

#include "common/binary_io.h"
#include "mapper/mapper.h"

namespace radslam {

namespace {

constexpr char kMagic[8] = {'R', 'S', 'M', 'A', 'P', 'C', 'K', '\0'};
constexpr uint32_t kFormat = 2;
constexpr uint32_t kOldestFormat = 1;  // format 1: no exposure (read as zero)

}  // namespace

void Mapper::saveCheckpoint(const std::string& path, bool with_images) const {
  BinaryWriter w(path, "checkpoint " + path);
  w.bytes(kMagic, sizeof(kMagic));
  w.put(kFormat);
  w.put<uint8_t>(field_.initialized());
  if (field_.initialized()) {
    const FieldGeometry& g = field_.geometry();
    w.put<uint32_t>(g.numLevels());
    for (double s : g.voxel_size) w.put(s);
    w.put<int32_t>(g.sh_degree);
    w.put(g.density_bias);
    w.put<int64_t>(field_.version());
    const SparseAdam& adam = trainer_.optimizer();
    for (int l = 0; l < field_.numLevels(); ++l) {
      w.put<uint32_t>(field_.numBlocks(l));
      for (int b = 0; b < field_.numBlocks(l); ++b) {
        for (int k = 0; k < 3; ++k) w.put<int32_t>(field_.blockIndex(l, b)[k]);
        w.put<int64_t>(field_.blockVersion(l, b));
        w.put<uint8_t>(field_.blockChanged(l, b));
      }
      w.bytes(field_.levelData(l), field_.levelSize(l) * sizeof(float));
      // Optimiser state may lag behind allocation (no step since): pad with zeros.
      std::vector<float> m(field_.levelSize(l), 0.f), v(field_.levelSize(l), 0.f);
      std::vector<int32_t> steps(size_t(field_.numBlocks(l)) * Field::kBlockVoxels, 0);
      if (l < static_cast<int>(adam.firstMoments().size())) {
        std::copy(adam.firstMoments()[l].begin(), adam.firstMoments()[l].end(), m.begin());
        std::copy(adam.secondMoments()[l].begin(), adam.secondMoments()[l].end(), v.begin());
        std::copy(adam.steps()[l].begin(), adam.steps()[l].end(), steps.begin());
      }
      w.vec(m);
      w.vec(v);
      w.vec(steps);
    }
  }
  w.put<int64_t>(trainer_.steps());
  w.put<uint64_t>(trainer_.rngState());
  w.put<int64_t>(keyframes_.arrivals());
  w.put<uint32_t>(keyframes_.size());
  for (int i = 0; i < keyframes_.size(); ++i) {
    const KeyframeEntry& e = keyframes_.entry(i);
    const Keyframe& kf = e.keyframe;
    w.put(kf.keyframe_id);
    w.put(kf.version);
    w.put(kf.frame_index);
    w.header(kf.header);
    w.se3(kf.T_world_cam);
    w.matrix(kf.covariance);
    w.camera(kf.camera);
    w.se3(e.T_world_cam);
    w.put<uint8_t>(e.pose_refined);
    w.matrix(e.pose_m);
    w.matrix(e.pose_v);
    w.put(e.pose_steps);
    w.matrix(e.exposure);
    w.matrix(e.exposure_m);
    w.matrix(e.exposure_v);
    w.put(e.exposure_steps);
    w.put(e.loss_ema);
    w.put(e.rays_trained);
    w.put(e.arrival);
    w.put<uint8_t>(with_images);
    if (with_images) {
      for (const cv::Mat* m : {&kf.color, &kf.inv_depth, &kf.inv_depth_var, &kf.depth,
                               &kf.depth_var, &kf.dynamic_mask})
        w.mat(*m);
      w.vec(e.pixels);
    }
  }
  w.commit();
}

void Mapper::loadCheckpoint(const std::string& path) {
  BinaryReader r(path, "checkpoint " + path);
  char magic[8];
  r.bytes(magic, sizeof(magic));
  if (std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) r.fail("not a radslam mapper checkpoint");
  const uint32_t format = r.get<uint32_t>();
  if (format < kOldestFormat || format > kFormat)
    r.fail("format " + std::to_string(format) + ", this build reads " +
           std::to_string(kOldestFormat) + " to " + std::to_string(kFormat));
  // Everything is read into fresh objects first: a bad file leaves the mapper unchanged.
  Field field;
  SparseAdam adam(params_.trainer.adam);
  if (r.get<uint8_t>()) {
    FieldGeometry g;
    const uint32_t levels = r.get<uint32_t>();
    if (levels < 1 || levels > Field::kMaxLevels) r.fail("bad level count");
    for (uint32_t l = 0; l < levels; ++l) g.voxel_size.push_back(r.get<double>());
    g.sh_degree = r.get<int32_t>();
    g.density_bias = r.get<float>();
    try {
      field = Field(g);
    } catch (const std::exception& e) {
      r.fail(e.what());
    }
    field.restoreVersion(r.get<int64_t>());
    for (int l = 0; l < field.numLevels(); ++l) {
      const uint32_t blocks = r.get<uint32_t>();
      if (blocks > (1u << 26)) r.fail("absurd block count");
      for (uint32_t b = 0; b < blocks; ++b) {
        Eigen::Vector3i index;
        for (int k = 0; k < 3; ++k) index[k] = r.get<int32_t>();
        const int64_t version = r.get<int64_t>();
        const bool changed = r.get<uint8_t>() != 0;
        if (!Field::blockIndexInRange(index)) r.fail("bad block index");
        if (field.allocateBlock(l, index) != static_cast<int>(b)) r.fail("duplicate block");
        field.restoreBlockState(l, b, version, changed);
      }
      r.bytes(field.levelData(l), field.levelSize(l) * sizeof(float));
      adam.resize(field);
      r.vec(&adam.firstMoments()[l], field.levelSize(l));
      r.vec(&adam.secondMoments()[l], field.levelSize(l));
      r.vec(&adam.steps()[l], size_t(field.numBlocks(l)) * Field::kBlockVoxels);
    }
  }
  const int64_t steps = r.get<int64_t>();
  const uint64_t rng_state = r.get<uint64_t>();
  KeyframeStore store;
  store.setArrivals(r.get<int64_t>());
  const uint32_t count = r.get<uint32_t>();
  for (uint32_t i = 0; i < count; ++i) {
    KeyframeEntry e;
    Keyframe& kf = e.keyframe;
    kf.keyframe_id = r.get<int32_t>();
    kf.version = r.get<int32_t>();
    kf.frame_index = r.get<int64_t>();
    kf.header = r.header();
    kf.T_world_cam = r.se3();
    r.matrix(&kf.covariance);
    kf.camera = r.camera();
    const CameraModel& c = kf.camera;
    e.T_world_cam = r.se3();
    e.pose_refined = r.get<uint8_t>() != 0;
    r.matrix(&e.pose_m);
    r.matrix(&e.pose_v);
    e.pose_steps = r.get<int64_t>();
    if (format >= 2) {
      r.matrix(&e.exposure);
      r.matrix(&e.exposure_m);
      r.matrix(&e.exposure_v);
      e.exposure_steps = r.get<int64_t>();
    }
    e.loss_ema = r.get<double>();
    e.rays_trained = r.get<int64_t>();
    e.arrival = r.get<int64_t>();
    if (r.get<uint8_t>()) {
      for (cv::Mat* m : {&kf.color, &kf.inv_depth, &kf.inv_depth_var, &kf.depth, &kf.depth_var,
                         &kf.dynamic_mask})
        *m = r.mat();
      r.vec(&e.pixels);
      const bool sizes_ok = kf.color.cols == c.width && kf.color.rows == c.height &&
                            kf.depth.size == kf.color.size && kf.depth_var.size == kf.color.size;
      if (!sizes_ok) r.fail("keyframe " + std::to_string(kf.keyframe_id) + ": bad image sizes");
      for (int32_t p : e.pixels)
        if (p < 0 || p >= c.width * c.height) r.fail("bad pixel index");
    }
    store.restore(std::move(e));
  }
  if (!r.done()) r.fail("trailing bytes");
  field_ = std::move(field);
  field_.reserveBlocks(params_.max_fine_blocks);
  trainer_.optimizer() = std::move(adam);
  trainer_.restoreState(steps, rng_state);
  keyframes_ = std::move(store);
}

}  // namespace radslam
