#include "renderer/renderer_node.h"

#include <gtest/gtest.h>
#include <stdlib.h>

#include <filesystem>
#include <fstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>

#include "common/exr_io.h"
#include "mapper/field_io.h"
#include "renderer/demo_field.h"

namespace radslam {
namespace {

std::string tempDir() {
  std::string pattern = ::testing::TempDir() + "radslam_renderer_XXXXXX";
  const char* dir = mkdtemp(pattern.data());
  EXPECT_NE(dir, nullptr);
  return dir ? dir : "";
}

// Handles the bus until pred() holds (at most 200 rounds).
template <class Pred>
bool spinUntil(RendererNode* node, Pred pred) {
  for (int i = 0; i < 200 && !pred(); ++i) node->spinOnce(5);
  return pred();
}

TEST(RendererNode, JoinsLateAnswersRequestsAndWritesFinalOutputs) {
  const std::string out = tempDir();
  Bus bus("memq://", "RNDTEST_", "test");
  RendererParams params;
  params.follow_width = 0;  // no worker thread: deterministic
  params.video_max_frames = 5;
  params.video_width = 80;
  RendererNode node(&bus, params, out);

  std::vector<Control> controls;
  std::vector<RenderResult> results;
  bus.subscribe<Control>(channel::kControl, [&](const Control& c) { controls.push_back(c); });
  bus.subscribe<RenderResult>(channel::kRender,
                              [&](const RenderResult& r) { results.push_back(r); });

  DemoFieldOptions options;
  options.train_steps = 2;
  std::vector<Keyframe> keyframes;
  auto mapper = makeDemoMapper(options, &keyframes);
  const FieldUpdate first = mapper->makeUpdate(0);
  mapper->train(2);
  const FieldUpdate second = mapper->makeUpdate(first.version);

  // Late join: the first update it hears builds on a version it never had. Its blocks are
  // shown meanwhile; the snapshot makes the replica exact.
  bus.publish(channel::kField, second);
  ASSERT_TRUE(spinUntil(&node, [&] { return !controls.empty(); }));
  EXPECT_EQ(controls[0].command, ControlCommand::kSnapshot);
  EXPECT_EQ(controls[0].target, "mapper");
  EXPECT_EQ(node.fieldVersion(), second.version);
  EXPECT_TRUE(node.waitingForSnapshot());

  bus.publish(channel::kField, mapper->makeSnapshot());
  ASSERT_TRUE(spinUntil(&node, [&] { return !node.waitingForSnapshot(); }));
  EXPECT_EQ(node.fieldVersion(), mapper->field().version());

  RenderRequest bad;
  bad.request_id = 1;
  bus.publish(channel::kRenderRequest, bad);
  RenderRequest good;
  good.request_id = 2;
  good.T_world_cam = keyframes[0].T_world_cam;
  good.camera = keyframes[0].camera;
  bus.publish(channel::kRenderRequest, good);
  ASSERT_TRUE(spinUntil(&node, [&] { return results.size() == 2; }));
  EXPECT_FALSE(results[0].ok);
  EXPECT_FALSE(results[0].error.empty());
  EXPECT_TRUE(results[1].ok) << results[1].error;
  EXPECT_EQ(results[1].color.size(), keyframes[0].color.size());
  EXPECT_EQ(results[1].field_version, mapper->field().version());

  for (const Keyframe& kf : keyframes) {
    Frame frame;
    frame.header = kf.header;
    frame.frame_index = kf.frame_index;
    frame.camera = kf.camera;
    frame.color = kf.color;
    bus.publish(channel::kCamera, frame);
    PoseStamped pose;
    pose.header = kf.header;
    pose.frame_index = kf.frame_index;
    pose.T_world_cam = kf.T_world_cam;
    bus.publish(channel::kPose, pose);
    bus.publish(channel::kKeyframe, kf);
  }
  Control stop;
  stop.command = ControlCommand::kStop;
  stop.target = "renderer";
  bus.publish(channel::kControl, stop);
  EXPECT_EQ(node.run(), 0);  // handles the queue, stops on CONTROL STOP, writes the outputs

  EXPECT_NE(node.viewer().stateJson().find("\"keyframes\":4"), std::string::npos);
  int pngs = 0;
  for (const auto& entry : std::filesystem::directory_iterator(out + "/renders/final")) {
    if (entry.path().extension() != ".png") continue;
    ++pngs;
    const cv::Mat color = cv::imread(entry.path().string());
    EXPECT_EQ(color.size(), keyframes[0].color.size());
    std::filesystem::path exr = entry.path();
    exr.replace_extension(".exr");
    const ExrChannels channels = readExr(exr.string());
    ASSERT_EQ(channels.size(), 2u);
    EXPECT_EQ(channels[0].first, "depth");
    EXPECT_GT(cv::countNonZero(channels[0].second), 0);
  }
  EXPECT_EQ(pngs, 4);
  cv::VideoCapture video(out + "/renders/flythrough.avi");
  ASSERT_TRUE(video.isOpened());
  EXPECT_EQ(static_cast<int>(video.get(cv::CAP_PROP_FRAME_COUNT)), 4);
  std::filesystem::remove_all(out);
}

TEST(RendererNode, AsksForASnapshotWhenTheMappersStatusReportsAVersionThatNeverCame) {
  Bus bus("memq://", "RNDLOST_", "test");
  RendererParams params;
  params.follow_width = 0;
  RendererNode node(&bus, params, "");
  std::vector<Control> controls;
  bus.subscribe<Control>(channel::kControl, [&](const Control& c) { controls.push_back(c); });
  const auto mapper_status = [&](int64_t version) {
    Status s;
    s.process = "mapper";
    s.values = {{"field_version", static_cast<double>(version)}};
    bus.publish(channel::kStatus, s);
    for (int i = 0; i < 5; ++i) node.spinOnce(1);
  };

  DemoFieldOptions options;
  options.train_steps = 2;
  std::vector<Keyframe> keyframes;
  auto mapper = makeDemoMapper(options, &keyframes);
  const FieldUpdate first = mapper->makeUpdate(0);
  bus.publish(channel::kField, first);
  mapper_status(first.version);
  mapper_status(first.version);
  EXPECT_TRUE(controls.empty());  // in step
  EXPECT_EQ(node.fieldVersion(), first.version);

  // The last update of the run is lost: no later one shows the gap, the STATUS after it does
  // (one STATUS later, so that an update on its way is not taken for lost).
  mapper->train(2);
  const FieldUpdate lost = mapper->makeUpdate(first.version);
  ASSERT_GT(lost.version, first.version);
  mapper_status(lost.version);
  EXPECT_TRUE(controls.empty());
  mapper_status(lost.version);
  ASSERT_EQ(controls.size(), 1u);
  EXPECT_EQ(controls[0].command, ControlCommand::kSnapshot);
  EXPECT_TRUE(node.waitingForSnapshot());
  mapper_status(lost.version);
  EXPECT_EQ(controls.size(), 1u);  // asked once until the snapshot comes

  bus.publish(channel::kField, mapper->makeSnapshot());
  ASSERT_TRUE(spinUntil(&node, [&] { return !node.waitingForSnapshot(); }));
  EXPECT_EQ(node.fieldVersion(), mapper->field().version());
  mapper_status(mapper->field().version());
  EXPECT_EQ(controls.size(), 1u);
}

TEST(RendererParams, UnknownKeysAndBadValuesAreErrors) {
  const std::string dir = tempDir();
  const std::string path = dir + "/r.yaml";
  std::ofstream(path) << "renderer:\n  follow_width: 200\n  bogus_key: 1\n";
  EXPECT_THROW(loadRendererParams(path, {}, nullptr, nullptr), std::runtime_error);
  std::ofstream(path) << "renderer:\n  follow_width: 200\n  video_fps: 10\n";
  std::string dump;
  const RendererParams p = loadRendererParams(path, {}, &dump, nullptr);
  EXPECT_EQ(p.follow_width, 200);
  EXPECT_EQ(p.video_fps, 10);
  EXPECT_NE(dump.find("follow_width: 200"), std::string::npos);
  EXPECT_THROW(loadRendererParams(path, {"render_threads=0"}, nullptr, nullptr),
               std::runtime_error);
  EXPECT_THROW(loadRendererParams(path, {"final_render_threads=-1"}, nullptr, nullptr),
               std::runtime_error);
  EXPECT_EQ(
      loadRendererParams(path, {"final_render_threads=3"}, nullptr, nullptr).final_render_threads,
      3);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace radslam
