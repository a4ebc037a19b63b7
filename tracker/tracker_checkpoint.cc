// Tracker checkpoints: one little-endian binary file (common/binary_io.h).
//   "RSTRKCK\0", u32 format version
//   the options the state depends on (mode, working size, grid, window, objects), checked
//   u8 has camera, then the input camera and its rolling shutter readout
//   stereo baseline, flags, lost streak, statistics
//   u32 levels of the previous frame's coarse images (rolling shutter), each image; its time
//   u32 frames, each: header, index, reference keyframe, relative pose and covariance, state
//   u32 pending frames, each: frame record, its correspondences and measured depth
//   the keyframe graph (KeyframeGraph::save), the object tracker and the motion segmenter
#include <array>
#include <cstring>
#include <stdexcept>
#include <string>
#include <tuple>

#include "common/binary_io.h"
#include "tracker/tracker_internal.h"

namespace radslam {
namespace {

constexpr char kMagic[8] = {'R', 'S', 'T', 'R', 'K', 'C', 'K', '\0'};
constexpr uint32_t kFormat = 5;  // 2: object windows and planes; 3: rolling shutter;
                                 // 4: measured depth; 5: flow information matrices

/// What a checkpoint's state is only valid with.
struct StateOptions {
  int32_t mode = 0, working_pixels = 0, grid_cell = 0, window_size = 0;
  uint8_t dynamic_objects = 0, motion_segmentation = 0;

  explicit StateOptions(const TrackerParams& p, TrackerMode m)
      : mode(static_cast<int32_t>(m)),
        working_pixels(p.working_pixels),
        grid_cell(p.grid_cell),
        window_size(p.window_size),
        dynamic_objects(p.dynamic_objects),
        motion_segmentation(p.motion_segmentation) {}
  StateOptions() = default;
  void write(BinaryWriter* w) const {
    for (int32_t v : {mode, working_pixels, grid_cell, window_size}) w->put(v);
    w->put(dynamic_objects);
    w->put(motion_segmentation);
  }
  void read(BinaryReader* r) {
    for (int32_t* v : {&mode, &working_pixels, &grid_cell, &window_size}) *v = r->get<int32_t>();
    dynamic_objects = r->get<uint8_t>();
    motion_segmentation = r->get<uint8_t>();
  }
  bool operator==(const StateOptions& o) const {
    return std::tie(mode, working_pixels, grid_cell, window_size, dynamic_objects,
                    motion_segmentation) == std::tie(o.mode, o.working_pixels, o.grid_cell,
                                                     o.window_size, o.dynamic_objects,
                                                     o.motion_segmentation);
  }
  std::string describe() const {
    return std::string("mode ") + trackerModeName(static_cast<TrackerMode>(mode)) +
           ", working_pixels " + std::to_string(working_pixels) + ", grid_cell " +
           std::to_string(grid_cell) + ", window_size " + std::to_string(window_size) +
           ", dynamic_objects " + std::to_string(dynamic_objects) + ", motion_segmentation " +
           std::to_string(motion_segmentation);
  }
};

/// Empty, or of this size and one of these types.
bool imageFits(const cv::Mat& m, cv::Size size, const std::array<int, 2>& types) {
  return m.empty() || (m.size() == size && (m.type() == types[0] || m.type() == types[1]));
}

/// The images of a loaded state have the sizes and types the tracker works with (a file that
/// passes the reader's own checks may still hold images of another size: they would break
/// the next frame, not the load). Returns what is wrong, or "".
std::string checkImages(const KeyframeGraph& graph, const std::vector<PendingFrame>& pending,
                        const GridGeometry& g) {
  const cv::Size work = g.workingSize(), grid = g.gridSize();
  for (const KeyframeData& k : graph.all()) {
    for (const auto& image : keyframeImages(k))
      if (!imageFits(*image.image, image.grid ? grid : work, image.types))
        return "keyframe " + std::to_string(k.id) + ": " + image.name + " of a wrong size or type";
    const bool paired = k.grey.empty() == k.structure.empty() &&
                        k.ba.prior_inv_depth.empty() == k.ba.prior_inv_depth_var.empty() &&
                        k.sensor_inv_depth.empty() == k.sensor_inv_depth_var.empty() &&
                        k.ba.measured_inv_depth.empty() == k.ba.measured_inv_depth_var.empty() &&
                        k.stereo_target.empty() == k.stereo_weight.empty();
    if (!paired || k.ba.inv_depth.empty())
      return "keyframe " + std::to_string(k.id) + ": images missing";
  }
  for (int id : graph.windowIds())
    if (graph.keyframe(id).grey.empty() || graph.keyframe(id).gradients.empty() ||
        !graph.keyframe(id).in_window)
      return "window keyframe " + std::to_string(id) + " without its image";
  for (const PendingFrame& f : pending) {
    if (f.target.size() != grid || f.weight.size() != grid || f.target.type() != CV_32FC2 ||
        f.weight.type() != kFlowWeightType)
      return "pending frame with correspondences of a wrong size";
    const std::array<int, 2> depth_types{CV_32FC1, CV_32FC1};
    if (!imageFits(f.measured.inv_depth, grid, depth_types) ||
        !imageFits(f.measured.inv_depth_var, grid, depth_types) ||
        f.measured.inv_depth.empty() != f.measured.inv_depth_var.empty())
      return "pending frame with a measured depth of a wrong size";
  }
  return "";
}

}  // namespace

void Tracker::saveCheckpoint(const std::string& path) const {
  const Impl& s = *impl_;
  BinaryWriter w(path, "tracker checkpoint " + path);
  w.bytes(kMagic, sizeof(kMagic));
  w.put(kFormat);
  StateOptions(params_, mode_).write(&w);
  w.put<uint8_t>(s.preparer != nullptr);
  if (s.preparer) {
    w.camera(s.preparer->input());
    w.put(s.preparer->input().readout_s);
  }
  w.put(s.baseline_m);
  w.put<uint8_t>(s.ba_ran);
  w.put<uint8_t>(s.first_ba_done);
  w.put<int32_t>(s.lost_streak);
  w.put(s.stats);
  w.put<uint32_t>(s.previous_frame_pyramid.levels.size());
  for (const cv::Mat& level : s.previous_frame_pyramid.levels) w.mat(level);
  w.put<int64_t>(s.previous_frame_utime);
  w.put<uint32_t>(s.frames.size());
  for (const FrameRecord& f : s.frames) {
    w.header(f.header);
    w.put<int64_t>(f.frame_index);
    w.put<int32_t>(f.ref_kf);
    w.se3(f.T_kf_frame);
    w.matrix(f.cov_rel);
    w.put(f.state);
    w.put<uint8_t>(f.is_keyframe);
  }
  w.put<uint32_t>(s.pending_frames.size());
  for (const PendingFrame& f : s.pending_frames) {
    w.put<uint64_t>(f.record);
    w.mat(f.target);
    w.mat(f.weight);
    w.mat(f.measured.inv_depth);
    w.mat(f.measured.inv_depth_var);
  }
  s.graph.save(&w);
  w.put<uint8_t>(s.objects != nullptr);
  if (s.objects) s.objects->save(&w);
  w.put<uint8_t>(s.segmenter != nullptr);
  if (s.segmenter) s.segmenter->save(&w);
  w.commit();
}

void Tracker::loadCheckpoint(const std::string& path) {
  BinaryReader r(path, "tracker checkpoint " + path);
  char magic[8];
  r.bytes(magic, sizeof(magic));
  if (std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) r.fail("not a radslam tracker checkpoint");
  const uint32_t format = r.get<uint32_t>();
  if (format != kFormat)
    r.fail("format " + std::to_string(format) + ", this build reads " + std::to_string(kFormat));
  const StateOptions ours(params_, mode_);
  StateOptions saved;
  saved.read(&r);
  if (!(saved == ours))
    r.fail("written with " + saved.describe() + "; this tracker runs " + ours.describe());
  // Everything is read into a fresh state first: a bad file leaves this tracker unchanged.
  auto s = std::make_unique<Impl>(params_, mode_);
  if (r.get<uint8_t>()) {
    try {
      CameraModel camera = r.camera();
      camera.readout_s = r.get<double>();
      s->setUpCamera(s->makePreparer(camera));
    } catch (const std::invalid_argument& e) {
      r.fail(std::string("camera: ") + e.what());
    }
  }
  s->baseline_m = r.get<double>();
  s->ba_ran = r.get<uint8_t>() != 0;
  s->first_ba_done = r.get<uint8_t>() != 0;
  s->lost_streak = r.get<int32_t>();
  s->stats = r.get<TrackerStats>();
  const size_t coarse_levels = r.count(8);
  for (size_t i = 0; i < coarse_levels; ++i) s->previous_frame_pyramid.levels.push_back(r.mat());
  s->previous_frame_utime = r.get<int64_t>();
  if (coarse_levels > 0) {
    // The cameras follow from the working camera; the images must fit them.
    const CameraModel* working = s->preparer ? &s->preparer->geometry().working : nullptr;
    if (!working) r.fail("coarse images without a camera");
    const ImagePyramid expected =
        coarsePyramid(cv::Mat(working->height, working->width, CV_8UC1, cv::Scalar(0)), *working,
                      Impl::kRotationLevels[0], Impl::kRotationLevels[1]);
    if (expected.levels.size() != coarse_levels) r.fail("wrong number of coarse images");
    for (size_t i = 0; i < coarse_levels; ++i) {
      const cv::Mat& level = s->previous_frame_pyramid.levels[i];
      if (level.type() != CV_8UC1 || level.size() != expected.levels[i].size())
        r.fail("coarse image " + std::to_string(i) + " does not fit the working camera");
    }
    s->previous_frame_pyramid.cameras = expected.cameras;
  }
  s->frames.resize(r.count(64));
  for (FrameRecord& f : s->frames) {
    f.header = r.header();
    f.frame_index = r.get<int64_t>();
    f.ref_kf = r.get<int32_t>();
    f.T_kf_frame = r.se3();
    r.matrix(&f.cov_rel);
    f.state = r.get<TrackingState>();
    f.is_keyframe = r.get<uint8_t>() != 0;
  }
  s->pending_frames.resize(r.count(16));
  for (PendingFrame& f : s->pending_frames) {
    f.record = r.get<uint64_t>();
    if (f.record >= s->frames.size()) r.fail("pending frame out of range");
    f.target = r.mat();
    f.weight = r.mat();
    f.measured.inv_depth = r.mat();
    f.measured.inv_depth_var = r.mat();
  }
  s->graph.load(&r);
  for (const FrameRecord& f : s->frames)
    if (f.ref_kf < 0 || f.ref_kf >= s->graph.size()) r.fail("frame with an unknown keyframe");
  if (!s->preparer && (!s->graph.empty() || !s->frames.empty())) r.fail("frames without a camera");
  if (s->preparer) {
    const std::string wrong = checkImages(s->graph, s->pending_frames, s->preparer->geometry());
    if (!wrong.empty()) r.fail(wrong);
  }
  if (!s->graph.empty() && (s->graph.windowIds().empty() || s->frames.empty()))
    r.fail("keyframes without a window or frames");
  if ((r.get<uint8_t>() != 0) != (s->objects != nullptr)) r.fail("object tracker state mismatch");
  if (s->objects) s->objects->load(&r);
  if ((r.get<uint8_t>() != 0) != (s->segmenter != nullptr)) r.fail("segmenter state mismatch");
  if (s->segmenter) s->segmenter->load(&r, s->preparer->geometry().workingSize());
  if (!r.done()) r.fail("trailing bytes");
  impl_ = std::move(s);
}

int64_t Tracker::lastFrameIndex() const {
  return impl_->frames.empty() ? -1 : impl_->frames.back().frame_index;
}

}  // namespace radslam
