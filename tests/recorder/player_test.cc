// Player core on a small synthetic dataset: ranges, stride, ground truth,
// lock-step acknowledgements, skipped frames.
#include "recorder/player.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "common/synthetic.h"

namespace radslam {
namespace {

class PlayerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = ::testing::TempDir() + "/player_test_synthetic";
    std::filesystem::remove_all(dir_);
    SyntheticConfig config;
    config.scene = "room";
    config.frames = 12;
    config.width = 96;
    config.height = 72;
    generateSyntheticDataset(config, dir_);
  }
  static std::string dir_;
};
std::string PlayerTest::dir_;

TEST_F(PlayerTest, PlaysRangeWithStrideAndGroundTruth) {
  auto dataset = openDataset("synthetic:" + dir_);
  ASSERT_EQ(dataset->size(), 12u);
  PlayerParams params;
  params.rate = 0;
  params.start = 2;
  params.end = 11;
  params.stride = 3;
  std::vector<int64_t> indices;
  std::vector<PoseStamped> truth;
  PlayerSinks sinks;
  sinks.frame = [&](const Frame& f) {
    indices.push_back(f.frame_index);
    EXPECT_EQ(f.color.cols, 96);
    EXPECT_EQ(f.color_compression, WireCompression::kRaw);
  };
  sinks.ground_truth = [&](const PoseStamped& p) { truth.push_back(p); };
  Player player(params, sinks);
  const PlayerStats stats = player.play(*dataset);
  EXPECT_EQ(indices, (std::vector<int64_t>{2, 5, 8}));
  EXPECT_EQ(stats.frames_sent, 3);
  ASSERT_EQ(truth.size(), 3u);
  for (size_t k = 0; k < truth.size(); ++k) {
    EXPECT_EQ(truth[k].frame_index, indices[k]);
    EXPECT_EQ(truth[k].state, TrackingState::kGroundTruth);
    const StampedPose& expected = dataset->groundTruth()[static_cast<size_t>(indices[k])];
    EXPECT_NEAR((truth[k].T_world_cam.translation() - expected.T_world_cam.translation()).norm(), 0,
                1e-9);
  }
}

TEST_F(PlayerTest, LockstepWaitsForEveryFrameAndGivesUpOnSilence) {
  auto dataset = openDataset("synthetic:" + dir_);
  PlayerParams params;
  params.rate = 0;
  params.lockstep = true;
  params.end = 6;
  params.ack_timeout_s = 0.01;
  std::vector<int64_t> asked;
  PlayerSinks sinks;
  sinks.frame = [](const Frame&) {};
  // Acknowledges frames 0..2, then goes silent: lock-step must be abandoned once.
  sinks.wait_for_ack = [&](int64_t index, double) {
    asked.push_back(index);
    return index < 3;
  };
  Player player(params, sinks);
  const PlayerStats stats = player.play(*dataset);
  EXPECT_EQ(stats.frames_sent, 6);
  EXPECT_EQ(stats.acks_missed, 1);
  EXPECT_EQ(asked, (std::vector<int64_t>{0, 1, 2, 3}));
}

// A tracker resumed from a checkpoint at frame 1 after frame 4 was sent: the player plays frames
// 2 to 4 again, then goes on; with a stride and in the backwards loop too.
TEST_F(PlayerTest, LockstepPlaysAgainFromTheFrameAskedFor) {
  auto dataset = openDataset("synthetic:" + dir_);
  for (const int stride : {1, 2}) {
    PlayerParams params;
    params.rate = 0;
    params.lockstep = true;
    params.end = 6;
    params.stride = stride;
    params.loops = 2;
    std::vector<int64_t> sent;
    int64_t rewind_after = stride == 1 ? 4 : 8, rewind_to = stride == 1 ? 2 : 7;
    PlayerSinks sinks;
    sinks.frame = [&](const Frame& f) { sent.push_back(f.frame_index); };
    sinks.wait_for_ack = [](int64_t, double) { return true; };
    sinks.take_rewind = [&]() -> int64_t {
      if (sent.back() != rewind_after) return -1;
      rewind_after = -1;  // once
      return rewind_to;
    };
    Player player(params, sinks);
    const PlayerStats stats = player.play(*dataset);
    EXPECT_EQ(stats.rewinds, 1);
    if (stride == 1) {
      EXPECT_EQ(sent, (std::vector<int64_t>{0, 1, 2, 3, 4, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11}));
    } else {
      // Indices 0 2 4 | 6 8 10; 7 is not played: the next one from it is 8.
      EXPECT_EQ(sent, (std::vector<int64_t>{0, 2, 4, 6, 8, 8, 10}));
    }
  }
}

TEST_F(PlayerTest, UnreadableFrameIsSkippedWithoutStopping) {
  const std::string broken = ::testing::TempDir() + "/player_test_broken";
  std::filesystem::remove_all(broken);
  std::filesystem::copy(dir_, broken, std::filesystem::copy_options::recursive);
  // Truncate one PNG: that frame must be skipped, the others played.
  std::filesystem::resize_file(broken + "/rgb/000004.png", 40);
  auto dataset = openDataset("synthetic:" + broken);
  PlayerParams params;
  params.rate = 0;
  int64_t played = 0;
  PlayerSinks sinks;
  sinks.frame = [&](const Frame& f) {
    EXPECT_NE(f.frame_index, 4);
    ++played;
  };
  Player player(params, sinks);
  const PlayerStats stats = player.play(*dataset);
  EXPECT_EQ(played, 11);
  EXPECT_EQ(stats.frames_skipped, 1);
}

TEST_F(PlayerTest, LoopsGoBackAndForthWithIndicesAndTimesGoingOn) {
  auto dataset = openDataset("synthetic:" + dir_);
  PlayerParams params;
  params.rate = 0;
  params.start = 1;
  params.end = 5;
  params.loops = 3;
  std::vector<int64_t> indices, utimes;
  std::vector<PoseStamped> truth;
  PlayerSinks sinks;
  sinks.frame = [&](const Frame& f) {
    indices.push_back(f.frame_index);
    utimes.push_back(f.header.utime);
  };
  sinks.ground_truth = [&](const PoseStamped& p) { truth.push_back(p); };
  Player player(params, sinks);
  EXPECT_EQ(player.play(*dataset).frames_sent, 12);
  EXPECT_EQ(indices, (std::vector<int64_t>{1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12}));
  // Times go on by one frame interval across the loop boundary.
  const int64_t interval = utimes[1] - utimes[0];
  for (size_t k = 1; k < utimes.size(); ++k) EXPECT_NEAR(utimes[k] - utimes[k - 1], interval, 2);
  ASSERT_EQ(truth.size(), 12u);
  EXPECT_EQ(truth[4].frame_index, 5);
  const auto same = [&](int a, int b) {
    return (truth[a].T_world_cam.translation() - truth[b].T_world_cam.translation()).norm() < 1e-12;
  };
  // The second loop plays frames 4, 3, 2, 1 (it turns round), the third 1 to 4 again.
  for (int k = 0; k < 4; ++k) {
    EXPECT_TRUE(same(4 + k, 3 - k)) << k;
    EXPECT_TRUE(same(8 + k, k)) << k;
  }
  for (size_t k = 0; k < truth.size(); ++k) EXPECT_NEAR(truth[k].header.utime, utimes[k], 1);
}

TEST_F(PlayerTest, RejectsBadParameters) {
  PlayerParams loops;
  loops.loops = 0;
  EXPECT_THROW(Player(loops, PlayerSinks{}), std::invalid_argument);
  PlayerParams params;
  params.color_compression = "webp";
  EXPECT_THROW(Player(params, PlayerSinks{}), std::invalid_argument);
  params = PlayerParams{};
  params.lockstep = true;  // without an acknowledgement source
  EXPECT_THROW(Player(params, PlayerSinks{}), std::invalid_argument);
  auto dataset = openDataset("synthetic:" + dir_);
  params = PlayerParams{};
  params.start = 100;
  PlayerSinks sinks;
  sinks.frame = [](const Frame&) {};
  Player player(params, sinks);
  EXPECT_THROW(player.play(*dataset), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
