// KeyframeArchive: keyframes read back from a log by the offsets noted while writing it.
#include "recorder/keyframe_archive.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "common/bus.h"
#include "common/lcm_log.h"
#include "common/types.h"

namespace radslam {
namespace {

Keyframe keyframe(int32_t id, int32_t version) {
  Keyframe k;
  k.header.utime = 1000 * id + version;
  k.keyframe_id = id;
  k.version = version;
  k.frame_index = 10 * id;
  k.camera.width = 4;
  k.camera.height = 3;
  k.camera.fx = k.camera.fy = 5;
  k.camera.cx = 1.5;
  k.camera.cy = 1;
  return k;
}

// Writes the keyframes (and a STATUS between them) into a log, noting each in the archive.
void writeLog(const std::string& path, const std::vector<Keyframe>& keyframes,
              KeyframeArchive* archive) {
  LogWriter log(path);
  for (const Keyframe& k : keyframes) {
    const std::vector<uint8_t> status = encode(Status{});
    log.write(1, "STATUS", status.data(), status.size());
    const std::vector<uint8_t> bytes = encode(k);
    const int64_t offset = log.position();
    log.write(2, "KEYFRAME", bytes.data(), bytes.size());
    archive->add(k.keyframe_id, k.version, offset);
  }
  log.flush();
}

Keyframe decoded(const LogEvent& event) {
  Keyframe k;
  std::string error;
  EXPECT_EQ(event.channel, "KEYFRAME");
  EXPECT_TRUE(decode(event.data.data(), event.data.size(), &k, &error)) << error;
  return k;
}

TEST(KeyframeArchive, ReadsBackTheLatestVersionOfWhatIsAskedFor) {
  const std::string path = ::testing::TempDir() + "/archive.lcmlog";
  KeyframeArchive archive(path);
  writeLog(path, {keyframe(0, 1), keyframe(1, 1), keyframe(0, 3), keyframe(2, 1)}, &archive);
  archive.add(0, 2, 0);  // an older version arriving late changes nothing
  EXPECT_EQ(archive.size(), 3u);
  std::string error;
  EXPECT_FALSE(archive.next(&error).has_value());  // nothing asked for

  EXPECT_EQ(archive.request({}), 3u);   // all
  EXPECT_EQ(archive.request({1}), 3u);  // queued already
  std::vector<std::pair<int32_t, int32_t>> got;
  while (archive.pending()) {
    const std::optional<LogEvent> event = archive.next(&error);
    ASSERT_TRUE(event.has_value()) << error;
    const Keyframe k = decoded(*event);
    got.emplace_back(k.keyframe_id, k.version);
  }
  EXPECT_EQ(got, (std::vector<std::pair<int32_t, int32_t>>{{0, 3}, {1, 1}, {2, 1}}));

  EXPECT_EQ(archive.request({2, 99}), 1u);  // 99 is unknown
  const std::optional<LogEvent> event = archive.next(&error);
  ASSERT_TRUE(event.has_value()) << error;
  EXPECT_EQ(decoded(*event).keyframe_id, 2);
}

TEST(KeyframeArchive, AnUnreadableLogGivesAnErrorNotACrash) {
  const std::string path = ::testing::TempDir() + "/archive_gone.lcmlog";
  KeyframeArchive archive(path);
  writeLog(path, {keyframe(0, 1)}, &archive);
  std::filesystem::remove(path);
  archive.request({});
  std::string error;
  EXPECT_FALSE(archive.next(&error).has_value());
  EXPECT_NE(error.find("archive_gone.lcmlog"), std::string::npos) << error;
  EXPECT_EQ(archive.size(), 1u);
}

}  // namespace
}  // namespace radslam
