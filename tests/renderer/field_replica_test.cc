#include "renderer/field_replica.h"

#include <gtest/gtest.h>
#include <cstring>

#include <opencv2/core.hpp>

#include "mapper/field_io.h"
#include "renderer/demo_field.h"

namespace radslam {
namespace {

bool identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  const size_t bytes = a.total() * a.elemSize();
  return std::memcmp(a.ptr(), b.ptr(), bytes) == 0;  // bitwise, NaN-safe
}

void expectSameImages(const RenderImages& a, const RenderImages& b) {
  EXPECT_TRUE(identical(a.color, b.color));
  EXPECT_TRUE(identical(a.depth, b.depth));
  EXPECT_TRUE(identical(a.sigma, b.sigma));
  EXPECT_TRUE(identical(a.weight, b.weight));
}

CameraModel viewCamera() {
  CameraModel c;
  c.width = 96;
  c.height = 72;
  c.fx = c.fy = 80;
  c.cx = 47.5;
  c.cy = 35.5;
  return c;
}

TEST(FieldReplica, RendersExactlyWhatTheMapperRenders) {
  DemoFieldOptions options;
  options.train_steps = 5;
  std::vector<Keyframe> keyframes;
  auto mapper = makeDemoMapper(options, &keyframes);
  FieldReplica replica;
  std::string error;
  ASSERT_EQ(replica.apply(mapper->makeUpdate(0), &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(replica.field().sameContent(mapper->field()));
  ASSERT_GT(cv::countNonZero(mapper->render(keyframes[1].T_world_cam, viewCamera()).weight), 100);
  // A keyframe's pose and a pose off the training path.
  const SE3 off =
      keyframes[1].T_world_cam * SE3::exp((Vec6() << 0.1, -0.05, 0.1, 0.05, 0.1, 0).finished());
  for (const SE3& T : {keyframes[1].T_world_cam, off}) {
    expectSameImages(replica.render(T, viewCamera()), mapper->render(T, viewCamera()));
  }
}

TEST(FieldReplica, LateJoinerConvergesThroughASnapshot) {
  DemoFieldOptions options;
  options.train_steps = 0;
  auto mapper = makeDemoMapper(options);
  // Updates 1..n, each after a few training steps; a snapshot at k.
  const int n = 5, k = 2;
  std::vector<FieldUpdate> updates;
  FieldUpdate snapshot;
  int64_t version = 0;
  for (int i = 1; i <= n; ++i) {
    mapper->train(2);
    updates.push_back(mapper->makeUpdate(version));
    ASSERT_FALSE(updates.back().blocks.empty());
    version = updates.back().version;
    if (i == k) snapshot = mapper->makeSnapshot();
  }
  ASSERT_TRUE(snapshot.is_snapshot);
  ASSERT_EQ(snapshot.version, updates[k - 1].version);

  FieldReplica a;
  std::string error;
  for (const FieldUpdate& u : updates)
    ASSERT_EQ(a.apply(u, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(a.field().sameContent(mapper->field()));

  FieldReplica b;
  std::vector<std::string> requests;
  b.setSnapshotRequest([&](const std::string& why) { requests.push_back(why); });
  // Joins late: update k - 1 skips the earlier ones; its blocks are shown all the same and the
  // updates that follow it apply, but only the snapshot makes the replica exact.
  EXPECT_EQ(b.apply(updates[k - 1], &error), ApplyResult::kGap);
  EXPECT_EQ(b.version(), updates[k - 1].version);
  EXPECT_EQ(b.apply(updates[k], &error), ApplyResult::kApplied) << error;
  ASSERT_EQ(requests.size(), 1u);  // asked once until the snapshot arrives
  EXPECT_TRUE(b.waitingForSnapshot());
  EXPECT_FALSE(b.field().sameContent(mapper->field()));
  EXPECT_EQ(b.apply(snapshot, &error), ApplyResult::kApplied) << error;
  EXPECT_FALSE(b.waitingForSnapshot());
  EXPECT_EQ(b.version(), snapshot.version);
  for (int i = k; i < n; ++i)
    ASSERT_EQ(b.apply(updates[i], &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(b.field().sameContent(a.field()));
  EXPECT_EQ(b.version(), a.version());
  // Old updates are stale, not errors.
  EXPECT_EQ(b.apply(updates[0], &error), ApplyResult::kStale);
  const SE3 T = SE3::exp((Vec6() << 0, 0, -0.2, 0, 0, 0).finished());
  expectSameImages(a.render(T, viewCamera()), b.render(T, viewCamera()));
}

TEST(FieldReplica, GapInTheMiddleAppliesTheBlocksAndAsksForASnapshot) {
  DemoFieldOptions options;
  options.train_steps = 0;
  auto mapper = makeDemoMapper(options);
  FieldReplica replica;
  int requests = 0;
  replica.setSnapshotRequest([&](const std::string&) { ++requests; });
  std::string error;
  const FieldUpdate u1 = mapper->makeUpdate(0);
  mapper->train(2);
  const FieldUpdate u2 = mapper->makeUpdate(u1.version);
  mapper->train(2);
  const FieldUpdate u3 = mapper->makeUpdate(u2.version);
  ASSERT_EQ(replica.apply(u1, &error), ApplyResult::kApplied);
  EXPECT_EQ(replica.apply(u3, &error), ApplyResult::kGap);  // u2 lost
  EXPECT_EQ(requests, 1);
  EXPECT_FALSE(error.empty());
  // u3's blocks are in (each carries its whole state); those only u2 changed are stale.
  EXPECT_EQ(replica.version(), u3.version);
  for (const FieldBlock& b : u3.blocks) {
    const int id = replica.field().findBlock(b.level, b.index.x(), b.index.y(), b.index.z());
    ASSERT_GE(id, 0);
    EXPECT_EQ(std::memcmp(replica.field().blockData(b.level, id), b.data.data(), b.data.size()), 0);
  }
  ASSERT_EQ(replica.apply(mapper->makeSnapshot(), &error), ApplyResult::kApplied);
  EXPECT_TRUE(replica.field().sameContent(mapper->field()));
}

TEST(FieldReplica, ChunkedSnapshotAfterALostChunkAndAStalledRequest) {
  DemoFieldOptions options;
  options.train_steps = 0;
  auto mapper = makeDemoMapper(options);
  FieldReplica replica;
  std::vector<std::string> requests;
  replica.setSnapshotRequest([&](const std::string& why) { requests.push_back(why); });
  std::string error;
  mapper->train(2);
  const FieldUpdate u1 = mapper->makeUpdate(0);
  mapper->train(2);
  const FieldUpdate u2 = mapper->makeUpdate(u1.version);
  replica.retryStalledSnapshot(100.0, 15.0);
  EXPECT_EQ(replica.apply(u2, &error), ApplyResult::kGap);  // joined late
  ASSERT_EQ(requests.size(), 1u);
  // The first snapshot loses a chunk: the replica asks for the next one at once.
  SnapshotSender lossy = mapper->makeSnapshotSender(1, 20);
  ASSERT_GT(lossy.chunkCount(), 2);
  const FieldUpdate first = lossy.next();
  EXPECT_EQ(replica.apply(first, &error), ApplyResult::kPartial);
  lossy.next();
  const FieldUpdate third = lossy.next();
  EXPECT_EQ(replica.apply(third, &error), ApplyResult::kGap);
  EXPECT_TRUE(replica.waitingForSnapshot());
  EXPECT_EQ(requests.size(), 2u);
  // The chunks that arrived repaired the live field all the same.
  for (const FieldUpdate* chunk : {&first, &third}) {
    for (const FieldBlock& b : chunk->blocks) {
      const int id = replica.field().findBlock(b.level, b.index.x(), b.index.y(), b.index.z());
      ASSERT_GE(id, 0);
      EXPECT_EQ(std::memcmp(replica.field().blockData(b.level, id), b.data.data(), b.data.size()),
                0);
    }
  }
  // No snapshot for longer than the stall time (a lost request): asked again.
  replica.retryStalledSnapshot(110.0, 15.0);
  EXPECT_EQ(requests.size(), 2u);
  replica.retryStalledSnapshot(130.0, 15.0);
  EXPECT_EQ(requests.size(), 3u);
  // A complete snapshot, then the update since its version: the mapper's field exactly.
  SnapshotSender sender = mapper->makeSnapshotSender(2, 20);
  ApplyResult last = ApplyResult::kPartial;
  while (!sender.done()) last = replica.apply(sender.next(), &error);
  EXPECT_EQ(last, ApplyResult::kApplied) << error;
  EXPECT_FALSE(replica.waitingForSnapshot());
  mapper->train(2);
  ASSERT_EQ(replica.apply(mapper->makeUpdate(sender.version()), &error), ApplyResult::kApplied)
      << error;
  EXPECT_TRUE(replica.field().sameContent(mapper->field()));
  // A replica in step ignores the chunks of a snapshot someone else asked for.
  SnapshotSender other = mapper->makeSnapshotSender(3, 20);
  EXPECT_EQ(replica.apply(other.next(), &error), ApplyResult::kStale);
}

TEST(FieldReplica, MalformedUpdateIsRejectedAndEmptyReplicaRendersBackground) {
  FieldReplica replica;
  FieldUpdate bad;
  bad.version = 1;
  bad.layout = "not a layout";
  bad.voxel_size = {0.1};
  bad.block_dim = 8;
  bad.blocks.resize(1);
  std::string error;
  EXPECT_EQ(replica.apply(bad, &error), ApplyResult::kInvalid);
  EXPECT_FALSE(error.empty());
  const RenderImages r = replica.render(SE3(), viewCamera());
  EXPECT_EQ(r.color.size(), cv::Size(96, 72));
  EXPECT_EQ(cv::countNonZero(r.depth), 0);
  CameraModel zero;
  EXPECT_THROW(replica.render(SE3(), zero), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
