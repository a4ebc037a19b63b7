// encode<T> / decode<T> without a bus: lossless round trips, depth
// quantisation, JPEG tolerance, and rejection of malformed bytes.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/bus.h"
#include "tests/common/message_samples.h"

namespace radslam {
namespace {

using namespace testing_samples;

template <class T>
T roundTrip(const T& msg) {
  const std::vector<uint8_t> bytes = encode(msg);
  T out;
  std::string error;
  EXPECT_TRUE(decode(bytes.data(), bytes.size(), &out, &error)) << error;
  return out;
}

template <class T>
std::string decodeError(const std::vector<uint8_t>& bytes) {
  T out;
  std::string error;
  EXPECT_FALSE(decode(bytes.data(), bytes.size(), &out, &error));
  return error;
}

// image_t enum values (lcmtypes/image_t.lcm).
constexpr int8_t kGrey8 = 0, kRgb8 = 1, kUint16 = 2, kFloat32 = 3;
constexpr int8_t kRaw = 0, kPng = 1, kJpeg = 2;

TEST(Codec, FrameRawRoundTripIsExact) {
  const Frame f = sampleFrame(WireCompression::kRaw);
  expectFrameEq(f, roundTrip(f));
}

TEST(Codec, FramePngRoundTripIsExact) {
  const Frame f = sampleFrame(WireCompression::kPng);
  expectFrameEq(f, roundTrip(f));
}

TEST(Codec, FrameGreyAndAbsentImages) {
  Frame f;
  f.header = sampleHeader(5);
  f.camera = sampleCamera(30, 20);
  cv::cvtColor(colorImage(30, 20), f.color, cv::COLOR_BGR2GRAY);
  for (WireCompression c : {WireCompression::kRaw, WireCompression::kPng}) {
    f.color_compression = c;
    const Frame out = roundTrip(f);
    expectFrameEq(f, out);
    EXPECT_TRUE(out.right.empty() && out.depth.empty() && out.instance.empty());
  }
}

TEST(Codec, FrameJpegColourWithinTolerance) {
  Frame f = sampleFrame(WireCompression::kJpeg);
  f.right = colorImage(64, 48);
  const Frame out = roundTrip(f);
  for (const auto& [sent, got] : {std::pair{f.color, out.color}, std::pair{f.right, out.right}}) {
    ASSERT_EQ(got.type(), CV_8UC3);
    ASSERT_EQ(got.size(), sent.size());
    // Quality 95 on a smooth image: a few grey levels at most.
    EXPECT_LT(cv::norm(sent, got, cv::NORM_L1) / sent.total() / 3, 2.0);
    EXPECT_LE(cv::norm(sent, got, cv::NORM_INF), 24.0);
  }
  EXPECT_EQ(out.color_compression, WireCompression::kJpeg);
  EXPECT_TRUE(sameImage(f.depth, out.depth));  // depth stays lossless
}

TEST(Codec, ColourTravelsAsRgbBytes) {
  Frame f;
  f.color = cv::Mat(1, 2, CV_8UC3);
  f.color.at<cv::Vec3b>(0, 0) = cv::Vec3b(11, 22, 33);  // B, G, R
  f.color.at<cv::Vec3b>(0, 1) = cv::Vec3b(44, 55, 66);
  const std::vector<uint8_t> bytes = encode(f);
  const std::vector<uint8_t> rgb = {33, 22, 11, 66, 55, 44};
  const std::vector<uint8_t> bgr = {11, 22, 33, 44, 55, 66};
  EXPECT_NE(std::search(bytes.begin(), bytes.end(), rgb.begin(), rgb.end()), bytes.end());
  EXPECT_EQ(std::search(bytes.begin(), bytes.end(), bgr.begin(), bgr.end()), bytes.end());
  expectFrameEq(f, roundTrip(f));
}

TEST(Codec, DepthQuantisationErrorWithinHalfAStep) {
  Frame f;
  const double scale = 1.0 / 5000.0;  // TUM: 0.2 mm
  f.depth_wire_scale = scale;
  f.depth = cv::Mat(40, 50, CV_32FC1);
  cv::RNG rng(7);
  rng.fill(f.depth, cv::RNG::UNIFORM, 0.01, 13.0);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  const std::vector<float> invalid = {0.0f, -1.5f, nan, inf, -inf, 13.2f, 1e9f};
  for (size_t i = 0; i < invalid.size(); ++i)
    f.depth.at<float>(0, static_cast<int>(i)) = invalid[i];
  const float max_depth =
      static_cast<float>(65535 * static_cast<double>(static_cast<float>(scale)));
  f.depth.at<float>(1, 0) = max_depth;  // the largest value that fits

  const Frame out = roundTrip(f);
  ASSERT_EQ(out.depth.type(), CV_32FC1);
  ASSERT_EQ(out.depth.size(), f.depth.size());
  EXPECT_NEAR(out.depth_wire_scale, scale, 1e-10);
  for (size_t i = 0; i < invalid.size(); ++i) {
    EXPECT_EQ(out.depth.at<float>(0, static_cast<int>(i)), 0.0f) << "input " << invalid[i];
  }
  EXPECT_NEAR(out.depth.at<float>(1, 0), max_depth, 1e-5);
  double worst = 0;
  for (int r = 1; r < f.depth.rows; ++r) {
    for (int c = 0; c < f.depth.cols; ++c) {
      worst = std::max(worst, std::abs(static_cast<double>(out.depth.at<float>(r, c)) -
                                       f.depth.at<float>(r, c)));
    }
  }
  EXPECT_LE(worst, scale / 2 * 1.01);  // 1% for float rounding of metres
  EXPECT_GT(worst, scale / 4);         // and it really quantised
}

TEST(Codec, QuantisedDepthIsSmallerThanFloat) {
  Frame f;
  f.depth = cv::Mat(48, 64, CV_32FC1, cv::Scalar(2.0f));
  const size_t float_bytes = encode(f).size();
  f.depth_wire_scale = 0.001;
  // Raw images: 16-bit depth takes half the bytes of float32.
  EXPECT_LT(encode(f).size(), float_bytes * 3 / 5);
  // Compressed images: depth goes as PNG.
  f.color_compression = WireCompression::kPng;
  EXPECT_LT(encode(f).size(), float_bytes / 4);
}

TEST(Codec, PoseStampedRoundTrip) {
  const PoseStamped p = samplePoseStamped();
  expectPoseStampedEq(p, roundTrip(p));
}

TEST(Codec, KeyframeFloatImagesExact) {
  const Keyframe k = sampleKeyframe();
  const Keyframe out = roundTrip(k);
  expectKeyframeEq(k, out);
  EXPECT_TRUE(std::isnan(out.inv_depth.at<float>(0, 0)));
  EXPECT_TRUE(std::isinf(out.inv_depth.at<float>(0, 1)));
}

TEST(Codec, KeyframeGreyWithoutMask) {
  Keyframe k = sampleKeyframe();
  k.color = randomImage(40, 30, CV_8UC1, 3);
  k.dynamic_mask = cv::Mat();
  expectKeyframeEq(k, roundTrip(k));
}

TEST(Codec, OtherMessagesRoundTrip) {
  expectObjectsEq(sampleObjects(), roundTrip(sampleObjects()));
  expectFieldUpdateEq(sampleFieldUpdate(), roundTrip(sampleFieldUpdate()));
  expectRenderRequestEq(sampleRenderRequest(), roundTrip(sampleRenderRequest()));
  expectRenderResultEq(sampleRenderResult(), roundTrip(sampleRenderResult()));
  expectStatusEq(sampleStatus(), roundTrip(sampleStatus()));
  expectControlEq(sampleControl(), roundTrip(sampleControl()));
  // Defaults (empty strings, lists and images) survive as well.
  expectObjectsEq(ObjectList(), roundTrip(ObjectList()));
  expectFieldUpdateEq(FieldUpdate(), roundTrip(FieldUpdate()));
  expectRenderResultEq(RenderResult(), roundTrip(RenderResult()));
  expectStatusEq(Status(), roundTrip(Status()));
}

TEST(Codec, EncodeRejectsUnsupportedContent) {
  Frame f;
  f.color = cv::Mat(4, 4, CV_32FC3, cv::Scalar::all(0));
  EXPECT_THROW(encode(f), std::invalid_argument);
  f = sampleFrame();
  f.depth = cv::Mat(48, 64, CV_16UC1, cv::Scalar(1));  // must be metres
  EXPECT_THROW(encode(f), std::invalid_argument);
  f = sampleFrame();
  f.depth = cv::Mat(10, 10, CV_32FC1, cv::Scalar(1));  // not the colour size
  try {
    encode(f);
    ADD_FAILURE() << "mismatched depth size accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("Frame.depth is 10x10"), std::string::npos) << e.what();
  }
  f = sampleFrame();
  f.depth_time_offset_s = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(encode(f), std::invalid_argument);
  Keyframe k = sampleKeyframe();
  k.inv_depth.convertTo(k.inv_depth, CV_64F);
  EXPECT_THROW(encode(k), std::invalid_argument);
}

TEST(Codec, WrongTypeTruncatedAndTrailingBytes) {
  const std::vector<uint8_t> status = encode(sampleStatus());
  EXPECT_EQ(decodeError<Frame>(status), "message is not a radslam.frame_t (fingerprint mismatch)");
  EXPECT_NE(decodeError<Status>({status.begin(), status.begin() + 5}).find("truncated"),
            std::string::npos);
  const std::string half =
      decodeError<Status>({status.begin(), status.begin() + status.size() / 2});
  EXPECT_NE(half.find("malformed radslam.status_t"), std::string::npos) << half;
  std::vector<uint8_t> longer = status;
  longer.push_back(0);
  EXPECT_NE(decodeError<Status>(longer).find("1 bytes after the end"), std::string::npos);
  // Every prefix of a valid message is rejected without crashing.
  const std::vector<uint8_t> frame = encode(sampleFrame(WireCompression::kPng));
  for (size_t n = 0; n < frame.size(); n += 97) {
    Frame out;
    std::string error;
    EXPECT_FALSE(decode(frame.data(), n, &out, &error)) << n;
  }
}

TEST(Codec, ZeroLengthStringIsRejected) {
  LcmWriter w;
  w.raw(fingerprintOf<Control>());
  w.i64(1);
  w.i64(2);
  w.i32(0);  // sender: a length of 0 has no room for the NUL
  const std::string error = decodeError<Control>(w.bytes);
  // The patched generated decoder refuses it before allocating.
  EXPECT_NE(error.find("malformed radslam.control_t (28 bytes)"), std::string::npos) << error;
}

TEST(Codec, PoseValidation) {
  const std::vector<uint8_t> good = encode(PoseStamped());
  using L = PoseStampedLayout;
  {  // NaN position
    std::vector<uint8_t> b = good;
    putDouble(&b, L::kPosition + 8, std::nan(""));
    EXPECT_NE(decodeError<PoseStamped>(b).find("T_world_cam: position is not finite"),
              std::string::npos);
  }
  {  // infinite quaternion component
    std::vector<uint8_t> b = good;
    putDouble(&b, L::kOrientation + 16, std::numeric_limits<double>::infinity());
    EXPECT_NE(decodeError<PoseStamped>(b).find("orientation is not finite"), std::string::npos);
  }
  {  // slightly off unit norm: renormalised
    std::vector<uint8_t> b = good;
    ASSERT_EQ(getDouble(b, L::kOrientation), 1.0);  // w of the identity
    putDouble(&b, L::kOrientation, 1.0005);
    PoseStamped out;
    std::string error;
    ASSERT_TRUE(decode(b.data(), b.size(), &out, &error)) << error;
    EXPECT_NEAR(out.T_world_cam.quaternion().norm(), 1.0, 1e-15);
  }
  {  // far from unit norm: rejected
    std::vector<uint8_t> b = good;
    putDouble(&b, L::kOrientation, 0.5);
    EXPECT_NE(decodeError<PoseStamped>(b).find("quaternion norm 0.5"), std::string::npos);
  }
  {  // covariance NaN
    std::vector<uint8_t> b = good;
    putDouble(&b, L::kCovariance + 8 * 35, std::nan(""));
    EXPECT_NE(decodeError<PoseStamped>(b).find("covariance is not finite"), std::string::npos);
  }
  {  // enum out of range
    std::vector<uint8_t> b = good;
    b[L::kState] = 9;
    EXPECT_NE(decodeError<PoseStamped>(b).find("unknown tracking state 9"), std::string::npos);
  }
}

TEST(Codec, EnumRangesChecked) {
  std::vector<uint8_t> b = encode(Control());
  b[8 + 8 + 8 + 5] = 6;  // command after the header (empty sender)
  EXPECT_NE(decodeError<Control>(b).find("unknown control command 6"), std::string::npos);
  b = encode(Status());
  b[8 + 8 + 8 + 5 + 5 + 4] = static_cast<uint8_t>(-1);  // state after process "" and pid
  EXPECT_NE(decodeError<Status>(b).find("unknown process state -1"), std::string::npos);
  RenderRequest r;
  r.channels = 8;
  EXPECT_NE(decodeError<RenderRequest>(encode(r)).find("channels 8 has unknown bits"),
            std::string::npos);
  ObjectList objects = sampleObjects();
  objects.objects[1].joint_type = static_cast<JointType>(3);
  EXPECT_NE(decodeError<ObjectList>(encode(objects)).find("objects[1]: unknown joint type 3"),
            std::string::npos);
  FieldUpdate u = sampleFieldUpdate();
  u.blocks[2].level = 2;  // only two levels
  EXPECT_NE(decodeError<FieldUpdate>(encode(u)).find("blocks[2]: level 2 outside [0, 2)"),
            std::string::npos);
  u = sampleFieldUpdate();
  u.chunk_index = u.chunk_count;
  EXPECT_NE(decodeError<FieldUpdate>(encode(u)).find("chunk 5 of 5 is invalid"), std::string::npos);
  Frame f;
  f.camera.type = static_cast<CameraModel::Type>(4);
  EXPECT_NE(decodeError<Frame>(encode(f)).find("camera: unknown camera model 4"),
            std::string::npos);
  f.camera.type = CameraModel::Type::kPinhole;
  f.camera.readout_s = -0.01;
  EXPECT_NE(decodeError<Frame>(encode(f)).find("camera: rolling shutter readout"),
            std::string::npos);
}

TEST(Codec, ImageValidation) {
  struct Case {
    std::vector<uint8_t> bytes;
    std::string expected;
  };
  const std::vector<uint8_t> rgb_2x2(12, 100);
  cv::Mat grey(3, 4, CV_8UC1, cv::Scalar(9));
  std::vector<uint8_t> png_4x3;
  cv::imencode(".png", grey, png_4x3);
  std::vector<uint8_t> corrupt_png = png_4x3;
  for (size_t i = 33; i < corrupt_png.size(); ++i) corrupt_png[i] = 0x5a;
  const std::vector<Case> cases = {
      {craftRender(1000000, 2, kRgb8, kRaw, 12, rgb_2x2), "color: image size 1000000x2 outside"},
      {craftRender(2, -3, kRgb8, kRaw, 12, rgb_2x2), "color: image size 2x-3 outside"},
      {craftRender(2, 2, kRgb8, kRaw, 11, std::vector<uint8_t>(11)),
       "color: RAW RGB8 2x2 needs 12 bytes, message has 11"},
      {craftRender(2, 2, 9, kRaw, 12, rgb_2x2), "color: unknown pixel format 9"},
      {craftRender(2, 2, kRgb8, 7, 12, rgb_2x2), "color: unknown compression 7"},
      {craftRender(2, 2, kFloat32, kRaw, 16, std::vector<uint8_t>(16)),
       "color: pixel format FLOAT32 not allowed here (GREY8 or RGB8 expected)"},
      {craftRender(0, 0, kRgb8, kRaw, 12, rgb_2x2), "width 0 (no image) but height 0 and 12"},
      {craftRender(4, 0, kGrey8, kRaw, 0, {}), "color: image size 4x0 has no rows"},
      {craftRender(8, 6, kGrey8, kPng, static_cast<int32_t>(png_4x3.size()), png_4x3),
       "color: PNG header says 4x3 but the message declares 8x6"},
      {craftRender(4, 3, kRgb8, kPng, static_cast<int32_t>(png_4x3.size()), png_4x3),
       "color: PNG data decodes to a 4x3 CV_8UC1 image, expected 4x3 RGB8"},
      {craftRender(4, 3, kGrey8, kPng, static_cast<int32_t>(corrupt_png.size()), corrupt_png),
       "color: PNG data does not decode"},
      {craftRender(4, 3, kGrey8, kJpeg, static_cast<int32_t>(png_4x3.size()), png_4x3),
       "color: data is not a valid JPEG stream"},
      {craftRender(2, 2, kUint16, kJpeg, 12, rgb_2x2), "not allowed here"},
  };
  for (const Case& c : cases) {
    const std::string error = decodeError<RenderResult>(c.bytes);
    EXPECT_NE(error.find(c.expected), std::string::npos)
        << "expected '" << c.expected << "' in '" << error << "'";
  }
  // The same crafted path accepts a well-formed image.
  RenderResult out;
  std::string error;
  const auto ok = craftRender(4, 3, kGrey8, kPng, static_cast<int32_t>(png_4x3.size()), png_4x3);
  ASSERT_TRUE(decode(ok.data(), ok.size(), &out, &error)) << error;
  EXPECT_TRUE(sameImage(out.color, grey));
}

// A 4x2 frame_t with a grey colour image and a depth image of depth_width x 2.
std::vector<uint8_t> frameBytes(int depth_width, double depth_time_offset_s) {
  LcmWriter w;
  w.raw(fingerprintOf<Frame>());
  w.i64(1);
  w.i64(0);
  w.str("p");
  w.i64(3);  // frame_index
  // camera_t: 4x2 pinhole, no distortion
  w.i32(4);
  w.i32(2);
  w.i8(0);
  for (int i = 0; i < 4; ++i) w.f64(100.0);
  w.i32(0);
  w.f64(0.0);                                                        // readout_s
  w.image(4, 2, kGrey8, kRaw, 0.0f, 8, std::vector<uint8_t>(8, 1));  // color
  w.emptyImage();                                                    // right
  w.f64(0.0);                                                        // baseline
  w.image(depth_width, 2, kUint16, kRaw, 0.001f, 4 * depth_width,
          std::vector<uint8_t>(4 * depth_width, 1));  // depth
  w.f64(depth_time_offset_s);
  w.emptyImage();
  w.emptyImage();
  return w.bytes;
}

TEST(Codec, FrameImagesMustAgreeInSize) {
  Frame frame;
  std::string error;
  const std::vector<uint8_t> good = frameBytes(4, -0.012);
  ASSERT_TRUE(decode(good.data(), good.size(), &frame, &error)) << error;
  EXPECT_EQ(frame.depth_time_offset_s, -0.012);
  error = decodeError<Frame>(frameBytes(2, 0));
  EXPECT_NE(error.find("depth is 2x2 but color is 4x2"), std::string::npos) << error;
}

TEST(Codec, FrameDepthTimeOffsetIsChecked) {
  for (double offset : {1.5, -2.0, std::numeric_limits<double>::quiet_NaN()}) {
    const std::string error = decodeError<Frame>(frameBytes(4, offset));
    EXPECT_NE(error.find("depth_time_offset_s"), std::string::npos) << error;
  }
}

}  // namespace
}  // namespace radslam
