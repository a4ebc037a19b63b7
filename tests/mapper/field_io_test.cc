// Field updates reproduce the mapper's field bitwise in a replica; checkpoints round-trip
// exactly and resume training identically; keyframe versions replace or are ignored.
#include "mapper/field_io.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <fstream>

#include <gtest/gtest.h>

#include "common/synthetic.h"
#include "mapper/mapper.h"

namespace radslam {
namespace {

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

SyntheticScene tinyRoom() {
  SyntheticConfig config;
  config.scene = "room";
  config.frames = 40;
  config.width = 80;
  config.height = 60;
  config.stereo = false;
  return SyntheticScene::make(config);
}

MapperParams smallParams() {
  MapperParams params;
  params.trainer.batch_rays = 512;
  params.trainer.pose_warmup_rays = 500;  // poses move within the test
  return params;
}

std::string tempPath(const std::string& name) { return ::testing::TempDir() + "/" + name; }

TEST(FieldUpdates, ReplayReproducesTheFieldBitwise) {
  const SyntheticScene scene = tinyRoom();
  Mapper mapper(smallParams());
  Field replica;
  int64_t published = 0;
  std::string error;
  for (int i = 0; i < 4; ++i) {
    mapper.addKeyframe(keyframeOf(scene, i * 10, i));
    for (int k = 0; k < 3; ++k) {
      mapper.train(2);
      // Bounded updates: a few blocks at a time, the rest follow in later updates.
      const FieldUpdate u = mapper.makeUpdate(published, 40);
      EXPECT_FALSE(u.is_snapshot);
      EXPECT_EQ(u.base_version, published);
      if (u.blocks.empty()) continue;
      ASSERT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
      published = u.version;
      EXPECT_EQ(replica.version(), published);
    }
  }
  // Flush what is still pending: the replica then equals the mapper bit for bit.
  for (FieldUpdate u = mapper.makeUpdate(published); !u.blocks.empty();
       u = mapper.makeUpdate(published)) {
    ASSERT_EQ(applyFieldUpdate(u, &replica, &error), ApplyResult::kApplied) << error;
    published = u.version;
  }
  EXPECT_EQ(mapper.field().pendingBlocks(), 0);
  EXPECT_TRUE(replica.sameContent(mapper.field()));
  EXPECT_EQ(replica.version(), mapper.field().version());

  // A snapshot rebuilds an identical replica from nothing.
  Field fresh;
  const FieldUpdate snap = mapper.makeSnapshot();
  EXPECT_TRUE(snap.is_snapshot);
  ASSERT_EQ(applyFieldUpdate(snap, &fresh, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(fresh.sameContent(mapper.field()));

  // Renders of the replica are identical too (the renderer process relies on it).
  const Keyframe kf = keyframeOf(scene, 5, 9);
  const VolumeRenderer renderer;
  MarchParams mp = mapper.marchParams();
  const RenderImages a = renderer.render(mapper.field(), kf.T_world_cam, kf.camera, mp);
  const RenderImages b = renderer.render(replica, kf.T_world_cam, kf.camera, mp);
  EXPECT_EQ(cv::norm(a.color, b.color, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0);
}

TEST(FieldUpdates, SnapshotInChunksWhileTrainingGoesOn) {
  const SyntheticScene scene = tinyRoom();
  Mapper mapper(smallParams());
  int64_t published = 0;
  for (int i = 0; i < 3; ++i) {
    mapper.addKeyframe(keyframeOf(scene, i * 10, i));
    mapper.train(2);
    published = mapper.makeUpdate(published).version;  // what replicas in step have seen
  }
  const int total_blocks = static_cast<int>(mapper.field().totalBlocks());
  SnapshotSender sender = mapper.makeSnapshotSender(7, 10);
  ASSERT_GT(sender.chunkCount(), 2);
  EXPECT_EQ(sender.chunkCount(), (total_blocks + 9) / 10);
  SnapshotAssembler assembler;
  std::string error;
  int chunks = 0;
  while (!sender.done()) {
    const FieldUpdate chunk = sender.next();
    EXPECT_TRUE(chunk.is_snapshot);
    EXPECT_EQ(chunk.snapshot_id, 7);
    EXPECT_EQ(chunk.chunk_index, chunks);
    EXPECT_LE(chunk.blocks.size(), 10u);
    const SnapshotAssembler::Result r = assembler.add(chunk, &error);
    ++chunks;
    ASSERT_EQ(r, chunks < sender.chunkCount() ? SnapshotAssembler::Result::kIncomplete
                                              : SnapshotAssembler::Result::kComplete)
        << error;
    mapper.train(1);  // the field changes while the chunks are on their way
  }
  EXPECT_EQ(chunks, sender.chunkCount());
  Field replica = std::move(assembler.field());
  EXPECT_EQ(replica.version(), sender.version());
  // The mapper's next update, based at the snapshot's version, completes the replica.
  const FieldUpdate catch_up = mapper.makeUpdate(std::min(published, sender.version()));
  ASSERT_EQ(applyFieldUpdate(catch_up, &replica, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(replica.sameContent(mapper.field()));

  // Lost chunks are asked for again and sent with their content then; the chunks of another
  // snapshot start over.
  SnapshotSender again = mapper.makeSnapshotSender(8, 10);
  SnapshotAssembler lossy;
  std::vector<int> lost;
  for (int i = 0; !again.done(); ++i) {
    const FieldUpdate chunk = again.next();
    if (i == 1 || i == again.chunkCount() - 1) {
      lost.push_back(chunk.chunk_index);
      continue;
    }
    ASSERT_EQ(lossy.add(chunk, &error), SnapshotAssembler::Result::kIncomplete) << error;
    mapper.train(1);
  }
  EXPECT_TRUE(lossy.inProgress());
  EXPECT_EQ(lossy.snapshotId(), 8);
  EXPECT_EQ(lossy.missing(), lost);
  EXPECT_EQ(again.resend({lost[0], lost[0], -1, again.chunkCount()}), 1);
  EXPECT_EQ(again.resend(lost), 1);  // lost[0] is queued already
  ASSERT_FALSE(again.done());
  ASSERT_EQ(lossy.add(again.next(), &error), SnapshotAssembler::Result::kIncomplete) << error;
  EXPECT_EQ(lossy.missing(), std::vector<int>{lost[1]});
  const int64_t assembled_version = mapper.field().version();
  ASSERT_EQ(lossy.add(again.next(), &error), SnapshotAssembler::Result::kComplete) << error;
  EXPECT_TRUE(again.done());
  EXPECT_FALSE(lossy.inProgress());
  Field resent = std::move(lossy.field());
  EXPECT_EQ(resent.version(), assembled_version);
  EXPECT_EQ(again.version(), assembled_version);
  ASSERT_EQ(applyFieldUpdate(mapper.makeUpdate(again.version()), &resent, &error),
            ApplyResult::kApplied)
      << error;
  EXPECT_TRUE(resent.sameContent(mapper.field()));

  SnapshotSender first = mapper.makeSnapshotSender(9, 10);
  SnapshotSender second = mapper.makeSnapshotSender(10, 10);
  SnapshotAssembler switching;
  ASSERT_EQ(switching.add(first.next(), &error), SnapshotAssembler::Result::kIncomplete);
  second.next();  // lost
  ASSERT_EQ(switching.add(second.next(), &error), SnapshotAssembler::Result::kIncomplete);
  EXPECT_EQ(switching.snapshotId(), 10);
  EXPECT_EQ(switching.missing().front(), 0);
  EXPECT_EQ(switching.missing().size(), static_cast<size_t>(second.chunkCount() - 1));
  FieldUpdate bad = second.next();
  bad.chunk_index = bad.chunk_count;
  EXPECT_EQ(switching.add(bad, &error), SnapshotAssembler::Result::kInvalid);
  EXPECT_NE(error.find("is not a chunk"), std::string::npos) << error;
}

TEST(FieldUpdates, SnapshotChunksArgument) {
  int64_t id = 0;
  std::vector<int> chunks;
  EXPECT_EQ(snapshotChunksArgument(1733490000123456, {3, 23, 43}),
            "chunks 1733490000123456 3,23,43");
  ASSERT_TRUE(parseSnapshotChunksArgument("chunks 1733490000123456 3,23,43", &id, &chunks));
  EXPECT_EQ(id, 1733490000123456);
  EXPECT_EQ(chunks, (std::vector<int>{3, 23, 43}));
  for (const char* bad :
       {"renderer", "", "chunks", "chunks 7", "chunks 7 ", "chunks -1 3", "chunks 7 3,,4",
        "chunks 7 3,x", "chunks 7 -3", "chunks 7 3 more", "snapshot 7 3"}) {
    id = 0;
    chunks.clear();
    EXPECT_FALSE(parseSnapshotChunksArgument(bad, &id, &chunks)) << bad;
    EXPECT_EQ(id, 0) << bad;
    EXPECT_TRUE(chunks.empty()) << bad;
  }
}

TEST(FieldUpdates, CatchUpRepairsAReplicaThatLostUpdates) {
  const SyntheticScene scene = tinyRoom();
  Mapper mapper(smallParams());
  mapper.addKeyframe(keyframeOf(scene, 0, 0));
  const FieldUpdate u1 = mapper.makeUpdate(0);
  mapper.train(1);
  const FieldUpdate u2 = mapper.makeUpdate(u1.version);  // lost
  mapper.train(1);
  const FieldUpdate u3 = mapper.makeUpdate(u2.version);
  std::string error;
  Field lossy, in_step;
  for (const FieldUpdate* u : {&u1, &u2, &u3})
    ASSERT_EQ(applyFieldUpdate(*u, &in_step, &error), ApplyResult::kApplied) << error;
  ASSERT_EQ(applyFieldUpdate(u1, &lossy, &error), ApplyResult::kApplied) << error;
  ASSERT_EQ(applyFieldUpdate(u3, &lossy, &error, GapPolicy::kApply), ApplyResult::kGap);
  ASSERT_EQ(lossy.version(), mapper.field().version());  // at the latest, but not exact
  ASSERT_FALSE(lossy.sameContent(mapper.field()));

  // Nothing is pending: the catch-up still takes a new version, so both replicas apply it.
  const int total = static_cast<int>(mapper.field().totalBlocks());
  const FieldUpdate catch_up = mapper.makeCatchUp(u1.version, total);
  EXPECT_EQ(catch_up.base_version, u1.version);
  EXPECT_EQ(catch_up.version, u3.version + 1);
  ASSERT_FALSE(catch_up.blocks.empty());
  EXPECT_LT(catch_up.blocks.size(), static_cast<size_t>(total));
  ASSERT_EQ(applyFieldUpdate(catch_up, &lossy, &error), ApplyResult::kApplied) << error;
  ASSERT_EQ(applyFieldUpdate(catch_up, &in_step, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(lossy.sameContent(mapper.field()));
  EXPECT_TRUE(in_step.sameContent(mapper.field()));
  // Updates go on from the catch-up's version.
  mapper.train(1);
  const FieldUpdate u4 = mapper.makeUpdate(catch_up.version);
  ASSERT_EQ(applyFieldUpdate(u4, &lossy, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(lossy.sameContent(mapper.field()));
  // More blocks changed since than one message holds: none (a snapshot is asked for then).
  const int64_t before = mapper.field().version();
  EXPECT_TRUE(mapper.makeCatchUp(0, 3).blocks.empty());
  EXPECT_EQ(mapper.field().version(), before);

  int64_t since = -1;
  EXPECT_EQ(catchUpArgument(42), "since 42");
  ASSERT_TRUE(parseCatchUpArgument("since 42", &since));
  EXPECT_EQ(since, 42);
  for (const char* bad : {"since", "since -1", "since 4x", "since 4 5", "chunks 1 2", ""}) {
    since = -1;
    EXPECT_FALSE(parseCatchUpArgument(bad, &since)) << bad;
    EXPECT_EQ(since, -1) << bad;
  }
}

TEST(FieldUpdates, StaleGapAndInvalidUpdates) {
  const SyntheticScene scene = tinyRoom();
  Mapper mapper(smallParams());
  mapper.addKeyframe(keyframeOf(scene, 0, 0));
  const FieldUpdate u1 = mapper.makeUpdate(0);
  mapper.train(1);
  const FieldUpdate u2 = mapper.makeUpdate(u1.version);
  mapper.train(1);
  const FieldUpdate u3 = mapper.makeUpdate(u2.version);
  ASSERT_FALSE(u1.blocks.empty());
  ASSERT_FALSE(u3.blocks.empty());
  Field replica;
  std::string error;
  // u3 needs u2 first.
  ASSERT_EQ(applyFieldUpdate(u1, &replica, &error), ApplyResult::kApplied) << error;
  EXPECT_EQ(applyFieldUpdate(u3, &replica, &error), ApplyResult::kGap);
  EXPECT_NE(error.find("replica is at"), std::string::npos) << error;
  ASSERT_EQ(applyFieldUpdate(u2, &replica, &error), ApplyResult::kApplied) << error;
  EXPECT_EQ(applyFieldUpdate(u2, &replica, &error), ApplyResult::kStale);
  ASSERT_EQ(applyFieldUpdate(u3, &replica, &error), ApplyResult::kApplied) << error;

  FieldUpdate bad = u3;
  bad.layout = "rsvox9 f16";
  EXPECT_EQ(applyFieldUpdate(bad, &replica, &error), ApplyResult::kInvalid);
  EXPECT_NE(error.find("layout"), std::string::npos) << error;
  bad = u3;
  bad.version += 10;
  bad.blocks[0].data.resize(7);
  EXPECT_EQ(applyFieldUpdate(bad, &replica, &error), ApplyResult::kInvalid);
  bad = u3;
  bad.version += 10;
  bad.blocks[0].level = 5;
  EXPECT_EQ(applyFieldUpdate(bad, &replica, &error), ApplyResult::kInvalid);
  bad = u3;
  bad.version += 10;
  bad.blocks[0].index.x() = INT32_MIN;  // |INT_MIN| does not exist: compared as it is
  EXPECT_EQ(applyFieldUpdate(bad, &replica, &error), ApplyResult::kInvalid);
  bad = u3;
  bad.version += 10;
  bad.block_dim = 16;
  EXPECT_EQ(applyFieldUpdate(bad, &replica, &error), ApplyResult::kInvalid);
  bad = u3;
  bad.version += 10;
  bad.voxel_size[0] *= 2;  // another geometry needs a snapshot
  EXPECT_EQ(applyFieldUpdate(bad, &replica, &error), ApplyResult::kInvalid);
  EXPECT_EQ(replica.version(), u3.version);  // unchanged by the rejected updates
}

TEST(FieldUpdates, ZstdEncodingIsLosslessSmallerAndCheckedBeforeUse) {
  const SyntheticScene scene = tinyRoom();
  Mapper mapper(smallParams());
  mapper.addKeyframe(keyframeOf(scene, 0, 0));
  mapper.addKeyframe(keyframeOf(scene, 10, 1));
  mapper.train(3);
  const FieldUpdate raw = mapper.makeUpdate(0);
  ASSERT_FALSE(raw.blocks.empty());
  FieldUpdate packed = raw;
  encodeFieldUpdate(FieldEncoding::kZstd, &packed);
  EXPECT_THROW(encodeFieldUpdate(FieldEncoding::kZstd, &packed), std::invalid_argument);
  size_t raw_bytes = 0, packed_bytes = 0;
  for (size_t i = 0; i < raw.blocks.size(); ++i) {
    raw_bytes += raw.blocks[i].data.size();
    packed_bytes += packed.blocks[i].data.size();
  }
  EXPECT_LT(packed_bytes * 2, raw_bytes);  // untouched voxels keep their initial values
  FieldEncoding encoding = FieldEncoding::kRaw;
  FieldGeometry g;
  std::string error;
  ASSERT_TRUE(parseFieldLayout(packed.layout, packed.voxel_size, &g, &error, &encoding)) << error;
  EXPECT_EQ(encoding, FieldEncoding::kZstd);
  EXPECT_TRUE(g == mapper.field().geometry());

  Field from_raw, from_packed;
  ASSERT_EQ(applyFieldUpdate(raw, &from_raw, &error), ApplyResult::kApplied) << error;
  ASSERT_EQ(applyFieldUpdate(packed, &from_packed, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(from_packed.sameContent(from_raw));
  EXPECT_TRUE(from_packed.sameContent(mapper.field()));

  // Malformed blocks are rejected before the replica changes.
  mapper.train(1);
  FieldUpdate next = mapper.makeUpdate(packed.version);
  ASSERT_FALSE(next.blocks.empty());
  FieldUpdate raw_next = next;
  encodeFieldUpdate(FieldEncoding::kZstd, &next);
  FieldUpdate bad = next;
  bad.blocks.back().data.resize(bad.blocks.back().data.size() / 2);  // truncated frame
  EXPECT_EQ(applyFieldUpdate(bad, &from_packed, &error), ApplyResult::kInvalid);
  EXPECT_NE(error.find("decompress"), std::string::npos) << error;
  bad = next;
  bad.blocks[0].data = raw_next.blocks[0].data;  // raw values where a frame belongs
  EXPECT_EQ(applyFieldUpdate(bad, &from_packed, &error), ApplyResult::kInvalid);
  EXPECT_NE(error.find("not a zstd frame"), std::string::npos) << error;
  EXPECT_EQ(from_packed.version(), packed.version);
  EXPECT_TRUE(from_packed.sameContent(from_raw));
}

TEST(FieldUpdates, LayoutRoundTripsTheGeometryExactly) {
  for (int sh : {0, 1}) {
    const FieldGeometry g = FieldGeometry::make(0.0123456789, 3, 2, sh, -4.6f);
    FieldGeometry back;
    std::string error;
    ASSERT_TRUE(parseFieldLayout(fieldLayout(g), g.voxel_size, &back, &error)) << error;
    EXPECT_TRUE(back == g) << fieldLayout(g);
  }
}

TEST(Checkpoint, RoundTripIsExactAndResumesIdentically) {
  const SyntheticScene scene = tinyRoom();
  Mapper a(smallParams());
  for (int i = 0; i < 3; ++i) a.addKeyframe(keyframeOf(scene, i * 10, i));
  a.train(8);
  ASSERT_FALSE(a.takeRefinedPoses().empty());  // poses have moved: they must round-trip
  ASSERT_NE(a.keyframes().entry(1).exposure, Vec6::Zero());  // and so have the exposures
  a.train(1);
  const std::string path = tempPath("mapper_checkpoint.bin");
  a.saveCheckpoint(path);
  Mapper b(smallParams());
  b.loadCheckpoint(path);
  EXPECT_TRUE(b.field().sameContent(a.field()));
  EXPECT_EQ(b.field().version(), a.field().version());
  EXPECT_EQ(b.field().pendingBlocks(), a.field().pendingBlocks());
  ASSERT_EQ(b.keyframes().size(), a.keyframes().size());
  for (int i = 0; i < a.keyframes().size(); ++i) {
    const KeyframeEntry& ea = a.keyframes().entry(i);
    const KeyframeEntry& eb = b.keyframes().entry(i);
    EXPECT_EQ(eb.T_world_cam.matrix(), ea.T_world_cam.matrix());
    EXPECT_EQ(eb.keyframe.T_world_cam.matrix(), ea.keyframe.T_world_cam.matrix());
    EXPECT_EQ(eb.pose_m, ea.pose_m);
    EXPECT_EQ(eb.pose_v, ea.pose_v);
    EXPECT_EQ(eb.pose_steps, ea.pose_steps);
    EXPECT_EQ(eb.exposure, ea.exposure);
    EXPECT_EQ(eb.exposure_m, ea.exposure_m);
    EXPECT_EQ(eb.exposure_v, ea.exposure_v);
    EXPECT_EQ(eb.exposure_steps, ea.exposure_steps);
    EXPECT_EQ(eb.loss_ema, ea.loss_ema);
    EXPECT_EQ(eb.rays_trained, ea.rays_trained);
    EXPECT_EQ(eb.keyframe.version, ea.keyframe.version);
    EXPECT_EQ(eb.keyframe.header.utime, ea.keyframe.header.utime);
    EXPECT_EQ(cv::norm(eb.keyframe.color, ea.keyframe.color, cv::NORM_INF), 0);
    EXPECT_EQ(cv::norm(eb.keyframe.depth_var, ea.keyframe.depth_var, cv::NORM_INF), 0);
  }
  const SparseAdam& oa = a.trainer().optimizer();
  const SparseAdam& ob = b.trainer().optimizer();
  for (int l = 0; l < a.field().numLevels(); ++l) {
    EXPECT_EQ(oa.firstMoments()[l], ob.firstMoments()[l]);
    EXPECT_EQ(oa.secondMoments()[l], ob.secondMoments()[l]);
    EXPECT_EQ(oa.steps()[l], ob.steps()[l]);
  }
  // Training on from the checkpoint is bit-identical to training on without it.
  a.train(3);
  b.train(3);
  EXPECT_TRUE(b.field().sameContent(a.field()));
  EXPECT_EQ(b.keyframes().entry(2).T_world_cam.matrix(),
            a.keyframes().entry(2).T_world_cam.matrix());

  // Without images: poses and field only.
  const std::string light = tempPath("mapper_checkpoint_light.bin");
  a.saveCheckpoint(light, false);
  Mapper c(smallParams());
  c.loadCheckpoint(light);
  EXPECT_TRUE(c.field().sameContent(a.field()));
  EXPECT_TRUE(c.keyframes().entry(1).keyframe.color.empty());
  EXPECT_EQ(c.keyframes().entry(1).T_world_cam.matrix(),
            a.keyframes().entry(1).T_world_cam.matrix());
  EXPECT_NO_THROW(c.train(1));  // nothing to draw rays from, but no crash
}

TEST(Checkpoint, BadFilesGiveErrorsNamingTheFile) {
  Mapper m;
  const std::string missing = tempPath("no_such_checkpoint.bin");
  try {
    m.loadCheckpoint(missing);
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(missing), std::string::npos) << e.what();
  }
  const std::string garbage = tempPath("garbage_checkpoint.bin");
  std::ofstream(garbage) << "this is not a checkpoint";
  EXPECT_THROW(m.loadCheckpoint(garbage), std::runtime_error);
  // Truncated: a valid checkpoint cut in half.
  const SyntheticScene scene = tinyRoom();
  Mapper a(smallParams());
  a.addKeyframe(keyframeOf(scene, 0, 0));
  a.train(1);
  const std::string path = tempPath("truncated_checkpoint.bin");
  a.saveCheckpoint(path);
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::ofstream(path, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  Mapper b(smallParams());
  b.addKeyframe(keyframeOf(scene, 0, 0));
  try {
    b.loadCheckpoint(path);
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
  }
  EXPECT_EQ(b.keyframes().size(), 1);  // a failed load leaves the mapper as it was
  EXPECT_THROW(a.saveCheckpoint("/nonexistent_dir/x.bin"), std::runtime_error);
}

TEST(KeyframeStore, HigherVersionsReplaceLowerOnesAreIgnored) {
  const SyntheticScene scene = tinyRoom();
  Mapper mapper(smallParams());
  Keyframe kf = keyframeOf(scene, 0, 7);
  kf.version = 1;
  EXPECT_EQ(mapper.addKeyframe(kf), KeyframeStore::InsertResult::kAdded);
  mapper.addKeyframe(keyframeOf(scene, 10, 8));
  Keyframe newer = keyframeOf(scene, 20, 7);  // same id, other image and pose
  newer.version = 2;
  EXPECT_EQ(mapper.addKeyframe(newer), KeyframeStore::InsertResult::kReplaced);
  EXPECT_EQ(mapper.keyframes().size(), 2);
  const KeyframeEntry& e = mapper.keyframes().entry(mapper.keyframes().find(7));
  EXPECT_EQ(e.keyframe.version, 2);
  EXPECT_EQ(e.T_world_cam.matrix(), newer.T_world_cam.matrix());
  EXPECT_EQ(cv::norm(e.keyframe.color, newer.color, cv::NORM_INF), 0);
  Keyframe older = keyframeOf(scene, 30, 7);
  older.version = 1;
  EXPECT_EQ(mapper.addKeyframe(older), KeyframeStore::InsertResult::kIgnored);
  older.version = 2;  // equal: ignored too
  EXPECT_EQ(mapper.addKeyframe(older), KeyframeStore::InsertResult::kIgnored);
  EXPECT_EQ(mapper.keyframes().entry(mapper.keyframes().find(7)).T_world_cam.matrix(),
            newer.T_world_cam.matrix());
  EXPECT_EQ(mapper.keyframes().gaugeIndex(), mapper.keyframes().find(7));
}

TEST(KeyframeStore, AReSentImageKeepsItsExposureAnotherImageStartsOver) {
  const SyntheticScene scene = tinyRoom();
  KeyframeStore store;
  Keyframe kf = keyframeOf(scene, 0, 3);
  kf.version = 1;
  store.insert(kf);
  store.entry(0).exposure << 0.1, -0.1, 0.05, 0.01, 0.02, 0.03;
  store.entry(0).exposure_steps = 40;
  kf.version = 2;  // the same image with a refined pose
  kf.T_world_cam = scene.cameraPose(1);
  ASSERT_EQ(store.insert(kf), KeyframeStore::InsertResult::kReplaced);
  EXPECT_DOUBLE_EQ(store.entry(0).exposure[0], 0.1);
  EXPECT_EQ(store.entry(0).exposure_steps, 40);
  EXPECT_EQ(store.entry(0).rays_trained, 0);
  Keyframe other = keyframeOf(scene, 5, 3);  // same id, another image
  other.version = 3;
  ASSERT_EQ(store.insert(other), KeyframeStore::InsertResult::kReplaced);
  EXPECT_EQ(store.entry(0).exposure, Vec6::Zero());
  EXPECT_EQ(store.entry(0).exposure_steps, 0);
}

TEST(Mapper, AReSentKeyframeSeedsOnlyTheBlocksItsNewDepthAdds) {
  const SyntheticScene scene = tinyRoom();
  MapperParams params = smallParams();
  params.exposure_init_stride = 0;  // no exposure fit: seeds compare bitwise
  Mapper resent(params), added(params);
  for (Mapper* m : {&resent, &added}) {
    m->addKeyframe(keyframeOf(scene, 0, 0));
    m->addKeyframe(keyframeOf(scene, 10, 1));
  }
  const Field before = resent.field();
  const int fine = before.numLevels() - 1;
  const int old_blocks = before.numBlocks(fine);
  // Version 2 of keyframe 1: the bundle adjustment moved its surfaces 6 % further away.
  Keyframe refined = keyframeOf(scene, 10, 1);
  refined.version = 2;
  refined.depth *= 1.06;
  ASSERT_EQ(resent.addKeyframe(refined), KeyframeStore::InsertResult::kReplaced);
  Keyframe as_new = refined;  // the same images as another keyframe: seeded everywhere
  as_new.keyframe_id = 2;
  ASSERT_EQ(added.addKeyframe(as_new), KeyframeStore::InsertResult::kAdded);
  const Field& a = resent.field();
  const Field& b = added.field();
  ASSERT_EQ(a.numBlocks(fine), b.numBlocks(fine));
  ASSERT_GT(a.numBlocks(fine), old_blocks);
  const size_t block_floats = size_t(Field::kBlockVoxels) * a.channels();
  auto same = [&](const Field& x, const Field& y, int block) {
    return std::memcmp(x.blockData(fine, block), y.blockData(fine, block),
                       block_floats * sizeof(float)) == 0;
  };
  int old_seeded_by_new_keyframe = 0, new_seeded = 0;
  for (int blk = 0; blk < old_blocks; ++blk) {
    EXPECT_TRUE(same(a, before, blk)) << "old block " << blk << " was seeded again";
    old_seeded_by_new_keyframe += !same(b, before, blk);
  }
  for (int blk = old_blocks; blk < a.numBlocks(fine); ++blk) {
    // The skipped pixels reach no new block: new blocks get exactly what a full seeding gives.
    EXPECT_TRUE(same(a, b, blk)) << "new block " << blk;
    const float* data = a.blockData(fine, blk);
    new_seeded += std::any_of(data, data + block_floats, [](float v) { return v != 0.f; });
  }
  EXPECT_GT(old_seeded_by_new_keyframe, 0);  // what a re-sent keyframe saves
  EXPECT_GT(new_seeded, 0);
}

TEST(KeyframeStore, RejectsMalformedKeyframesWithClearErrors) {
  const SyntheticScene scene = tinyRoom();
  KeyframeStore store;
  auto expectError = [&](const Keyframe& kf, const std::string& what) {
    try {
      store.insert(kf);
      ADD_FAILURE() << "no exception for " << what;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("keyframe 3"), std::string::npos) << e.what();
    }
  };
  Keyframe kf = keyframeOf(scene, 0, 3);
  Keyframe bad = kf;
  bad.color = cv::Mat();
  expectError(bad, "colour image is missing");
  bad = kf;
  bad.depth = cv::Mat(10, 10, CV_32FC1, cv::Scalar(1));
  expectError(bad, "depth image is 10x10");
  bad = kf;
  bad.depth_var = cv::Mat(kf.depth.size(), CV_64FC1, cv::Scalar(1));
  expectError(bad, "depth_var image has the wrong type");
  bad = kf;
  bad.camera.fx = 0;
  expectError(bad, "focal");
  bad = kf;
  bad.camera.type = CameraModel::Type::kRadTan;
  bad.camera.distortion = {0.1, 0, 0, 0};
  expectError(bad, "distortion");
  EXPECT_EQ(store.size(), 0);

  // Depth from inverse depth; bad values become unknown; caller's images untouched.
  Keyframe inv = kf;
  inv.depth = cv::Mat();
  inv.depth_var = cv::Mat();
  inv.inv_depth = cv::Mat(kf.color.size(), CV_32FC1, cv::Scalar(0.5));
  inv.inv_depth_var = cv::Mat(kf.color.size(), CV_32FC1, cv::Scalar(0.01));
  inv.inv_depth.at<float>(0, 0) = NAN;
  inv.inv_depth.at<float>(0, 1) = -1;
  const cv::Mat before = inv.inv_depth.clone();
  store.insert(inv);
  const Keyframe& stored = store.entry(0).keyframe;
  EXPECT_FLOAT_EQ(stored.depth.at<float>(5, 5), 2.f);
  EXPECT_FLOAT_EQ(stored.depth_var.at<float>(5, 5), 0.01f * 16);  // var(1/z) z^4
  EXPECT_EQ(stored.depth.at<float>(0, 0), 0.f);
  EXPECT_EQ(stored.depth.at<float>(0, 1), 0.f);
  EXPECT_EQ(cv::norm(inv.inv_depth, before, cv::NORM_INF | cv::NORM_RELATIVE), 0);
}

}  // namespace
}  // namespace radslam
