// The real executables end to end through file:// LCM URLs (deterministic, no
// network): play -> log, log -> replay reproduces it byte for byte, the
// recorder re-records and exports it, lcm-logplayer replays the recording,
// and bad input ends with a clear message and exit code 2.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/bus.h"
#include "common/lcm_log.h"
#include "common/synthetic.h"

namespace radslam {
namespace {

namespace fs = std::filesystem;

const std::string kBin = RADSLAM_BINARY_DIR "/bin/";

struct CommandResult {
  int exit_code = -1;
  std::string output;  // stdout + stderr
};

CommandResult runCommand(const std::string& command) {
  CommandResult result;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return result;
  char buffer[4096];
  while (size_t n = fread(buffer, 1, sizeof(buffer), pipe)) result.output.append(buffer, n);
  const int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

std::vector<LogEvent> readLog(const std::string& path) {
  std::vector<LogEvent> events;
  LogReader reader(path);
  while (auto event = reader.next()) events.push_back(std::move(*event));
  return events;
}

// The player's own STATUS heartbeats differ between runs; everything else is data.
std::vector<LogEvent> withoutStatus(std::vector<LogEvent> events) {
  events.erase(std::remove_if(events.begin(), events.end(),
                              [](const LogEvent& e) { return e.channel == "STATUS"; }),
               events.end());
  return events;
}

size_t countChannel(const std::vector<LogEvent>& events, const std::string& channel) {
  size_t n = 0;
  for (const auto& e : events) n += e.channel == channel;
  return n;
}

class PlayRecordTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = ::testing::TempDir() + "/play_record_test";
    fs::remove_all(root_);
    fs::create_directories(root_);
    SyntheticConfig config;
    config.scene = "room";
    config.frames = 10;
    config.width = 128;
    config.height = 96;
    generateSyntheticDataset(config, root_ + "/data");
  }
  static std::string root_;
};
std::string PlayRecordTest::root_;

TEST_F(PlayRecordTest, PlayReplayRecordAreByteExact) {
  const std::string played = root_ + "/played.lcmlog";
  CommandResult play = runCommand(kBin + "radslam-play --dataset synthetic:" + root_ +
                                  "/data --rate 0 --url 'file://" + played + "?mode=w'");
  ASSERT_EQ(play.exit_code, 0) << play.output;
  const std::vector<LogEvent> original = withoutStatus(readLog(played));
  EXPECT_EQ(countChannel(original, "CAMERA"), 10u);
  EXPECT_EQ(countChannel(original, "GROUND_TRUTH"), 10u);

  // Replaying the log reproduces every message byte for byte.
  const std::string replayed = root_ + "/replayed.lcmlog";
  CommandResult replay =
      runCommand(kBin + "radslam-play --dataset log:" + played + " --rate 0 --log-channels '.*'" +
                 " --url 'file://" + replayed + "?mode=w'");
  ASSERT_EQ(replay.exit_code, 0) << replay.output;
  const std::vector<LogEvent> copy = withoutStatus(readLog(replayed));
  ASSERT_EQ(copy.size(), original.size());
  for (size_t i = 0; i < copy.size(); ++i) {
    EXPECT_EQ(copy[i].channel, original[i].channel);
    EXPECT_EQ(copy[i].data, original[i].data) << "event " << i;
  }

  // The recorder records what it hears and exports the run folder.
  const std::string run = root_ + "/run";
  CommandResult record =
      runCommand(kBin + "radslam-record --url 'file://" + played + "?speed=0' --out " + run);
  ASSERT_EQ(record.exit_code, 0) << record.output;
  EXPECT_NE(record.output.find("frames played          10"), std::string::npos) << record.output;
  const std::vector<LogEvent> recorded = readLog(run + "/run.lcmlog");
  EXPECT_EQ(countChannel(recorded, "CAMERA"), 10u);
  for (const auto& event : recorded) {
    if (event.channel != "CAMERA") continue;
    bool found = false;
    for (const auto& o : original) found |= o.channel == "CAMERA" && o.data == event.data;
    EXPECT_TRUE(found) << "a recorded CAMERA message differs from the played one";
  }
  EXPECT_TRUE(fs::exists(run + "/summary.json"));
  EXPECT_TRUE(fs::exists(run + "/summary.txt"));
  EXPECT_EQ(readTumTrajectory(run + "/groundtruth.txt").size(), 10u);

  // lcm-logplayer (LCM's own tool) replays the recorded log.
  const std::string relayed = root_ + "/relayed.lcmlog";
  CommandResult logplayer =
      runCommand("lcm-logplayer -s 1000 -l 'file://" + relayed + "?mode=w' " + run + "/run.lcmlog");
  ASSERT_EQ(logplayer.exit_code, 0) << logplayer.output;
  EXPECT_EQ(countChannel(readLog(relayed), "CAMERA"), 10u);

  // Decoding a played frame gives back the dataset's images exactly (PNG).
  Frame frame;
  std::string error;
  for (const auto& e : original) {
    if (e.channel != "CAMERA") continue;
    ASSERT_TRUE(decode(e.data.data(), e.data.size(), &frame, &error)) << error;
    break;
  }
  EXPECT_EQ(frame.color.cols, 128);
  EXPECT_EQ(frame.frame_index, 0);
}

TEST_F(PlayRecordTest, ARestartedRecorderContinuesItsLogAndExports) {
  const std::string played = root_ + "/played_for_resume.lcmlog";
  ASSERT_EQ(runCommand(kBin + "radslam-play --dataset synthetic:" + root_ +
                       "/data --rate 0 --url 'file://" + played + "?mode=w'")
                .exit_code,
            0);
  // The bus as two halves: what the first recorder heard before it was killed, and the rest.
  const std::vector<LogEvent> all = readLog(played);
  const std::string first = root_ + "/first_half.lcmlog", second = root_ + "/second_half.lcmlog";
  {
    LogWriter a(first), b(second);
    for (size_t i = 0; i < all.size(); ++i)
      (i < all.size() / 2 ? a : b)
          .write(all[i].utime, all[i].channel, all[i].data.data(), all[i].data.size());
  }
  const std::string run = root_ + "/resumed_run";
  CommandResult before =
      runCommand(kBin + "radslam-record --url 'file://" + first + "?speed=0' --out " + run);
  ASSERT_EQ(before.exit_code, 0) << before.output;
  // Killed while writing an event: a torn tail (magic and part of a header).
  const size_t complete = fs::file_size(run + "/run.lcmlog");
  {
    std::ofstream torn(run + "/run.lcmlog", std::ios::binary | std::ios::app);
    torn.write("\xED\xA1\xDA\x01\x00\x00\x00", 7);
  }
  CommandResult after = runCommand(kBin + "radslam-record --url 'file://" + second +
                                   "?speed=0' --out " + run + " --resume");
  ASSERT_EQ(after.exit_code, 0) << after.output;
  EXPECT_NE(after.output.find("resuming"), std::string::npos) << after.output;
  EXPECT_NE(after.output.find("frames played          10"), std::string::npos) << after.output;
  EXPECT_EQ(readTumTrajectory(run + "/groundtruth.txt").size(), 10u);
  // Everything heard before and after, in order, the torn tail cut.
  const std::vector<LogEvent> recorded = withoutStatus(readLog(run + "/run.lcmlog"));
  const std::vector<LogEvent> expected = withoutStatus(all);
  ASSERT_EQ(recorded.size(), expected.size());
  for (size_t i = 0; i < recorded.size(); ++i) {
    EXPECT_EQ(recorded[i].channel, expected[i].channel) << i;
    EXPECT_EQ(recorded[i].data, expected[i].data) << i;
  }
  EXPECT_GT(fs::file_size(run + "/run.lcmlog"), complete);
  // And LCM's own player reads the continued log to its end.
  const std::string relayed = root_ + "/resumed_relayed.lcmlog";
  ASSERT_EQ(
      runCommand("lcm-logplayer -s 1000 -l 'file://" + relayed + "?mode=w' " + run + "/run.lcmlog")
          .exit_code,
      0);
  EXPECT_EQ(countChannel(readLog(relayed), "CAMERA"), 10u);
}

TEST_F(PlayRecordTest, BadInputGivesClearErrors) {
  CommandResult missing = runCommand(kBin + "radslam-play --dataset tum:/no/such/folder --rate 0" +
                                     " --url 'file://" + root_ + "/x.lcmlog?mode=w'");
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.output.find("/no/such/folder"), std::string::npos) << missing.output;

  CommandResult kind = runCommand(kBin + "radslam-play --dataset nope:/tmp --rate 0" +
                                  " --url 'file://" + root_ + "/y.lcmlog?mode=w'");
  EXPECT_EQ(kind.exit_code, 2);
  EXPECT_NE(kind.output.find("nope"), std::string::npos) << kind.output;

  CommandResult flag = runCommand(kBin + "radslam-record --out " + root_ + "/z --bogus 1");
  EXPECT_EQ(flag.exit_code, 2);
  EXPECT_NE(flag.output.find("--bogus"), std::string::npos) << flag.output;

  CommandResult log = runCommand(kBin + "radslam-play --dataset log:/no/such.lcmlog --rate 0" +
                                 " --url 'file://" + root_ + "/w.lcmlog?mode=w'");
  EXPECT_EQ(log.exit_code, 2);
  EXPECT_NE(log.output.find("/no/such.lcmlog"), std::string::npos) << log.output;
}

}  // namespace
}  // namespace radslam
