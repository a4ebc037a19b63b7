#include "renderer/final_outputs.h"

#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "common/exr_io.h"
#include "common/trajectory.h"

namespace radslam {

CameraModel scaledCamera(const CameraModel& camera, int width) {
  if (width <= 0 || camera.width <= 0) return camera;
  CameraModel c = camera;
  const double s = static_cast<double>(width) / camera.width;
  c.width = width;
  c.height = std::max(1, static_cast<int>(std::lround(camera.height * s)));
  c.fx *= s;
  c.fy *= s;
  c.cx = (camera.cx + 0.5) * s - 0.5;
  c.cy = (camera.cy + 0.5) * s - 0.5;
  c.distortion.clear();
  return c;
}

int writeFinalRenders(const FieldReplica& replica, const std::vector<ViewPose>& views,
                      const std::string& dir, int threads, const std::function<void()>& progress) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw std::runtime_error(dir + ": cannot create the render folder: " + ec.message());
  int written = 0;
  for (const ViewPose& v : views) {
    const RenderImages images = replica.render(v.T_world_cam, v.camera, nullptr, threads);
    const std::string stem = dir + "/" + stampFileName(v.utime);
    if (!cv::imwrite(stem + ".png", toBgr8(images.color)))
      throw std::runtime_error(stem + ".png: cannot write the render");
    writeExr(stem + ".exr", {{"depth", images.depth}, {"sigma", images.sigma}});
    ++written;
    if (progress) progress();
  }
  return written;
}

int writeFlyThrough(const FieldReplica& replica, const std::vector<ViewPose>& views,
                    const std::string& path, double fps, int threads,
                    const std::function<void()>& progress) {
  if (views.empty()) return 0;
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  if (ec) throw std::runtime_error(path + ": cannot create its folder: " + ec.message());
  const CameraModel& c0 = views.front().camera;
  cv::VideoWriter writer(path, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), fps,
                         cv::Size(c0.width, c0.height));
  if (!writer.isOpened()) throw std::runtime_error(path + ": cannot open an MJPG video writer");
  int frames = 0;
  for (const ViewPose& v : views) {
    CameraModel c = v.camera;
    if (c.width != c0.width || c.height != c0.height) c = c0;  // one size per video
    writer.write(toBgr8(replica.render(v.T_world_cam, c, nullptr, threads).color));
    ++frames;
    if (progress) progress();
  }
  return frames;
}

}  // namespace radslam
