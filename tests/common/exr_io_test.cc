#include "common/exr_io.h"

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>
#include <gtest/gtest.h>

namespace radslam {
namespace {

class ExrIoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern = ::testing::TempDir() + "/exr_io_test_XXXXXX";
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string path(const std::string& name) const { return dir_ + "/" + name; }

  std::string dir_;
};

bool bitIdentical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int r = 0; r < a.rows; ++r)
    if (std::memcmp(a.ptr(r), b.ptr(r), a.cols * a.elemSize()) != 0) return false;
  return true;
}

// Depth and sigma with the special values a depth map really holds.
ExrChannels depthAndSigma() {
  cv::Mat depth(37, 53, CV_32FC1), sigma(37, 53, CV_32FC1);
  cv::randu(depth, 0.1f, 10.0f);
  cv::randu(sigma, 0.0f, 0.5f);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  depth.at<float>(0, 0) = nan;
  depth.at<float>(1, 2) = inf;
  depth.at<float>(3, 4) = -inf;
  depth.at<float>(5, 6) = 0.0f;
  depth.at<float>(7, 8) = -0.0f;
  depth.at<float>(9, 10) = std::numeric_limits<float>::denorm_min();
  sigma.at<float>(36, 52) = nan;
  sigma.at<float>(0, 52) = inf;
  sigma.at<float>(36, 0) = 0.0f;
  return {{"depth", depth}, {"sigma", sigma}};
}

TEST_F(ExrIoTest, MultiChannelRoundTripIsBitExact) {
  const ExrChannels written = depthAndSigma();
  writeExr(path("kf.exr"), written);
  const ExrChannels read = readExr(path("kf.exr"));
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[0].first, "depth");
  EXPECT_EQ(read[1].first, "sigma");
  EXPECT_TRUE(bitIdentical(read[0].second, written[0].second));
  EXPECT_TRUE(bitIdentical(read[1].second, written[1].second));
  EXPECT_TRUE(std::isnan(read[0].second.at<float>(0, 0)));
  EXPECT_TRUE(std::signbit(read[0].second.at<float>(7, 8)));
  EXPECT_TRUE(bitIdentical(readExrChannel(path("kf.exr"), "sigma"), written[1].second));
}

TEST_F(ExrIoTest, ChannelsComeBackSortedByName) {
  cv::Mat a(4, 5, CV_32FC1, cv::Scalar(1)), b(4, 5, CV_32FC1, cv::Scalar(2));
  writeExr(path("order.exr"), {{"zeta", a}, {"alpha", b}});
  const ExrChannels read = readExr(path("order.exr"));
  ASSERT_EQ(read.size(), 2u);
  EXPECT_EQ(read[0].first, "alpha");
  EXPECT_EQ(read[0].second.at<float>(3, 4), 2.0f);
  EXPECT_EQ(read[1].first, "zeta");
  EXPECT_EQ(read[1].second.at<float>(3, 4), 1.0f);
}

TEST_F(ExrIoTest, WritesNonContiguousRegions) {
  cv::Mat big(20, 30, CV_32FC1);
  cv::randu(big, -5.0f, 5.0f);
  const cv::Mat roi = big(cv::Rect(3, 4, 11, 7));
  ASSERT_FALSE(roi.isContinuous());
  writeExr(path("roi.exr"), {{"v", roi}});
  EXPECT_TRUE(bitIdentical(readExrChannel(path("roi.exr"), "v"), roi));
}

TEST_F(ExrIoTest, ReadsHalfChannelsAsFloat) {
  // A HALF channel written with OpenEXR directly, as other tools do.
  const int width = 3, height = 2;
  std::vector<half> pixels = {half(0.5f),    half(1.0f), half(-2.0f),
                              half(1024.0f), half(0.0f), half(0.25f)};
  Imf::Header header(width, height);
  header.channels().insert("Y", Imf::Channel(Imf::HALF));
  Imf::FrameBuffer buffer;
  buffer.insert("Y", Imf::Slice(Imf::HALF, reinterpret_cast<char*>(pixels.data()), sizeof(half),
                                sizeof(half) * width));
  {
    Imf::OutputFile file(path("half.exr").c_str(), header);
    file.setFrameBuffer(buffer);
    file.writePixels(height);
  }
  const cv::Mat y = readExrChannel(path("half.exr"), "Y");
  ASSERT_EQ(y.type(), CV_32FC1);
  EXPECT_EQ(y.at<float>(0, 0), 0.5f);
  EXPECT_EQ(y.at<float>(0, 2), -2.0f);
  EXPECT_EQ(y.at<float>(1, 0), 1024.0f);
  EXPECT_EQ(y.at<float>(1, 2), 0.25f);
}

// Runs f, expects std::runtime_error whose message contains every fragment.
template <class F>
void expectError(F f, const std::vector<std::string>& fragments) {
  try {
    f();
    ADD_FAILURE() << "no exception; expected one mentioning " << fragments.front();
  } catch (const std::runtime_error& e) {
    for (const std::string& fragment : fragments)
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos)
          << "message '" << e.what() << "' lacks '" << fragment << "'";
  }
}

TEST_F(ExrIoTest, MissingChannelNamesFileAndChannels) {
  writeExr(path("kf.exr"), depthAndSigma());
  expectError([&] { readExrChannel(path("kf.exr"), "variance"); },
              {path("kf.exr"), "no channel 'variance'", "depth, sigma"});
}

TEST_F(ExrIoTest, MissingFileIsAnError) {
  expectError([&] { readExr(path("absent.exr")); }, {path("absent.exr"), "not found"});
}

TEST_F(ExrIoTest, NonExrFileIsAnError) {
  std::ofstream(path("text.exr")) << "this is not an image\n";
  expectError([&] { readExr(path("text.exr")); }, {path("text.exr"), "not an OpenEXR file"});
}

TEST_F(ExrIoTest, TruncatedFileIsAnError) {
  // Large enough for several ZIP chunks, so the cut falls inside the pixel data.
  cv::Mat noise(256, 256, CV_32FC1);
  cv::randu(noise, 0.0f, 1.0f);
  writeExr(path("full.exr"), {{"depth", noise}});
  std::ifstream in(path("full.exr"), std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 4000u);
  std::ofstream(path("cut.exr"), std::ios::binary).write(bytes.data(), bytes.size() / 2);
  expectError([&] { readExr(path("cut.exr")); }, {path("cut.exr")});
  // A header cut short is reported too.
  std::ofstream(path("header.exr"), std::ios::binary).write(bytes.data(), 40);
  expectError([&] { readExr(path("header.exr")); }, {path("header.exr")});
}

TEST_F(ExrIoTest, WriteRejectsBadChannels) {
  const cv::Mat a(4, 5, CV_32FC1, cv::Scalar(0));
  const cv::Mat other_size(5, 5, CV_32FC1, cv::Scalar(0));
  const cv::Mat doubles(4, 5, CV_64FC1, cv::Scalar(0));
  const std::string file = path("bad.exr");
  expectError([&] { writeExr(file, {}); }, {file, "no channels"});
  expectError([&] { writeExr(file, {{"a", a}, {"b", other_size}}); }, {file, "'b' is 5x5"});
  expectError([&] { writeExr(file, {{"a", doubles}}); }, {file, "not CV_32FC1"});
  expectError([&] { writeExr(file, {{"a", a}, {"a", a}}); }, {file, "given twice"});
  expectError([&] { writeExr(file, {{"", a}}); }, {file, "empty name"});
  expectError([&] { writeExr(file, {{"a", cv::Mat()}}); }, {file, "empty"});
  expectError([&] { writeExr(dir_ + "/no/such/dir/x.exr", {{"a", a}}); }, {"no/such/dir/x.exr"});
}

}  // namespace
}  // namespace radslam
