#include "common/keyframe_files.h"

#include <filesystem>
#include <stdexcept>
#include <utility>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "common/exr_io.h"
#include "common/trajectory.h"

namespace radslam {

void writeKeyframeFiles(const std::string& dir, const Keyframe& keyframe) {
  std::filesystem::create_directories(dir);
  const std::string stem = dir + "/" + stampFileName(keyframe.header.utime);
  ExrChannels channels = {{"depth", keyframe.depth}};
  if (!keyframe.depth_var.empty()) {
    cv::Mat sigma;
    cv::sqrt(cv::max(keyframe.depth_var, 0.0), sigma);
    channels.emplace_back("sigma", sigma);
  }
  if (!keyframe.inv_depth.empty()) channels.emplace_back("inv_depth", keyframe.inv_depth);
  if (!keyframe.inv_depth_var.empty())
    channels.emplace_back("inv_depth_var", keyframe.inv_depth_var);
  writeExr(stem + ".exr", channels);
  if (!keyframe.color.empty() && !cv::imwrite(stem + ".png", keyframe.color))
    throw std::runtime_error("cannot write " + stem + ".png");
}

}  // namespace radslam
