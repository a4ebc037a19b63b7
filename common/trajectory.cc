#include "common/trajectory.h"

#include <algorithm>
#include <charconv>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <stdexcept>
#include <tuple>

namespace radslam {
namespace {

std::string where(const std::string& path, int line) {
  return path + ":" + std::to_string(line) + ": ";
}

// Splits on spaces, tabs and commas (TUM/KITTI use spaces, CSV exports commas).
std::vector<std::string> splitTokens(const std::string& line) {
  std::vector<std::string> tokens;
  std::string token;
  for (char c : line) {
    if (c == ' ' || c == '\t' || c == ',' || c == '\r') {
      if (!token.empty()) tokens.push_back(std::move(token));
      token.clear();
    } else {
      token += c;
    }
  }
  if (!token.empty()) tokens.push_back(std::move(token));
  return tokens;
}

bool parseDouble(const std::string& token, double* value) {
  const char* first = token.data();
  const char* last = token.data() + token.size();
  if (first != last && *first == '+') ++first;  // from_chars rejects a leading '+'
  const auto [end, ec] = std::from_chars(first, last, *value);
  return ec == std::errc() && end == last;
}

// Time stamps in fixed notation (as TUM files have them), shortest exact digits.
std::string formatTime(double t) {
  if (!std::isfinite(t) || std::abs(t) >= 1e15) return formatDouble(t);
  char buffer[64];
  const auto [end, ec] =
      std::to_chars(buffer, buffer + sizeof(buffer), t, std::chars_format::fixed);
  return ec == std::errc() ? std::string(buffer, end) : formatDouble(t);
}

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};

std::unique_ptr<std::FILE, FileCloser> openForWriting(const std::string& path) {
  std::unique_ptr<std::FILE, FileCloser> file(std::fopen(path.c_str(), "w"));
  if (!file) throw std::runtime_error(path + ": cannot open for writing");
  return file;
}

void finishWriting(const std::string& path, std::unique_ptr<std::FILE, FileCloser> file) {
  const bool failed = std::ferror(file.get()) != 0;
  if (std::fclose(file.release()) != 0 || failed)
    throw std::runtime_error(path + ": write failed (disk full?)");
}

}  // namespace

std::string stampFileName(int64_t utime) {
  char buffer[48];
  const int64_t s = utime / 1000000, us = utime % 1000000;
  std::snprintf(buffer, sizeof(buffer), "%" PRId64 ".%06" PRId64, s, us < 0 ? -us : us);
  return buffer;
}

std::string formatDouble(double value) {
  char buffer[64];
  const auto [end, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
  return ec == std::errc() ? std::string(buffer, end) : std::string("nan");
}

std::vector<NumericRow> readNumericRows(const std::string& path, size_t columns,
                                        const std::string& what) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  std::vector<NumericRow> rows;
  std::string line;
  int line_number = 0;
  const std::string expected = "expected " + std::to_string(columns) + " numbers (" + what + ")";
  while (std::getline(in, line)) {
    ++line_number;
    const std::vector<std::string> tokens = splitTokens(line);
    if (tokens.empty() || tokens.front()[0] == '#') continue;
    NumericRow row;
    row.line = line_number;
    for (const std::string& token : tokens) {
      double value = 0;
      if (!parseDouble(token, &value))
        throw std::runtime_error(where(path, line_number) +
                                 (columns > 0 ? expected + ", but '" : "'") + token +
                                 "' is not a number");
      if (!std::isfinite(value))
        throw std::runtime_error(where(path, line_number) + "'" + token +
                                 "' is not a finite number");
      row.values.push_back(value);
    }
    if (columns > 0 && row.values.size() != columns)
      throw std::runtime_error(where(path, line_number) + expected + ", got " +
                               std::to_string(row.values.size()));
    rows.push_back(std::move(row));
  }
  if (in.bad()) throw std::runtime_error(path + ": read error");
  return rows;
}

Trajectory readTumTrajectory(const std::string& path) {
  Trajectory trajectory;
  for (const NumericRow& row : readNumericRows(path, 8, "t tx ty tz qx qy qz qw")) {
    const std::vector<double>& v = row.values;
    const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);  // file order x y z w
    if (q.norm() < 1e-6)
      throw std::runtime_error(where(path, row.line) + "quaternion (qx qy qz qw) has zero norm");
    trajectory.push_back({v[0], SE3(q, Vec3(v[1], v[2], v[3]))});
  }
  return trajectory;
}

void writeTumTrajectory(const std::string& path, const Trajectory& trajectory) {
  auto file = openForWriting(path);
  std::fprintf(file.get(), "# t tx ty tz qx qy qz qw\n");
  for (const StampedPose& pose : trajectory) {
    const Vec3& t = pose.T_world_cam.translation();
    const Eigen::Quaterniond& q = pose.T_world_cam.quaternion();
    std::string line = formatTime(pose.t);
    for (double value : {t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w()})
      line += " " + formatDouble(value);
    std::fprintf(file.get(), "%s\n", line.c_str());
  }
  finishWriting(path, std::move(file));
}

Trajectory readKittiTrajectory(const std::string& path, const std::vector<double>& times) {
  const std::vector<NumericRow> rows = readNumericRows(path, 12, "3x4 row-major T_world_cam");
  if (!times.empty() && times.size() != rows.size())
    throw std::runtime_error(path + ": " + std::to_string(rows.size()) + " poses but " +
                             std::to_string(times.size()) + " time stamps");
  Trajectory trajectory;
  trajectory.reserve(rows.size());
  for (size_t i = 0; i < rows.size(); ++i) {
    Mat4 T = Mat4::Identity();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) T(r, c) = rows[i].values[4 * r + c];
    if (std::abs(T.topLeftCorner<3, 3>().determinant()) < 1e-6)
      throw std::runtime_error(where(path, rows[i].line) + "rotation block is singular");
    trajectory.push_back({times.empty() ? static_cast<double>(i) : times[i], SE3(T)});
  }
  return trajectory;
}

void writeKittiTrajectory(const std::string& path, const Trajectory& trajectory) {
  auto file = openForWriting(path);
  for (const StampedPose& pose : trajectory) {
    const Mat4 T = pose.T_world_cam.matrix();
    std::string line;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) line += (line.empty() ? "" : " ") + formatDouble(T(r, c));
    std::fprintf(file.get(), "%s\n", line.c_str());
  }
  finishWriting(path, std::move(file));
}

std::vector<std::pair<size_t, size_t>> associateTimes(const std::vector<double>& a,
                                                      const std::vector<double>& b,
                                                      double max_dt_s) {
  std::vector<size_t> b_order;
  for (size_t j = 0; j < b.size(); ++j)
    if (std::isfinite(b[j])) b_order.push_back(j);
  std::sort(b_order.begin(), b_order.end(), [&](size_t x, size_t y) { return b[x] < b[y]; });

  // Every pair within max_dt_s, then accept them nearest first.
  std::vector<std::tuple<double, size_t, size_t>> candidates;
  for (size_t i = 0; i < a.size(); ++i) {
    if (!std::isfinite(a[i])) continue;
    auto it = std::lower_bound(b_order.begin(), b_order.end(), a[i] - max_dt_s,
                               [&](size_t j, double t) { return b[j] < t; });
    for (; it != b_order.end() && b[*it] <= a[i] + max_dt_s; ++it)
      candidates.emplace_back(std::abs(a[i] - b[*it]), i, *it);
  }
  std::sort(candidates.begin(), candidates.end());

  std::vector<bool> used_a(a.size(), false), used_b(b.size(), false);
  std::vector<std::pair<size_t, size_t>> pairs;
  for (const auto& [dt, i, j] : candidates) {
    if (used_a[i] || used_b[j]) continue;
    used_a[i] = used_b[j] = true;
    pairs.emplace_back(i, j);
  }
  std::sort(pairs.begin(), pairs.end(), [&](const auto& x, const auto& y) {
    return std::make_pair(a[x.first], x.first) < std::make_pair(a[y.first], y.first);
  });
  return pairs;
}

std::vector<std::pair<size_t, size_t>> associateByTime(const Trajectory& a, const Trajectory& b,
                                                       double max_dt_s) {
  std::vector<double> ta, tb;
  for (const StampedPose& p : a) ta.push_back(p.t);
  for (const StampedPose& p : b) tb.push_back(p.t);
  return associateTimes(ta, tb, max_dt_s);
}

}  // namespace radslam
