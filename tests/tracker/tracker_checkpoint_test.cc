// Tracker checkpoints: a tracker loaded from a checkpoint continues exactly as the one that
// wrote it; bad files are refused with the file named and leave the tracker unchanged.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/synthetic.h"
#include "tracker/tracker.h"

namespace radslam {
namespace {

std::vector<Frame> sceneFrames(const std::string& scene_name, int frames, double readout_s = 0) {
  SyntheticConfig config;
  config.readout_s = readout_s;
  config.scene = scene_name;
  config.width = 320;
  config.height = 240;
  config.frames = frames;
  config.stereo = true;
  const SyntheticScene scene = SyntheticScene::make(config);
  std::vector<Frame> out;
  for (int i = 0; i < frames; ++i) out.push_back(scene.frame(i));
  return out;
}

std::string tempPath(const std::string& name) {
  return ::testing::TempDir() + "radslam_tracker_ckpt_" + name;
}

bool samePose(const PoseStamped& a, const PoseStamped& b) {
  return a.frame_index == b.frame_index && a.state == b.state && a.is_keyframe == b.is_keyframe &&
         a.T_world_cam.matrix() == b.T_world_cam.matrix() && a.covariance == b.covariance;
}

/// Bit for bit (depth images hold NaN and infinity where unknown).
bool sameImage(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  return a.empty() || std::equal(a.datastart, a.dataend, b.datastart);
}

/// Two trackers' outputs for the same frame are identical: pose, keyframes (id, version,
/// pose, covariance, depths) and objects.
void expectSameOutput(const TrackerOutput& a, const TrackerOutput& b, const std::string& where) {
  ASSERT_EQ(a.has_pose, b.has_pose) << where;
  if (a.has_pose) {
    EXPECT_TRUE(samePose(a.pose, b.pose)) << where;
  }
  ASSERT_EQ(a.keyframes.size(), b.keyframes.size()) << where;
  for (size_t k = 0; k < a.keyframes.size(); ++k) {
    const Keyframe &x = a.keyframes[k], &y = b.keyframes[k];
    EXPECT_EQ(x.keyframe_id, y.keyframe_id) << where;
    EXPECT_EQ(x.version, y.version) << where;
    EXPECT_EQ(x.T_world_cam.matrix(), y.T_world_cam.matrix()) << where;
    EXPECT_EQ(x.covariance, y.covariance) << where;
    EXPECT_TRUE(sameImage(x.inv_depth, y.inv_depth)) << where;
    EXPECT_TRUE(sameImage(x.depth_var, y.depth_var)) << where;
  }
  ASSERT_EQ(a.refreshed_poses.size(), b.refreshed_poses.size()) << where;
  for (size_t i = 0; i < a.refreshed_poses.size(); ++i)
    EXPECT_TRUE(samePose(a.refreshed_poses[i], b.refreshed_poses[i])) << where << " pose " << i;
  ASSERT_EQ(a.has_objects, b.has_objects) << where;
  ASSERT_EQ(a.objects.objects.size(), b.objects.objects.size()) << where;
  for (size_t i = 0; i < a.objects.objects.size(); ++i) {
    const TrackedObject &x = a.objects.objects[i], &y = b.objects.objects[i];
    EXPECT_EQ(x.object_id, y.object_id) << where;
    EXPECT_EQ(x.T_world_object.matrix(), y.T_world_object.matrix()) << where;
    EXPECT_EQ(x.twist, y.twist) << where;
    EXPECT_EQ(x.joint_type, y.joint_type) << where;
  }
}

/// Runs `frames` through one tracker; at frame `split` it saves a checkpoint that a second
/// tracker loads, and both go on to the end and finish(): every output must be the same.
void expectResumedRunIdentical(const std::string& mode, const std::string& scene, int frames,
                               int split, double readout_s = 0) {
  TrackerParams params;
  params.mode = mode;
  params.window_size = 3;
  const std::vector<Frame> sequence = sceneFrames(scene, frames, readout_s);
  Tracker original(params);
  for (int i = 0; i < split; ++i) original.process(sequence[i]);
  const std::string path = tempPath(mode + "_" + scene);
  original.saveCheckpoint(path);
  Tracker resumed(params);
  resumed.loadCheckpoint(path);
  EXPECT_EQ(resumed.lastFrameIndex(), sequence[split - 1].frame_index);
  EXPECT_EQ(resumed.graph().size(), original.graph().size());
  EXPECT_GT(original.graph().size(), params.window_size) << "the window slid before the split";
  for (int i = split; i < frames; ++i) {
    expectSameOutput(original.process(sequence[i]), resumed.process(sequence[i]),
                     mode + " " + scene + " frame " + std::to_string(i));
  }
  expectSameOutput(original.finish(), resumed.finish(), mode + " " + scene + " finish");
  std::remove(path.c_str());
}

// The street scenes (10 Hz) make keyframes fast enough for the window to slide in a few frames.
TEST(TrackerCheckpoint, MonocularRunResumesExactly) {
  expectResumedRunIdentical("mono", "car", 30, 16);
}

TEST(TrackerCheckpoint, RgbdRunWithSeveralObjectsResumesExactly) {
  expectResumedRunIdentical("rgbd", "multi", 30, 18);
}

TEST(TrackerCheckpoint, StereoRunWithACarResumesExactly) {
  expectResumedRunIdentical("stereo", "car", 30, 18);
}

// With a rolling shutter the checkpoint also holds the previous frame's coarse images.
TEST(TrackerCheckpoint, RollingShutterRunResumesExactly) {
  expectResumedRunIdentical("rgbd", "car", 30, 16, 0.03);
}

TEST(TrackerCheckpoint, BadFilesAreRefusedAndTheTrackerIsUnchanged) {
  TrackerParams params;
  params.mode = "rgbd";
  const std::vector<Frame> sequence = sceneFrames("room", 12);
  Tracker tracker(params);
  for (int i = 0; i < 8; ++i) tracker.process(sequence[i]);
  const std::string path = tempPath("bad");
  tracker.saveCheckpoint(path);
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 1000u);

  auto expectRefused = [&](const std::string& content, const std::string& reason,
                           const TrackerParams& p) {
    const std::string bad = tempPath("bad_copy");
    std::ofstream(bad, std::ios::binary) << content;
    Tracker other(p);
    for (int i = 0; i < 4; ++i) other.process(sequence[i]);
    try {
      other.loadCheckpoint(bad);
      ADD_FAILURE() << "accepted: " << reason;
    } catch (const std::runtime_error& e) {
      const std::string message = e.what();
      EXPECT_NE(message.find(bad), std::string::npos) << message;
      EXPECT_NE(message.find(reason), std::string::npos) << message;
    }
    EXPECT_EQ(other.lastFrameIndex(), sequence[3].frame_index) << "state unchanged";
    std::remove(bad.c_str());
  };
  expectRefused(bytes.substr(0, bytes.size() / 2), "truncated", params);
  expectRefused("not a checkpoint at all", "not a radslam tracker checkpoint", params);
  TrackerParams other_window = params;
  other_window.window_size = 5;
  expectRefused(bytes, "window_size 8", other_window);
  std::string trailing = bytes + "x";
  expectRefused(trailing, "trailing bytes", params);

  // The tracker that wrote it goes on after a failed load elsewhere.
  EXPECT_TRUE(tracker.process(sequence[8]).has_pose);
  std::remove(path.c_str());
}

}  // namespace
}  // namespace radslam
