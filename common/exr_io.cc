#include "common/exr_io.h"

#include <filesystem>
#include <memory>
#include <set>
#include <stdexcept>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfTestFile.h>

namespace radslam {
namespace {

// A corrupt header can claim any size; refuse before allocating it.
constexpr int64_t kMaxPixels = int64_t{1} << 28;

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw std::runtime_error(path + ": " + what);
}

std::string channelNames(const Imf::ChannelList& list) {
  std::string names;
  for (auto it = list.begin(); it != list.end(); ++it) {
    if (!names.empty()) names += ", ";
    names += it.name();
  }
  return names.empty() ? "none" : names;
}

// Opens `path` for reading with clear errors for the common failures.
std::unique_ptr<Imf::InputFile> openInput(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) fail(path, "EXR file not found");
  bool tiled = false;
  if (!Imf::isOpenExrFile(path.c_str(), tiled))
    fail(path, "not an OpenEXR file (bad magic number)");
  try {
    return std::make_unique<Imf::InputFile>(path.c_str());
  } catch (const std::exception& e) {
    fail(path, std::string("cannot read EXR header: ") + e.what());
  }
}

// Reads the listed channels of an open file as CV_32FC1 images.
ExrChannels readChannels(const std::string& path, Imf::InputFile& file,
                         const std::vector<std::string>& names) {
  const Imath::Box2i window = file.header().dataWindow();
  const int64_t width = int64_t{window.max.x} - window.min.x + 1;
  const int64_t height = int64_t{window.max.y} - window.min.y + 1;
  if (width <= 0 || height <= 0 || width * height > kMaxPixels)
    fail(path, "implausible data window " + std::to_string(width) + "x" + std::to_string(height));

  ExrChannels channels;
  Imf::FrameBuffer buffer;
  for (const std::string& name : names) {
    const Imf::Channel* channel = file.header().channels().findChannel(name);
    if (channel->xSampling != 1 || channel->ySampling != 1)
      fail(path, "channel '" + name + "' is subsampled, which is not supported");
    cv::Mat image(static_cast<int>(height), static_cast<int>(width), CV_32FC1);
    // FLOAT slices make OpenEXR convert HALF/UINT channels for us.
    buffer.insert(name,
                  Imf::Slice::Make(Imf::FLOAT, image.data, window, sizeof(float), image.step));
    channels.emplace_back(name, image);
  }
  try {
    file.setFrameBuffer(buffer);
    file.readPixels(window.min.y, window.max.y);
  } catch (const std::exception& e) {
    fail(path, std::string("corrupt EXR pixel data: ") + e.what());
  }
  return channels;
}

}  // namespace

void writeExr(const std::string& path, const ExrChannels& channels) {
  if (channels.empty()) fail(path, "no channels to write");
  const cv::Size size = channels.front().second.size();
  if (size.area() == 0) fail(path, "channel '" + channels.front().first + "' is empty");
  std::set<std::string> seen;
  for (const auto& [name, image] : channels) {
    if (name.empty()) fail(path, "a channel has an empty name");
    if (!seen.insert(name).second) fail(path, "channel '" + name + "' given twice");
    if (image.type() != CV_32FC1)
      fail(path,
           "channel '" + name + "' is not CV_32FC1 (type " + std::to_string(image.type()) + ")");
    if (image.size() != size)
      fail(path, "channel '" + name + "' is " + std::to_string(image.cols) + "x" +
                     std::to_string(image.rows) + " but '" + channels.front().first + "' is " +
                     std::to_string(size.width) + "x" + std::to_string(size.height));
  }

  Imf::Header header(size.width, size.height);
  header.compression() = Imf::ZIP_COMPRESSION;
  Imf::FrameBuffer buffer;
  for (const auto& [name, image] : channels) {
    header.channels().insert(name, Imf::Channel(Imf::FLOAT));
    // OpenEXR only reads through this pointer when writing; its API is not const.
    buffer.insert(name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(image.data), sizeof(float),
                                   image.step));
  }
  try {
    Imf::OutputFile file(path.c_str(), header);
    file.setFrameBuffer(buffer);
    file.writePixels(size.height);
  } catch (const std::exception& e) {
    fail(path, std::string("cannot write EXR: ") + e.what());
  }
}

ExrChannels readExr(const std::string& path) {
  std::unique_ptr<Imf::InputFile> file = openInput(path);
  std::vector<std::string> names;
  const Imf::ChannelList& list = file->header().channels();
  for (auto it = list.begin(); it != list.end(); ++it) names.emplace_back(it.name());
  if (names.empty()) fail(path, "EXR file has no channels");
  return readChannels(path, *file, names);
}

cv::Mat readExrChannel(const std::string& path, const std::string& name) {
  std::unique_ptr<Imf::InputFile> file = openInput(path);
  const Imf::ChannelList& list = file->header().channels();
  if (list.findChannel(name) == nullptr)
    fail(path, "no channel '" + name + "' (channels: " + channelNames(list) + ")");
  return readChannels(path, *file, {name}).front().second;
}

}  // namespace radslam
