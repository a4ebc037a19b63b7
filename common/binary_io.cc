#include "common/binary_io.h"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <stdexcept>

namespace radslam {

BinaryWriter::BinaryWriter(const std::string& path, const std::string& what)
    : path_(path), tmp_(path + ".tmp"), what_(what), out_(tmp_, std::ios::binary) {
  if (!out_) throw std::runtime_error(what_ + ": cannot open " + tmp_ + " for writing");
}

BinaryWriter::~BinaryWriter() {
  if (committed_) return;
  out_.close();
  std::remove(tmp_.c_str());
}

void BinaryWriter::str(const std::string& s) {
  put<uint64_t>(s.size());
  bytes(s.data(), s.size());
}

void BinaryWriter::mat(const cv::Mat& m) {
  put<int32_t>(m.rows);
  put<int32_t>(m.cols);
  put<int32_t>(m.type());
  if (m.empty()) return;
  const cv::Mat c = m.isContinuous() ? m : m.clone();
  bytes(c.data, c.total() * c.elemSize());
}

void BinaryWriter::se3(const SE3& T) {
  const Eigen::Quaterniond& q = T.quaternion();
  for (double v : {q.x(), q.y(), q.z(), q.w()}) put(v);
  for (int i = 0; i < 3; ++i) put(T.translation()[i]);
}

void BinaryWriter::header(const Header& h) {
  put(h.utime);
  put(h.seq);
  str(h.sender);
}

void BinaryWriter::camera(const CameraModel& c) {
  put<int32_t>(c.width);
  put<int32_t>(c.height);
  put(c.type);
  for (double v : {c.fx, c.fy, c.cx, c.cy}) put(v);
  vec(c.distortion);
}

void BinaryWriter::commit() {
  out_.flush();
  if (!out_) throw std::runtime_error(what_ + ": write failed (disk full?)");
  out_.close();
  if (std::rename(tmp_.c_str(), path_.c_str()) != 0)
    throw std::runtime_error(what_ + ": cannot rename " + tmp_ + " into place");
  committed_ = true;
}

BinaryReader::BinaryReader(const std::string& path, const std::string& what) : what_(what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(what_ + ": cannot open");
  data_.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void BinaryReader::fail(const std::string& message) const {
  throw std::runtime_error(what_ + ": " + message + " (at byte " + std::to_string(pos_) + " of " +
                           std::to_string(data_.size()) + ")");
}

void BinaryReader::bytes(void* out, size_t n) {
  if (n > data_.size() - pos_) fail("truncated");
  std::memcpy(out, data_.data() + pos_, n);
  pos_ += n;
}

std::string BinaryReader::str() {
  const uint64_t n = get<uint64_t>();
  if (n > data_.size() - pos_) fail("truncated: string longer than the rest of the file");
  std::string s(n, '\0');
  bytes(s.data(), n);
  return s;
}

cv::Mat BinaryReader::mat() {
  const int rows = get<int32_t>(), cols = get<int32_t>(), type = get<int32_t>();
  if (rows == 0 || cols == 0) return cv::Mat();
  const bool type_ok = type == CV_8UC1 || type == CV_8UC3 || type == CV_16UC1 || type == CV_32FC1 ||
                       type == CV_32FC2 || type == CV_32FC3;
  if (rows < 0 || cols < 0 || rows > 100000 || cols > 100000 || !type_ok) fail("bad image header");
  const size_t n = size_t(rows) * size_t(cols) * CV_ELEM_SIZE(type);
  if (n > data_.size() - pos_) fail("truncated: image larger than the rest of the file");
  cv::Mat m(rows, cols, type);
  bytes(m.data, n);
  return m;
}

SE3 BinaryReader::se3() {
  double q[4], t[3];
  for (double& v : q) v = get<double>();
  for (double& v : t) v = get<double>();
  const Eigen::Quaterniond quat(q[3], q[0], q[1], q[2]);
  const Vec3 translation(t[0], t[1], t[2]);
  if (!quat.coeffs().allFinite() || std::abs(quat.norm() - 1) > 1e-9 || !translation.allFinite())
    fail("bad pose");
  return SE3(SO3::fromUnitQuaternion(quat), translation);
}

uint32_t BinaryReader::count(size_t min_bytes) {
  const uint32_t n = get<uint32_t>();
  if (min_bytes > 0 && n > (data_.size() - pos_) / min_bytes)
    fail("truncated: count larger than the rest of the file");
  return n;
}

Header BinaryReader::header() {
  Header h;
  h.utime = get<int64_t>();
  h.seq = get<int64_t>();
  h.sender = str();
  return h;
}

CameraModel BinaryReader::camera() {
  CameraModel c;
  c.width = get<int32_t>();
  c.height = get<int32_t>();
  c.type = get<CameraModel::Type>();
  for (double* v : {&c.fx, &c.fy, &c.cx, &c.cy}) *v = get<double>();
  vec(&c.distortion);
  return c;
}

}  // namespace radslam
