#include "common/dataset.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "common/trajectory.h"

namespace radslam {
namespace {

namespace fs = std::filesystem;
const std::string kData = RADSLAM_SOURCE_DIR "/../shared/data";

#define SKIP_WITHOUT(path)                          \
  if (!fs::exists(path))                            \
  GTEST_SKIP() << "real data not found: " << (path) \
               << " (the shared data folder is optional; see DESIGN.md section 6)"

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

bool contains(const std::string& text, const std::string& fragment) {
  return text.find(fragment) != std::string::npos;
}

class DatasetTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern = ::testing::TempDir() + "/dataset_test_XXXXXX";
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Absolute path of `relative` inside the test folder, parents created.
  std::string path(const std::string& relative) const {
    const fs::path p = fs::path(dir_) / relative;
    fs::create_directories(p.parent_path());
    return p.string();
  }
  std::string writeText(const std::string& relative, const std::string& text) const {
    const std::string p = path(relative);
    std::ofstream(p) << text;
    return p;
  }
  std::string writeImage(const std::string& relative, const cv::Mat& image) const {
    const std::string p = path(relative);
    EXPECT_TRUE(cv::imwrite(p, image)) << p;
    return p;
  }
  // Cuts a file to half its size, as an interrupted copy would.
  void truncate(const std::string& file) const { fs::resize_file(file, fs::file_size(file) / 2); }

  std::string dir_;
};

cv::Mat noiseImage(int rows, int cols, int type, unsigned seed) {
  cv::Mat image(rows, cols, type);
  cv::RNG rng(seed);
  rng.fill(image, cv::RNG::UNIFORM, 0, 255);
  return image;
}

// --- openDataset --------------------------------------------------------------

TEST_F(DatasetTest, OpenRejectsBadSpecs) {
  expectError([&] { openDataset("nerf:" + dir_); }, {"unknown dataset kind 'nerf'", "tum"});
  expectError([&] { openDataset(dir_); }, {"must be KIND:PATH"});
  expectError([&] { openDataset("tum:"); }, {"has no PATH"});
  for (const std::string kind : {"tum", "euroc", "kitti", "replica", "synthetic"})
    expectError([&] { openDataset(kind + ":" + dir_ + "/absent"); },
                {dir_ + "/absent", "does not exist"});
  // Folders that exist but lack their index files name what is missing.
  expectError([&] { openDataset("kitti:" + dir_); }, {dir_ + "/calib.txt", "not found"});
  expectError([&] { openDataset("euroc:" + dir_); }, {dir_, "mav0"});
  expectError([&] { openDataset("replica:" + dir_); }, {dir_, "results/"});
  expectError([&] { openDataset("synthetic:" + dir_); }, {dir_ + "/camera.yaml"});
}

// --- real sequences -------------------------------------------------------------

TEST(RealData, TumFr1RpyHas170DepthFrames) {
  const std::string path = kData + "/tum_fr1_rpy/rgbd_dataset_freiburg1_rpy";
  SKIP_WITHOUT(path);
  const auto dataset = openDataset("tum:" + path);
  ASSERT_EQ(dataset->size(), 170u);
  EXPECT_TRUE(dataset->hasDepth());
  EXPECT_FALSE(dataset->hasStereo());
  EXPECT_GT(dataset->groundTruth().size(), 500u);
  EXPECT_DOUBLE_EQ(dataset->timestamp(0), 1305031229.528748);
  for (size_t i : {size_t{0}, size_t{169}}) {
    std::string error;
    const std::optional<Frame> frame = dataset->frame(i, &error);
    ASSERT_TRUE(frame) << error;
    EXPECT_EQ(frame->frame_index, static_cast<int64_t>(i));
    EXPECT_EQ(frame->header.utime, std::llround(dataset->timestamp(i) * 1e6));
    EXPECT_EQ(frame->color.type(), CV_8UC3);
    EXPECT_EQ(frame->color.size(), cv::Size(640, 480));
    ASSERT_EQ(frame->depth.type(), CV_32FC1);
    ASSERT_EQ(frame->depth.size(), cv::Size(640, 480));
    // A desk seen from about a metre: valid depths mostly between 0.4 and 5 m.
    const cv::Mat valid = frame->depth > 0;
    EXPECT_GT(cv::countNonZero(valid), 640 * 480 / 2);
    const double mean = cv::mean(frame->depth, valid)[0];
    EXPECT_GT(mean, 0.4);
    EXPECT_LT(mean, 5.0);
    EXPECT_EQ(frame->camera.type, CameraModel::Type::kRadTan);
    EXPECT_DOUBLE_EQ(frame->camera.fx, 517.3);
    EXPECT_EQ(frame->camera.distortion.size(), 5u);
    EXPECT_GT(frame->camera.readout_s, 0);  // the Kinect's rolling shutter
  }
}

TEST(RealData, TumFr2DeskMiniHas20MonocularFrames) {
  const std::string path = kData + "/tum_fr2_desk_mini/rgbd_dataset_freiburg2_desk";
  SKIP_WITHOUT(path);
  const auto dataset = openDataset("tum:" + path);
  ASSERT_EQ(dataset->size(), 20u);
  EXPECT_FALSE(dataset->hasDepth());
  EXPECT_GT(dataset->groundTruth().size(), 20u);
  std::string error;
  const std::optional<Frame> frame = dataset->frame(19, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_TRUE(frame->depth.empty());
  EXPECT_EQ(frame->color.size(), cv::Size(640, 480));
  EXPECT_DOUBLE_EQ(frame->camera.fx, 520.9);
  EXPECT_DOUBLE_EQ(frame->camera.distortion[4], 0.9172);
}

TEST(RealData, Kitti07Has160GreyFramesWithGroundTruth) {
  const std::string path = kData + "/kitti_odometry_07/sequences/07";
  SKIP_WITHOUT(path);
  const auto dataset = openDataset("kitti:" + path);
  ASSERT_EQ(dataset->size(), 160u);
  EXPECT_FALSE(dataset->hasStereo());  // only image_0 is staged
  ASSERT_EQ(dataset->groundTruth().size(), 160u);
  EXPECT_DOUBLE_EQ(dataset->timestamp(1), 1.038752e-01);
  EXPECT_DOUBLE_EQ(dataset->groundTruth()[1].t, 1.038752e-01);
  EXPECT_NEAR(dataset->groundTruth()[1].T_world_cam.translation().z(), 9.154274e-02, 1e-9);
  for (size_t i : {size_t{0}, size_t{159}}) {
    std::string error;
    const std::optional<Frame> frame = dataset->frame(i, &error);
    ASSERT_TRUE(frame) << error;
    EXPECT_EQ(frame->color.type(), CV_8UC1);
    EXPECT_EQ(frame->color.size(), cv::Size(1226, 370));
    EXPECT_EQ(frame->camera.width, 1226);
    EXPECT_DOUBLE_EQ(frame->camera.fx, 707.0912);
    EXPECT_DOUBLE_EQ(frame->camera.cy, 183.1104);
    EXPECT_EQ(frame->camera.type, CameraModel::Type::kPinhole);
    EXPECT_TRUE(frame->right.empty());
  }
}

TEST(RealData, ReplicaOffice0Has4DepthFrames) {
  const std::string path = kData + "/replica_office0_nice_slam/Replica/office0";
  SKIP_WITHOUT(path);
  const auto dataset = openDataset("replica:" + path);
  ASSERT_EQ(dataset->size(), 4u);
  EXPECT_TRUE(dataset->hasDepth());
  ASSERT_EQ(dataset->groundTruth().size(), 4u);
  EXPECT_DOUBLE_EQ(dataset->timestamp(3), 3.0 / 30.0);
  std::string error;
  const std::optional<Frame> frame = dataset->frame(2, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_EQ(frame->color.type(), CV_8UC3);
  EXPECT_EQ(frame->color.size(), cv::Size(1200, 680));
  ASSERT_EQ(frame->depth.size(), cv::Size(1200, 680));
  const float centre = frame->depth.at<float>(340, 600);
  EXPECT_GT(centre, 0.5f);
  EXPECT_LT(centre, 10.0f);
  EXPECT_DOUBLE_EQ(frame->camera.fx, 600.0);
  EXPECT_DOUBLE_EQ(frame->camera.cy, 339.5);
  // Poses are rigid camera-to-world transforms of an indoor scene.
  EXPECT_LT(dataset->groundTruth()[0].T_world_cam.translation().norm(), 10.0);
}

// --- TUM on a folder written here -----------------------------------------------

class TumFolderTest : public DatasetTest {
 protected:
  // 16x12 images; depth 5 ms after colour, the last colour frame has no depth.
  void SetUp() override {
    DatasetTest::SetUp();
    if (HasFatalFailure()) return;
    writeText("seq/camera.yaml",
              "%YAML:1.0\nwidth: 16\nheight: 12\nfx: 20.0\nfy: 21.0\ncx: 8.0\ncy: 6.0\n"
              "k1: 0.1\nk2: -0.01\n");
    std::string rgb = "# color images\n", depth = "# depth\n";
    for (int i = 0; i < 4; ++i) {
      const std::string t = std::to_string(100 + i) + ".000000";
      const std::string td = std::to_string(100 + i) + ".005000";
      rgb += t + " rgb/" + t + ".png\n";
      writeImage("seq/rgb/" + t + ".png", noiseImage(12, 16, CV_8UC3, i));
      if (i == 3) continue;
      cv::Mat d(12, 16, CV_16UC1, cv::Scalar(5000 * (i + 1)));
      d.at<uint16_t>(0, 0) = 0;
      depth += td + " depth/" + td + ".png\n";
      writeImage("seq/depth/" + td + ".png", d);
    }
    writeText("seq/rgb.txt", rgb);
    writeText("seq/depth.txt", depth);
    writeText("seq/groundtruth.txt", "100.0 0 0 0 0 0 0 1\n100.01 1 0 0 0 0 0 1\n");
  }
};

TEST_F(TumFolderTest, AssociatesColourAndDepthWithin20ms) {
  const auto dataset = openDataset("tum:" + dir_ + "/seq/");
  EXPECT_EQ(dataset->name(), "tum:" + dir_ + "/seq");
  ASSERT_EQ(dataset->size(), 3u);  // frame 3 has no depth within 20 ms
  EXPECT_TRUE(dataset->hasDepth());
  EXPECT_EQ(dataset->groundTruth().size(), 2u);
  std::string error;
  const std::optional<Frame> frame = dataset->frame(1, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_EQ(frame->header.utime, 101000000);
  EXPECT_EQ(frame->camera.width, 16);
  EXPECT_DOUBLE_EQ(frame->camera.fy, 21.0);
  ASSERT_EQ(frame->camera.type, CameraModel::Type::kRadTan);
  EXPECT_EQ(frame->camera.distortion, (std::vector<double>{0.1, -0.01, 0, 0, 0}));
  EXPECT_EQ(frame->depth.at<float>(5, 5), 2.0f);  // 10000 / 5000
  EXPECT_EQ(frame->depth.at<float>(0, 0), 0.0f);  // invalid stays 0
  EXPECT_NEAR(frame->depth_time_offset_s, 0.005, 1e-9);
  const cv::Mat expected = noiseImage(12, 16, CV_8UC3, 1);
  EXPECT_EQ(cv::norm(frame->color, expected, cv::NORM_INF), 0.0);
}

TEST_F(TumFolderTest, UsesAssociationsWhenPresentAndIsMonocularWithoutDepth) {
  writeText("seq/associations.txt",
            "103.005000 depth/102.005000.png 103.000000 rgb/103.000000.png\n");
  const auto paired = openDataset("tum:" + dir_ + "/seq");
  ASSERT_EQ(paired->size(), 1u);
  EXPECT_DOUBLE_EQ(paired->timestamp(0), 103.0);
  std::string error;
  const auto frame = paired->frame(0, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_EQ(frame->depth.at<float>(5, 5), 3.0f);
  EXPECT_NEAR(frame->depth_time_offset_s, 0.005, 1e-9);

  fs::remove(dir_ + "/seq/associations.txt");
  fs::remove(dir_ + "/seq/depth.txt");
  fs::remove_all(dir_ + "/seq/depth");
  const auto mono = openDataset("tum:" + dir_ + "/seq");
  ASSERT_EQ(mono->size(), 4u);
  EXPECT_FALSE(mono->hasDepth());
  const auto mono_frame = mono->frame(3, &error);
  ASSERT_TRUE(mono_frame) << error;
  EXPECT_TRUE(mono_frame->depth.empty());
}

TEST_F(TumFolderTest, ListsTheImageFolderWithoutRgbTxt) {
  fs::remove(dir_ + "/seq/rgb.txt");
  fs::remove(dir_ + "/seq/depth.txt");
  const auto dataset = openDataset("tum:" + dir_ + "/seq");
  ASSERT_EQ(dataset->size(), 3u);
  EXPECT_DOUBLE_EQ(dataset->timestamp(2), 102.0);
}

TEST_F(TumFolderTest, BadFramesReturnErrorsNamingTheFile) {
  const auto dataset = openDataset("tum:" + dir_ + "/seq");
  std::string error;
  // Truncated colour PNG.
  truncate(dir_ + "/seq/rgb/100.000000.png");
  EXPECT_FALSE(dataset->frame(0, &error));
  EXPECT_TRUE(contains(error, "rgb/100.000000.png")) << error;
  EXPECT_TRUE(contains(error, "cannot decode")) << error;
  // Depth of another size than the colour image.
  writeImage("seq/depth/101.005000.png", cv::Mat(6, 8, CV_16UC1, cv::Scalar(1)));
  EXPECT_FALSE(dataset->frame(1, &error));
  EXPECT_TRUE(contains(error, "depth/101.005000.png")) << error;
  EXPECT_TRUE(contains(error, "8x6, expected 16x12")) << error;
  // An 8-bit "depth" (a mask, say) is not depth.
  writeImage("seq/depth/102.005000.png", cv::Mat(12, 16, CV_8UC1, cv::Scalar(1)));
  EXPECT_FALSE(dataset->frame(2, &error));
  EXPECT_TRUE(contains(error, "expected a 16-bit")) << error;
  // Missing file; out of range.
  fs::remove(dir_ + "/seq/depth/102.005000.png");
  EXPECT_FALSE(dataset->frame(2, &error));
  EXPECT_TRUE(contains(error, "depth/102.005000.png: image file not found")) << error;
  EXPECT_FALSE(dataset->frame(3, &error));
  EXPECT_TRUE(contains(error, "out of range")) << error;
}

TEST_F(TumFolderTest, BadIndexAndCameraFilesThrow) {
  writeText("seq/rgb.txt", "100.0 rgb/100.000000.png\nnot-a-time rgb/x.png\n");
  expectError([&] { openDataset("tum:" + dir_ + "/seq"); },
              {dir_ + "/seq/rgb.txt:2", "timestamp filename"});
  writeText("seq/camera.yaml", "%YAML:1.0\nwidth: 16\nheight: 12\nfx: 20.0\ncx: 8.0\ncy: 6.0\n");
  expectError([&] { openDataset("tum:" + dir_ + "/seq"); },
              {dir_ + "/seq/camera.yaml", "missing key 'fy'"});
  writeText("seq/camera.yaml",
            "%YAML:1.0\nwidth: 16\nheight: 12\nfx: 20.0\nfy: 20.0\ncx: 8.0\ncy: 6.0\n"
            "readout_s: -0.02\n");
  expectError([&] { openDataset("tum:" + dir_ + "/seq"); },
              {dir_ + "/seq/camera.yaml", "readout_s (rolling shutter, s) must be in [0, 1)"});
  fs::remove(dir_ + "/seq/camera.yaml");
  expectError([&] { openDataset("tum:" + dir_ + "/seq"); }, {"freiburg1/2/3", "camera.yaml"});
}

// --- synthetic format -----------------------------------------------------------

class SyntheticFolderTest : public DatasetTest {
 protected:
  void SetUp() override {
    DatasetTest::SetUp();
    if (HasFatalFailure()) return;
    writeText("syn/camera.yaml",
              "%YAML:1.0\nwidth: 10\nheight: 8\nfx: 12.5\nfy: 12.5\ncx: 4.5\ncy: 3.5\n"
              "baseline_m: 0.12\ndepth_scale: 0.001\n");
    writeText("syn/times.txt", "0.0\n0.1\n");
    std::string gt;
    for (int i = 0; i < 2; ++i) {
      char name[16];
      std::snprintf(name, sizeof(name), "%06d.png", i);
      writeImage(std::string("syn/rgb/") + name, noiseImage(8, 10, CV_8UC3, 10 + i));
      writeImage(std::string("syn/right/") + name, noiseImage(8, 10, CV_8UC3, 20 + i));
      writeImage(std::string("syn/depth/") + name, cv::Mat(8, 10, CV_16UC1, cv::Scalar(1234)));
      writeImage(std::string("syn/instance/") + name, cv::Mat(8, 10, CV_16UC1, cv::Scalar(7)));
      writeImage(std::string("syn/class/") + name, cv::Mat(8, 10, CV_16UC1, cv::Scalar(3)));
      gt += "0." + std::to_string(i) + " " + std::to_string(i) + " 0 0 0 0 0 1\n";
    }
    writeText("syn/groundtruth.txt", gt);
    writeText("syn/objects.txt",
              "# t object_id class_id tx ty tz qx qy qz qw\n"
              "0.0 7 3 1 2 0 0 0 0 1\n0.1 7 3 1.5 2 0 0 0 0.0499792 0.9987503\n");
    writeText("syn/classes.yaml",
              "%YAML:1.0\nclasses:\n"
              "  - { id: 1, name: road, dynamic: 0, joint: free, parent: \"\" }\n"
              "  - { id: 3, name: car, dynamic: 1, joint: planar, parent: road }\n"
              "  - { id: 4, name: door, dynamic: 1, joint: revolute, parent: road }\n");
  }
};

TEST_F(SyntheticFolderTest, ReadsEveryChannel) {
  const auto dataset = openDataset("synthetic:" + dir_ + "/syn");
  ASSERT_EQ(dataset->size(), 2u);
  EXPECT_TRUE(dataset->hasDepth());
  EXPECT_TRUE(dataset->hasStereo());
  ASSERT_EQ(dataset->groundTruth().size(), 2u);
  EXPECT_EQ(dataset->groundTruth()[1].T_world_cam.translation(), Vec3(1, 0, 0));
  std::string error;
  const auto frame = dataset->frame(1, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_EQ(frame->header.utime, 100000);
  EXPECT_EQ(frame->camera.width, 10);
  EXPECT_EQ(frame->camera.type, CameraModel::Type::kPinhole);
  EXPECT_DOUBLE_EQ(frame->baseline_m, 0.12);
  EXPECT_EQ(cv::norm(frame->color, noiseImage(8, 10, CV_8UC3, 11), cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(frame->right, noiseImage(8, 10, CV_8UC3, 21), cv::NORM_INF), 0.0);
  EXPECT_FLOAT_EQ(frame->depth.at<float>(7, 9), 1.234f);
  ASSERT_EQ(frame->instance.type(), CV_16UC1);
  EXPECT_EQ(frame->instance.at<uint16_t>(0, 0), 7);
  EXPECT_EQ(frame->class_id.at<uint16_t>(0, 0), 3);

  const std::vector<ObjectPoseSample> objects = dataset->objectGroundTruth();
  ASSERT_EQ(objects.size(), 2u);
  EXPECT_EQ(objects[1].object_id, 7);
  EXPECT_EQ(objects[1].class_id, 3);
  EXPECT_NEAR(objects[1].T_world_object.so3().log().z(), 0.1, 1e-6);
  const std::vector<SemanticClass> classes = dataset->classes();
  ASSERT_EQ(classes.size(), 3u);
  EXPECT_EQ(classes[1].name, "car");
  EXPECT_TRUE(classes[1].dynamic);
  EXPECT_EQ(classes[1].joint, JointType::kPlanar);
  EXPECT_EQ(classes[1].parent, "road");
  EXPECT_FALSE(classes[0].dynamic);
  EXPECT_EQ(classes[2].joint, JointType::kRevolute);
}

TEST_F(SyntheticFolderTest, BadFilesAreReported) {
  const auto dataset = openDataset("synthetic:" + dir_ + "/syn");
  std::string error;
  writeImage("syn/instance/000000.png", cv::Mat(4, 10, CV_16UC1, cv::Scalar(1)));
  EXPECT_FALSE(dataset->frame(0, &error));
  EXPECT_TRUE(contains(error, "instance/000000.png: image is 10x4, expected 10x8")) << error;
  truncate(dir_ + "/syn/depth/000001.png");
  EXPECT_FALSE(dataset->frame(1, &error));
  EXPECT_TRUE(contains(error, "depth/000001.png: cannot decode")) << error;

  writeText("syn/objects.txt", "0.0 7 3 1 2 0 0 0 0 1\n0.1 7 3 1 2 0 0 0 1\n");
  expectError([&] { openDataset("synthetic:" + dir_ + "/syn"); },
              {dir_ + "/syn/objects.txt:2: expected 10 numbers", "got 9"});
  writeText("syn/objects.txt", "0.0 7.5 3 1 2 0 0 0 0 1\n");
  expectError([&] { openDataset("synthetic:" + dir_ + "/syn"); }, {"objects.txt:1:", "integers"});
  fs::remove(dir_ + "/syn/objects.txt");
  writeText("syn/classes.yaml", "%YAML:1.0\nclasses:\n  - { id: 3, name: car, joint: hinge }\n");
  expectError([&] { openDataset("synthetic:" + dir_ + "/syn"); },
              {dir_ + "/syn/classes.yaml", "unknown joint 'hinge'"});
  writeText("syn/classes.yaml", "%YAML:1.0\nclasses:\n  - { id: 3, name: car, parent: road }\n");
  expectError([&] { openDataset("synthetic:" + dir_ + "/syn"); }, {"unknown parent 'road'"});
  fs::remove(dir_ + "/syn/classes.yaml");
  writeText("syn/camera.yaml",
            "%YAML:1.0\nwidth: 10\nheight: 8\nfx: 12.5\nfy: 12.5\n"
            "cx: 4.5\ncy: 3.5\ndepth_scale: 0.001\n");
  expectError([&] { openDataset("synthetic:" + dir_ + "/syn"); }, {"camera.yaml", "baseline_m"});
}

// --- KITTI stereo on a folder written here -----------------------------------------

TEST_F(DatasetTest, KittiStereoUsesP1BaselineAndExistingImagesOnly) {
  writeText("dataset/sequences/03/calib.txt",
            "P0: 100 0 20 0 0 100 10 0 0 0 1 0\nP1: 100 0 20 -54 0 100 10 0 0 0 1 0\n");
  writeText("dataset/sequences/03/times.txt", "0\n0.1\n0.2\n0.3\n0.4\n");
  writeText("dataset/poses/03.txt",
            "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 1\n"
            "1 0 0 0 0 1 0 0 0 0 1 2\n1 0 0 0 0 1 0 0 0 0 1 3\n"
            "1 0 0 0 0 1 0 0 0 0 1 4\n");
  for (const char* name : {"000000.png", "000001.png", "000002.png"}) {
    writeImage(std::string("dataset/sequences/03/image_0/") + name, noiseImage(20, 40, CV_8UC1, 1));
    writeImage(std::string("dataset/sequences/03/image_1/") + name, noiseImage(20, 40, CV_8UC1, 2));
  }
  const auto dataset = openDataset("kitti:" + dir_ + "/dataset/sequences/03");
  ASSERT_EQ(dataset->size(), 3u);
  EXPECT_TRUE(dataset->hasStereo());
  ASSERT_EQ(dataset->groundTruth().size(), 3u);
  EXPECT_EQ(dataset->groundTruth()[2].t, 0.2);
  EXPECT_EQ(dataset->groundTruth()[2].T_world_cam.translation().z(), 2.0);
  std::string error;
  const auto frame = dataset->frame(2, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_DOUBLE_EQ(frame->baseline_m, 0.54);
  EXPECT_EQ(frame->right.size(), cv::Size(40, 20));
  EXPECT_EQ(frame->camera.width, 40);

  writeImage("dataset/sequences/03/image_1/000001.png", noiseImage(10, 40, CV_8UC1, 2));
  EXPECT_FALSE(dataset->frame(1, &error));
  EXPECT_TRUE(contains(error, "image_1/000001.png: image is 40x10, expected 40x20")) << error;
}

// --- EuRoC on a folder written here ------------------------------------------------

struct EurocCam {
  double fx, fy, cx, cy;
  std::vector<double> distortion;
  SE3 T_body_cam;
};

// sensor.yaml as EuRoC writes it (optionally without OpenCV's %YAML:1.0 line).
std::string sensorYaml(const EurocCam& cam, const std::string& model, bool header) {
  std::string text = header ? "%YAML:1.0\n" : "";
  text += "# General sensor definitions.\nsensor_type: camera\ncomment: VI-Sensor (MT9M034)\n\n";
  text += "T_BS:\n  cols: 4\n  rows: 4\n  data: [";
  const Mat4 T = cam.T_body_cam.matrix();
  for (int k = 0; k < 16; ++k) text += (k ? ", " : "") + formatDouble(T(k / 4, k % 4));
  text += "]\n\nrate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\n";
  text += "intrinsics: [" + formatDouble(cam.fx) + ", " + formatDouble(cam.fy) + ", " +
          formatDouble(cam.cx) + ", " + formatDouble(cam.cy) + "] #fu, fv, cu, cv\n";
  text += "distortion_model: " + model + "\ndistortion_coefficients: [";
  for (size_t k = 0; k < cam.distortion.size(); ++k)
    text += (k ? ", " : "") + formatDouble(cam.distortion[k]);
  return text + "]\n";
}

// Gaussian blobs (sigma 1.5 px) centred on sub-pixel positions.
cv::Mat renderBlobs(const std::vector<cv::Point2d>& centres) {
  cv::Mat image(480, 752, CV_8UC1, cv::Scalar(0));
  for (const cv::Point2d& c : centres)
    for (int y = static_cast<int>(c.y) - 6; y <= static_cast<int>(c.y) + 6; ++y)
      for (int x = static_cast<int>(c.x) - 6; x <= static_cast<int>(c.x) + 6; ++x) {
        const double r2 = (x - c.x) * (x - c.x) + (y - c.y) * (y - c.y);
        uint8_t& pixel = image.at<uint8_t>(y, x);
        pixel = std::max<uint8_t>(pixel, cv::saturate_cast<uint8_t>(250 * std::exp(-r2 / 4.5)));
      }
  return image;
}

// Intensity centroid in a window around `guess`.
cv::Point2d centroid(const cv::Mat& image, const cv::Point2d& guess) {
  double sum = 0, sx = 0, sy = 0;
  for (int y = static_cast<int>(guess.y) - 8; y <= static_cast<int>(guess.y) + 8; ++y)
    for (int x = static_cast<int>(guess.x) - 8; x <= static_cast<int>(guess.x) + 8; ++x) {
      const double w = image.at<uint8_t>(y, x);
      sum += w, sx += w * x, sy += w * y;
    }
  return sum > 0 ? cv::Point2d(sx / sum, sy / sum) : cv::Point2d(-1e9, -1e9);
}

std::vector<cv::Point2d> project(const std::vector<cv::Point3d>& points_cam, const EurocCam& cam) {
  std::vector<cv::Point2d> pixels;
  const cv::Mat K = (cv::Mat_<double>(3, 3) << cam.fx, 0, cam.cx, 0, cam.fy, cam.cy, 0, 0, 1);
  cv::projectPoints(points_cam, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), K, cam.distortion, pixels);
  return pixels;
}

class EurocFolderTest : public DatasetTest {
 protected:
  static constexpr int64_t kStampNs = 1403636579763555584;

  void SetUp() override {
    DatasetTest::SetUp();
    if (HasFatalFailure()) return;
    // EuRoC's own cam0 calibration; cam1 ~11 cm to the right, slightly rotated
    // and offset so that rectification has real work to do.
    cam0_ = {458.654,
             457.296,
             367.215,
             248.375,
             {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05},
             SE3(SO3(Mat3((Mat3() << 0, -1, 0, 1, 0, 0, 0, 0, 1).finished())),
                 Vec3(-0.0216, -0.0647, 0.0098))};
    const SE3 T_cam0_cam1(SO3::exp(Vec3(0.01, -0.02, 0.005)), Vec3(0.11, 0.003, -0.001));
    cam1_ = {457.587,
             456.134,
             379.999,
             255.238,
             {-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05},
             cam0_.T_body_cam * T_cam0_cam1};
    T_world_body_ = SE3::exp((Vec6() << 0.5, -0.3, 1.2, 0.1, -0.2, 0.3).finished());
    for (int r = -1; r <= 1; ++r)
      for (int c = -1; c <= 1; ++c) {
        const double z = 2.0 + 0.25 * (3 * (r + 1) + c + 1);
        points_cam0_.emplace_back(0.25 * c * z, 0.15 * r * z, z);
      }

    writeText("euroc/mav0/cam0/sensor.yaml", sensorYaml(cam0_, "radial-tangential", false));
    const std::string stamp = std::to_string(kStampNs);
    writeText("euroc/mav0/cam0/data.csv", "#timestamp [ns],filename\n" + stamp + "," + stamp +
                                              ".png\n" + std::to_string(kStampNs + 50000000) +
                                              ",missing.png\n");
    writeImage("euroc/mav0/cam0/data/" + stamp + ".png", renderBlobs(project(points_cam0_, cam0_)));
    // Ground truth of the body (IMU) at 200 Hz around the frame.
    std::string gt =
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
        "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], ...\n";
    for (int k = -1; k <= 1; ++k) {
      const SE3 T = T_world_body_ * SE3::exp(Vec6::Constant(0.01 * k));
      const Eigen::Quaterniond q = T.quaternion();
      gt += std::to_string(kStampNs + 5000000 * k);
      for (double v : {T.translation().x(), T.translation().y(), T.translation().z(), q.w(), q.x(),
                       q.y(), q.z(), 0.0, 0.0, 0.0})
        gt += "," + formatDouble(v);
      gt += "\n";
    }
    writeText("euroc/mav0/state_groundtruth_estimate0/data.csv", gt);
  }

  void addCam1() {
    const std::string stamp = std::to_string(kStampNs);
    writeText("euroc/mav0/cam1/sensor.yaml", sensorYaml(cam1_, "radial-tangential", true));
    writeText("euroc/mav0/cam1/data.csv",
              "#timestamp [ns],filename\n" + stamp + "," + stamp + ".png\n");
    std::vector<cv::Point3d> points_cam1;
    const SE3 T_cam1_cam0 = cam1_.T_body_cam.inverse() * cam0_.T_body_cam;
    for (const cv::Point3d& p : points_cam0_) {
      const Vec3 q = T_cam1_cam0 * Vec3(p.x, p.y, p.z);
      points_cam1.emplace_back(q.x(), q.y(), q.z());
    }
    writeImage("euroc/mav0/cam1/data/" + stamp + ".png", renderBlobs(project(points_cam1, cam1_)));
  }

  // Ground-truth sample at the frame's time.
  static SE3 poseAt(const DatasetReader& dataset, double t) {
    for (const StampedPose& p : dataset.groundTruth())
      if (std::abs(p.t - t) < 1e-6) return p.T_world_cam;
    ADD_FAILURE() << "no ground truth at " << t;
    return SE3();
  }

  EurocCam cam0_, cam1_;
  SE3 T_world_body_;
  std::vector<cv::Point3d> points_cam0_;
};

TEST_F(EurocFolderTest, MonocularGivesTheRawCameraAndCameraGroundTruth) {
  const auto dataset = openDataset("euroc:" + dir_ + "/euroc");
  ASSERT_EQ(dataset->size(), 2u);
  EXPECT_FALSE(dataset->hasStereo());
  EXPECT_DOUBLE_EQ(dataset->timestamp(0), static_cast<double>(kStampNs) * 1e-9);
  std::string error;
  const auto frame = dataset->frame(0, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_EQ(frame->header.utime, 1403636579763556);
  EXPECT_EQ(frame->color.type(), CV_8UC1);
  EXPECT_EQ(frame->camera.type, CameraModel::Type::kRadTan);
  EXPECT_EQ(frame->camera.distortion, cam0_.distortion);
  EXPECT_DOUBLE_EQ(frame->camera.cx, 367.215);
  EXPECT_EQ(frame->camera.width, 752);
  EXPECT_TRUE(frame->right.empty());
  ASSERT_EQ(dataset->groundTruth().size(), 3u);
  const SE3 expected = T_world_body_ * cam0_.T_body_cam;
  const SE3 gt = poseAt(*dataset, dataset->timestamp(0));
  EXPECT_LT((gt.inverse() * expected).log().norm(), 1e-9);
  // The second listed image does not exist.
  EXPECT_FALSE(dataset->frame(1, &error));
  EXPECT_TRUE(contains(error, "cam0/data/missing.png: image file not found")) << error;
}

TEST_F(EurocFolderTest, StereoIsRectifiedConsistentlyWithGroundTruth) {
  addCam1();
  const auto dataset = openDataset("euroc:" + dir_ + "/euroc");
  ASSERT_EQ(dataset->size(), 1u);  // only the stamp both cameras have
  EXPECT_TRUE(dataset->hasStereo());
  std::string error;
  const auto frame = dataset->frame(0, &error);
  ASSERT_TRUE(frame) << error;
  const CameraModel& cam = frame->camera;
  EXPECT_EQ(cam.type, CameraModel::Type::kPinhole);
  EXPECT_TRUE(cam.distortion.empty());
  EXPECT_NEAR(frame->baseline_m, Vec3(0.11, 0.003, -0.001).norm(), 1e-9);
  ASSERT_EQ(frame->right.size(), frame->color.size());

  // Every world point lands where the rectified camera at its ground-truth pose
  // puts it, in the left image, and on the same row, shifted by f b / z, in the right.
  const SE3 T_rect_world = poseAt(*dataset, dataset->timestamp(0)).inverse();
  for (const cv::Point3d& p : points_cam0_) {
    const Vec3 p_world = T_world_body_ * cam0_.T_body_cam * Vec3(p.x, p.y, p.z);
    const Vec3 q = T_rect_world * p_world;
    const cv::Point2d left(cam.fx * q.x() / q.z() + cam.cx, cam.fy * q.y() / q.z() + cam.cy);
    const cv::Point2d right(left.x - cam.fx * frame->baseline_m / q.z(), left.y);
    const cv::Point2d found_left = centroid(frame->color, left);
    const cv::Point2d found_right = centroid(frame->right, right);
    EXPECT_LT(cv::norm(found_left - left), 0.3) << "left " << left << " found " << found_left;
    EXPECT_LT(cv::norm(found_right - right), 0.3) << "right " << right << " found " << found_right;
  }
}

TEST_F(EurocFolderTest, EquidistantAndBadCalibrations) {
  writeText(
      "euroc/mav0/cam0/sensor.yaml",
      sensorYaml({400, 400, 376, 240, {0.01, -0.02, 0.003, -0.001}, SE3()}, "equidistant", true));
  const auto fisheye = openDataset("euroc:" + dir_ + "/euroc");
  std::string error;
  const auto frame = fisheye->frame(0, &error);
  ASSERT_TRUE(frame) << error;
  EXPECT_EQ(frame->camera.type, CameraModel::Type::kEquidistant);
  EXPECT_EQ(frame->camera.distortion.size(), 4u);

  const std::string yaml = dir_ + "/euroc/mav0/cam0/sensor.yaml";
  writeText("euroc/mav0/cam0/sensor.yaml",
            sensorYaml({400, 400, 376, 240, {0.1}, SE3()}, "radial-tangential", true));
  expectError([&] { openDataset("euroc:" + dir_ + "/euroc"); },
              {yaml, "4 or 5 distortion_coefficients"});
  writeText("euroc/mav0/cam0/sensor.yaml",
            sensorYaml({400, 400, 376, 240, {}, SE3()}, "omni", true));
  expectError([&] { openDataset("euroc:" + dir_ + "/euroc"); }, {yaml, "'omni'"});
  writeText("euroc/mav0/cam0/sensor.yaml", "%YAML:1.0\nT_BS:\n  data: [1, 0, 0]\n");
  expectError([&] { openDataset("euroc:" + dir_ + "/euroc"); }, {yaml, "intrinsics"});
}

}  // namespace
}  // namespace radslam
