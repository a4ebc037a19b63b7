// Bus over memq:// (one process) and file:// logs: typed round trips of every
// message type, prefixes, and malformed messages skipped and counted.
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/bus.h"
#include "tests/common/message_samples.h"

// Largest single operator new request, to show malformed sizes never reach an
// allocation. (cv::Mat allocates through cv::fastMalloc, which this misses;
// image sizes are checked before any Mat exists.)
static std::atomic<size_t> g_largest_new{0};

// GCC pairs the builtin new with free() when it inlines these replacements.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void* operator new(size_t n) {
  size_t seen = g_largest_new.load();
  while (n > seen && !g_largest_new.compare_exchange_weak(seen, n)) {
  }
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

namespace radslam {
namespace {

using namespace testing_samples;

// Runs handle() until pred() holds or 2 s pass.
template <class Pred>
bool handleUntil(Bus& bus, Pred pred) {
  for (int i = 0; i < 200 && !pred(); ++i) bus.handle(10);
  return pred();
}

template <class T>
struct Inbox {
  std::vector<T> got;
  void attach(Bus& bus, const std::string& channel) {
    bus.subscribe<T>(channel, [this](const T& m) { got.push_back(m); });
  }
};

TEST(Bus, ConstructorRejectsBadUrl) {
  try {
    Bus bus("bogus://nowhere", "", "test");
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()), "cannot open LCM URL 'bogus://nowhere'");
  }
}

TEST(Bus, EveryMessageTypeRoundTrips) {
  Bus bus("memq://", "T_", "tester");
  Inbox<Frame> frames;
  Inbox<PoseStamped> poses, truths;
  Inbox<Keyframe> keyframes;
  Inbox<ObjectList> objects;
  Inbox<FieldUpdate> fields;
  Inbox<RenderRequest> requests;
  Inbox<RenderResult> renders;
  Inbox<Status> statuses;
  Inbox<Control> controls;
  frames.attach(bus, channel::kCamera);
  poses.attach(bus, channel::kPose);
  truths.attach(bus, channel::kGroundTruth);
  keyframes.attach(bus, channel::kKeyframe);
  objects.attach(bus, channel::kObjects);
  fields.attach(bus, channel::kField);
  requests.attach(bus, channel::kRenderRequest);
  renders.attach(bus, channel::kRender);
  statuses.attach(bus, channel::kStatus);
  controls.attach(bus, channel::kControl);

  const Frame frame_png = sampleFrame(WireCompression::kPng);
  const Frame frame_raw = sampleFrame(WireCompression::kRaw);
  Frame frame_jpeg = sampleFrame(WireCompression::kJpeg);
  frame_jpeg.depth_wire_scale = 0.001;
  frame_jpeg.depth = cv::Mat(48, 64, CV_32FC1, cv::Scalar(1.2345f));
  EXPECT_TRUE(bus.publish(channel::kCamera, frame_png));
  EXPECT_TRUE(bus.publish(channel::kCamera, frame_raw));
  EXPECT_TRUE(bus.publish(channel::kCamera, frame_jpeg));
  PoseStamped truth = samplePoseStamped();
  truth.state = TrackingState::kGroundTruth;
  EXPECT_TRUE(bus.publish(channel::kPose, samplePoseStamped()));
  EXPECT_TRUE(bus.publish(channel::kGroundTruth, truth));
  EXPECT_TRUE(bus.publish(channel::kKeyframe, sampleKeyframe()));
  EXPECT_TRUE(bus.publish(channel::kObjects, sampleObjects()));
  EXPECT_TRUE(bus.publish(channel::kField, sampleFieldUpdate()));
  EXPECT_TRUE(bus.publish(channel::kRenderRequest, sampleRenderRequest()));
  EXPECT_TRUE(bus.publish(channel::kRender, sampleRenderResult()));
  EXPECT_TRUE(bus.publish(channel::kStatus, sampleStatus()));
  EXPECT_TRUE(bus.publish(channel::kControl, sampleControl()));

  ASSERT_TRUE(handleUntil(bus, [&] { return controls.got.size() == 1 && frames.got.size() == 3; }));
  EXPECT_EQ(bus.droppedMessages(), 0);

  // The bus writes sender and a per-channel sequence number.
  auto stamped = [](auto msg, int64_t seq) {
    msg.header.sender = "tester";
    msg.header.seq = seq;
    return msg;
  };
  ASSERT_EQ(frames.got.size(), 3u);
  expectFrameEq(stamped(frame_png, 0), frames.got[0]);
  expectFrameEq(stamped(frame_raw, 1), frames.got[1]);
  const Frame& jpeg = frames.got[2];
  EXPECT_EQ(jpeg.header.seq, 2);
  EXPECT_EQ(jpeg.color_compression, WireCompression::kJpeg);
  EXPECT_LT(cv::norm(frame_jpeg.color, jpeg.color, cv::NORM_L1) / frame_jpeg.color.total() / 3,
            2.0);
  EXPECT_LE(cv::norm(jpeg.depth, frame_jpeg.depth, cv::NORM_INF), 0.0005 + 1e-6);
  ASSERT_EQ(poses.got.size(), 1u);
  expectPoseStampedEq(stamped(samplePoseStamped(), 0), poses.got[0]);
  ASSERT_EQ(truths.got.size(), 1u);
  expectPoseStampedEq(stamped(truth, 0), truths.got[0]);
  ASSERT_EQ(keyframes.got.size(), 1u);
  expectKeyframeEq(stamped(sampleKeyframe(), 0), keyframes.got[0]);
  ASSERT_EQ(objects.got.size(), 1u);
  expectObjectsEq(stamped(sampleObjects(), 0), objects.got[0]);
  ASSERT_EQ(fields.got.size(), 1u);
  expectFieldUpdateEq(stamped(sampleFieldUpdate(), 0), fields.got[0]);
  ASSERT_EQ(requests.got.size(), 1u);
  expectRenderRequestEq(stamped(sampleRenderRequest(), 0), requests.got[0]);
  ASSERT_EQ(renders.got.size(), 1u);
  expectRenderResultEq(stamped(sampleRenderResult(), 0), renders.got[0]);
  ASSERT_EQ(statuses.got.size(), 1u);
  expectStatusEq(stamped(sampleStatus(), 0), statuses.got[0]);
  ASSERT_EQ(controls.got.size(), 1u);
  expectControlEq(stamped(sampleControl(), 0), controls.got[0]);
}

TEST(Bus, PrefixIsAppliedAndMatchedLiterally) {
  Bus bus("memq://", "run.7/", "tester");
  EXPECT_EQ(bus.fullChannel("POSE"), "run.7/POSE");
  std::vector<std::string> raw_channels;
  bus.subscribeRaw("POSE|STATUS", [&](const std::string& ch, int64_t recv_utime,
                                      const uint8_t* data, size_t size) {
    EXPECT_GT(recv_utime, 0);
    EXPECT_NE(data, nullptr);
    EXPECT_GT(size, 8u);
    raw_channels.push_back(ch);
  });
  Inbox<PoseStamped> poses;
  poses.attach(bus, "POSE");

  const std::vector<uint8_t> bytes = encode(samplePoseStamped());
  EXPECT_TRUE(bus.publishRaw("POSE", bytes.data(), bytes.size()));        // no prefix
  EXPECT_TRUE(bus.publishRaw("runX7/POSE", bytes.data(), bytes.size()));  // '.' is literal
  EXPECT_TRUE(bus.publishRaw("run.7/POSEX", bytes.data(), bytes.size()));
  EXPECT_TRUE(bus.publish("POSE", samplePoseStamped()));
  EXPECT_TRUE(bus.publish("STATUS", sampleStatus()));
  EXPECT_TRUE(bus.publish("CONTROL", sampleControl()));
  for (int i = 0; i < 20; ++i) bus.handle(5);
  EXPECT_EQ(poses.got.size(), 1u);
  EXPECT_EQ(raw_channels, (std::vector<std::string>{"run.7/POSE", "run.7/STATUS"}));
  EXPECT_EQ(bus.droppedMessages(), 0);
}

TEST(Bus, WrongTypeIsSkippedWithOneWarning) {
  Bus bus("memq://", "W_", "tester");
  Inbox<PoseStamped> poses;
  poses.attach(bus, channel::kPose);
  ::testing::internal::CaptureStderr();
  EXPECT_TRUE(bus.publish(channel::kPose, sampleStatus()));  // a Status on POSE
  EXPECT_TRUE(bus.publish(channel::kPose, samplePoseStamped()));
  ASSERT_TRUE(handleUntil(bus, [&] { return poses.got.size() == 1; }));
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(bus.droppedMessages(), 1);
  EXPECT_NE(err.find("channel W_POSE: message is not a radslam.pose_stamped_t (fingerprint "
                     "mismatch)"),
            std::string::npos)
      << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1);
}

TEST(Bus, WarningsAreRateLimitedPerChannel) {
  Bus bus("memq://", "R_", "tester");
  Inbox<Control> controls;
  controls.attach(bus, channel::kControl);
  Inbox<Status> statuses;
  statuses.attach(bus, channel::kStatus);
  const std::vector<uint8_t> junk(20, 0xab);
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 250; ++i) {
    bus.publishRaw(bus.fullChannel(channel::kControl), junk.data(), junk.size());
    if (i % 100 == 0) bus.handle(0);  // keep the memq queue short
  }
  for (int i = 0; i < 3; ++i) bus.publishRaw("R_STATUS", junk.data(), junk.size());
  while (bus.handle(0) > 0) {
  }
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(bus.droppedMessages(), 253);
  // CONTROL: 1-5, 100, 200; STATUS: 1-3.
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 10) << err;
  EXPECT_NE(err.find("200 on this channel"), std::string::npos) << err;
  EXPECT_NE(err.find("channel R_STATUS"), std::string::npos) << err;
  EXPECT_TRUE(controls.got.empty() && statuses.got.empty());
}

TEST(Bus, TruncatedMessageIsSkipped) {
  Bus bus("memq://", "", "tester");
  Inbox<Keyframe> keyframes;
  keyframes.attach(bus, channel::kKeyframe);
  const std::vector<uint8_t> bytes = encode(sampleKeyframe());
  ::testing::internal::CaptureStderr();
  EXPECT_TRUE(bus.publishRaw(channel::kKeyframe, bytes.data(), bytes.size() / 2));
  EXPECT_TRUE(bus.publishRaw(channel::kKeyframe, bytes.data(), 3));
  EXPECT_TRUE(bus.publishRaw(channel::kKeyframe, bytes.data(), bytes.size()));
  ASSERT_TRUE(handleUntil(bus, [&] { return keyframes.got.size() == 1; }));
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(bus.droppedMessages(), 2);
  EXPECT_NE(err.find("channel KEYFRAME: malformed radslam.keyframe_t"), std::string::npos) << err;
  EXPECT_NE(err.find("channel KEYFRAME: truncated radslam.keyframe_t (3 bytes"), std::string::npos)
      << err;
  expectKeyframeEq(keyframes.got[0], sampleKeyframe());
}

TEST(Bus, AbsurdSizesAreRejectedWithoutAllocating) {
  struct Case {
    std::vector<uint8_t> bytes;
    std::string expected;
  };
  const std::vector<uint8_t> pixels(12, 7);
  std::vector<Case> cases = {
      // Width of a million pixels with a consistent-looking payload.
      {craftRender(1000000, 1000000, 1, 0, 12, pixels),
       "color: image size 1000000x1000000 outside"},
      // size field 2^31-1 with only 12 bytes behind it.
      {craftRender(2, 2, 1, 0, 2147483647, pixels), "or an array or string length exceeds"},
      // Negative size field.
      {craftRender(2, 2, 1, 0, -5, pixels), "or an array or string length exceeds"},
  };
  {  // A string claiming 2 GB.
    LcmWriter w;
    w.raw(fingerprintOf<Status>());
    w.i64(1);
    w.i64(2);
    w.i32(2147483647);
    w.raw(std::vector<uint8_t>(40, 'x'));
    cases.push_back({w.bytes, "or an array or string length exceeds"});
  }
  {  // An object count of 2^31-1.
    LcmWriter w;
    w.raw(fingerprintOf<ObjectList>());
    w.i64(1);
    w.i64(2);
    w.str("x");
    w.i64(3);
    w.i32(2147483647);
    cases.push_back({w.bytes, "or an array or string length exceeds"});
  }

  // Directly through decode: no allocation near the claimed sizes.
  for (const Case& c : cases) {
    std::string error;
    bool ok = true;
    RenderResult render;
    Status status;
    ObjectList objects;
    const std::vector<uint8_t> fp(c.bytes.begin(), c.bytes.begin() + 8);
    if (fp == fingerprintOf<RenderResult>()) {
      g_largest_new = 0;
      ok = decode(c.bytes.data(), c.bytes.size(), &render, &error);
    } else if (fp == fingerprintOf<Status>()) {
      g_largest_new = 0;
      ok = decode(c.bytes.data(), c.bytes.size(), &status, &error);
    } else {
      g_largest_new = 0;
      ok = decode(c.bytes.data(), c.bytes.size(), &objects, &error);
    }
    EXPECT_FALSE(ok);
    EXPECT_LT(g_largest_new.load(), 4096u) << error;
    EXPECT_NE(error.find(c.expected), std::string::npos)
        << "expected '" << c.expected << "' in '" << error << "'";
  }

  {  // Control: a genuine keyframe does allocate its 40x30 float payloads.
    const std::vector<uint8_t> bytes = encode(sampleKeyframe());
    Keyframe keyframe;
    g_largest_new = 0;
    ASSERT_TRUE(decode(bytes.data(), bytes.size(), &keyframe, nullptr));
    EXPECT_GE(g_largest_new.load(), 40u * 30u * 4u);
  }

  // And over the bus: skipped, counted, the bus keeps working.
  Bus bus("memq://", "A_", "tester");
  Inbox<RenderResult> renders;
  renders.attach(bus, channel::kRender);
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 3; ++i) {
    bus.publishRaw("A_RENDER", cases[static_cast<size_t>(i)].bytes.data(),
                   cases[static_cast<size_t>(i)].bytes.size());
  }
  bus.publish(channel::kRender, sampleRenderResult());
  ASSERT_TRUE(handleUntil(bus, [&] { return renders.got.size() == 1; }));
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(bus.droppedMessages(), 3);
  EXPECT_NE(err.find("image size 1000000x1000000 outside [0, 16384]"), std::string::npos) << err;
}

TEST(Bus, NanPoseIsRejected) {
  Bus bus("memq://", "", "tester");
  Inbox<PoseStamped> poses;
  poses.attach(bus, channel::kPose);
  PoseStamped bad = samplePoseStamped();
  bad.T_world_cam.translation().x() = std::nan("");
  ::testing::internal::CaptureStderr();
  EXPECT_TRUE(bus.publish(channel::kPose, bad));
  EXPECT_TRUE(bus.publish(channel::kPose, samplePoseStamped()));
  ASSERT_TRUE(handleUntil(bus, [&] { return poses.got.size() == 1; }));
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(bus.droppedMessages(), 1);
  EXPECT_NE(err.find("T_world_cam: position is not finite"), std::string::npos) << err;
  EXPECT_EQ(poses.got[0].header.seq, 1);  // the bad one used seq 0
}

TEST(Bus, HandlerExceptionPropagatesFromHandle) {
  Bus bus("memq://", "", "tester");
  int calls = 0;
  bus.subscribe<Control>(channel::kControl, [&](const Control&) {
    if (++calls == 1) throw std::runtime_error("handler failed");
  });
  bus.publish(channel::kControl, sampleControl());
  bus.publish(channel::kControl, sampleControl());
  EXPECT_THROW(handleUntil(bus, [&] { return calls > 0; }), std::runtime_error);
  EXPECT_TRUE(handleUntil(bus, [&] { return calls == 2; }));
}

TEST(Bus, HandleTimesOutWithNothingToDo) {
  Bus bus("memq://", "", "tester");
  Inbox<Status> statuses;
  statuses.attach(bus, channel::kStatus);
  EXPECT_EQ(bus.handle(0), 0);
  EXPECT_EQ(bus.handle(20), 0);
  for (int i = 0; i < 4; ++i) bus.publish(channel::kStatus, sampleStatus());
  EXPECT_EQ(bus.handle(100), 4);  // the queued messages are drained in one call
  EXPECT_EQ(statuses.got.size(), 4u);
}

TEST(Bus, FaultInjectionDropsTheGivenFractionOfAChannel) {
  ASSERT_EQ(setenv("RADSLAM_DROP", "STATUS=0.05", 1), 0);
  Bus bus("memq://", "", "tester");
  unsetenv("RADSLAM_DROP");
  Inbox<Status> statuses;
  Inbox<Control> controls;
  statuses.attach(bus, channel::kStatus);
  controls.attach(bus, channel::kControl);
  constexpr int kSent = 2000;
  for (int i = 0; i < kSent; ++i) {
    EXPECT_TRUE(bus.publish(channel::kStatus, sampleStatus()));
    EXPECT_TRUE(bus.publish(channel::kControl, Control{}));
    while (bus.handle(0) > 0) {
    }
  }
  EXPECT_EQ(controls.got.size(), size_t{kSent});  // other channels untouched
  const int lost = kSent - static_cast<int>(statuses.got.size());
  EXPECT_EQ(lost, kSent / 20);  // the 10th, 30th, ...
  EXPECT_EQ(statuses.got[8].header.seq, 8);
  EXPECT_EQ(statuses.got[9].header.seq, 10);
  // A lost message keeps its sequence number: receivers count the gaps.
  int64_t gaps = statuses.got.front().header.seq;
  for (size_t i = 1; i < statuses.got.size(); ++i)
    gaps += statuses.got[i].header.seq - statuses.got[i - 1].header.seq - 1;
  gaps += kSent - 1 - statuses.got.back().header.seq;
  EXPECT_EQ(gaps, lost);
  ASSERT_EQ(setenv("RADSLAM_DROP", "STATUS=2", 1), 0);
  EXPECT_THROW(Bus("memq://", "", "tester"), std::runtime_error);
  ASSERT_EQ(setenv("RADSLAM_DROP", "STATUS", 1), 0);
  EXPECT_THROW(Bus("memq://", "", "tester"), std::runtime_error);
  unsetenv("RADSLAM_DROP");
}

// Processes on one host: multicast on loopback, with keyframes large enough to
// be fragmented (LCM splits messages over 65,499 bytes).
TEST(Bus, UdpmDeliversFragmentedMessages) {
  const std::string url = "udpm://239.255.76.67:7669?ttl=0&recv_buf_size=8388608";
  std::optional<Bus> bus;
  try {
    bus.emplace(url, "U" + std::to_string(getpid()) + "_", "tester");
  } catch (const std::runtime_error& e) {
    GTEST_SKIP() << "no multicast here (" << e.what()
                 << "); in a fresh network namespace: ip link set lo up; "
                    "ip route add 224.0.0.0/4 dev lo";
  }
  Inbox<Keyframe> keyframes;
  keyframes.attach(*bus, channel::kKeyframe);
  Keyframe k = sampleKeyframe();
  k.inv_depth = randomImage(320, 240, CV_32FC1, 5);  // 300 kB: 5 fragments
  k.color = cv::Mat();
  k.inv_depth_var = k.depth = k.depth_var = k.dynamic_mask = cv::Mat();
  k.camera.width = 320;
  k.camera.height = 240;
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(bus->publish(channel::kKeyframe, k));
  ASSERT_TRUE(handleUntil(*bus, [&] { return keyframes.got.size() == 3; }));
  EXPECT_EQ(keyframes.got[2].header.seq, 2);
  EXPECT_TRUE(sameImage(keyframes.got[2].inv_depth, k.inv_depth));
  EXPECT_EQ(bus->droppedMessages(), 0);
}

TEST(Bus, FileLogReplayDeliversTheSameBytes) {
  std::string dir_template = ::testing::TempDir() + "radslam_bus_XXXXXX";
  ASSERT_NE(mkdtemp(dir_template.data()), nullptr);
  const std::string log = dir_template + "/run.lcmlog";

  std::vector<std::pair<std::string, std::vector<uint8_t>>> sent;
  {
    Bus writer("file://" + log + "?mode=w", "L_", "player");
    Frame frame = sampleFrame(WireCompression::kPng);
    for (int i = 0; i < 3; ++i) {
      frame.frame_index = i;
      ASSERT_TRUE(writer.publish(channel::kCamera, frame));
      Frame stamped = frame;
      stamped.header.sender = "player";
      stamped.header.seq = i;
      sent.emplace_back("L_CAMERA", encode(stamped));
      PoseStamped truth = samplePoseStamped();
      truth.frame_index = i;
      ASSERT_TRUE(writer.publish(channel::kGroundTruth, truth));
      truth.header.sender = "player";
      truth.header.seq = i;
      sent.emplace_back("L_GROUND_TRUTH", encode(truth));
    }
  }

  Bus reader("file://" + log + "?speed=0", "L_", "reader");
  std::vector<std::pair<std::string, std::vector<uint8_t>>> received;
  reader.subscribeRaw(".*", [&](const std::string& ch, int64_t, const uint8_t* data, size_t size) {
    received.emplace_back(ch, std::vector<uint8_t>(data, data + size));
  });
  Inbox<Frame> frames;
  frames.attach(reader, channel::kCamera);
  for (int i = 0; i < 1000 && received.size() < sent.size(); ++i) {
    if (reader.handle(50) < 0) break;  // end of the log
  }
  ASSERT_EQ(received.size(), sent.size());
  for (size_t i = 0; i < sent.size(); ++i) {
    EXPECT_EQ(received[i].first, sent[i].first);
    EXPECT_TRUE(received[i].second == sent[i].second) << "message " << i << " differs";
  }
  ASSERT_EQ(frames.got.size(), 3u);
  EXPECT_EQ(frames.got[2].frame_index, 2);
  EXPECT_EQ(reader.droppedMessages(), 0);
  std::remove(log.c_str());
  rmdir(dir_template.c_str());
}

}  // namespace
}  // namespace radslam
