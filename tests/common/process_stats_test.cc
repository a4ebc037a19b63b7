// Memory figures, busy time and the Status a StatusReporter assembles.
#include "common/process_stats.h"

#include <unistd.h>

#include <chrono>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace radslam {
namespace {

void spin(double seconds) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
  }
}

TEST(ProcessStats, RssGrowsWithTouchedMemory) {
  const double before = currentRssMb();
  ASSERT_GT(before, 0.0) << "/proc/self/status unreadable";
  std::vector<char> block(64 << 20, 1);  // 64 MiB, written
  const double during = currentRssMb();
  EXPECT_GT(during - before, 50.0);
  EXPECT_GE(peakRssMb(), during - 1e-9);
  block.clear();
  block.shrink_to_fit();
  EXPECT_GE(peakRssMb(), during - 1e-9);  // the peak stays
}

TEST(ProcessStats, WallClockIsEpochMicroseconds) {
  const int64_t t = wallClockMicros();
  EXPECT_GT(t, 1'600'000'000'000'000);  // after 2020
  EXPECT_LT(t, 4'000'000'000'000'000);
}

TEST(ProcessStats, BusyTimerCountsOnlyBusyIntervals) {
  BusyTimer timer;
  EXPECT_EQ(timer.seconds(), 0.0);
  {
    BusyTimer::Scope scope(timer);
    EXPECT_TRUE(timer.running());
    spin(0.05);
  }
  EXPECT_FALSE(timer.running());
  std::this_thread::sleep_for(std::chrono::milliseconds(100));  // idle: not counted
  timer.start();
  timer.start();  // no effect while running
  spin(0.05);
  timer.stop();
  timer.stop();
  EXPECT_GT(timer.seconds(), 0.099);
  EXPECT_LT(timer.seconds(), 0.149);
  timer.reset();
  EXPECT_EQ(timer.seconds(), 0.0);
}

TEST(ProcessStats, ReporterFillsStatus) {
  StatusReporter reporter("tracker");
  Status s = reporter.make();
  EXPECT_EQ(s.process, "tracker");
  EXPECT_EQ(s.pid, static_cast<int32_t>(getpid()));
  EXPECT_EQ(s.state, ProcessState::kStarting);
  EXPECT_EQ(s.fps, 0.0);
  EXPECT_EQ(s.last_frame_index, -1);

  reporter.setState(ProcessState::kRunning);
  for (int i = 0; i < 5; ++i) {
    BusyTimer::Scope busy(reporter.busy());
    spin(0.01);
    reporter.itemHandled(i, 1000 * i);
  }
  reporter.itemHandled();  // an item without a frame leaves the last frame
  reporter.setQueueDepth(3);
  reporter.setValue("keyframes", 2);
  reporter.setValue("ba_cost", 0.5);
  reporter.setValue("keyframes", 3);
  reporter.setError("lost track at frame 4");
  const int64_t t0 = wallClockMicros();
  s = reporter.make();
  EXPECT_GE(s.header.utime, t0);
  EXPECT_EQ(s.state, ProcessState::kRunning);
  EXPECT_EQ(s.items_handled, 6);
  EXPECT_EQ(s.last_frame_index, 4);
  EXPECT_EQ(s.last_frame_utime, 4000);
  EXPECT_GT(s.busy_s, 0.049);
  EXPECT_NEAR(s.fps, 6 / s.busy_s, 1e-9);
  EXPECT_EQ(s.queue_depth, 3);
  EXPECT_GT(s.rss_mb, 0.0);
  EXPECT_GE(s.peak_rss_mb, s.rss_mb);
  EXPECT_EQ(s.last_error, "lost track at frame 4");
  EXPECT_EQ(s.values,
            (std::vector<std::pair<std::string, double>>{{"keyframes", 3}, {"ba_cost", 0.5}}));
}

}  // namespace
}  // namespace radslam
