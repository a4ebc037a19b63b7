#include "common/synthetic.h"

#include <gtest/gtest.h>
#include <stdlib.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "common/dataset.h"

namespace radslam {
namespace {

SyntheticConfig smallConfig(const std::string& scene, int width = 160, int height = 120) {
  SyntheticConfig c;
  c.scene = scene;
  c.frames = 30;
  c.width = width;
  c.height = height;
  return c;
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  return a.empty() || cv::norm(a, b, cv::NORM_INF) == 0;
}

Vec3 backProject(const CameraModel& cam, double x, double y, double z) {
  return Vec3((x - cam.cx) / cam.fx * z, (y - cam.cy) / cam.fy * z, z);
}

double grey(const cv::Vec3b& c) { return (c[0] + c[1] + c[2]) / 3.0; }

double median(std::vector<double> v) {
  if (v.empty()) return 1e9;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

/// Median grey difference between view a and view b at the points a sees (with a's depth),
/// counting only points b also sees (its depth agrees within 2 %). *count = points compared.
double photometricError(const RenderedView& a, const SE3& T_world_a, const RenderedView& b,
                        const SE3& T_world_b, const CameraModel& cam, int* count) {
  const SE3 T_b_a = T_world_b.inverse() * T_world_a;
  std::vector<double> diffs;
  for (int y = 2; y < cam.height - 2; y += 2)
    for (int x = 2; x < cam.width - 2; x += 2) {
      const float z = a.depth.at<float>(y, x);
      if (z <= 0) continue;
      const Vec3 p = T_b_a * backProject(cam, x, y, z);
      if (p.z() < 0.1) continue;
      const int u = static_cast<int>(std::lround(cam.fx * p.x() / p.z() + cam.cx));
      const int v = static_cast<int>(std::lround(cam.fy * p.y() / p.z() + cam.cy));
      if (u < 0 || v < 0 || u >= cam.width || v >= cam.height) continue;
      const float zb = b.depth.at<float>(v, u);
      if (std::abs(zb - p.z()) > 0.02 * p.z()) continue;  // occluded in b
      diffs.push_back(
          std::abs(grey(a.color.at<cv::Vec3b>(y, x)) - grey(b.color.at<cv::Vec3b>(v, u))));
    }
  *count = static_cast<int>(diffs.size());
  return median(diffs);
}

TEST(SyntheticTest, SameSeedGivesIdenticalFramesAndOtherSeedsDiffer) {
  SyntheticConfig c = smallConfig("car");
  c.image_noise_sigma = 3;
  c.depth_noise_rel = 0.002;
  const Frame f1 = SyntheticScene::make(c).frame(4);
  const Frame f2 = SyntheticScene::make(c).frame(4);
  EXPECT_TRUE(identical(f1.color, f2.color));
  EXPECT_TRUE(identical(f1.right, f2.right));
  EXPECT_TRUE(identical(f1.depth, f2.depth));
  EXPECT_TRUE(identical(f1.instance, f2.instance));
  EXPECT_TRUE(identical(f1.class_id, f2.class_id));
  // The thread count does not change a byte.
  c.threads = 3;
  EXPECT_TRUE(identical(SyntheticScene::make(c).frame(4).color, f1.color));
  c.threads = 1;
  c.seed = 2;
  EXPECT_FALSE(identical(SyntheticScene::make(c).frame(4).color, f1.color));
}

TEST(SyntheticTest, RoadDepthIsTheAnalyticDistanceToTheRoadPlane) {
  const SyntheticScene scene = SyntheticScene::make(smallConfig("street"));
  const CameraModel cam = scene.camera();
  // A pose tilted towards the road, away from the scene's own path.
  const SE3 T_world_cam =
      scene.cameraPose(3) * SE3(SO3::exp(Vec3(-0.3, 0.1, 0.05)), Vec3(0.2, -0.3, 0));
  const RenderedView view = scene.render(T_world_cam, cam, 3);
  const Vec3 c = T_world_cam.translation();
  int road = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      if (view.instance.at<uint16_t>(y, x) != 1) continue;
      // Ray c + t R (x_n, y_n, 1) meets z = 0 at t = -c_z / (R (x_n, y_n, 1))_z: t is the depth.
      const Vec3 d = T_world_cam.rotation() * backProject(cam, x, y, 1.0);
      const double expected = -c.z() / d.z();
      ASSERT_NEAR(view.depth.at<float>(y, x), expected, 1e-5 * expected) << x << "," << y;
      ++road;
    }
  EXPECT_GT(road, cam.width * cam.height / 10);
}

TEST(SyntheticTest, RoomPixelsLieOnTheSurfaceTheirInstanceNames) {
  const SyntheticScene scene = SyntheticScene::make(smallConfig("room"));
  const CameraModel cam = scene.camera();
  int checked = 0;
  for (int frame : {0, 50, 140}) {
    const SE3 T_world_cam = scene.cameraPose(frame);
    const RenderedView view = scene.render(T_world_cam, cam, frame);
    for (int y = 0; y < cam.height; ++y)
      for (int x = 0; x < cam.width; ++x) {
        const float z = view.depth.at<float>(y, x);
        ASSERT_GT(z, 0.3f) << "every room pixel hits a surface, none closer than 0.3 m";
        const Vec3 p = T_world_cam * backProject(cam, x, y, z);
        const uint16_t id = view.instance.at<uint16_t>(y, x);
        const double tol = 1e-4 * z;
        if (id == 1) {
          EXPECT_NEAR(p.z(), 0.0, tol);  // floor
        } else if (id == 3) {
          EXPECT_NEAR(p.z(), 2.8, tol);  // ceiling
        } else if (id == 2) {
          const double wall =
              std::min(std::abs(std::abs(p.x()) - 4.0), std::abs(std::abs(p.y()) - 3.0));
          EXPECT_LT(wall, tol);
        } else {
          continue;
        }
        ++checked;
      }
  }
  EXPECT_GT(checked, cam.width * cam.height);
}

TEST(SyntheticTest, StaticViewsArePhotometricallyConsistentThroughDepthAndPoses) {
  const SyntheticScene scene = SyntheticScene::make(smallConfig("room", 320, 240));
  const CameraModel cam = scene.camera();
  const SE3 Ta = scene.cameraPose(10), Tb = scene.cameraPose(16);
  EXPECT_GT((Ta.translation() - Tb.translation()).norm(), 0.06) << "1-2 cm per frame at 30 Hz";
  const RenderedView a = scene.render(Ta, cam, 10), b = scene.render(Tb, cam, 16);
  int count = 0;
  const double error = photometricError(a, Ta, b, Tb, cam, &count);
  EXPECT_GT(count, 5000);
  EXPECT_LT(error, 3.0);
  // The check can fail: a pose 3 cm off gives a clearly larger error on this texture.
  const double wrong = photometricError(a, Ta * SE3(SO3(), Vec3(0.03, 0, 0)), b, Tb, cam, &count);
  EXPECT_GT(wrong, 2.0 * error + 2.0);
}

TEST(SyntheticTest, RightImageMatchesLeftShiftedByDisparity) {
  const SyntheticScene scene = SyntheticScene::make(smallConfig("street", 320, 240));
  const CameraModel cam = scene.camera();
  const Frame f = scene.frame(5);
  RenderedView left{f.color, f.depth, f.instance, f.class_id};
  RenderedView right = scene.render(scene.rightCameraPose(5), cam, 5);
  ASSERT_TRUE(identical(right.color, f.right));
  int count = 0;
  const double error =
      photometricError(left, scene.cameraPose(5), right, scene.rightCameraPose(5), cam, &count);
  EXPECT_GT(count, 3000);
  EXPECT_LT(error, 3.0);
  // Right camera: +baseline along the left camera's x.
  const SE3 T_left_right = scene.cameraPose(5).inverse() * scene.rightCameraPose(5);
  EXPECT_NEAR((T_left_right.translation() - Vec3(0.1, 0, 0)).norm(), 0.0, 1e-12);
}

TEST(SyntheticTest, CarPosesObeyThePlanarJointOnTheRoad) {
  const SyntheticScene scene = SyntheticScene::make(smallConfig("car"));
  ASSERT_EQ(scene.objects().size(), 1u);
  EXPECT_EQ(scene.objects()[0].joint, JointType::kPlanar);
  EXPECT_EQ(scene.objects()[0].class_id, 10);
  double min_yaw = 1e9, max_yaw = -1e9;
  for (int f = 0; f < 300; f += 3) {
    const std::vector<ObjectPoseSample> poses = scene.objectPoses(f);
    ASSERT_EQ(poses.size(), 1u);
    const SE3& T = poses[0].T_world_object;
    EXPECT_NEAR(T.translation().z(), 0.0, 1e-12) << "origin on the road plane z = 0";
    EXPECT_NEAR((T.rotation() * Vec3::UnitZ() - Vec3::UnitZ()).norm(), 0.0, 1e-12)
        << "rotation only about the plane normal";
    const double yaw = T.so3().log().z();
    min_yaw = std::min(min_yaw, yaw), max_yaw = std::max(max_yaw, yaw);
    // Ahead of the camera, never on it.
    EXPECT_GT(T.translation().x() - scene.cameraPose(f).translation().x(), 8.0);
  }
  EXPECT_GT(max_yaw - min_yaw, 0.05) << "the car turns";
  const Vec3 moved = scene.objectPoses(20)[0].T_world_object.translation() -
                     scene.objectPoses(0)[0].T_world_object.translation();
  EXPECT_GT(moved.norm(), 10.0);
}

TEST(SyntheticTest, DoorPosesObeyTheRevoluteJoint) {
  for (const std::string name : {"door", "multi"}) {
    const SyntheticScene scene = SyntheticScene::make(smallConfig(name));
    int doors = 0;
    for (const SyntheticObject& o : scene.objects()) {
      if (o.joint != JointType::kRevolute) continue;
      ++doors;
      EXPECT_EQ(o.class_id, 11);
      EXPECT_NEAR((o.T_world_joint.rotation() * Vec3::UnitZ() - Vec3::UnitZ()).norm(), 0.0, 1e-12)
          << "vertical hinge";
      double min_angle = 1e9, max_angle = -1e9;
      for (int f = 0; f < 300; f += 5) {
        for (const ObjectPoseSample& s : scene.objectPoses(f)) {
          if (s.object_id != o.object_id) continue;
          for (double h : {0.0, 1.0, 2.0}) {
            const Vec3 axis_point = o.T_world_joint * Vec3(0, 0, h);
            EXPECT_NEAR((s.T_world_object * Vec3(0, 0, h) - axis_point).norm(), 0.0, 1e-9)
                << "hinge points stay fixed";
          }
          const SE3 T_joint_object = o.T_world_joint.inverse() * s.T_world_object;
          const Vec3 w = T_joint_object.so3().log();
          EXPECT_NEAR(w.head<2>().norm(), 0.0, 1e-9) << "rotation about the hinge only";
          min_angle = std::min(min_angle, w.z()), max_angle = std::max(max_angle, w.z());
        }
      }
      EXPECT_GT(max_angle - min_angle, 0.8) << name << ": the door swings";
    }
    EXPECT_EQ(doors, 1) << name;
  }
}

/// Every pixel of instance `id` back-projects into the object's own box [lo, hi].
int checkObjectMask(const std::string& name, int id, int frame, const Vec3& lo, const Vec3& hi) {
  const SyntheticScene scene = SyntheticScene::make(smallConfig(name, 320, 240));
  const CameraModel cam = scene.camera();
  const SE3 T_world_cam = scene.cameraPose(frame);
  const RenderedView view = scene.render(T_world_cam, cam, frame);
  SE3 T_world_object;
  int class_id = 0;
  for (const ObjectPoseSample& s : scene.objectPoses(frame))
    if (s.object_id == id) T_world_object = s.T_world_object, class_id = s.class_id;
  const SE3 T_object_cam = T_world_object.inverse() * T_world_cam;
  int pixels = 0;
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      if (view.instance.at<uint16_t>(y, x) != id) continue;
      ++pixels;
      EXPECT_EQ(view.class_id.at<uint16_t>(y, x), class_id);
      const Vec3 p = T_object_cam * backProject(cam, x, y, view.depth.at<float>(y, x));
      const double eps = 1e-3;
      EXPECT_TRUE((p.array() > lo.array() - eps).all() && (p.array() < hi.array() + eps).all())
          << name << " pixel " << x << "," << y << " at " << p.transpose();
    }
  return pixels;
}

TEST(SyntheticTest, InstanceMasksCoverTheObjects) {
  EXPECT_GT(checkObjectMask("car", 100, 10, Vec3(-2.15, -0.92, 0), Vec3(2.15, 0.92, 1.5)), 500);
  EXPECT_GT(checkObjectMask("door", 100, 40, Vec3(0, 0, 0), Vec3(0.9, 0.045, 2.05)), 500);
  // The truck of "large" covers a large share of the image.
  EXPECT_GT(checkObjectMask("large", 100, 10, Vec3(-0.1, -1.25, 0), Vec3(8.5, 1.25, 3.9)),
            320 * 240 / 5);
}

TEST(SyntheticTest, CameraNeverEntersGeometry) {
  // Also with the objects frozen at their first pose (the reference scene of the dynamic
  // benchmark): the camera passes them.
  for (const bool frozen : {false, true}) {
    for (const std::string& name : SyntheticScene::sceneNames()) {
      SyntheticConfig config = smallConfig(name, 64, 48);
      config.freeze_objects = frozen;
      const SyntheticScene scene = SyntheticScene::make(config);
      const CameraModel cam = scene.camera();
      // (Frozen objects stand where the sequence ends: only its frames are checked then.)
      for (int f = 0; f < (frozen ? config.frames : 300); f += frozen ? 3 : 10) {
        const RenderedView view = scene.render(scene.cameraPose(f), cam, f);
        double min_depth = 1e9;
        for (int y = 0; y < cam.height; ++y)
          for (int x = 0; x < cam.width; ++x)
            if (view.depth.at<float>(y, x) > 0)
              min_depth = std::min<double>(min_depth, view.depth.at<float>(y, x));
        EXPECT_GT(min_depth, 0.5) << name << (frozen ? " (frozen)" : "") << " frame " << f;
      }
    }
  }
}

TEST(SyntheticTest, SensorNoiseHasTheConfiguredStatistics) {
  SyntheticConfig c = smallConfig("room");
  const Frame clean = SyntheticScene::make(c).frame(2);
  c.image_noise_sigma = 4;
  c.depth_noise_rel = 0.01;
  const Frame noisy = SyntheticScene::make(c).frame(2);
  cv::Mat diff;
  cv::subtract(noisy.color, clean.color, diff, cv::noArray(), CV_64F);
  cv::Scalar mean, stddev;
  cv::meanStdDev(diff.reshape(1), mean, stddev);
  EXPECT_NEAR(mean[0], 0.0, 0.3);
  EXPECT_NEAR(stddev[0], 4.0, 0.5);
  double sum2 = 0;
  int n = 0;
  for (int y = 0; y < clean.depth.rows; ++y)
    for (int x = 0; x < clean.depth.cols; ++x) {
      const double z = clean.depth.at<float>(y, x);
      const double r = (noisy.depth.at<float>(y, x) - z) / (0.01 * z * z);
      sum2 += r * r, ++n;
    }
  EXPECT_NEAR(std::sqrt(sum2 / n), 1.0, 0.1) << "sigma_z = depth_noise_rel z^2";
}

TEST(SyntheticTest, BadConfigurationsAreRejected) {
  SyntheticConfig c = smallConfig("castle");
  EXPECT_THROW(SyntheticScene::make(c), std::invalid_argument);
  c = smallConfig("room");
  c.frames = 0;
  EXPECT_THROW(SyntheticScene::make(c), std::invalid_argument);
  c = smallConfig("room", 0, 10);
  EXPECT_THROW(SyntheticScene::make(c), std::invalid_argument);
  const SyntheticScene scene = SyntheticScene::make(smallConfig("room"));
  CameraModel distorted = scene.camera();
  distorted.type = CameraModel::Type::kRadTan;
  distorted.distortion = {0.1, 0, 0, 0};
  EXPECT_THROW(scene.render(scene.cameraPose(0), distorted, 0), std::invalid_argument);
}

// Rolling shutter: row y is seen at the frame's time + (y / (h - 1) - 0.5) readout. With the
// readout two frame periods long, the first row is the previous frame's and the last row the
// next frame's, moving objects included.
TEST(SyntheticScene, RollingShutterRowsAreSeenAtTheirOwnTime) {
  SyntheticConfig c = smallConfig("car", 64, 48);
  c.fps = 10;
  c.stereo = true;
  const SyntheticScene global = SyntheticScene::make(c);
  c.readout_s = 0.2;
  const SyntheticScene rolling = SyntheticScene::make(c);
  EXPECT_DOUBLE_EQ(rolling.camera().readout_s, 0.2);
  const Frame f = rolling.frame(5);
  EXPECT_DOUBLE_EQ(f.camera.readout_s, 0.2);
  const Frame before = global.frame(4), now = global.frame(5), after = global.frame(6);
  auto rowDifference = [](const cv::Mat& a, const cv::Mat& b, int row) {
    return cv::norm(a.row(row), b.row(row), cv::NORM_L1) / (a.cols * a.channels());
  };
  const int last = c.height - 1;
  EXPECT_LT(rowDifference(f.color, before.color, 0), 0.5);
  EXPECT_LT(rowDifference(f.color, after.color, last), 0.5);
  EXPECT_LT(rowDifference(f.depth, after.depth, last), 1e-4);
  EXPECT_LT(rowDifference(f.right, after.right, last), 0.5);
  EXPECT_TRUE(identical(f.instance.row(0), before.instance.row(0)));
  // The rows differ from the frame's own time.
  EXPECT_GT(rowDifference(f.color, now.color, 0), 2.0);
  EXPECT_GT(rowDifference(f.color, now.color, last), 2.0);
  c.readout_s = 1.0;
  EXPECT_THROW(SyntheticScene::make(c), std::invalid_argument);
}

class SyntheticFolderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = ::testing::TempDir() + "/synthetic_test_XXXXXX";
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string dir_;
};

TEST_F(SyntheticFolderTest, WritesEveryFileOfTheFormat) {
  SyntheticConfig c = smallConfig("multi", 64, 48);
  c.frames = 3;
  int calls = 0;
  generateSyntheticDataset(c, dir_, [&](int done, int total) {
    ++calls;
    EXPECT_EQ(total, 3);
    EXPECT_EQ(done, calls);
  });
  EXPECT_EQ(calls, 3);
  for (const char* file :
       {"camera.yaml", "times.txt", "groundtruth.txt", "objects.txt", "classes.yaml"})
    EXPECT_TRUE(std::filesystem::is_regular_file(dir_ + "/" + file)) << file;
  const SyntheticScene scene = SyntheticScene::make(c);
  for (int i = 0; i < 3; ++i) {
    char name[16];
    std::snprintf(name, sizeof(name), "/%06d.png", i);
    const cv::Mat rgb = cv::imread(dir_ + "/rgb" + name, cv::IMREAD_UNCHANGED);
    const cv::Mat right = cv::imread(dir_ + "/right" + name, cv::IMREAD_UNCHANGED);
    const cv::Mat depth = cv::imread(dir_ + "/depth" + name, cv::IMREAD_UNCHANGED);
    const cv::Mat instance = cv::imread(dir_ + "/instance" + name, cv::IMREAD_UNCHANGED);
    const cv::Mat class_id = cv::imread(dir_ + "/class" + name, cv::IMREAD_UNCHANGED);
    EXPECT_EQ(rgb.type(), CV_8UC3);
    EXPECT_EQ(right.type(), CV_8UC3);
    EXPECT_EQ(depth.type(), CV_16UC1);
    EXPECT_EQ(instance.type(), CV_16UC1);
    EXPECT_EQ(class_id.type(), CV_16UC1);
    const Frame f = scene.frame(i);
    EXPECT_TRUE(identical(rgb, f.color));
    EXPECT_TRUE(identical(instance, f.instance));
    for (int y = 0; y < depth.rows; ++y)
      for (int x = 0; x < depth.cols; ++x) {
        const double z = f.depth.at<float>(y, x);
        const int expected = (z > 0 && z < 65.5) ? static_cast<int>(std::lround(z * 1000)) : 0;
        ASSERT_EQ(depth.at<uint16_t>(y, x), expected) << "depth_scale 0.001 m, 0 = invalid";
      }
  }
  cv::FileStorage camera(dir_ + "/camera.yaml", cv::FileStorage::READ);
  EXPECT_EQ(static_cast<int>(camera["width"]), 64);
  EXPECT_EQ(static_cast<int>(camera["height"]), 48);
  EXPECT_DOUBLE_EQ(static_cast<double>(camera["fx"]), 0.8 * 64);
  EXPECT_DOUBLE_EQ(static_cast<double>(camera["baseline_m"]), 0.1);
  EXPECT_DOUBLE_EQ(static_cast<double>(camera["depth_scale"]), 0.001);
  EXPECT_TRUE(camera["readout_s"].empty()) << "a global shutter writes no readout";
  cv::FileStorage classes(dir_ + "/classes.yaml", cv::FileStorage::READ);
  int dynamic = 0;
  for (const cv::FileNode& n : classes["classes"]) dynamic += static_cast<int>(n["dynamic"]);
  EXPECT_EQ(dynamic, 2) << "car and door";

  // Ground truth: 3 poses in TUM format with full precision.
  std::ifstream gt(dir_ + "/groundtruth.txt");
  std::string line;
  int poses = 0;
  while (std::getline(gt, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    double t, v[7];
    in >> t;
    for (double& x : v) in >> x;
    ASSERT_FALSE(in.fail()) << line;
    const SE3 T = scene.cameraPose(poses);
    EXPECT_NEAR(t, poses / 10.0, 1e-9);
    EXPECT_NEAR((Vec3(v[0], v[1], v[2]) - T.translation()).norm(), 0.0, 1e-8);
    ++poses;
  }
  EXPECT_EQ(poses, 3);
  std::ifstream objects(dir_ + "/objects.txt");
  int rows = 0;
  while (std::getline(objects, line)) ++rows;
  EXPECT_EQ(rows, 3 * 3) << "two cars and a gate per frame";

  // Round trip through the dataset reader.
  const std::unique_ptr<DatasetReader> reader = openDataset("synthetic:" + dir_);
  ASSERT_EQ(reader->size(), 3u);
  EXPECT_TRUE(reader->hasStereo());
  EXPECT_TRUE(reader->hasDepth());
  EXPECT_EQ(reader->objectGroundTruth().size(), 9u);
  EXPECT_EQ(reader->classes().size(), scene.classes().size());
  std::string error;
  const std::optional<Frame> f = reader->frame(2, &error);
  ASSERT_TRUE(f.has_value()) << error;
  EXPECT_TRUE(identical(f->color, scene.frame(2).color));
}

TEST_F(SyntheticFolderTest, UnwritableFolderIsAnErrorNamingIt) {
  const std::string blocker = dir_ + "/file";
  std::ofstream(blocker) << "x";
  SyntheticConfig c = smallConfig("room", 32, 24);
  c.frames = 1;
  try {
    generateSyntheticDataset(c, blocker + "/out");
    FAIL() << "expected an exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(blocker), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace radslam
