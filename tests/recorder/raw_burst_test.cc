// The recorder's raw subscription keeps a burst that arrives while it is busy: over udpm,
// LCM queues at most 30 messages per subscription by default and drops the rest, which lost
// the tracker's final poses behind its keyframes. Skips when multicast is unavailable.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <thread>

#include "common/bus.h"

namespace radslam {
namespace {

TEST(RawBurst, AllMessagesOfABurstPublishedWhileNotHandlingArrive) {
  const int port = 7900 + static_cast<int>(getpid() % 90);
  const std::string url =
      "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0&recv_buf_size=8388608";
  Bus publisher(url, "BURST_", "publisher");
  Bus recorder(url, "BURST_", "recorder");
  int received = 0;
  int64_t last_index = -1;
  bool in_order = true;
  bool probes_seen = false;
  recorder.subscribeRaw("DATA", [&](const std::string&, int64_t, const uint8_t* data, size_t) {
    int64_t index = 0;
    std::memcpy(&index, data, sizeof(index));
    if (index < 0) {  // the probe (LCM may hand over a late copy of it)
      probes_seen = true;
      return;
    }
    in_order = in_order && index == last_index + 1;
    last_index = index;
    ++received;
  });
  // Multicast may be unusable here (no route): probe once.
  std::vector<uint8_t> probe(8, 0);
  int64_t probe_index = -1;
  std::memcpy(probe.data(), &probe_index, sizeof(probe_index));
  if (!publisher.publishRaw("BURST_DATA", probe.data(), probe.size()))
    GTEST_SKIP() << "cannot publish on " << url << " (multicast unavailable here?)";
  for (int i = 0; i < 40 && !probes_seen; ++i) recorder.handle(50);
  if (!probes_seen) GTEST_SKIP() << "nothing received on " << url << " (multicast unavailable)";

  // A burst of 300 messages (1 kB each, 300 kB in all: within the socket buffer) while the
  // subscriber is not dispatching, as when the recorder writes a large keyframe.
  const int burst = 300;
  std::vector<uint8_t> data(1000, 0x5a);
  for (int64_t i = 0; i < burst; ++i) {
    std::memcpy(data.data(), &i, sizeof(i));
    ASSERT_TRUE(publisher.publishRaw("BURST_DATA", data.data(), data.size()));
  }
  // Let LCM's receive thread take them all off the socket before the first dispatch.
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (received < burst && std::chrono::steady_clock::now() < deadline) recorder.handle(50);
  EXPECT_EQ(received, burst);
  EXPECT_TRUE(in_order);
}

}  // namespace
}  // namespace radslam
