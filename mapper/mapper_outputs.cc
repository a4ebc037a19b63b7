#include "mapper/mapper_outputs.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iterator>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/exr_io.h"
#include "common/trajectory.h"
#include "mapper/mapping_eval.h"
#include "mapper/mesh_export.h"

namespace radslam {

SE3 followRefinement(const KeyframeEntry& keyframe, const SE3& T_world_frame) {
  return keyframe.T_world_cam * keyframe.keyframe.T_world_cam.inverse() * T_world_frame;
}

std::vector<FrameView> nonKeyframeViews(const std::map<int64_t, PoseStamped>& poses,
                                        const KeyframeStore& keyframes, int stride,
                                        size_t max_views) {
  std::vector<FrameView> views;
  if (keyframes.size() == 0 || stride < 1) return views;
  std::map<int64_t, int> by_frame;  // keyframe frame index -> store index
  for (int i = 0; i < keyframes.size(); ++i) by_frame[keyframes.entry(i).keyframe.frame_index] = i;
  int others = 0;  // tracked frames that are not keyframes, in frame order
  for (const auto& [frame_index, pose] : poses) {
    if (pose.is_keyframe || by_frame.count(frame_index)) continue;
    if (pose.state != TrackingState::kTracking && pose.state != TrackingState::kGroundTruth)
      continue;
    if (others++ % stride != stride / 2) continue;  // the middle of each run of stride
    // Nearest keyframe in frame index: its camera is the one the field was trained at.
    auto next = by_frame.lower_bound(frame_index);
    auto nearest = next;
    if (next == by_frame.end() ||
        (next != by_frame.begin() &&
         frame_index - std::prev(next)->first < next->first - frame_index))
      nearest = std::prev(next);
    const KeyframeEntry& e = keyframes.entry(nearest->second);
    FrameView v;
    v.utime = pose.header.utime;
    v.frame_index = frame_index;
    v.T_world_cam = followRefinement(e, pose.T_world_cam);  // the tracker measured it from e
    v.camera = e.keyframe.camera;
    // The keyframes around it (the same one past either end).
    const KeyframeEntry& before =
        keyframes.entry((next == by_frame.begin() ? next : std::prev(next))->second);
    const KeyframeEntry& after =
        keyframes.entry((next == by_frame.end() ? std::prev(next) : next)->second);
    v.exposure =
        interpolateExposure(double(v.utime), double(before.keyframe.header.utime), before.exposure,
                            double(after.keyframe.header.utime), after.exposure);
    views.push_back(v);
  }
  return evenlySpread(views, max_views);
}

namespace {

double secondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// One view: renders/rgb/<stem>.png, the colour under `exposure` (also into *seen when given),
// and renders/depth/<stem>.exr. Returns the images in the field's own colour.
RenderImages writeRender(const Mapper& mapper, const SE3& T_world_cam, const CameraModel& camera,
                         const Vec6& exposure, int64_t utime, const std::filesystem::path& rgb_dir,
                         const std::filesystem::path& depth_dir, int threads,
                         cv::Mat* seen = nullptr) {
  RenderImages images = mapper.render(T_world_cam, camera, threads);
  cv::Mat color = images.color.clone();
  applyExposure(exposure, &color);
  if (seen) *seen = color;
  const std::string stem = stampFileName(utime);
  const std::string png = (rgb_dir / (stem + ".png")).string();
  if (!cv::imwrite(png, toBgr8(color)))
    throw std::runtime_error("mapper outputs: cannot write " + png);
  writeExr((depth_dir / (stem + ".exr")).string(),
           {{"depth", images.depth}, {"sigma", images.sigma}});
  return images;
}

}  // namespace

MapperOutputSummary writeMapperOutputs(const Mapper& mapper, const std::string& out_dir,
                                       const MapperOutputOptions& options,
                                       const std::vector<FrameView>& frames) {
  namespace fs = std::filesystem;
  MapperOutputSummary summary;
  const fs::path out(out_dir);
  const fs::path rgb_dir = out / "renders" / "rgb", depth_dir = out / "renders" / "depth";
  std::error_code ec;
  for (const fs::path& dir : {out, rgb_dir, depth_dir}) {
    fs::create_directories(dir, ec);
    if (ec)
      throw std::runtime_error("mapper outputs: cannot create " + dir.string() + ": " +
                               ec.message());
  }
  const auto progress = [&] {
    if (options.progress) options.progress();
  };
  auto t0 = std::chrono::steady_clock::now();
  summary.checkpoint = (out / "mapper.ckpt").string();
  mapper.saveCheckpoint(summary.checkpoint, options.checkpoint_images);
  summary.checkpoint_s = secondsSince(t0);
  progress();

  // Keyframes in time order.
  const KeyframeStore& store = mapper.keyframes();
  std::vector<int> order(store.size());
  for (int i = 0; i < store.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return store.entry(a).keyframe.header.utime < store.entry(b).keyframe.header.utime;
  });
  Trajectory trajectory;
  for (int i : order) {
    const KeyframeEntry& e = store.entry(i);
    trajectory.push_back({e.keyframe.header.utime * 1e-6, e.T_world_cam});
  }
  summary.trajectory = (out / "mapper_keyframes.txt").string();
  writeTumTrajectory(summary.trajectory, trajectory);

  t0 = std::chrono::steady_clock::now();
  const Mesh mesh = extractMeshWithin(mapper.field(), options.mesh_iso,
                                      static_cast<size_t>(options.mesh_max_faces));
  summary.mesh = (out / "map_mesh.ply").string();
  writePly(summary.mesh, mesh);
  summary.mesh_faces = mesh.faces.size();
  summary.mesh_stride = mesh.stride;
  summary.mesh_s = secondsSince(t0);
  progress();

  // The keyframe renders also give the point cloud.
  t0 = std::chrono::steady_clock::now();
  SurfacePointCloud surface(mapper.field());
  for (int i : order) {
    const KeyframeEntry& e = store.entry(i);
    cv::Mat seen;
    const RenderImages images =
        writeRender(mapper, e.T_world_cam, e.keyframe.camera, e.exposure, e.keyframe.header.utime,
                    rgb_dir, depth_dir, options.render_threads, &seen);
    surface.add(e.T_world_cam, e.keyframe.camera, images, options.cloud_stride);
    cv::Mat reference = e.keyframe.color;
    if (reference.channels() == 1) cv::cvtColor(reference, reference, cv::COLOR_GRAY2BGR);
    summary.keyframe_psnr_db += psnr(reference, seen);
    ++summary.renders;
    progress();
  }
  if (summary.renders > 0) summary.keyframe_psnr_db /= summary.renders;
  const PointCloud cloud = surface.points();
  summary.cloud = (out / "map_points.ply").string();
  writePly(summary.cloud, cloud);
  summary.cloud_points = cloud.points.size();
  for (const FrameView& v : frames) {
    writeRender(mapper, v.T_world_cam, v.camera, v.exposure, v.utime, rgb_dir, depth_dir,
                options.render_threads);
    ++summary.frame_renders;
    progress();
  }
  summary.renders_s = secondsSince(t0);
  return summary;
}

}  // namespace radslam
