#include "renderer/viewer_server.h"

#include <gtest/gtest.h>
#include <httplib.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/synthetic.h"
#include "renderer/demo_field.h"
#include "renderer/render_service.h"

namespace radslam {
namespace {

// A viewer over a small trained field, with a camera frame, poses and a status.
class ViewerServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    DemoFieldOptions options;
    options.train_steps = 10;
    mapper_ = makeDemoMapper(options, &keyframes_);
    std::string error;
    ASSERT_EQ(replica_.apply(mapper_->makeSnapshot(), &error), ApplyResult::kApplied) << error;
    server_ = std::make_unique<ViewerServer>(
        &state_, [this](const RenderRequest& r) { return renderView(replica_, r); },
        defaultWebDir());
    port_ = server_->start("127.0.0.1", 0);
    ASSERT_GT(port_, 0);
    client_ = std::make_unique<httplib::Client>("127.0.0.1", port_);
    client_->set_read_timeout(20, 0);
  }

  void feed() {
    const Field& f = replica_.field();
    state_.setField(replica_.version(), f.totalBlocks(), f.boundsMin(), f.boundsMax());
    for (size_t i = 0; i < keyframes_.size(); ++i) {
      Frame frame;
      frame.frame_index = keyframes_[i].frame_index;
      frame.camera = keyframes_[i].camera;
      frame.color = keyframes_[i].color;
      state_.setCamera(frame);
      PoseStamped pose;
      pose.frame_index = keyframes_[i].frame_index;
      pose.T_world_cam = keyframes_[i].T_world_cam;
      state_.addPose(pose);
      pose.T_world_cam.translation().x() += 0.02;  // ground truth a little apart
      state_.addGroundTruth(pose);
      state_.addKeyframe(keyframes_[i].keyframe_id);
    }
    RenderRequest r;
    r.T_world_cam = keyframes_.back().T_world_cam;
    r.camera = keyframes_.back().camera;
    r.channels = kRenderColor | kRenderDepth | kRenderSigma;
    const RenderResult result = renderView(replica_, r);
    ASSERT_TRUE(result.ok) << result.error;
    state_.setRender(result.color, result.depth, result.sigma);
    Status s;
    s.process = "tracker";
    s.state = ProcessState::kRunning;
    s.fps = 12.5;
    s.items_handled = 42;
    s.last_error = "a \"quoted\" warning";
    state_.setStatus(s);
  }

  std::unique_ptr<Mapper> mapper_;
  std::vector<Keyframe> keyframes_;
  FieldReplica replica_;
  ViewerState state_;
  std::unique_ptr<ViewerServer> server_;
  std::unique_ptr<httplib::Client> client_;
  int port_ = 0;
};

TEST_F(ViewerServerTest, ServesThePageStateAndImages) {
  auto page = client_->Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("<canvas id=\"render\""), std::string::npos);
  auto js = client_->Get("/viewer.js");
  ASSERT_TRUE(js);
  EXPECT_EQ(js->status, 200);
  EXPECT_NE(js->body.find("state.json"), std::string::npos);
  ASSERT_TRUE(client_->Get("/style.css"));

  EXPECT_EQ(client_->Get("/image/camera.jpg")->status, 404);  // nothing yet
  feed();
  auto state = client_->Get("/state.json");
  ASSERT_TRUE(state);
  EXPECT_EQ(state->status, 200);
  EXPECT_EQ(state->get_header_value("Content-Type"), "application/json");
  const std::string& json = state->body;
  EXPECT_NE(json.find("\"keyframes\":4"), std::string::npos) << json;
  EXPECT_NE(json.find("\"process\":\"tracker\""), std::string::npos) << json;
  EXPECT_NE(json.find("a \\\"quoted\\\" warning"), std::string::npos) << json;
  EXPECT_NE(json.find("\"bounds\":["), std::string::npos) << json;
  for (const char* name : {"camera", "render", "depth", "sigma"}) {
    auto img = client_->Get((std::string("/image/") + name + ".jpg").c_str());
    ASSERT_TRUE(img);
    ASSERT_EQ(img->status, 200) << name;
    const cv::Mat decoded =
        cv::imdecode(std::vector<uint8_t>(img->body.begin(), img->body.end()), cv::IMREAD_COLOR);
    EXPECT_EQ(decoded.cols, keyframes_[0].camera.width) << name;
  }
}

TEST_F(ViewerServerTest, RefusesPathsOutsideItsWhitelist) {
  for (const char* path : {"/../../etc/passwd", "/%2e%2e/%2e%2e/etc/passwd", "/etc/passwd",
                           "/index.html/../../../etc/passwd", "/viewer.js.bak", "/web/index.html",
                           "/image/../../etc/passwd"}) {
    auto res = client_->Get(path);
    ASSERT_TRUE(res) << path;
    EXPECT_GE(res->status, 400) << path;
    EXPECT_EQ(res->body.find("root:"), std::string::npos) << path;
  }
}

TEST_F(ViewerServerTest, RendersFreeViewsAndRejectsBadOnes) {
  const SE3& T = keyframes_[0].T_world_cam;
  const Eigen::Quaterniond q = T.quaternion();
  char pose[256];
  std::snprintf(pose, sizeof(pose), "%.6f,%.6f,%.6f,%.9f,%.9f,%.9f,%.9f", T.translation().x(),
                T.translation().y(), T.translation().z(), q.x(), q.y(), q.z(), q.w());
  auto res =
      client_->Get((std::string("/render?pose=") + pose + "&w=80&h=60&fx=64&kind=color").c_str());
  ASSERT_TRUE(res);
  ASSERT_EQ(res->status, 200) << res->body;
  EXPECT_EQ(res->get_header_value("Content-Type"), "image/png");
  const cv::Mat png =
      cv::imdecode(std::vector<uint8_t>(res->body.begin(), res->body.end()), cv::IMREAD_COLOR);
  ASSERT_EQ(png.size(), cv::Size(80, 60));
  cv::Scalar mean, stddev;
  cv::meanStdDev(png, mean, stddev);
  EXPECT_GT(stddev[0] + stddev[1] + stddev[2], 3.0);  // a scene, not a blank image
  for (const std::string& bad :
       {std::string("/render?w=80&h=60&fx=64"), std::string("/render?pose=1,2,3&w=80&h=60&fx=64"),
        std::string("/render?pose=") + pose + "&w=0&h=60&fx=64",
        std::string("/render?pose=") + pose + "&w=5000&h=60&fx=64",
        std::string("/render?pose=") + pose + "&w=80&h=60&fx=-1",
        std::string("/render?pose=") + pose + "&w=80&h=60&fx=nan",
        std::string("/render?pose=0,0,0,0,0,0,0&w=80&h=60&fx=64"),
        std::string("/render?pose=") + pose + "&w=80&h=60&fx=64&kind=evil"}) {
    auto r = client_->Get(bad.c_str());
    ASSERT_TRUE(r) << bad;
    EXPECT_EQ(r->status, 400) << bad;
    EXPECT_NE(r->body.find("\"ok\":false"), std::string::npos) << r->body;
  }
}

// parseRenderQuery on its own: every number finite, the pose complete, the
// quaternion normalised even from components whose squares overflow.
TEST(ViewerServer, RenderQueryRejectsNonFiniteAndIncompleteInput) {
  const std::map<std::string, std::string> good = {
      {"pose", "1,2,3,0,0,0,1"}, {"w", "8"}, {"h", "6"}, {"fx", "10"}, {"kind", "depth"}};
  RenderRequest request;
  std::string kind, error;
  ASSERT_TRUE(parseRenderQuery(good, &request, &kind, &error)) << error;
  EXPECT_EQ(kind, "depth");
  EXPECT_EQ(request.channels, kRenderDepth);
  EXPECT_DOUBLE_EQ(request.camera.cx, 3.5);
  struct Case {
    std::string key, value, expected;
  };
  for (const Case& c : std::vector<Case>{
           {"pose", "1,2,3,0,0,0,nan", "pose must be 7 finite numbers"},
           {"pose", "1,2,inf,0,0,0,1", "pose must be 7 finite numbers"},
           {"pose", "1,2,3,0,0,1", "pose must be 7 finite numbers"},
           {"pose", "1,2,3", "pose must be 7 finite numbers"},
           {"pose", "", "pose must be 7 finite numbers"},
           {"pose", "1,2,3,0,0,0,1,4", "pose must be 7 finite numbers"},
           {"pose", "1,2,3,0,0,0,1e-300", "non-zero quaternion"},
           {"w", "nan", "parameter w is not a finite number"},
           {"h", "1e400", "parameter h is not a finite number"},
           {"fx", "-inf", "parameter fx is not a finite number"},
           {"fy", "NAN", "parameter fy is not a finite number"},
           {"cx", "inf", "parameter cx is not a finite number"},
           {"cy", "0x1p2000", "parameter cy is not a finite number"},
           {"w", "8.5", "w and h must be integers"},
           {"fx", "0", "focal lengths must be > 0"},
       }) {
    std::map<std::string, std::string> query = good;
    query[c.key] = c.value;
    error.clear();
    EXPECT_FALSE(parseRenderQuery(query, &request, &kind, &error)) << c.key << "=" << c.value;
    EXPECT_NE(error.find(c.expected), std::string::npos)
        << c.key << "=" << c.value << ": " << error;
  }
  // Components whose squares overflow double: normalised, not rejected or NaN.
  std::map<std::string, std::string> huge = good;
  huge["pose"] = "0,0,0,0,0,1e200,1e200";
  ASSERT_TRUE(parseRenderQuery(huge, &request, &kind, &error)) << error;
  EXPECT_TRUE(request.T_world_cam.matrix().allFinite());
  EXPECT_NEAR(request.T_world_cam.quaternion().z(), std::sqrt(0.5), 1e-12);
}

TEST(ViewerServer, MissingWebFileIsAClearError) {
  ViewerState state;
  try {
    ViewerServer server(&state, nullptr, "/nonexistent-radslam-web");
    FAIL() << "expected an error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-radslam-web/index.html"), std::string::npos);
  }
}

// Headless Chromium loads the page against the server and takes a screenshot; the rendered
// view's panel must show an image (not a uniform area).
TEST_F(ViewerServerTest, BrowserShowsTheRenderedView) {
  const char* chromium = "/usr/bin/chromium";
  if (access(chromium, X_OK) != 0) GTEST_SKIP() << chromium << " not installed: no browser test";
  feed();
  const std::string dir =
      ::testing::TempDir() + "radslam_viewer_browser_" + std::to_string(getpid());
  std::filesystem::create_directories(dir);
  const std::string shot = dir + "/viewer.png";
  const std::string cmd =
      std::string("timeout 60 ") + chromium +
      " --headless --no-sandbox --disable-gpu --disable-quic --no-first-run"
      " --disable-background-networking --disable-component-update --disable-sync"
      " --user-data-dir=" +
      dir + "/profile --screenshot=" + shot +
      " --window-size=1280,800 --virtual-time-budget=5000 http://127.0.0.1:" +
      std::to_string(port_) + "/ > " + dir + "/chromium.log 2>&1";
  const int rc = std::system(cmd.c_str());
  ASSERT_EQ(rc, 0) << "chromium failed; see " << dir << "/chromium.log";
  const cv::Mat image = cv::imread(shot, cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty()) << shot << " missing";
  ASSERT_EQ(image.size(), cv::Size(1280, 800));
  // Grid of three columns: the rendered view is the middle panel of the first row.
  const cv::Mat panel = image(cv::Rect(470, 80, 340, 220));
  cv::Scalar mean, stddev;
  cv::meanStdDev(panel, mean, stddev);
  EXPECT_GT(stddev[0] + stddev[1] + stddev[2], 10.0) << "rendered panel looks empty: " << shot;
  std::cout << "screenshot: " << shot << "\n";
}

}  // namespace
}  // namespace radslam
