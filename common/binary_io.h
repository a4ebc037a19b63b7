// Little-endian binary files of fixed-size values, strings, arrays, OpenCV images, poses and
// Eigen matrices: the checkpoints of the mapper and the tracker. Written to PATH.tmp and
// renamed into place by commit(), so a crash never leaves a half-written file; read whole, with
// every size checked against the bytes left before anything is allocated.
#pragma once

#include <cstdint>
#include <fstream>
#include <string>
#include <type_traits>
#include <vector>

#include <opencv2/core.hpp>

#include "common/lie.h"
#include "common/types.h"

namespace radslam {

class BinaryWriter {
 public:
  /// `what` names the file in errors ("checkpoint PATH"). Throws std::runtime_error when
  /// PATH.tmp cannot be opened.
  BinaryWriter(const std::string& path, const std::string& what);
  ~BinaryWriter();  // removes PATH.tmp unless commit() ran
  BinaryWriter(const BinaryWriter&) = delete;
  BinaryWriter& operator=(const BinaryWriter&) = delete;

  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    bytes(&v, sizeof(T));
  }
  void bytes(const void* data, size_t n) { out_.write(static_cast<const char*>(data), n); }
  template <class T, class Alloc>
  void vec(const std::vector<T, Alloc>& v) {
    put<uint64_t>(v.size());
    if (!v.empty()) bytes(v.data(), v.size() * sizeof(T));
  }
  void str(const std::string& s);
  /// Header (rows, cols, type) and the pixels; an empty matrix is a header of zeros.
  void mat(const cv::Mat& m);
  /// Quaternion (x, y, z, w) and translation, bit for bit.
  void se3(const SE3& T);
  template <int R, int C>
  void matrix(const Eigen::Matrix<double, R, C>& m) {
    for (int i = 0; i < m.size(); ++i) put(m.data()[i]);
  }
  void header(const Header& h);
  /// Size, model type, fx fy cx cy and distortion (not the rolling shutter readout: the files
  /// that hold an input camera write it themselves).
  void camera(const CameraModel& c);
  /// Flushes, closes and renames PATH.tmp to PATH. Throws std::runtime_error (disk full, ...).
  void commit();

 private:
  std::string path_, tmp_, what_;
  std::ofstream out_;
  bool committed_ = false;
};

class BinaryReader {
 public:
  /// Reads the whole file. Throws std::runtime_error naming `what` when it cannot be opened.
  BinaryReader(const std::string& path, const std::string& what);

  /// Throws std::runtime_error: "<what>: <message> (at byte N of M)".
  [[noreturn]] void fail(const std::string& message) const;
  void bytes(void* out, size_t n);
  template <class T>
  T get() {
    static_assert(std::is_trivially_copyable_v<T>);
    T v;
    bytes(&v, sizeof(T));
    return v;
  }
  /// `expected` (when given) is the size the array must have.
  template <class T, class Alloc>
  void vec(std::vector<T, Alloc>* v, size_t expected = SIZE_MAX) {
    const uint64_t n = get<uint64_t>();
    if (n > (data_.size() - pos_) / sizeof(T))
      fail("truncated: array longer than the rest of the file");
    if (expected != SIZE_MAX && n != expected) fail("array of unexpected size");
    v->resize(n);
    if (n) bytes(v->data(), n * sizeof(T));
  }
  std::string str();
  /// Images of 8U C1/C3, 16U C1 and 32F C1..C3 up to 100000 px a side.
  cv::Mat mat();
  /// Fails on a quaternion that is not of unit norm; the pose equals the saved one exactly.
  SE3 se3();
  template <int R, int C>
  void matrix(Eigen::Matrix<double, R, C>* m) {
    for (int i = 0; i < m->size(); ++i) m->data()[i] = get<double>();
  }
  Header header();
  /// As written by BinaryWriter::camera (not validated: the caller checks the camera).
  CameraModel camera();
  /// A count of items of at least min_bytes each; fails when the rest of the file cannot hold
  /// them (checked before anything is allocated).
  uint32_t count(size_t min_bytes);
  bool done() const { return pos_ == data_.size(); }

 private:
  std::string what_;
  std::vector<char> data_;
  size_t pos_ = 0;
};

}  // namespace radslam
