// Helpers shared by the dataset readers (private to common/dataset*.cc).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/dataset.h"

namespace radslam::dataset_internal {

bool isDirectory(const std::string& path);
bool isFile(const std::string& path);
std::string joinPath(const std::string& a, const std::string& b);

/// Strict parses of a whole field (no trailing characters; finite numbers only).
bool parseNumber(const std::string& text, double* value);
bool parseInteger(const std::string& text, int64_t* value);

/// Seconds to the microseconds of Header::utime, rounded.
int64_t secondsToUtime(double t_s);

/// Non-comment, non-blank lines of a text file split on whitespace (and on
/// commas when `commas`), each with its 1-based line number. Throws when the
/// file cannot be opened.
struct TextRow {
  int line = 0;
  std::vector<std::string> fields;
};
std::vector<TextRow> readTextRows(const std::string& path, bool commas);

/// One time stamp (s) per line.
std::vector<double> readTimes(const std::string& path);

/// Files PREFIX<digits>SUFFIX in `dir` as (number, file name), sorted by number.
std::vector<std::pair<int64_t, std::string>> listNumberedFiles(const std::string& dir,
                                                               const std::string& prefix,
                                                               const std::string& suffix);

/// Opens a cv::FileStorage YAML file, adding the "%YAML:1.0" first line that
/// OpenCV requires when the file lacks it. Throws naming the file on failure.
cv::FileStorage openYaml(const std::string& path);

/// Pinhole or RadTan camera from a cv::FileStorage node with keys width height
/// fx fy cx cy and optional k1 k2 p1 p2 k3 and readout_s (rolling shutter). Throws
/// naming `path` on missing or implausible values.
CameraModel readCameraNode(const cv::FileNode& node, const std::string& path);

/// Image loaders: false plus *error (naming the file and the problem) when the
/// file is missing, undecodable, of the wrong type or of the wrong size.
/// `expected` of 0x0 skips the size check.
bool loadColorImage(const std::string& path, bool grey, const cv::Size& expected, cv::Mat* image,
                    std::string* error);
bool loadUint16Image(const std::string& path, const cv::Size& expected, cv::Mat* image,
                     std::string* error);
/// uint16 depth PNG to CV_32FC1 metres (value * metres_per_unit; 0 stays 0 = invalid).
bool loadDepthImage(const std::string& path, double metres_per_unit, const cv::Size& expected,
                    cv::Mat* depth, std::string* error);

/// Sets *error (when non-null) and returns nullopt: the readers' failure path.
std::optional<Frame> frameError(std::string* error, const std::string& message);

std::unique_ptr<DatasetReader> openTum(const std::string& path);
std::unique_ptr<DatasetReader> openEuroc(const std::string& path);
std::unique_ptr<DatasetReader> openKitti(const std::string& path);
std::unique_ptr<DatasetReader> openReplica(const std::string& path);
std::unique_ptr<DatasetReader> openSynthetic(const std::string& path);

}  // namespace radslam::dataset_internal
