#include "renderer/render_service.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "renderer/demo_field.h"

namespace radslam {
namespace {

RenderRequest goodRequest() {
  RenderRequest r;
  r.request_id = 7;
  r.client = "test";
  r.camera.width = 64;
  r.camera.height = 48;
  r.camera.fx = r.camera.fy = 50;
  r.camera.cx = 31.5;
  r.camera.cy = 23.5;
  r.channels = kRenderColor | kRenderDepth | kRenderSigma;
  return r;
}

TEST(RenderService, BadRequestsGetAnErrorReply) {
  FieldReplica replica;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<std::pair<std::string, RenderRequest>> cases;
  auto add = [&](const std::string& what, auto change) {
    RenderRequest r = goodRequest();
    change(&r);
    cases.emplace_back(what, r);
  };
  add("size", [](RenderRequest* r) { r->camera.width = 0; });
  add("size", [](RenderRequest* r) { r->camera.height = -3; });
  add("exceeds", [](RenderRequest* r) { r->camera.width = 5000; });
  add("exceeds", [](RenderRequest* r) { r->camera.height = 4097; });
  add("focal", [](RenderRequest* r) { r->camera.fx = 0; });
  add("focal", [](RenderRequest* r) { r->camera.fy = -10; });
  add("intrinsics", [&](RenderRequest* r) { r->camera.fx = nan; });
  add("intrinsics", [&](RenderRequest* r) { r->camera.cx = inf; });
  add("pose", [&](RenderRequest* r) { r->T_world_cam.translation().x() = nan; });
  add("pose", [&](RenderRequest* r) { r->T_world_cam.translation().z() = -inf; });
  add("channels", [](RenderRequest* r) { r->channels = 0; });
  add("channels", [](RenderRequest* r) { r->channels = 64; });
  for (const auto& [what, request] : cases) {
    const RenderResult result = renderView(replica, request);
    EXPECT_FALSE(result.ok) << what;
    EXPECT_NE(result.error.find(what), std::string::npos) << result.error;
    EXPECT_EQ(result.request_id, 7);
    EXPECT_EQ(result.client, "test");
    EXPECT_TRUE(result.color.empty());
  }
}

TEST(RenderService, RendersTheRequestedChannels) {
  DemoFieldOptions options;
  options.train_steps = 3;
  std::vector<Keyframe> keyframes;
  auto mapper = makeDemoMapper(options, &keyframes);
  FieldReplica replica;
  std::string error;
  ASSERT_EQ(replica.apply(mapper->makeSnapshot(), &error), ApplyResult::kApplied) << error;
  RenderRequest r = goodRequest();
  r.T_world_cam = keyframes[0].T_world_cam;
  RenderResult result = renderView(replica, r);
  ASSERT_TRUE(result.ok) << result.error;
  EXPECT_EQ(result.field_version, mapper->field().version());
  EXPECT_EQ(result.color.type(), CV_8UC3);
  EXPECT_EQ(result.color.size(), cv::Size(64, 48));
  EXPECT_EQ(result.depth.type(), CV_32FC1);
  EXPECT_EQ(result.sigma.size(), cv::Size(64, 48));
  EXPECT_GT(cv::countNonZero(result.depth), 64 * 48 / 2);  // the room surrounds the camera
  const RenderImages ref = mapper->render(r.T_world_cam, r.camera);
  EXPECT_EQ(cv::norm(result.depth, ref.depth, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(result.color, toBgr8(ref.color), cv::NORM_INF), 0);

  r.channels = kRenderDepth;
  result = renderView(replica, r);
  ASSERT_TRUE(result.ok);
  EXPECT_TRUE(result.color.empty());
  EXPECT_TRUE(result.sigma.empty());
  EXPECT_FALSE(result.depth.empty());
}

TEST(RenderService, ColorizeMarksUnknownPixelsBlack) {
  cv::Mat depth(4, 4, CV_32FC1, cv::Scalar(2.0f));
  depth.at<float>(0, 0) = 0;
  depth.at<float>(1, 1) = std::numeric_limits<float>::quiet_NaN();
  depth.at<float>(2, 2) = 4;
  const cv::Mat c = colorizeDepth(depth);
  ASSERT_EQ(c.type(), CV_8UC3);
  EXPECT_EQ(c.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(c.at<cv::Vec3b>(1, 1), cv::Vec3b(0, 0, 0));
  EXPECT_NE(c.at<cv::Vec3b>(2, 2), c.at<cv::Vec3b>(3, 3));  // far differs from near
  EXPECT_TRUE(colorizeSigma(cv::Mat()).empty());
}

}  // namespace
}  // namespace radslam
