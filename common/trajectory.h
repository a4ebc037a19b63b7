// Stamped pose sequences and their file formats.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "common/lie.h"

namespace radslam {

struct StampedPose {
  double t = 0;  // seconds on the dataset's own clock
  SE3 T_world_cam;
};
using Trajectory = std::vector<StampedPose>;

/// TUM format: one line per pose, "t tx ty tz qx qy qz qw", '#' comments.
/// Throws std::runtime_error naming the file and line on malformed input.
Trajectory readTumTrajectory(const std::string& path);
/// Writes with the shortest decimal form that reads back to the same double
/// (times in fixed notation), so a write/read round trip is exact.
void writeTumTrajectory(const std::string& path, const Trajectory& trajectory);

/// KITTI format: one line per pose, the 3x4 row-major T_world_cam. Timestamps
/// come from `times` (seconds, same length) or are the row index when empty.
Trajectory readKittiTrajectory(const std::string& path, const std::vector<double>& times = {});
void writeKittiTrajectory(const std::string& path, const Trajectory& trajectory);

/// Pairs of indices (i into a, j into b) whose stamps differ by at most
/// max_dt_s, greedily nearest first, each index used once, sorted by a's time.
std::vector<std::pair<size_t, size_t>> associateByTime(const Trajectory& a, const Trajectory& b,
                                                       double max_dt_s);
/// The same on plain time stamps (seconds); non-finite stamps never match.
std::vector<std::pair<size_t, size_t>> associateTimes(const std::vector<double>& a,
                                                      const std::vector<double>& b,
                                                      double max_dt_s);

/// One row of a numeric text table with its 1-based line number.
struct NumericRow {
  int line = 0;
  std::vector<double> values;
};

/// Reads a table of finite numbers separated by spaces, tabs or commas; blank
/// lines and lines starting with '#' are skipped. When columns > 0 every row
/// must hold exactly that many numbers. Throws std::runtime_error
/// "FILE:LINE: expected N numbers (what), got M" (or naming the bad token), or
/// "FILE: cannot open" when the file cannot be read.
std::vector<NumericRow> readNumericRows(const std::string& path, size_t columns,
                                        const std::string& what);

/// "<seconds>.<microseconds>" of a sensor time in microseconds: the file stem of everything a
/// run folder names by a frame's timestamp (keyframe EXR, renders), as in the dataset's clock.
std::string stampFileName(int64_t utime);

/// Shortest decimal text that parses back to exactly `value`.
std::string formatDouble(double value);

/// At most max_items of items, evenly spread over them (the first kept, order kept): the
/// views a run renders at its end, whatever its length.
template <class T>
std::vector<T> evenlySpread(const std::vector<T>& items, size_t max_items) {
  if (items.size() <= max_items) return items;
  std::vector<T> spread;
  for (size_t k = 0; k < max_items; ++k) spread.push_back(items[k * items.size() / max_items]);
  return spread;
}

}  // namespace radslam
