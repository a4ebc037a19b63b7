// LogReader on valid, truncated and corrupt LCM logs.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "common/lcm_log.h"

namespace radslam {
namespace {

std::string tempPath(const std::string& name) {
  return ::testing::TempDir() + "/radslam_lcm_log_test_" + std::to_string(getpid()) + "_" + name;
}

// One event header as lcm writes it (big endian).
std::string eventHeader(int64_t utime, int32_t channel_bytes, int32_t data_bytes) {
  std::string h;
  auto put = [&h](uint64_t v, int bytes) {
    for (int i = bytes - 1; i >= 0; --i) h += static_cast<char>((v >> (8 * i)) & 0xff);
  };
  put(0xEDA1DA01u, 4);
  put(0, 8);
  put(static_cast<uint64_t>(utime), 8);
  put(static_cast<uint32_t>(channel_bytes), 4);
  put(static_cast<uint32_t>(data_bytes), 4);
  return h;
}

void writeFile(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

TEST(LcmLog, WrittenEventsReadBack) {
  const std::string path = tempPath("roundtrip");
  const std::vector<uint8_t> payload = {1, 2, 3, 250};
  {
    LogWriter writer(path);
    writer.write(100, "CAMERA", payload.data(), payload.size());
    writer.write(250, "POSE", payload.data(), 0);
  }
  LogReader reader(path);
  auto first = reader.next();
  ASSERT_TRUE(first);
  EXPECT_EQ(first->utime, 100);
  EXPECT_EQ(first->channel, "CAMERA");
  EXPECT_EQ(first->data, payload);
  auto second = reader.next();
  ASSERT_TRUE(second);
  EXPECT_EQ(second->utime, 250);
  EXPECT_EQ(second->channel, "POSE");
  EXPECT_TRUE(second->data.empty());
  EXPECT_FALSE(reader.next());
  std::remove(path.c_str());
}

TEST(LcmLog, GarbageBeforeAnEventIsSkipped) {
  const std::string path = tempPath("garbage");
  writeFile(path, "junk" + eventHeader(7, 1, 2) + "Cxy");
  LogReader reader(path);
  auto event = reader.next();
  ASSERT_TRUE(event);
  EXPECT_EQ(event->channel, "C");
  EXPECT_EQ(event->data, (std::vector<uint8_t>{'x', 'y'}));
  EXPECT_FALSE(reader.next());
  std::remove(path.c_str());
}

TEST(LcmLog, TruncatedAndCorruptEventsEndTheLog) {
  const std::string path = tempPath("corrupt");
  for (const std::string& bytes :
       {eventHeader(1, 1, 10) + "Cabc",          // truncated data
        eventHeader(1, -1, 1) + "Cx",            // negative channel length
        eventHeader(1, 5000, 1) + "Cx",          // channel length over lcm's limit
        eventHeader(1, 1, -7) + "Cx",            // negative data length
        eventHeader(1, 1, 0x7ffffff0) + "Cabc",  // data length far past the file
        eventHeader(1, 1, 1).substr(0, 20)}) {   // truncated header
    writeFile(path, bytes);
    LogReader reader(path);
    EXPECT_FALSE(reader.next());
  }
  std::remove(path.c_str());
}

// Reads the first event of `path` with the address space limited to 512 MiB
// above what the process maps now; exits 0 when the reader returns no event.
[[noreturn]] void readFirstEventUnderMemoryLimit(const std::string& path) {
  long pages = 0, resident = 0;
  std::FILE* statm = std::fopen("/proc/self/statm", "r");
  if (!statm || std::fscanf(statm, "%ld %ld", &pages, &resident) != 2) std::_Exit(3);
  std::fclose(statm);
  const rlim_t limit =
      static_cast<rlim_t>(pages) * static_cast<rlim_t>(sysconf(_SC_PAGESIZE)) + (512u << 20);
  const rlimit as_limit{limit, limit};
  if (setrlimit(RLIMIT_AS, &as_limit) != 0) std::_Exit(4);
  LogReader reader(path);
  std::_Exit(reader.next() ? 1 : 0);
}

// A 31-byte log claiming 2 GiB of data must not make the reader allocate it
// (lcm 1.3.1's own reader does): run it under an address-space limit far below.
TEST(LcmLog, HugeDataLengthIsNotAllocated) {
  const std::string path = tempPath("huge");
  writeFile(path, eventHeader(1, 3, 0x7ffffff0) + "abc");
  EXPECT_EXIT(readFirstEventUnderMemoryLimit(path), ::testing::ExitedWithCode(0), "");
  std::remove(path.c_str());
}

TEST(LcmLog, MissingFileOrFolderIsAClearError) {
  EXPECT_THROW(LogReader(tempPath("missing")), std::runtime_error);
  EXPECT_THROW(LogReader(::testing::TempDir()), std::runtime_error);
}

}  // namespace
}  // namespace radslam
