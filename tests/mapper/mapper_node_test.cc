// The mapper on an in-process bus (memq://): keyframes and tracked poses in; field updates a
// replica follows bitwise, snapshots and checkpoints on request, status, and the final outputs
// (with renders of every 10th non-keyframe at its latest tracked pose) after STOP.
#include "mapper/mapper_node.h"

#include <stdlib.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <set>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/exr_io.h"
#include "common/synthetic.h"
#include "common/trajectory.h"
#include "mapper/field_io.h"
#include "mapper/mapper_outputs.h"
#include "mapper/mapping_eval.h"

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

SyntheticScene smallRoom(int frames) {
  SyntheticConfig config;
  config.scene = "room";
  config.frames = frames;
  config.width = 80;
  config.height = 60;
  config.stereo = false;
  return SyntheticScene::make(config);
}

MapperNodeParams nodeParams() {
  MapperNodeParams p;
  p.core.trainer.batch_rays = 512;
  p.core.trainer.pose_warmup_rays = 200;
  p.update_period_s = 1e-3;
  p.status_period_s = 1e-3;
  p.max_blocks_per_update = 50;
  p.final_training_s = 0.2;
  p.final_rays_per_keyframe = 0;
  return p;
}

TEST(MapperNode, FollowsKeyframesPublishesUpdatesAndWritesOutputs) {
  const SyntheticScene scene = smallRoom(41);
  const std::string out = tempDir();
  Bus bus("memq://", "MAPTEST_", "test");
  // A block budget that messages of a quarter of the FIELD limit must split (54 RGB blocks).
  MapperNodeParams params = nodeParams();
  params.max_blocks_per_update = 200;
  MapperNode node(&bus, params, out);

  std::vector<FieldUpdate> updates;
  std::vector<Status> statuses;
  std::vector<PoseStamped> poses;
  bus.subscribe<FieldUpdate>(channel::kField, [&](const FieldUpdate& u) { updates.push_back(u); });
  bus.subscribe<Status>(channel::kStatus, [&](const Status& s) { statuses.push_back(s); });
  bus.subscribe<PoseStamped>(kMapperPoseChannel, [&](const PoseStamped& p) { poses.push_back(p); });

  std::vector<Keyframe> keyframes;
  const int keyframe_frames[3] = {0, 15, 25};
  for (int i = 0; i < 3; ++i) {
    keyframes.push_back(keyframeOf(scene, keyframe_frames[i], i));
    bus.publish(channel::kKeyframe, keyframes.back());
  }
  // Tracked poses: frame 17 first with a wrong pose, then re-published with the right one;
  // frame 30 never arrives and frame 40 is lost. The other frames are 1-14, 16-24, 26-29 and
  // 31-39: the middle one of each run of 10 (frames 6, 17, 28 and 39) gets a frame render.
  PoseStamped stale;
  stale.frame_index = 17;
  stale.header = scene.frame(17).header;
  stale.T_world_cam = SE3(SO3(), Vec3(5, 5, 5));
  bus.publish(channel::kPose, stale);
  for (int frame = 0; frame <= 40; ++frame) {
    if (frame == 30) continue;
    PoseStamped p;
    p.header = scene.frame(frame).header;
    p.frame_index = frame;
    p.is_keyframe = frame == 0 || frame == 15 || frame == 25;
    p.state = frame == 40 ? TrackingState::kLost : TrackingState::kTracking;
    p.T_world_cam = scene.cameraPose(frame);
    bus.publish(channel::kPose, p);
  }
  Keyframe bad = keyframeOf(scene, 5, 9);
  // A valid message the mapper cannot use (it needs undistorted keyframes).
  bad.camera.type = CameraModel::Type::kRadTan;
  bad.camera.distortion = {0.1, 0.01, 0, 0};
  bus.publish(channel::kKeyframe, bad);
  for (int i = 0; i < 30; ++i) ASSERT_TRUE(node.spinOnce(5));
  EXPECT_EQ(node.mapper().keyframes().size(), 3);  // the malformed one was skipped
  ASSERT_FALSE(updates.empty());
  ASSERT_FALSE(statuses.empty());
  EXPECT_EQ(statuses.back().process, "mapper");
  EXPECT_NE(statuses.back().last_error.find("keyframe 9"), std::string::npos);

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
  // One snapshot, in chunks of at most max_blocks_per_update blocks, one per update period
  // (as the FIELD limit lets them go: up to a few seconds here).
  auto snapshotSent = [&] {
    for (const FieldUpdate& u : updates)
      if (u.is_snapshot && u.chunk_index + 1 == u.chunk_count) return true;
    return false;
  };
  for (int i = 0; i < 3000 && !snapshotSent(); ++i) node.spinOnce(5);
  std::set<int64_t> snapshot_ids;
  int chunks = 0, last_count = 0;
  for (const FieldUpdate& u : updates) {
    if (!u.is_snapshot) continue;
    snapshot_ids.insert(u.snapshot_id);
    EXPECT_EQ(u.chunk_index, chunks);
    EXPECT_LE(static_cast<int>(u.blocks.size()), params.max_blocks_per_update);
    ++chunks;
    last_count = u.chunk_count;
  }
  EXPECT_EQ(snapshot_ids.size(), 1u);
  EXPECT_GE(chunks, 1);
  EXPECT_EQ(chunks, last_count);

  // A catch-up for a replica that lost the updates after a recent version: one delta based
  // there (a snapshot instead when more changed since than a message holds: field_io_test).
  int64_t since = -1;
  for (const FieldUpdate& u : updates) since = std::max(since, u.version);
  ASSERT_GT(since, 0);
  Control catch_up;
  catch_up.command = ControlCommand::kSnapshot;
  catch_up.target = "mapper";
  catch_up.argument = catchUpArgument(since);
  bus.publish(channel::kControl, catch_up);
  const size_t before = updates.size();
  for (int i = 0; i < 3000 && updates.size() == before; ++i) node.spinOnce(5);
  ASSERT_GT(updates.size(), before);
  EXPECT_FALSE(updates[before].is_snapshot);
  EXPECT_EQ(updates[before].base_version, since);

  Control stop;
  stop.command = ControlCommand::kStop;
  bus.publish(channel::kControl, stop);
  node.spinOnce(5);
  EXPECT_TRUE(node.stopRequested());
  node.finish();
  bus.handle(0);
  EXPECT_EQ(statuses.back().state, ProcessState::kDone);

  // MAPPER_POSE: refined poses as they move past the deadband, and the final one of every
  // refined keyframe (not the first: it holds the gauge) at the end.
  std::map<int64_t, SE3> last_pose;
  for (const PoseStamped& p : poses) last_pose[p.frame_index] = p.T_world_cam;
  const KeyframeStore& store = node.mapper().keyframes();
  ASSERT_EQ(last_pose.size(), static_cast<size_t>(store.size() - 1));
  // Not one per keyframe and update period: 46 here, 1759 without the deadband.
  EXPECT_LT(poses.size(), 40 * last_pose.size());
  for (int k = 0; k < store.size(); ++k) {
    const int64_t frame = store.entry(k).keyframe.frame_index;
    if (!last_pose.count(frame)) continue;
    EXPECT_EQ((last_pose[frame].inverse() * store.entry(k).T_world_cam).log().norm(), 0) << frame;
  }

  // FIELD stays within field_max_mb_per_s in every 1 s window (send times in header.utime).
  const double limit = nodeParams().field_max_mb_per_s * 1e6;
  double largest_window = 0;
  for (size_t i = 0; i < updates.size(); ++i) {
    double window = 0;
    for (size_t j = i;
         j < updates.size() && updates[j].header.utime < updates[i].header.utime + 1'000'000; ++j)
      for (const FieldBlock& b : updates[j].blocks) window += b.data.size();
    largest_window = std::max(largest_window, window);
  }
  EXPECT_LE(largest_window, limit);
  EXPECT_GT(largest_window, 0.5 * limit);  // the flush ran at the limit
  // No message over a quarter of the limit, and the block budget split into several.
  double largest_message = 0;
  size_t most_blocks = 0;
  for (const FieldUpdate& u : updates) {
    double bytes = 0;
    for (const FieldBlock& b : u.blocks) bytes += b.data.size();
    largest_message = std::max(largest_message, bytes);
    most_blocks = std::max(most_blocks, u.blocks.size());
  }
  EXPECT_LE(largest_message, 0.25 * limit);
  EXPECT_EQ(most_blocks, 54u);  // 450 kB of 8 kB blocks

  // A replica that applied the deltas in order (ignoring the snapshot) equals the final field.
  Field replica;
  std::string error;
  for (const FieldUpdate& u : updates) {
    if (u.is_snapshot) continue;
    // Also right after the snapshot: a delta never outgrows the budget.
    EXPECT_LE(static_cast<int>(u.blocks.size()), params.max_blocks_per_update);
    ASSERT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
  }
  EXPECT_TRUE(replica.sameContent(node.mapper().field()));

  // Outputs.
  for (const char* name : {"mapper.ckpt", "map_points.ply", "map_mesh.ply", "mapper_keyframes.txt"})
    EXPECT_TRUE(std::filesystem::exists(out + "/" + name)) << name;
  for (const Keyframe& kf : keyframes) {
    const std::string stem = stampFileName(kf.header.utime);
    EXPECT_TRUE(std::filesystem::exists(out + "/renders/rgb/" + stem + ".png")) << stem;
    const cv::Mat depth = readExrChannel(out + "/renders/depth/" + stem + ".exr", "depth");
    ASSERT_EQ(depth.size(), kf.depth.size());
    EXPECT_NEAR(depth.at<float>(30, 40), kf.depth.at<float>(30, 40), 0.1);
  }
  for (int frame : {6, 17, 28, 39}) {
    const Frame f = scene.frame(frame);
    const std::string stem = stampFileName(f.header.utime);
    EXPECT_TRUE(std::filesystem::exists(out + "/renders/rgb/" + stem + ".png")) << stem;
    const cv::Mat depth = readExrChannel(out + "/renders/depth/" + stem + ".exr", "depth");
    ASSERT_EQ(depth.size(), f.depth.size());
    EXPECT_NEAR(depth.at<float>(30, 40), f.depth.at<float>(30, 40), 0.1) << "frame " << frame;
  }
  for (int frame : {5, 10, 20, 30, 40}) {
    const std::string stem = stampFileName(scene.frame(frame).header.utime);
    EXPECT_FALSE(std::filesystem::exists(out + "/renders/rgb/" + stem + ".png")) << frame;
  }
  size_t rendered = 0;
  for (const auto& entry : std::filesystem::directory_iterator(out + "/renders/rgb")) {
    (void)entry;
    ++rendered;
  }
  EXPECT_EQ(rendered, 7u);  // 3 keyframes + 4 other frames
  // The final STATUS scores the keyframe renders against the keyframe images, as written.
  double psnr_written = 0;
  for (const Keyframe& kf : keyframes) {
    const cv::Mat png = cv::imread(out + "/renders/rgb/" + stampFileName(kf.header.utime) + ".png");
    cv::Mat rgb;
    png.convertTo(rgb, CV_32FC3, 1 / 255.0);
    cv::cvtColor(rgb, rgb, cv::COLOR_BGR2RGB);
    psnr_written += psnr(kf.color, rgb) / keyframes.size();
  }
  double psnr_status = 0;
  for (const auto& [key, value] : statuses.back().values)
    if (key == "keyframe_psnr_db") psnr_status = value;
  EXPECT_NEAR(psnr_status, psnr_written, 0.1);
  EXPECT_GT(psnr_written, 15);
  EXPECT_EQ(stampFileName(1305031102175304), "1305031102.175304");
}

TEST(MapperNode, ResumesFromACheckpointAsksForKeyframesAndResyncsReplicas) {
  const SyntheticScene scene = smallRoom(30);
  const std::string out = tempDir();
  const std::string checkpoint = out + "/mapper.ckpt";
  Bus bus("memq://", "RESUMETEST_", "test");
  std::vector<FieldUpdate> updates;
  std::vector<Control> controls;
  bus.subscribe<FieldUpdate>(channel::kField, [&](const FieldUpdate& u) { updates.push_back(u); });
  bus.subscribe<Control>(channel::kControl, [&](const Control& c) { controls.push_back(c); });

  // A first mapper learns two keyframes, checkpoints periodically and goes on past its last
  // checkpoint (what a crash loses); a replica follows it.
  Field replica;
  std::string error;
  MapperNodeParams params = nodeParams();
  params.checkpoint_period_s = 1e-3;
  {
    MapperNode first(&bus, params, out);
    bus.publish(channel::kKeyframe, keyframeOf(scene, 0, 0));
    bus.publish(channel::kKeyframe, keyframeOf(scene, 15, 1));
    for (int i = 0; i < 20; ++i) ASSERT_TRUE(first.spinOnce(5));
    ASSERT_TRUE(std::filesystem::exists(checkpoint));
    std::filesystem::rename(checkpoint, out + "/kept.ckpt");  // the crash loses what follows
    for (int i = 0; i < 20; ++i) ASSERT_TRUE(first.spinOnce(5));
    bus.handle(0);
  }
  for (const FieldUpdate& u : updates)
    ASSERT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
  const int64_t replica_version = replica.version();
  updates.clear();
  controls.clear();

  // The restarted mapper: the checkpoint's keyframes, a request for the others, and field
  // versions past the replica's so that its first delta is a gap there, not stale.
  params.checkpoint_period_s = 0;
  MapperNode second(&bus, params, out);
  second.resume(out + "/kept.ckpt");
  EXPECT_EQ(second.mapper().keyframes().size(), 2);
  EXPECT_GT(second.mapper().field().version(), replica_version);
  second.requestKeyframes();
  bus.handle(0);
  ASSERT_EQ(controls.size(), 1u);
  EXPECT_EQ(controls[0].command, ControlCommand::kRepublish);
  EXPECT_EQ(controls[0].target, "tracker");
  // The tracker's answer: both keyframes again at a higher version, and one the first mapper
  // never saw.
  for (int i = 0; i < 2; ++i) {
    Keyframe kf = keyframeOf(scene, 15 * i, i);
    kf.version = 1;
    bus.publish(channel::kKeyframe, kf);
  }
  bus.publish(channel::kKeyframe, keyframeOf(scene, 25, 2));
  for (int i = 0; i < 300; ++i) ASSERT_TRUE(second.spinOnce(5));
  EXPECT_EQ(second.mapper().keyframes().size(), 3);
  second.finish();  // the last deltas
  bus.handle(0);

  // The replica: every delta is newer than what it holds (none is dropped as stale), and the
  // snapshot with the deltas after it make it equal to the resumed field.
  ASSERT_FALSE(updates.empty());
  bool exact = false;
  SnapshotAssembler assembler;
  for (const FieldUpdate& u : updates) {
    if (u.is_snapshot) {
      std::string why;
      if (assembler.add(u, &why) == SnapshotAssembler::Result::kComplete) {
        replica = std::move(assembler.field());
        assembler.field() = Field();
        exact = true;
      }
      continue;
    }
    EXPECT_GT(u.version, replica_version);
    const ApplyResult r = applyFieldUpdate(u, &replica, &error, GapPolicy::kApply);
    EXPECT_TRUE(r == ApplyResult::kApplied || (r == ApplyResult::kGap && !exact)) << error;
  }
  ASSERT_TRUE(exact);
  EXPECT_TRUE(replica.sameContent(second.mapper().field()));
}

// What a renderer's STATUS tells the mapper at the end of a run.
void publishRendererStatus(Bus* bus, int64_t field_version, bool waiting_for_snapshot) {
  Status s;
  s.process = "renderer";
  s.pid = 1;
  s.state = ProcessState::kRunning;
  s.values = {{"field_version", static_cast<double>(field_version)},
              {"waiting_for_snapshot", waiting_for_snapshot ? 1.0 : 0.0}};
  bus->publish(channel::kStatus, s);
}

TEST(MapperNode, AfterTheFinalFlushServesASnapshotToARendererThatLostTheLastUpdate) {
  const SyntheticScene scene = smallRoom(20);
  Bus bus("memq://", "SYNCTEST_", "test");
  MapperNodeParams params = nodeParams();
  params.final_sync_s = 30;
  params.max_blocks_per_update = 50;  // snapshots of about ten chunks
  MapperNode node(&bus, params, "");
  bus.publish(channel::kKeyframe, keyframeOf(scene, 0, 0));
  bus.publish(channel::kKeyframe, keyframeOf(scene, 10, 1));
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(node.spinOnce(5));

  // A renderer that lost every update: it learns so from the mapper's final STATUS, asks for a
  // snapshot then, and reports its version as it goes. It also loses every third chunk of the
  // snapshot the first time and asks for those again once the last one arrived.
  Field replica;
  SnapshotAssembler assembler;
  bool asked = false;
  int chunks_asked = 0, chunks_resent = 0, max_chunk_count = 0;
  std::set<int> seen;
  const auto report = [&] {
    publishRendererStatus(&bus, replica.version(), !replica.initialized());
  };
  bus.subscribe<Status>(channel::kStatus, [&](const Status& s) {
    if (s.process != "mapper" || s.state != ProcessState::kDone || asked) return;
    asked = true;
    Control c;
    c.command = ControlCommand::kSnapshot;
    c.target = "mapper";
    bus.publish(channel::kControl, c);
  });
  bus.subscribe<FieldUpdate>(channel::kField, [&](const FieldUpdate& u) {
    if (!asked) return;  // lost
    std::string error;
    if (u.is_snapshot) {
      const bool again = !seen.insert(u.chunk_index).second;
      chunks_resent += again;
      max_chunk_count = std::max(max_chunk_count, u.chunk_count);
      if (!again && u.chunk_index % 3 == 1 && u.chunk_index < u.chunk_count - 1) return;  // lost
      if (assembler.add(u, &error) == SnapshotAssembler::Result::kComplete)
        replica = std::move(assembler.field());
      if (!again && u.chunk_index == u.chunk_count - 1) {
        const std::vector<int> missing = assembler.missing();
        chunks_asked += static_cast<int>(missing.size());
        Control c;
        c.command = ControlCommand::kSnapshot;
        c.target = "mapper";
        c.argument = snapshotChunksArgument(u.snapshot_id, missing);
        bus.publish(channel::kControl, c);
      }
    } else if (replica.initialized()) {
      EXPECT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
    }
    report();
  });
  report();
  bus.handle(0);

  const auto t0 = std::chrono::steady_clock::now();
  node.finish();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
            params.final_sync_s);
  EXPECT_TRUE(asked);
  EXPECT_GE(max_chunk_count, 5);
  EXPECT_GT(chunks_asked, 0);
  EXPECT_EQ(chunks_resent, chunks_asked);  // only those, once
  ASSERT_TRUE(replica.initialized());
  EXPECT_EQ(replica.version(), node.mapper().field().version());
  EXPECT_TRUE(replica.sameContent(node.mapper().field()));
}

TEST(MapperNode, AfterTheFinalFlushServesACatchUpToARendererThatLostTheLastUpdate) {
  const SyntheticScene scene = smallRoom(20);
  Bus bus("memq://", "CATCHUPTEST_", "test");
  MapperNodeParams params = nodeParams();
  params.final_sync_s = 30;
  MapperNode node(&bus, params, "");
  bus.publish(channel::kKeyframe, keyframeOf(scene, 0, 0));
  bus.publish(channel::kKeyframe, keyframeOf(scene, 10, 1));

  // A renderer that applies every update but the final flush's last delta; the mapper's final
  // STATUS shows it the loss, and it asks for what changed since its version.
  Field replica;
  std::vector<FieldUpdate> held;  // the final flush's deltas, one behind
  bool done = false, asked = false;
  int snapshots = 0;
  std::string error;
  const auto report = [&] { publishRendererStatus(&bus, replica.version(), false); };
  bus.subscribe<FieldUpdate>(channel::kField, [&](const FieldUpdate& u) {
    snapshots += u.is_snapshot;
    if (u.is_snapshot) return;
    if (asked) {  // the catch-up
      EXPECT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
      report();
      return;
    }
    if (!held.empty()) {
      EXPECT_EQ(applyFieldUpdate(held.back(), &replica, &error), ApplyResult::kApplied) << error;
    }
    held.push_back(u);
  });
  bus.subscribe<Status>(channel::kStatus, [&](const Status& s) {
    if (s.process != "mapper" || s.state != ProcessState::kDone || done) return;
    done = true;
    asked = true;
    ASSERT_LT(replica.version(), node.mapper().field().version());
    Control c;
    c.command = ControlCommand::kSnapshot;
    c.target = "mapper";
    c.argument = catchUpArgument(replica.version());
    bus.publish(channel::kControl, c);
  });
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(node.spinOnce(5));
  report();
  bus.handle(0);
  node.finish();
  EXPECT_TRUE(asked);
  EXPECT_EQ(snapshots, 0);
  EXPECT_EQ(replica.version(), node.mapper().field().version());
  EXPECT_TRUE(replica.sameContent(node.mapper().field()));
}

TEST(MapperNode, AddsNewKeyframesBeforeQueuedRefinementsOneRefinementPerStep) {
  const SyntheticScene scene = smallRoom(30);
  Bus bus("memq://", "QUEUETEST_", "test");
  MapperNode node(&bus, nodeParams(), "");
  auto version = [&](int32_t id) {
    const int i = node.mapper().keyframes().find(id);
    return i < 0 ? -1 : node.mapper().keyframes().entry(i).keyframe.version;
  };
  bus.publish(channel::kKeyframe, keyframeOf(scene, 0, 0));
  bus.publish(channel::kKeyframe, keyframeOf(scene, 10, 1));
  ASSERT_TRUE(node.spinOnce(5));
  ASSERT_EQ(version(0), 0);
  ASSERT_EQ(version(1), 0);

  // Two refinements (keyframe 1 twice: the versions merge) and a new keyframe in one burst.
  for (int v = 1; v <= 2; ++v) {
    Keyframe refined = keyframeOf(scene, 10, 1);
    refined.version = v;
    bus.publish(channel::kKeyframe, refined);
  }
  Keyframe refined0 = keyframeOf(scene, 0, 0);
  refined0.version = 1;
  bus.publish(channel::kKeyframe, refined0);
  bus.publish(channel::kKeyframe, keyframeOf(scene, 20, 2));
  ASSERT_TRUE(node.spinOnce(5));
  EXPECT_EQ(version(2), 0);               // the new keyframe, at once
  EXPECT_EQ(version(0) + version(1), 1);  // and one of the refinements
  ASSERT_TRUE(node.spinOnce(5));
  EXPECT_EQ(version(0), 1);
  EXPECT_EQ(version(1), 2);  // only the newest version of keyframe 1 was added
}

TEST(Mapper, KeyframeBoundRetiresTheOlderOfTheClosestPair) {
  const SyntheticScene scene = smallRoom(30);
  MapperParams params = nodeParams().core;
  params.max_keyframes = 4;
  Mapper mapper(params);
  const int frames[5] = {0, 10, 20, 21, 29};
  for (int i = 0; i < 5; ++i) mapper.addKeyframe(keyframeOf(scene, frames[i], i));
  ASSERT_EQ(mapper.keyframes().size(), 4);
  EXPECT_LT(mapper.keyframes().find(2), 0);  // frames 20 and 21 are the closest pair
  for (int id : {0, 1, 3, 4}) EXPECT_GE(mapper.keyframes().find(id), 0) << id;
  EXPECT_TRUE(mapper.retired(2));
  Keyframe again = keyframeOf(scene, 20, 2);
  again.version = 5;
  EXPECT_EQ(mapper.addKeyframe(again), KeyframeStore::InsertResult::kIgnored);
  EXPECT_EQ(mapper.keyframes().size(), 4);
}

TEST(MapperOutputs, NonKeyframeViewsTakeEveryTenthOtherTrackedFrameWithTheNearestCamera) {
  KeyframeStore store;
  SyntheticConfig config;
  config.scene = "room";
  config.frames = 60;
  config.width = 40;
  config.height = 30;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);
  Keyframe a = keyframeOf(scene, 0, 0), b = keyframeOf(scene, 50, 1);
  b.camera.fx *= 1.5;  // tells the two cameras apart
  a.header.utime = 0;  // the frames' clock below
  b.header.utime = 50000;
  store.insert(a);
  store.insert(b);
  const Vec6 exposure_a = (Vec6() << 0.1, -0.1, 0, 0.02, 0, -0.04).finished();
  const Vec6 exposure_b = (Vec6() << -0.1, 0.1, 0.2, 0, 0.06, 0).finished();
  store.entry(0).exposure = exposure_a;
  store.entry(1).exposure = exposure_b;
  // Frames 0-50; keyframes every other frame up to 20 (as when driving forward), 30 flagged
  // as one, 0 and 50 stored; frame 25 initialising.
  std::map<int64_t, PoseStamped> poses;
  for (int i = 0; i <= 50; ++i) {
    PoseStamped p;
    p.frame_index = i;
    p.header.utime = 1000 * i;
    p.is_keyframe = (i <= 20 && i % 2 == 0) || i == 30;
    p.T_world_cam = scene.cameraPose(i);
    poses[i] = p;
  }
  poses[25].state = TrackingState::kInitializing;
  EXPECT_TRUE(nonKeyframeViews(poses, KeyframeStore()).empty());
  // The others: 1 3 ... 19, 21-24, 26-29, 31-49: the 6th, 16th, 26th and 36th of them.
  const std::vector<FrameView> views = nonKeyframeViews(poses, store);
  ASSERT_EQ(views.size(), 4u);
  // Each with the exposure interpolated in time between the keyframes around it.
  for (const FrameView& v : views)
    EXPECT_TRUE(v.exposure.isApprox(exposure_a + (exposure_b - exposure_a) * (v.utime / 50000.0)))
        << v.frame_index;
  EXPECT_EQ(views[0].frame_index, 11);
  EXPECT_EQ(views[0].utime, 11000);
  EXPECT_EQ(views[0].camera.fx, a.camera.fx);
  EXPECT_EQ(views[1].frame_index, 27);
  EXPECT_EQ(views[1].camera.fx, b.camera.fx);
  EXPECT_EQ(views[2].frame_index, 38);
  EXPECT_EQ(views[3].frame_index, 48);
  EXPECT_TRUE(views[3].T_world_cam.matrix().isApprox(scene.cameraPose(48).matrix()));
  // A refined keyframe carries the frames it is nearest to; the others stay.
  const SE3 T_refined_received(SO3::exp(Vec3(0.01, -0.02, 0.005)), Vec3(0.03, 0, -0.01));
  store.entry(1).T_world_cam = T_refined_received * store.entry(1).T_world_cam;
  const std::vector<FrameView> moved = nonKeyframeViews(poses, store);
  ASSERT_EQ(moved.size(), 4u);
  EXPECT_TRUE(moved[0].T_world_cam.matrix().isApprox(scene.cameraPose(11).matrix()));
  EXPECT_TRUE(
      moved[3].T_world_cam.matrix().isApprox((T_refined_received * scene.cameraPose(48)).matrix()));
  // Past max_views, an evenly spread subset.
  for (int i = 51; i < 1000; ++i) {
    poses[i] = poses[49];
    poses[i].frame_index = i;
  }
  const std::vector<FrameView> few = nonKeyframeViews(poses, store, 1, 10);
  ASSERT_EQ(few.size(), 10u);
  EXPECT_EQ(few.front().frame_index, 1);
  EXPECT_GT(few.back().frame_index, 850);
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
  // The final training: its cap below its minimum, negative threads or rays.
  for (const char* bad :
       {"final_training_max_s=2", "final_training_threads=-1", "final_rays_per_keyframe=-5"})
    EXPECT_THROW(loadMapperParams("", {bad}, &dump, &source), std::invalid_argument) << bad;
  p = loadMapperParams("", {"final_training_threads=2", "final_rays_per_keyframe=0"}, &dump,
                       &source);
  EXPECT_EQ(p.final_training_threads, 2);
  EXPECT_EQ(p.final_rays_per_keyframe, 0);
}

}  // namespace
}  // namespace radslam
