// decode<T> at the bus boundary: inputs found by fuzzing the decoders (fuzz/)
// and the NaN/inf rules for poses, depths and intrinsics.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "common/bus.h"
#include "tests/common/message_samples.h"

namespace radslam {
namespace {

using namespace testing_samples;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

template <class T>
std::string decodeError(const std::vector<uint8_t>& bytes) {
  T out;
  std::string error;
  EXPECT_FALSE(decode(bytes.data(), bytes.size(), &out, &error));
  return error;
}

template <class T>
bool decodes(const std::vector<uint8_t>& bytes, T* out = nullptr) {
  T local;
  std::string error;
  const bool ok = decode(bytes.data(), bytes.size(), out ? out : &local, &error);
  EXPECT_TRUE(ok) << error;
  return ok;
}

// Encodes msg, in which one string holds "NUL@MARK", and turns its '@' into a
// NUL byte: the bytes a hostile or corrupt sender could put on the bus.
template <class T>
std::vector<uint8_t> withNulInString(const T& msg) {
  std::vector<uint8_t> bytes = encode(msg);
  const std::string mark = "NUL@MARK";
  const auto it = std::search(bytes.begin(), bytes.end(), mark.begin(), mark.end());
  EXPECT_NE(it, bytes.end());
  if (it != bytes.end()) *(it + 3) = 0;
  return bytes;
}

// Found by fuzzing: a string holding a NUL decoded, but the decoded message
// could not be encoded again (lcm encodes strings up to their first NUL), so a
// renderer echoing the client of such a request threw while publishing.
TEST(CodecBoundary, StringsWithNulBytesAreRejected) {
  const std::string mark = "NUL@MARK";
  {
    Control c = sampleControl();
    c.argument = mark;
    EXPECT_NE(decodeError<Control>(withNulInString(c)).find("argument contains a NUL byte"),
              std::string::npos);
    c.argument = "fine";
    c.header.sender = mark;
    EXPECT_NE(decodeError<Control>(withNulInString(c)).find("header.sender contains a NUL"),
              std::string::npos);
  }
  {
    RenderRequest r = sampleRenderRequest();
    r.client = mark;
    EXPECT_NE(decodeError<RenderRequest>(withNulInString(r)).find("client contains a NUL"),
              std::string::npos);
  }
  {
    RenderResult r = sampleRenderResult();
    r.error = mark;
    EXPECT_NE(decodeError<RenderResult>(withNulInString(r)).find("error contains a NUL"),
              std::string::npos);
  }
  {
    Status s = sampleStatus();
    s.values.emplace_back(mark, 1.0);
    EXPECT_NE(decodeError<Status>(withNulInString(s))
                  .find("keys[" + std::to_string(s.values.size() - 1) + "] contains a NUL"),
              std::string::npos);
  }
  {
    ObjectList o = sampleObjects();
    o.objects[0].class_name = mark;
    EXPECT_NE(
        decodeError<ObjectList>(withNulInString(o)).find("objects[0].class_name contains a NUL"),
        std::string::npos);
  }
  {
    PoseStamped p = samplePoseStamped();
    p.header.sender = mark;
    EXPECT_NE(decodeError<PoseStamped>(withNulInString(p)).find("header.sender"),
              std::string::npos);
    Frame f = sampleFrame();
    f.header.sender = mark;
    EXPECT_NE(decodeError<Frame>(withNulInString(f)).find("header.sender"), std::string::npos);
    Keyframe k = sampleKeyframe();
    k.header.sender = mark;
    EXPECT_NE(decodeError<Keyframe>(withNulInString(k)).find("header.sender"), std::string::npos);
  }
}

// What decode accepts, encode carries again (the fuzz targets check this on
// every accepted input).
TEST(CodecBoundary, DecodedMessagesEncodeAgain) {
  Status s = sampleStatus();
  s.last_error = "ok \x01\x7f";  // control bytes other than NUL are fine
  Status out;
  ASSERT_TRUE(decodes(encode(s), &out));
  EXPECT_EQ(out.last_error, s.last_error);
  EXPECT_NO_THROW(encode(out));
}

TEST(CodecBoundary, NonFiniteFrameDepthIsRejected) {
  for (const float bad : {kNaN, kInf, -kInf}) {
    Frame f = sampleFrame();
    f.depth.at<float>(2, 5) = bad;
    EXPECT_NE(decodeError<Frame>(encode(f)).find("depth: pixel (5, 2) is"), std::string::npos)
        << bad;
  }
  // Quantised depth whose scale overflows float once applied.
  Frame f = sampleFrame();
  f.depth.setTo(0);
  f.depth.at<float>(0, 0) = 3.4e38f;
  f.depth_wire_scale = 2e38;  // 3.4e38 / 2e38 rounds to 2 units: 4e38 m is no float
  EXPECT_NE(decodeError<Frame>(encode(f)).find("depth: pixel (0, 0) is inf"), std::string::npos);
  // Zero and negative depths stay (they mark invalid pixels).
  f = sampleFrame();
  f.depth.at<float>(0, 0) = 0;
  f.depth.at<float>(0, 1) = -1;
  EXPECT_TRUE(decodes<Frame>(encode(f)));
}

TEST(CodecBoundary, KeyframeDepthFiniteVarianceMayBeInfinite) {
  Keyframe k = sampleKeyframe();
  k.depth_var.at<float>(1, 1) = kInf;  // the tracker's "unknown"
  EXPECT_TRUE(decodes<Keyframe>(encode(k)));
  k.depth_var.at<float>(1, 1) = kNaN;
  EXPECT_NE(decodeError<Keyframe>(encode(k)).find("depth_var: pixel (1, 1) is nan"),
            std::string::npos);
  k.depth_var.at<float>(1, 1) = -kInf;
  EXPECT_NE(decodeError<Keyframe>(encode(k)).find("depth_var: pixel (1, 1)"), std::string::npos);
  k = sampleKeyframe();
  k.depth.at<float>(3, 2) = kInf;
  EXPECT_NE(decodeError<Keyframe>(encode(k)).find("depth: pixel (2, 3) is inf"), std::string::npos);
}

TEST(CodecBoundary, NonFiniteOrNonPositiveIntrinsicsAreRejected) {
  for (const double bad : {std::nan(""), std::numeric_limits<double>::infinity()}) {
    Frame f = sampleFrame();
    f.camera.cy = bad;
    EXPECT_NE(decodeError<Frame>(encode(f)).find("camera: intrinsics are not finite"),
              std::string::npos);
    RenderRequest r = sampleRenderRequest();
    r.camera.fx = bad;
    EXPECT_NE(decodeError<RenderRequest>(encode(r)).find("camera: intrinsics are not finite"),
              std::string::npos);
    Keyframe k = sampleKeyframe();
    k.camera.distortion = {0.1, bad, 0, 0};
    EXPECT_NE(decodeError<Keyframe>(encode(k)).find("camera: distortion is not finite"),
              std::string::npos);
  }
  RenderRequest r = sampleRenderRequest();
  r.camera.fy = 0;
  EXPECT_NE(decodeError<RenderRequest>(encode(r)).find("camera: focal lengths fx="),
            std::string::npos);
  // What the receiver's Undistorter would throw on is refused at the boundary.
  Frame radtan = sampleFrame();
  radtan.camera.distortion = {0.1, 0.01, 0.001};
  EXPECT_NE(decodeError<Frame>(encode(radtan)).find("camera: RadTan needs 4 or 5 coefficients"),
            std::string::npos);
  Keyframe pinhole = sampleKeyframe();
  pinhole.camera.distortion = {0.1, 0, 0, 0};
  EXPECT_NE(decodeError<Keyframe>(encode(pinhole)).find("pinhole model with non-zero distortion"),
            std::string::npos);
  // A camera without a size ("none") may leave its intrinsics at 0.
  Frame f = sampleFrame();
  f.camera = CameraModel();
  EXPECT_TRUE(decodes<Frame>(encode(f)));
}

TEST(CodecBoundary, NonFinitePosesAreRejected) {
  RenderRequest r = sampleRenderRequest();
  r.T_world_cam = SE3(Eigen::Quaterniond::Identity(), Vec3(0, std::nan(""), 0));
  EXPECT_NE(decodeError<RenderRequest>(encode(r)).find("T_world_cam: position is not finite"),
            std::string::npos);
  ObjectList o = sampleObjects();
  o.objects[1].T_world_joint =
      SE3(Eigen::Quaterniond::Identity(), Vec3(std::numeric_limits<double>::infinity(), 0, 0));
  EXPECT_NE(decodeError<ObjectList>(encode(o)).find("objects[1].T_world_joint"), std::string::npos);
  o = sampleObjects();
  o.objects[0].twist[4] = std::nan("");
  EXPECT_NE(decodeError<ObjectList>(encode(o)).find("objects[0].twist is not finite"),
            std::string::npos);
}

// A few bytes of PNG declaring a huge image are refused before OpenCV allocates
// the declared size (deflate cannot expand more than 1032:1).
TEST(CodecBoundary, CompressedImageCannotClaimMorePixelsThanItsBytesHold) {
  cv::Mat grey(3, 4, CV_8UC1, cv::Scalar(9));
  std::vector<uint8_t> png;
  cv::imencode(".png", grey, png);
  const int32_t side = 4000;
  for (int i = 0; i < 4; ++i) {
    png[16 + i] = static_cast<uint8_t>(side >> (24 - 8 * i));  // IHDR width
    png[20 + i] = static_cast<uint8_t>(side >> (24 - 8 * i));  // IHDR height
  }
  const std::string error = decodeError<RenderResult>(
      craftRender(side, side, /*GREY8*/ 0, /*PNG*/ 1, static_cast<int32_t>(png.size()), png));
  EXPECT_NE(error.find("cannot hold a 4000x4000 GREY8 image"), std::string::npos) << error;
  // A genuine large flat image compresses well below the limit and decodes.
  RenderResult flat;
  flat.color = cv::Mat(2048, 2048, CV_8UC3, cv::Scalar(0, 0, 0));
  RenderResult out;
  ASSERT_TRUE(decodes(encode(flat), &out));
  EXPECT_EQ(out.color.size(), flat.color.size());
}

}  // namespace
}  // namespace radslam
