// OpenEXR I/O of named float32 image channels (depth, depth variance, sigma...):
// lossless, so NaN, inf and 0 survive a round trip bit for bit.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

namespace radslam {

using ExrChannels = std::vector<std::pair<std::string, cv::Mat>>;

/// Writes `channels` (each CV_32FC1, all the same non-zero size, distinct
/// non-empty names) as one scanline EXR with FLOAT pixels and ZIP compression.
/// Throws std::runtime_error naming the file on bad input or a write failure.
void writeExr(const std::string& path, const ExrChannels& channels);

/// Reads every channel of an EXR as CV_32FC1 (HALF and UINT channels are
/// converted to float by OpenEXR), in the file's order, which OpenEXR keeps
/// sorted by name. Throws std::runtime_error naming the file when it is
/// missing, not an EXR, or corrupt.
ExrChannels readExr(const std::string& path);

/// Reads one channel; throws std::runtime_error naming the file and the
/// channels it has when `name` is not among them.
cv::Mat readExrChannel(const std::string& path, const std::string& name);

}  // namespace radslam
