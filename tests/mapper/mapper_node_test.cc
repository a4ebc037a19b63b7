// The mapper on an in-process bus (memq://): keyframes in; field updates a replica follows
// bitwise, snapshots and checkpoints on request, status, and the final outputs after STOP.
#include "mapper/mapper_node.h"

#include <stdlib.h>

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "common/exr_io.h"
#include "common/synthetic.h"
#include "mapper/field_io.h"
#include "mapper/mapper_outputs.h"

namespace radslam {
namespace {

std::string tempDir() {
  std::string pattern = ::testing::TempDir() + "radslam_mapper_XXXXXX";
  const char* dir = mkdtemp(pattern.data());
  EXPECT_NE(dir, nullptr);
  return dir ? dir : "";
}

Keyframe keyframeOf(const SyntheticScene& scene, int frame, int id) {
  const Frame f = scene.frame(frame);
  Keyframe kf;
  kf.header = f.header;
  kf.keyframe_id = id;
  kf.frame_index = frame;
  kf.T_world_cam = scene.cameraPose(frame);
  kf.camera = f.camera;
  kf.color = f.color;
  kf.depth = f.depth;
  kf.depth_var = cv::Mat(f.depth.size(), CV_32FC1, cv::Scalar(1e-4));
  return kf;
}

MapperNodeParams nodeParams() {
  MapperNodeParams p;
  p.core.trainer.batch_rays = 512;
  p.core.trainer.pose_warmup_rays = 200;
  p.update_period_s = 1e-3;
  p.status_period_s = 1e-3;
  p.max_blocks_per_update = 50;
  p.final_training_s = 0.2;
  return p;
}

TEST(MapperNode, FollowsKeyframesPublishesUpdatesAndWritesOutputs) {
  SyntheticConfig config;
  config.scene = "room";
  config.frames = 30;
  config.width = 80;
  config.height = 60;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);
  const std::string out = tempDir();
  Bus bus("memq://", "MAPTEST_", "test");
  MapperNode node(&bus, nodeParams(), out);

  std::vector<FieldUpdate> updates;
  std::vector<Status> statuses;
  std::vector<PoseStamped> poses;
  bus.subscribe<FieldUpdate>(channel::kField, [&](const FieldUpdate& u) { updates.push_back(u); });
  bus.subscribe<Status>(channel::kStatus, [&](const Status& s) { statuses.push_back(s); });
  bus.subscribe<PoseStamped>(kMapperPoseChannel, [&](const PoseStamped& p) { poses.push_back(p); });

  std::vector<Keyframe> keyframes;
  for (int i = 0; i < 3; ++i) {
    keyframes.push_back(keyframeOf(scene, i * 10, i));
    bus.publish(channel::kKeyframe, keyframes.back());
  }
  Keyframe bad = keyframeOf(scene, 5, 9);
  bad.camera.fx = -1;  // encodes, but is not a camera
  bus.publish(channel::kKeyframe, bad);
  for (int i = 0; i < 30; ++i) ASSERT_TRUE(node.spinOnce(5));
  EXPECT_EQ(node.mapper().keyframes().size(), 3);  // the malformed one was skipped
  ASSERT_FALSE(updates.empty());
  ASSERT_FALSE(statuses.empty());
  EXPECT_EQ(statuses.back().process, "mapper");
  EXPECT_NE(statuses.back().last_error.find("keyframe 9"), std::string::npos);
  EXPECT_FALSE(poses.empty());  // pose refinement started (warm-up 200 rays)

  // Snapshots and checkpoints on request; other targets are ignored.
  Control snapshot;
  snapshot.command = ControlCommand::kSnapshot;
  snapshot.target = "renderer";
  bus.publish(channel::kControl, snapshot);
  node.spinOnce(5);
  node.spinOnce(5);
  for (const FieldUpdate& u : updates) EXPECT_FALSE(u.is_snapshot);
  snapshot.target = "mapper";
  bus.publish(channel::kControl, snapshot);
  Control save;
  save.command = ControlCommand::kSave;
  save.argument = out + "/requested.ckpt";
  bus.publish(channel::kControl, save);
  for (int i = 0; i < 3; ++i) node.spinOnce(5);
  EXPECT_TRUE(std::filesystem::exists(save.argument));
  int snapshots = 0;
  for (const FieldUpdate& u : updates) snapshots += u.is_snapshot;
  EXPECT_EQ(snapshots, 1);

  Control stop;
  stop.command = ControlCommand::kStop;
  bus.publish(channel::kControl, stop);
  node.spinOnce(5);
  EXPECT_TRUE(node.stopRequested());
  node.finish();
  bus.handle(0);
  EXPECT_EQ(statuses.back().state, ProcessState::kDone);

  // A replica that applied the deltas in order (ignoring the snapshot) equals the final field.
  Field replica;
  std::string error;
  for (const FieldUpdate& u : updates) {
    if (u.is_snapshot) continue;
    ASSERT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
  }
  EXPECT_TRUE(replica.sameContent(node.mapper().field()));

  // Outputs.
  for (const char* name : {"mapper.ckpt", "map_points.ply", "map_mesh.ply", "mapper_keyframes.txt"})
    EXPECT_TRUE(std::filesystem::exists(out + "/" + name)) << name;
  for (const Keyframe& kf : keyframes) {
    const std::string stem = renderStem(kf.header.utime);
    EXPECT_TRUE(std::filesystem::exists(out + "/renders/rgb/" + stem + ".png")) << stem;
    const cv::Mat depth = readExrChannel(out + "/renders/depth/" + stem + ".exr", "depth");
    ASSERT_EQ(depth.size(), kf.depth.size());
    EXPECT_NEAR(depth.at<float>(30, 40), kf.depth.at<float>(30, 40), 0.1);
  }
  EXPECT_EQ(renderStem(1305031102175304), "1305031102.175304");
}

TEST(MapperParams, LoadsTheMapperSectionAndRejectsUnknownKeys) {
  const std::string dir = tempDir();
  const std::string path = dir + "/config.yaml";
  std::ofstream(path) << "%YAML:1.0\n---\nmapper:\n  levels: 3\n  depth_loss: raw\n"
                         "  lr_density: 0.2\n  update_period_s: 2.5\ntracker:\n  other: 1\n";
  std::string dump, source;
  MapperNodeParams p = loadMapperParams(path, {"batch_rays=1000"}, &dump, &source);
  EXPECT_EQ(p.core.levels, 3);
  EXPECT_EQ(p.core.trainer.depth_loss, DepthLoss::kRaw);
  EXPECT_FLOAT_EQ(p.core.trainer.adam.lr_density, 0.2f);
  EXPECT_EQ(p.update_period_s, 2.5);
  EXPECT_EQ(p.core.trainer.batch_rays, 1000);
  EXPECT_NE(dump.find("depth_loss"), std::string::npos);
  EXPECT_NE(source.find(path), std::string::npos);
  // Defaults only.
  p = loadMapperParams("", {}, &dump, &source);
  EXPECT_EQ(p.core.levels, 2);
  std::ofstream(path) << "mapper:\n  levelz: 3\n";
  EXPECT_THROW(loadMapperParams(path, {}, &dump, &source), std::runtime_error);
  std::ofstream(path) << "mapper:\n  depth_loss: l1\n";
  EXPECT_THROW(loadMapperParams(path, {}, &dump, &source), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
