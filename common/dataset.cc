// openDataset and the helpers the dataset readers share.
#include "common/dataset.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>

#include "common/dataset_internal.h"

namespace radslam {
namespace dataset_internal {

namespace fs = std::filesystem;

bool isDirectory(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec);
}

bool isFile(const std::string& path) {
  std::error_code ec;
  return fs::is_regular_file(path, ec);
}

std::string joinPath(const std::string& a, const std::string& b) {
  if (a.empty() || (!b.empty() && b.front() == '/')) return b;
  if (b.empty()) return a;
  return a.back() == '/' ? a + b : a + "/" + b;
}

bool parseNumber(const std::string& text, double* value) {
  const char* first = text.data();
  const char* last = text.data() + text.size();
  if (first != last && *first == '+') ++first;  // from_chars rejects a leading '+'
  const auto [end, ec] = std::from_chars(first, last, *value);
  return ec == std::errc() && end == last && std::isfinite(*value);
}

bool parseInteger(const std::string& text, int64_t* value) {
  const char* first = text.data();
  const char* last = text.data() + text.size();
  if (first != last && *first == '+') ++first;
  const auto [end, ec] = std::from_chars(first, last, *value);
  return ec == std::errc() && end == last;
}

int64_t secondsToUtime(double t_s) { return static_cast<int64_t>(std::llround(t_s * 1e6)); }

std::vector<TextRow> readTextRows(const std::string& path, bool commas) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  std::vector<TextRow> rows;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    TextRow row;
    row.line = line_number;
    std::string field;
    auto flush = [&] {
      if (!field.empty()) row.fields.push_back(field);
      field.clear();
    };
    for (char c : line) {
      if (std::isspace(static_cast<unsigned char>(c)) || (commas && c == ',')) {
        flush();
      } else {
        field += c;
      }
    }
    flush();
    if (row.fields.empty() || row.fields.front()[0] == '#') continue;
    rows.push_back(std::move(row));
  }
  return rows;
}

std::vector<double> readTimes(const std::string& path) {
  std::vector<double> times;
  for (const NumericRow& row : readNumericRows(path, 1, "time stamp in seconds"))
    times.push_back(row.values[0]);
  return times;
}

std::vector<std::pair<int64_t, std::string>> listNumberedFiles(const std::string& dir,
                                                               const std::string& prefix,
                                                               const std::string& suffix) {
  std::vector<std::pair<int64_t, std::string>> files;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.size() <= prefix.size() + suffix.size() ||
        name.compare(0, prefix.size(), prefix) != 0 ||
        name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0)
      continue;
    const std::string digits =
        name.substr(prefix.size(), name.size() - prefix.size() - suffix.size());
    if (digits.size() > 18 ||
        !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
      continue;
    files.emplace_back(std::stoll(digits), name);
  }
  std::sort(files.begin(), files.end());
  return files;
}

cv::FileStorage openYaml(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": file not found or unreadable");
  std::stringstream buffer;
  buffer << in.rdbuf();
  std::string text = buffer.str();
  // OpenCV insists on "%YAML:1.0" as the first line; many YAML writers omit it
  // or write the standard "%YAML 1.x".
  if (text.compare(0, 5, "%YAML") == 0) text.erase(0, text.find('\n'));
  text = "%YAML:1.0\n" + text;
  try {
    cv::FileStorage storage(
        text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
    if (!storage.isOpened()) throw std::runtime_error(path + ": cannot parse YAML");
    return storage;
  } catch (const cv::Exception& e) {
    throw std::runtime_error(path + ": cannot parse YAML: " + e.err);
  }
}

namespace {

double readNumber(const cv::FileNode& node, const std::string& key, const std::string& path) {
  const cv::FileNode value = node[key];
  if (value.empty()) throw std::runtime_error(path + ": missing key '" + key + "'");
  if (!value.isInt() && !value.isReal())
    throw std::runtime_error(path + ": key '" + key + "' is not a number");
  const double number = value.real();
  if (!std::isfinite(number)) throw std::runtime_error(path + ": key '" + key + "' is not finite");
  return number;
}

std::string describeType(const cv::Mat& image) {
  const int depth = image.depth();
  const char* bits = depth == CV_8U || depth == CV_8S     ? "8-bit"
                     : depth == CV_16U || depth == CV_16S ? "16-bit"
                                                          : "32/64-bit";
  return std::string(bits) + " " + std::to_string(image.channels()) + "-channel";
}

std::string sizeText(const cv::Size& size) {
  return std::to_string(size.width) + "x" + std::to_string(size.height);
}

bool fail(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

bool readImage(const std::string& path, int flags, const cv::Size& expected, cv::Mat* image,
               std::string* error) {
  if (!isFile(path)) return fail(error, path + ": image file not found");
  *image = cv::imread(path, flags);
  if (image->empty()) return fail(error, path + ": cannot decode image (truncated or corrupt)");
  if (expected.area() > 0 && image->size() != expected)
    return fail(
        error, path + ": image is " + sizeText(image->size()) + ", expected " + sizeText(expected));
  return true;
}

}  // namespace

CameraModel readCameraNode(const cv::FileNode& node, const std::string& path) {
  CameraModel camera;
  const double width = readNumber(node, "width", path);
  const double height = readNumber(node, "height", path);
  if (width < 1 || height < 1 || width > 1e5 || height > 1e5 || width != std::floor(width) ||
      height != std::floor(height))
    throw std::runtime_error(path + ": implausible image size " + std::to_string(width) + "x" +
                             std::to_string(height));
  camera.width = static_cast<int>(width);
  camera.height = static_cast<int>(height);
  camera.fx = readNumber(node, "fx", path);
  camera.fy = readNumber(node, "fy", path);
  camera.cx = readNumber(node, "cx", path);
  camera.cy = readNumber(node, "cy", path);
  if (camera.fx <= 0 || camera.fy <= 0)
    throw std::runtime_error(path + ": focal lengths fx, fy must be positive");
  bool distorted = false;
  std::vector<double> coefficients;
  for (const char* key : {"k1", "k2", "p1", "p2", "k3"}) {
    distorted |= !node[key].empty();
    coefficients.push_back(node[key].empty() ? 0.0 : readNumber(node, key, path));
  }
  if (distorted) {
    camera.type = CameraModel::Type::kRadTan;
    camera.distortion = coefficients;
  }
  if (!node["readout_s"].empty()) {
    camera.readout_s = readNumber(node, "readout_s", path);
    if (!(camera.readout_s >= 0 && camera.readout_s < 1))
      throw std::runtime_error(path + ": readout_s (rolling shutter, s) must be in [0, 1)");
  }
  return camera;
}

bool loadColorImage(const std::string& path, bool grey, const cv::Size& expected, cv::Mat* image,
                    std::string* error) {
  return readImage(path, grey ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR, expected, image, error);
}

bool loadUint16Image(const std::string& path, const cv::Size& expected, cv::Mat* image,
                     std::string* error) {
  if (!readImage(path, cv::IMREAD_UNCHANGED, expected, image, error)) return false;
  if (image->type() != CV_16UC1)
    return fail(error,
                path + ": expected a 16-bit single-channel image, got " + describeType(*image));
  return true;
}

bool loadDepthImage(const std::string& path, double metres_per_unit, const cv::Size& expected,
                    cv::Mat* depth, std::string* error) {
  cv::Mat raw;
  if (!loadUint16Image(path, expected, &raw, error)) return false;
  raw.convertTo(*depth, CV_32FC1, metres_per_unit);
  return true;
}

std::optional<Frame> frameError(std::string* error, const std::string& message) {
  if (error) *error = message;
  return std::nullopt;
}

}  // namespace dataset_internal

std::unique_ptr<DatasetReader> openDataset(const std::string& spec) {
  using namespace dataset_internal;
  const std::string kinds = "tum, euroc, kitti, replica, synthetic";
  const size_t colon = spec.find(':');
  if (colon == std::string::npos)
    throw std::runtime_error("dataset '" + spec + "' must be KIND:PATH with KIND one of " + kinds);
  const std::string kind = spec.substr(0, colon);
  std::string path = spec.substr(colon + 1);
  while (path.size() > 1 && path.back() == '/') path.pop_back();

  using Opener = std::unique_ptr<DatasetReader> (*)(const std::string&);
  const std::pair<const char*, Opener> openers[] = {{"tum", openTum},
                                                    {"euroc", openEuroc},
                                                    {"kitti", openKitti},
                                                    {"replica", openReplica},
                                                    {"synthetic", openSynthetic}};
  for (const auto& [name, open] : openers) {
    if (kind != name) continue;
    if (path.empty()) throw std::runtime_error("dataset '" + spec + "' has no PATH");
    if (!isDirectory(path))
      throw std::runtime_error(kind + " dataset folder '" + path + "' does not exist");
    return open(path);
  }
  throw std::runtime_error("unknown dataset kind '" + kind + "' in '" + spec +
                           "' (expected one of " + kinds + ")");
}

}  // namespace radslam
