#include "common/control.h"

#include <gtest/gtest.h>

namespace radslam {
namespace {

TEST(KeyframeRequest, AllOrAListOfIds) {
  std::vector<int32_t> ids = {5};
  EXPECT_TRUE(parseKeyframeRequest("", &ids));
  EXPECT_TRUE(ids.empty());
  EXPECT_TRUE(parseKeyframeRequest("keyframes", &ids));
  EXPECT_TRUE(ids.empty());
  EXPECT_TRUE(parseKeyframeRequest("keyframes:3,x,-1,7,,99999999999", &ids));
  EXPECT_EQ(ids, (std::vector<int32_t>{3, 7}));
  EXPECT_FALSE(parseKeyframeRequest("keyframes:x", &ids));  // nothing usable
  EXPECT_FALSE(parseKeyframeRequest("field", &ids));
}

TEST(Control, RewindRequestsRoundTripAndBadOnesAreRefused) {
  int64_t frame = -1;
  std::string token;
  ASSERT_TRUE(parseRewindRequest(rewindRequest(1234, "4711-9"), &frame, &token));
  EXPECT_EQ(frame, 1234);
  EXPECT_EQ(token, "4711-9");
  for (const char* bad : {"", "12", ":x", "-3:x", "1x:y", "99999999999999999999:x"})
    EXPECT_FALSE(parseRewindRequest(bad, &frame, &token)) << bad;
}

}  // namespace
}  // namespace radslam
