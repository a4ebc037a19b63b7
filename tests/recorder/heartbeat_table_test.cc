#include "recorder/heartbeat_table.h"

#include <gtest/gtest.h>

#include <sstream>

namespace radslam {
namespace {

Status statusOf(const std::string& process, int32_t pid, ProcessState state) {
  Status s;
  s.process = process;
  s.pid = pid;
  s.state = state;
  s.items_handled = 7;
  s.fps = 2.5;
  return s;
}

TEST(HeartbeatTable, AgesByLocalReceiveTime) {
  HeartbeatTable table;
  Status s = statusOf("mapper", 42, ProcessState::kRunning);
  s.header.utime = 1;  // a sender clock far in the past must not matter
  table.onStatus(s, 10.0);
  EXPECT_DOUBLE_EQ(table.ageOf("mapper", 12.5), 2.5);
  EXPECT_LT(table.ageOf("renderer", 12.5), 0.0);
}

TEST(HeartbeatTable, SilentListsOnlyProcessesPastTheThresholdThatAreNotDone) {
  HeartbeatTable table;
  table.onStatus(statusOf("mapper", 1, ProcessState::kRunning), 0.0);
  table.onStatus(statusOf("player", 2, ProcessState::kDone), 0.0);
  table.onStatus(statusOf("renderer", 3, ProcessState::kRunning), 4.0);
  const std::vector<std::string> silent = table.silent(6.0, 5.0);
  ASSERT_EQ(silent.size(), 1u);
  EXPECT_EQ(silent[0], "mapper");
  // A new heartbeat (e.g. from a restarted process) clears it and replaces the pid.
  table.onStatus(statusOf("mapper", 99, ProcessState::kStarting), 6.0);
  EXPECT_TRUE(table.silent(6.0, 5.0).empty());
  EXPECT_EQ(table.entries().at("mapper").pid, 99);
  EXPECT_EQ(table.entries().at("mapper").heartbeats, 2);
}

TEST(HeartbeatTable, TableHasOneFixedFieldLinePerProcess) {
  HeartbeatTable table;
  table.onStatus(statusOf("tracker", 5, ProcessState::kRunning), 1.0);
  table.onStatus(statusOf("bad name", 6, ProcessState::kError), 2.0);
  std::istringstream in(table.table(3.0));
  std::string line;
  std::vector<std::string> lines;
  while (std::getline(in, line)) lines.push_back(line);
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0], "bad_name 6 error 1.0 1 7 2.50");
  EXPECT_EQ(lines[1], "tracker 5 running 2.0 1 7 2.50");
}

TEST(HeartbeatTable, IgnoresStatusWithoutProcessName) {
  HeartbeatTable table;
  table.onStatus(statusOf("", 1, ProcessState::kRunning), 0.0);
  EXPECT_TRUE(table.entries().empty());
}

}  // namespace
}  // namespace radslam
