// Test helpers shared by codec_test and bus_test: one filled sample of every
// message type, field-by-field comparisons, and a writer for hand-crafted LCM
// bytes (big endian, as LCM encodes) to build malformed messages.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "common/bus.h"
#include "common/types.h"

namespace radslam {
namespace testing_samples {

/// Bit-exact equality of two images (NaN payloads included).
inline ::testing::AssertionResult sameImage(const cv::Mat& a, const cv::Mat& b) {
  if (a.empty() && b.empty()) return ::testing::AssertionSuccess();
  if (a.size() != b.size() || a.type() != b.type()) {
    return ::testing::AssertionFailure()
           << "size/type differ: " << a.cols << "x" << a.rows << " " << cv::typeToString(a.type())
           << " vs " << b.cols << "x" << b.rows << " " << cv::typeToString(b.type());
  }
  const size_t row_bytes = static_cast<size_t>(a.cols) * a.elemSize();
  for (int r = 0; r < a.rows; ++r) {
    if (std::memcmp(a.ptr(r), b.ptr(r), row_bytes) != 0) {
      return ::testing::AssertionFailure() << "pixels differ in row " << r;
    }
  }
  return ::testing::AssertionSuccess();
}

/// A smooth colour gradient with some texture (JPEG-friendly, PNG-exact).
inline cv::Mat colorImage(int w, int h) {
  cv::Mat m(h, w, CV_8UC3);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      m.at<cv::Vec3b>(y, x) =
          cv::Vec3b(static_cast<uint8_t>((x * 255) / w), static_cast<uint8_t>((y * 255) / h),
                    static_cast<uint8_t>(((x + y) * 127) / (w + h) + 64));
    }
  }
  return m;
}

inline cv::Mat randomImage(int w, int h, int type, uint64_t seed) {
  cv::Mat m(h, w, type);
  cv::RNG rng(seed);
  if (type == CV_32FC1) {
    rng.fill(m, cv::RNG::UNIFORM, -1e3, 1e3);
  } else {
    rng.fill(m, cv::RNG::UNIFORM, 0, type == CV_16UC1 ? 65536 : 256);
  }
  return m;
}

inline SE3 samplePose(double a) {
  return SE3::exp((Vec6() << 0.3 * a, -1.2, 2.5 * a, 0.1, -0.4 * a, 0.7).finished());
}

inline Mat6 sampleCovariance(double a) {
  Mat6 c;
  for (int r = 0; r < 6; ++r) {
    for (int k = 0; k < 6; ++k) c(r, k) = a * (r == k ? 1e-2 * (r + 1) : 1e-5 * (r - k));
  }
  return c;
}

inline CameraModel sampleCamera(int w, int h) {
  CameraModel c;
  c.width = w;
  c.height = h;
  c.type = CameraModel::Type::kRadTan;
  c.fx = 517.3;
  c.fy = 516.5;
  c.cx = 318.6;
  c.cy = 255.3;
  c.distortion = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
  c.readout_s = 0.025;
  return c;
}

inline Header sampleHeader(int64_t utime) {
  Header h;
  h.utime = utime;
  h.seq = 17;
  h.sender = "sampler";
  return h;
}

inline Frame sampleFrame(WireCompression compression = WireCompression::kRaw) {
  const int w = 64, h = 48;
  Frame f;
  f.header = sampleHeader(1305031102175304);
  f.frame_index = 42;
  f.camera = sampleCamera(w, h);
  f.color = colorImage(w, h);
  f.right = randomImage(w, h, CV_8UC3, 2);
  f.baseline_m = 0.537;
  f.depth_time_offset_s = -0.012;
  f.depth = randomImage(w, h, CV_32FC1, 3);
  f.instance = randomImage(w, h, CV_16UC1, 4);
  f.class_id = randomImage(w, h, CV_16UC1, 5);
  f.color_compression = compression;
  f.depth_wire_scale = 0;
  return f;
}

inline PoseStamped samplePoseStamped() {
  PoseStamped p;
  p.header = sampleHeader(1000001);
  p.frame_index = 7;
  p.state = TrackingState::kLost;
  p.is_keyframe = true;
  p.T_world_cam = samplePose(1.0);
  p.covariance = sampleCovariance(1.0);
  return p;
}

inline Keyframe sampleKeyframe() {
  const int w = 40, h = 30;
  Keyframe k;
  k.header = sampleHeader(2000002);
  k.keyframe_id = 3;
  k.version = 2;
  k.frame_index = 99;
  k.T_world_cam = samplePose(-0.5);
  k.covariance = sampleCovariance(2.0);
  k.camera = sampleCamera(w, h);
  k.camera.type = CameraModel::Type::kPinhole;
  k.camera.distortion.clear();
  k.color = randomImage(w, h, CV_8UC3, 11);
  k.inv_depth = randomImage(w, h, CV_32FC1, 12);
  k.inv_depth.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  k.inv_depth.at<float>(0, 1) = std::numeric_limits<float>::infinity();
  k.inv_depth_var = randomImage(w, h, CV_32FC1, 13);
  k.depth = randomImage(w, h, CV_32FC1, 14);
  k.depth_var = randomImage(w, h, CV_32FC1, 15);
  k.dynamic_mask = randomImage(w, h, CV_8UC1, 16);
  return k;
}

inline ObjectList sampleObjects() {
  ObjectList list;
  list.header = sampleHeader(3000003);
  list.frame_index = 12;
  for (int i = 0; i < 3; ++i) {
    TrackedObject o;
    o.object_id = 10 + i;
    o.class_id = 26 - i;
    o.class_name = i == 1 ? "door" : "car";
    o.T_world_object = samplePose(0.1 * i);
    o.twist << 1.0 * i, 0.0, -0.5, 0.0, 0.0, 0.25 * i;
    o.joint_type = static_cast<JointType>(i);
    o.T_world_joint = samplePose(-0.2 * i);
    o.parent_cluster = i - 1;
    o.covariance = sampleCovariance(0.5 + i);
    list.objects.push_back(o);
  }
  return list;
}

inline FieldUpdate sampleFieldUpdate() {
  FieldUpdate u;
  u.header = sampleHeader(4000004);
  u.version = 12;
  u.base_version = 9;
  u.is_snapshot = true;
  u.snapshot_id = 3;
  u.chunk_index = 1;
  u.chunk_count = 5;
  u.layout = "density_rgb_f16/v1";
  u.voxel_size = {0.08, 0.02};
  u.block_dim = 8;
  for (int i = 0; i < 4; ++i) {
    FieldBlock b;
    b.level = static_cast<int8_t>(i % 2);
    b.index = Eigen::Vector3i(i, -i, 2 * i + 1);
    for (int j = 0; j < 100 + i; ++j) b.data.push_back(static_cast<uint8_t>(j * 7 + i));
    u.blocks.push_back(b);
  }
  return u;
}

inline RenderRequest sampleRenderRequest() {
  RenderRequest r;
  r.header = sampleHeader(5000005);
  r.request_id = 77;
  r.client = "viewer-1";
  r.T_world_cam = samplePose(0.7);
  r.camera = sampleCamera(320, 240);
  r.camera.type = CameraModel::Type::kPinhole;
  r.camera.distortion.clear();
  r.channels = kRenderColor | kRenderSigma;
  return r;
}

inline RenderResult sampleRenderResult() {
  RenderResult r;
  r.header = sampleHeader(6000006);
  r.request_id = 77;
  r.client = "viewer-1";
  r.ok = true;
  r.error = "";
  r.field_version = 12;
  r.color = randomImage(32, 24, CV_8UC3, 21);
  r.depth = randomImage(32, 24, CV_32FC1, 22);
  r.sigma = randomImage(32, 24, CV_32FC1, 23);
  return r;
}

inline Status sampleStatus() {
  Status s;
  s.header = sampleHeader(7000007);
  s.process = "tracker";
  s.pid = 4321;
  s.state = ProcessState::kRunning;
  s.last_frame_index = 41;
  s.last_frame_utime = 1305031102175304;
  s.items_handled = 42;
  s.busy_s = 3.5;
  s.fps = 12.0;
  s.queue_depth = 2;
  s.rss_mb = 321.5;
  s.peak_rss_mb = 400.25;
  s.last_error = "none yet";
  s.values = {{"window", 8}, {"ba_cost", 0.125}};
  return s;
}

inline Control sampleControl() {
  Control c;
  c.header = sampleHeader(8000008);
  c.command = ControlCommand::kRepublish;
  c.target = "tracker";
  c.argument = "3,4,5";
  return c;
}

// ---- field-by-field comparisons ---------------------------------------------

inline void expectHeaderEq(const Header& a, const Header& b) {
  EXPECT_EQ(a.utime, b.utime);
  EXPECT_EQ(a.seq, b.seq);
  EXPECT_EQ(a.sender, b.sender);
}

inline void expectPoseEq(const SE3& a, const SE3& b) {
  // The receiver renormalises the quaternion: equal to the last bits.
  EXPECT_LT((a.matrix() - b.matrix()).cwiseAbs().maxCoeff(), 1e-15);
}

inline void expectCameraEq(const CameraModel& a, const CameraModel& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.type, b.type);
  EXPECT_EQ(a.fx, b.fx);
  EXPECT_EQ(a.fy, b.fy);
  EXPECT_EQ(a.cx, b.cx);
  EXPECT_EQ(a.cy, b.cy);
  EXPECT_EQ(a.distortion, b.distortion);
  EXPECT_EQ(a.readout_s, b.readout_s);
}

/// Frames with lossless encodings (raw or PNG colour, float depth).
inline void expectFrameEq(const Frame& a, const Frame& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.frame_index, b.frame_index);
  expectCameraEq(a.camera, b.camera);
  EXPECT_TRUE(sameImage(a.color, b.color));
  EXPECT_TRUE(sameImage(a.right, b.right));
  EXPECT_EQ(a.baseline_m, b.baseline_m);
  EXPECT_TRUE(sameImage(a.depth, b.depth));
  EXPECT_EQ(a.depth_time_offset_s, b.depth_time_offset_s);
  EXPECT_TRUE(sameImage(a.instance, b.instance));
  EXPECT_TRUE(sameImage(a.class_id, b.class_id));
  EXPECT_EQ(a.color_compression, b.color_compression);
  EXPECT_EQ(a.depth_wire_scale, b.depth_wire_scale);
}

inline void expectPoseStampedEq(const PoseStamped& a, const PoseStamped& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.frame_index, b.frame_index);
  EXPECT_EQ(a.state, b.state);
  EXPECT_EQ(a.is_keyframe, b.is_keyframe);
  expectPoseEq(a.T_world_cam, b.T_world_cam);
  EXPECT_EQ(a.covariance, b.covariance);
}

inline void expectKeyframeEq(const Keyframe& a, const Keyframe& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.keyframe_id, b.keyframe_id);
  EXPECT_EQ(a.version, b.version);
  EXPECT_EQ(a.frame_index, b.frame_index);
  expectPoseEq(a.T_world_cam, b.T_world_cam);
  EXPECT_EQ(a.covariance, b.covariance);
  expectCameraEq(a.camera, b.camera);
  EXPECT_TRUE(sameImage(a.color, b.color));
  EXPECT_TRUE(sameImage(a.inv_depth, b.inv_depth));
  EXPECT_TRUE(sameImage(a.inv_depth_var, b.inv_depth_var));
  EXPECT_TRUE(sameImage(a.depth, b.depth));
  EXPECT_TRUE(sameImage(a.depth_var, b.depth_var));
  EXPECT_TRUE(sameImage(a.dynamic_mask, b.dynamic_mask));
}

inline void expectObjectsEq(const ObjectList& a, const ObjectList& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.frame_index, b.frame_index);
  ASSERT_EQ(a.objects.size(), b.objects.size());
  for (size_t i = 0; i < a.objects.size(); ++i) {
    const TrackedObject& x = a.objects[i];
    const TrackedObject& y = b.objects[i];
    EXPECT_EQ(x.object_id, y.object_id);
    EXPECT_EQ(x.class_id, y.class_id);
    EXPECT_EQ(x.class_name, y.class_name);
    expectPoseEq(x.T_world_object, y.T_world_object);
    EXPECT_EQ(x.twist, y.twist);
    EXPECT_EQ(x.joint_type, y.joint_type);
    expectPoseEq(x.T_world_joint, y.T_world_joint);
    EXPECT_EQ(x.parent_cluster, y.parent_cluster);
    EXPECT_EQ(x.covariance, y.covariance);
  }
}

inline void expectFieldUpdateEq(const FieldUpdate& a, const FieldUpdate& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.version, b.version);
  EXPECT_EQ(a.base_version, b.base_version);
  EXPECT_EQ(a.is_snapshot, b.is_snapshot);
  EXPECT_EQ(a.snapshot_id, b.snapshot_id);
  EXPECT_EQ(a.chunk_index, b.chunk_index);
  EXPECT_EQ(a.chunk_count, b.chunk_count);
  EXPECT_EQ(a.layout, b.layout);
  EXPECT_EQ(a.voxel_size, b.voxel_size);
  EXPECT_EQ(a.block_dim, b.block_dim);
  ASSERT_EQ(a.blocks.size(), b.blocks.size());
  for (size_t i = 0; i < a.blocks.size(); ++i) {
    EXPECT_EQ(a.blocks[i].level, b.blocks[i].level);
    EXPECT_EQ(a.blocks[i].index, b.blocks[i].index);
    EXPECT_EQ(a.blocks[i].data, b.blocks[i].data);
  }
}

inline void expectRenderRequestEq(const RenderRequest& a, const RenderRequest& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.request_id, b.request_id);
  EXPECT_EQ(a.client, b.client);
  expectPoseEq(a.T_world_cam, b.T_world_cam);
  expectCameraEq(a.camera, b.camera);
  EXPECT_EQ(a.channels, b.channels);
}

inline void expectRenderResultEq(const RenderResult& a, const RenderResult& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.request_id, b.request_id);
  EXPECT_EQ(a.client, b.client);
  EXPECT_EQ(a.ok, b.ok);
  EXPECT_EQ(a.error, b.error);
  EXPECT_EQ(a.field_version, b.field_version);
  EXPECT_TRUE(sameImage(a.color, b.color));
  EXPECT_TRUE(sameImage(a.depth, b.depth));
  EXPECT_TRUE(sameImage(a.sigma, b.sigma));
}

inline void expectStatusEq(const Status& a, const Status& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.process, b.process);
  EXPECT_EQ(a.pid, b.pid);
  EXPECT_EQ(a.state, b.state);
  EXPECT_EQ(a.last_frame_index, b.last_frame_index);
  EXPECT_EQ(a.last_frame_utime, b.last_frame_utime);
  EXPECT_EQ(a.items_handled, b.items_handled);
  EXPECT_EQ(a.busy_s, b.busy_s);
  EXPECT_EQ(a.fps, b.fps);
  EXPECT_EQ(a.queue_depth, b.queue_depth);
  EXPECT_EQ(a.rss_mb, b.rss_mb);
  EXPECT_EQ(a.peak_rss_mb, b.peak_rss_mb);
  EXPECT_EQ(a.last_error, b.last_error);
  EXPECT_EQ(a.values, b.values);
}

inline void expectControlEq(const Control& a, const Control& b) {
  expectHeaderEq(a.header, b.header);
  EXPECT_EQ(a.command, b.command);
  EXPECT_EQ(a.target, b.target);
  EXPECT_EQ(a.argument, b.argument);
}

// ---- hand-crafted LCM bytes ---------------------------------------------------

/// Appends fields the way LCM encodes them (big endian; strings as int32
/// length including the NUL, then the bytes and the NUL).
struct LcmWriter {
  std::vector<uint8_t> bytes;

  void u8(uint8_t v) { bytes.push_back(v); }
  void i8(int8_t v) { bytes.push_back(static_cast<uint8_t>(v)); }
  void i32(int32_t v) {
    for (int s = 24; s >= 0; s -= 8)
      bytes.push_back(static_cast<uint8_t>(static_cast<uint32_t>(v) >> s));
  }
  void i64(int64_t v) {
    for (int s = 56; s >= 0; s -= 8)
      bytes.push_back(static_cast<uint8_t>(static_cast<uint64_t>(v) >> s));
  }
  void f32(float v) {
    uint32_t bits;
    std::memcpy(&bits, &v, 4);
    i32(static_cast<int32_t>(bits));
  }
  void f64(double v) {
    uint64_t bits;
    std::memcpy(&bits, &v, 8);
    i64(static_cast<int64_t>(bits));
  }
  void str(const std::string& s) {
    i32(static_cast<int32_t>(s.size() + 1));
    bytes.insert(bytes.end(), s.begin(), s.end());
    bytes.push_back(0);
  }
  void raw(const std::vector<uint8_t>& data) {
    bytes.insert(bytes.end(), data.begin(), data.end());
  }
  /// image_t with its declared fields and the given payload.
  void image(int32_t width, int32_t height, int8_t format, int8_t compression, float scale,
             int32_t size_field, const std::vector<uint8_t>& data) {
    i32(width);
    i32(height);
    i8(format);
    i8(compression);
    f32(scale);
    i32(size_field);
    raw(data);
  }
  void emptyImage() { image(0, 0, 0, 0, 0.0f, 0, {}); }
};

/// The 8 fingerprint bytes of T's LCM type (from a real encoding).
template <class T>
std::vector<uint8_t> fingerprintOf() {
  const std::vector<uint8_t> bytes = encode(T());
  return std::vector<uint8_t>(bytes.begin(), bytes.begin() + 8);
}

/// A radslam.render_t whose colour image carries the given image_t fields and
/// payload (depth and sigma absent).
inline std::vector<uint8_t> craftRender(int32_t width, int32_t height, int8_t format,
                                        int8_t compression, int32_t size_field,
                                        const std::vector<uint8_t>& data) {
  LcmWriter w;
  w.raw(fingerprintOf<RenderResult>());
  w.i64(123);       // header.utime
  w.i64(0);         // header.seq
  w.str("forger");  // header.sender
  w.i64(5);         // request_id
  w.str("client");
  w.i8(1);  // ok
  w.str("");
  w.i64(9);  // field_version
  w.image(width, height, format, compression, 0.0f, size_field, data);
  w.emptyImage();  // depth
  w.emptyImage();  // sigma
  return w.bytes;
}

/// Byte offsets in an encoded PoseStamped with header.sender == "".
struct PoseStampedLayout {
  static constexpr size_t kState = 8 + 8 + 8 + 5 + 8;  // fingerprint, utime, seq, sender, index
  static constexpr size_t kPosition = kState + 2;      // after state and is_keyframe
  static constexpr size_t kOrientation = kPosition + 24;
  static constexpr size_t kCovariance = kOrientation + 32;
};

inline void putDouble(std::vector<uint8_t>* bytes, size_t offset, double v) {
  uint64_t bits;
  std::memcpy(&bits, &v, 8);
  for (int i = 0; i < 8; ++i) (*bytes)[offset + i] = static_cast<uint8_t>(bits >> (56 - 8 * i));
}

inline double getDouble(const std::vector<uint8_t>& bytes, size_t offset) {
  uint64_t bits = 0;
  for (int i = 0; i < 8; ++i) bits = (bits << 8) | bytes[offset + i];
  double v;
  std::memcpy(&v, &bits, 8);
  return v;
}

}  // namespace testing_samples
}  // namespace radslam
