#include "common/trajectory.h"

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

namespace radslam {
namespace {

const std::string kData = RADSLAM_SOURCE_DIR "/../shared/data";

class TrajectoryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern = ::testing::TempDir() + "/trajectory_test_XXXXXX";
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string write(const std::string& name, const std::string& text) const {
    const std::string path = dir_ + "/" + name;
    std::ofstream(path) << text;
    return path;
  }

  std::string dir_;
};

Trajectory randomTrajectory(size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Trajectory trajectory;
  double t = 1305031229.528748;
  for (size_t i = 0; i < n; ++i) {
    Vec6 xi;
    for (int k = 0; k < 6; ++k) xi[k] = 3.0 * u(rng);
    t += 0.0333 + 1e-6 * static_cast<double>(i % 7);
    trajectory.push_back({t, SE3::exp(xi)});
  }
  return trajectory;
}

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

TEST_F(TrajectoryTest, TumRoundTripIsExact) {
  const Trajectory written = randomTrajectory(50, 1);
  const std::string path = dir_ + "/traj.txt";
  writeTumTrajectory(path, written);
  const Trajectory read = readTumTrajectory(path);
  ASSERT_EQ(read.size(), written.size());
  for (size_t i = 0; i < read.size(); ++i) {
    EXPECT_EQ(read[i].t, written[i].t);  // bit-exact
    EXPECT_EQ(read[i].T_world_cam.translation(), written[i].T_world_cam.translation());
    // The reader re-normalises the quaternion, which may move the last bit.
    EXPECT_TRUE(read[i].T_world_cam.quaternion().coeffs().isApprox(
        written[i].T_world_cam.quaternion().coeffs(), 1e-15));
  }
  // Times are in fixed notation with their microseconds, as TUM tools expect.
  std::ifstream in(path);
  std::string header, first;
  std::getline(in, header);
  std::getline(in, first);
  EXPECT_EQ(header[0], '#');
  EXPECT_EQ(first.find('e'), std::string::npos) << first;
}

TEST_F(TrajectoryTest, TumParsesCommentsBlankLinesAndNormalisesQuaternions) {
  const std::string path = write("gt.txt",
                                 "# ground truth\n"
                                 "\n"
                                 "1.5 1 2 3 0 0 0 2\n"
                                 "  2.5\t-1 -2 -3 0 0 1 1  \r\n");
  const Trajectory t = readTumTrajectory(path);
  ASSERT_EQ(t.size(), 2u);
  EXPECT_EQ(t[0].t, 1.5);
  EXPECT_EQ(t[0].T_world_cam.translation(), Vec3(1, 2, 3));
  EXPECT_TRUE(t[0].T_world_cam.rotation().isApprox(Mat3::Identity(), 1e-15));
  const Vec3 p = t[1].T_world_cam * Vec3(1, 0, 0);  // 90 degrees about z
  EXPECT_TRUE(p.isApprox(Vec3(-1, -1, -3), 1e-12)) << p.transpose();
}

TEST_F(TrajectoryTest, TumMalformedLinesNameFileAndLine) {
  const std::string short_line = write("short.txt", "# c\n1 2 3 4 5 6 7 1\n\n1 2 3 4 5 6 7\n");
  expectError([&] { readTumTrajectory(short_line); },
              {short_line + ":4: expected 8 numbers", "got 7"});
  const std::string word = write("word.txt", "1 2 3 4 5 6 abc 1\n");
  expectError([&] { readTumTrajectory(word); }, {word + ":1: expected 8 numbers", "'abc'"});
  const std::string nan = write("nan.txt", "1 2 3 nan 0 0 0 1\n");
  expectError([&] { readTumTrajectory(nan); }, {nan + ":1:", "finite"});
  const std::string zero_q = write("zeroq.txt", "1 2 3 4 0 0 0 0\n");
  expectError([&] { readTumTrajectory(zero_q); }, {zero_q + ":1:", "zero norm"});
  expectError([&] { readTumTrajectory(dir_ + "/absent.txt"); },
              {dir_ + "/absent.txt", "cannot open"});
  expectError([&] { writeTumTrajectory(dir_ + "/no/dir/x.txt", {}); }, {"no/dir/x.txt"});
}

TEST_F(TrajectoryTest, KittiRoundTripAndTimes) {
  const Trajectory written = randomTrajectory(20, 2);
  const std::string path = dir_ + "/poses.txt";
  writeKittiTrajectory(path, written);
  const Trajectory by_row = readKittiTrajectory(path);
  ASSERT_EQ(by_row.size(), written.size());
  std::vector<double> times;
  for (size_t i = 0; i < written.size(); ++i) {
    EXPECT_EQ(by_row[i].t, static_cast<double>(i));
    EXPECT_EQ(by_row[i].T_world_cam.translation(), written[i].T_world_cam.translation());
    EXPECT_TRUE(
        by_row[i].T_world_cam.rotation().isApprox(written[i].T_world_cam.rotation(), 1e-14));
    times.push_back(written[i].t);
  }
  const Trajectory timed = readKittiTrajectory(path, times);
  EXPECT_EQ(timed[7].t, written[7].t);
  times.pop_back();
  expectError([&] { readKittiTrajectory(path, times); }, {path, "20 poses but 19 time stamps"});
  const std::string bad = write("bad.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n");
  expectError([&] { readKittiTrajectory(bad); }, {bad + ":2: expected 12 numbers", "got 11"});
}

TEST(Trajectory, FormatDoubleIsShortestExact) {
  EXPECT_EQ(formatDouble(0.1), "0.1");
  EXPECT_EQ(formatDouble(-2.0), "-2");
  std::mt19937_64 rng(3);
  for (int i = 0; i < 1000; ++i) {
    uint64_t bits = rng();
    double value;
    std::memcpy(&value, &bits, sizeof(value));
    if (!std::isfinite(value)) continue;
    EXPECT_EQ(std::strtod(formatDouble(value).c_str(), nullptr), value);
  }
}

TEST(Trajectory, AssociateIsGreedyNearestFirstAndOneToOne) {
  // a[1] is nearer to b[0] than a[0] is, so a[0] stays unmatched.
  std::vector<double> a = {0.0, 0.011, 0.05, 0.1};
  std::vector<double> b = {0.010, 0.1005, 0.2};
  const auto pairs = associateTimes(a, b, 0.02);
  ASSERT_EQ(pairs.size(), 2u);
  EXPECT_EQ(pairs[0], std::make_pair(size_t{1}, size_t{0}));
  EXPECT_EQ(pairs[1], std::make_pair(size_t{3}, size_t{1}));
  // Unsorted input, result sorted by a's time; max_dt respected.
  a = {0.3, 0.1, 0.2};
  b = {0.201, 0.099, 0.35};
  const auto unsorted = associateTimes(a, b, 0.005);
  ASSERT_EQ(unsorted.size(), 2u);
  EXPECT_EQ(unsorted[0], std::make_pair(size_t{1}, size_t{1}));
  EXPECT_EQ(unsorted[1], std::make_pair(size_t{2}, size_t{0}));
  // Non-finite stamps never match.
  EXPECT_TRUE(associateTimes({std::nan("")}, {std::nan("")}, 1.0).empty());
}

TEST(Trajectory, AssociateByTimeMatchesTrajectories) {
  Trajectory a, b;
  for (int i = 0; i < 30; ++i) a.push_back({i / 30.0, SE3()});
  for (int i = 0; i < 300; ++i) b.push_back({i / 100.0 + 0.001, SE3()});
  const auto pairs = associateByTime(a, b, 0.01);
  ASSERT_EQ(pairs.size(), 30u);
  for (const auto& [i, j] : pairs) EXPECT_LE(std::abs(a[i].t - b[j].t), 0.005 + 1e-9);
}

TEST(Trajectory, ReadsRealTumAndKittiFiles) {
  const std::string tum = kData + "/tum_fr1_rpy/rgbd_dataset_freiburg1_rpy/groundtruth.txt";
  const std::string kitti = kData + "/kitti_odometry_07/poses/07.txt";
  if (!std::filesystem::exists(tum) || !std::filesystem::exists(kitti))
    GTEST_SKIP() << "real data not found under " << kData << " (see DESIGN.md section 6)";
  const Trajectory gt = readTumTrajectory(tum);
  ASSERT_GT(gt.size(), 100u);
  EXPECT_DOUBLE_EQ(gt[0].t, 1305031225.9334);
  EXPECT_TRUE(gt[0].T_world_cam.translation().isApprox(Vec3(1.3357, 0.6698, 1.6180), 1e-12));
  const Eigen::Quaterniond q = gt[0].T_world_cam.quaternion();
  EXPECT_NEAR(std::abs(q.w()), 0.3496, 1e-3);  // normalised from the file's 4 decimals

  const Trajectory poses = readKittiTrajectory(kitti);
  ASSERT_EQ(poses.size(), 1101u);
  EXPECT_TRUE(poses[0].T_world_cam.matrix().isApprox(Mat4::Identity(), 1e-9));
  EXPECT_NEAR(poses[1].T_world_cam.translation().z(), 9.154274e-02, 1e-9);
}

}  // namespace
}  // namespace radslam
