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
  b.setSnapshotRequest(
      [&](const FieldReplica::SnapshotAsk& ask) { requests.push_back(ask.reason); });
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
  replica.setSnapshotRequest([&](const FieldReplica::SnapshotAsk&) { ++requests; });
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

std::unique_ptr<Mapper> untrainedDemoMapper() {
  DemoFieldOptions options;
  options.train_steps = 0;
  return makeDemoMapper(options);
}

void recordRequests(FieldReplica* replica, std::vector<FieldReplica::SnapshotAsk>* requests) {
  replica->setSnapshotRequest(
      [requests](const FieldReplica::SnapshotAsk& ask) { requests->push_back(ask); });
}

TEST(FieldReplica, LostUpdateIsRepairedByACatchUp) {
  auto mapper = untrainedDemoMapper();
  FieldReplica replica;
  std::vector<FieldReplica::SnapshotAsk> requests;
  recordRequests(&replica, &requests);
  std::string error;
  const FieldUpdate u1 = mapper->makeUpdate(0);
  mapper->train(2);
  const FieldUpdate u2 = mapper->makeUpdate(u1.version);  // lost
  mapper->train(2);
  const FieldUpdate u3 = mapper->makeUpdate(u2.version);
  ASSERT_EQ(replica.apply(u1, &error), ApplyResult::kApplied) << error;
  EXPECT_EQ(replica.apply(u3, &error), ApplyResult::kGap);
  ASSERT_EQ(requests.size(), 1u);
  EXPECT_EQ(requests[0].since_version, u1.version);  // where it was last exact
  EXPECT_TRUE(requests[0].chunks.empty());
  EXPECT_TRUE(replica.waitingForSnapshot());
  // An update based past the gap does not repair it.
  mapper->train(2);
  const FieldUpdate u4 = mapper->makeUpdate(u3.version);
  ASSERT_EQ(replica.apply(u4, &error), ApplyResult::kApplied) << error;
  EXPECT_TRUE(replica.waitingForSnapshot());
  const FieldUpdate catch_up =
      mapper->makeCatchUp(requests[0].since_version, mapper->field().totalBlocks());
  ASSERT_EQ(replica.apply(catch_up, &error), ApplyResult::kApplied) << error;
  EXPECT_FALSE(replica.waitingForSnapshot());
  EXPECT_TRUE(replica.field().sameContent(mapper->field()));
  EXPECT_EQ(requests.size(), 1u);
}

TEST(FieldReplica, ChunkedSnapshotWithLostChunksAndAStalledRequest) {
  auto mapper = untrainedDemoMapper();
  FieldReplica replica;
  std::vector<FieldReplica::SnapshotAsk> requests;
  recordRequests(&replica, &requests);
  std::string error;
  mapper->train(2);
  const FieldUpdate u1 = mapper->makeUpdate(0);
  mapper->train(2);
  const FieldUpdate u2 = mapper->makeUpdate(u1.version);
  replica.retryStalledSnapshot(100.0, 5.0);
  EXPECT_EQ(replica.apply(u2, &error), ApplyResult::kGap);  // joined late
  ASSERT_EQ(requests.size(), 1u);
  EXPECT_TRUE(requests[0].chunks.empty());  // a whole snapshot
  // No snapshot for longer than the stall time (a lost request): asked again.
  replica.retryStalledSnapshot(104.0, 5.0);
  EXPECT_EQ(requests.size(), 1u);
  replica.retryStalledSnapshot(106.0, 5.0);
  ASSERT_EQ(requests.size(), 2u);
  EXPECT_TRUE(requests[1].chunks.empty());

  // Every sixth chunk is lost: each loss is asked for as soon as a later chunk shows it.
  SnapshotSender sender = mapper->makeSnapshotSender(1, 10);
  ASSERT_GT(sender.chunkCount(), 8);
  std::vector<FieldUpdate> arrived;
  std::vector<int> lost;
  for (int i = 0; !sender.done(); ++i) {
    FieldUpdate chunk = sender.next();
    if (i % 6 == 2 || chunk.chunk_index == sender.chunkCount() - 1) {
      lost.push_back(chunk.chunk_index);
      continue;
    }
    EXPECT_EQ(replica.apply(chunk, &error), ApplyResult::kPartial) << error;
    arrived.push_back(std::move(chunk));
    mapper->train(1);  // the field changes while the chunks are on their way
  }
  EXPECT_TRUE(replica.waitingForSnapshot());
  std::vector<int> asked;
  for (size_t r = 2; r < requests.size(); ++r) {
    EXPECT_EQ(requests[r].snapshot_id, 1);
    asked.insert(asked.end(), requests[r].chunks.begin(), requests[r].chunks.end());
  }
  // The last chunk's loss shows no later chunk: only the stall asks for it.
  EXPECT_EQ(asked, std::vector<int>(lost.begin(), lost.end() - 1));
  // The chunks that arrived repaired the live field already.
  for (const FieldUpdate& chunk : arrived) {
    for (const FieldBlock& b : chunk.blocks) {
      const int id = replica.field().findBlock(b.level, b.index.x(), b.index.y(), b.index.z());
      ASSERT_GE(id, 0);
      EXPECT_EQ(std::memcmp(replica.field().blockData(b.level, id), b.data.data(), b.data.size()),
                0);
    }
  }
  const size_t before_stall = requests.size();
  replica.retryStalledSnapshot(112.0, 5.0);
  ASSERT_EQ(requests.size(), before_stall + 1);
  EXPECT_EQ(requests.back().chunks, lost);  // every missing chunk again

  // The mapper sends them again; one more is lost and asked for when the next one arrives.
  sender.resend(requests.back().chunks);
  ApplyResult last = ApplyResult::kPartial;
  for (int i = 0; !sender.done(); ++i) {
    const FieldUpdate chunk = sender.next();
    if (i == 0) {
      sender.resend({chunk.chunk_index});  // lost; the replica asks for it below
      continue;
    }
    last = replica.apply(chunk, &error);
    if (i == 1) {
      EXPECT_EQ(requests.back().chunks, std::vector<int>{lost[0]});
    }
  }
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
