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

}  // namespace
}  // namespace radslam
