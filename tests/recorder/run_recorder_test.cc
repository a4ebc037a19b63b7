// RunRecorder exports: trajectories, keyframe EXR, summary with evaluation.
#include "recorder/run_recorder.h"

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/exr_io.h"

namespace radslam {
namespace {

std::string readFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

SE3 groundTruthPose(int k) {
  const double s = 0.1 * k;
  return SE3(SO3::exp(Vec3(0.05 * std::sin(s), 0.1 * s, 0.02 * k)),
             Vec3(std::cos(s), 0.3 * std::sin(2 * s), 0.05 * k));
}

// exr_on_arrival: keyframe EXRs written as keyframes arrive (radslam-record), else at export.
void exportsTrajectoriesKeyframesAndEvaluation(bool exr_on_arrival) {
  const std::string out =
      ::testing::TempDir() + "/run_recorder_test" + (exr_on_arrival ? "_arrival" : "");
  std::filesystem::remove_all(out);
  RecorderParams params;
  params.mode = "mono";
  if (exr_on_arrival) params.keyframe_exr_dir = out + "/keyframes";
  RunRecorder recorder(params);
  // Monocular estimate = ground truth seen through an unknown similarity.
  const SE3 T_est_world(SO3::exp(Vec3(0.3, -0.2, 0.1)), Vec3(1, 2, 3));
  const double scale = 0.5;
  for (int k = 0; k < 30; ++k) {
    const int64_t utime = 1'000'000 + k * 33'333;
    recorder.onCameraFrame(utime);
    PoseStamped gt;
    gt.header.utime = utime;
    gt.frame_index = k;
    gt.state = TrackingState::kGroundTruth;
    gt.T_world_cam = groundTruthPose(k);
    recorder.onGroundTruth(gt);
    PoseStamped est = gt;
    est.state = TrackingState::kTracking;
    const SE3 T = T_est_world * gt.T_world_cam;
    est.T_world_cam = SE3(T.so3(), scale * T.translation());
    recorder.onPose(est);
  }
  // A keyframe sent twice: the later version wins.
  Keyframe keyframe;
  keyframe.header.utime = 1'000'000;
  keyframe.keyframe_id = 0;
  keyframe.depth = cv::Mat(4, 5, CV_32F, cv::Scalar(2.0f));
  keyframe.depth_var = cv::Mat(4, 5, CV_32F, cv::Scalar(0.04f));
  keyframe.color = cv::Mat(4, 5, CV_8UC3, cv::Scalar(10, 20, 30));
  recorder.onKeyframe(keyframe, 50'000'000);
  keyframe.version = 1;
  keyframe.depth.setTo(3.0f);
  recorder.onKeyframe(keyframe, 51'000'000);
  if (exr_on_arrival) {  // on disk already, before any export (a killed recorder keeps it)
    EXPECT_FLOAT_EQ(readExrChannel(out + "/keyframes/1.000000.exr", "depth").at<float>(0, 0), 3.0f);
  }
  Status tracker;
  tracker.process = "tracker";
  tracker.fps = 42;
  tracker.peak_rss_mb = 100;
  tracker.values = {{"window", 8}};
  recorder.onStatus(tracker, 52'000'000);

  const std::string summary = recorder.exportRun(out, 1.5, 10, 1000);
  EXPECT_NE(summary.find("keyframes              1 (1 depth/sigma EXR)"), std::string::npos)
      << summary;
  EXPECT_NE(summary.find("ATE RMSE (sim3)"), std::string::npos) << summary;
  EXPECT_EQ(summary.find("mapper lag"), std::string::npos) << summary;  // no mapper ran

  EXPECT_EQ(readTumTrajectory(out + "/trajectory.txt").size(), 30u);
  EXPECT_EQ(readTumTrajectory(out + "/groundtruth.txt").size(), 30u);
  EXPECT_EQ(readTumTrajectory(out + "/keyframes.txt").size(), 1u);
  const cv::Mat depth = readExrChannel(out + "/keyframes/1.000000.exr", "depth");
  EXPECT_FLOAT_EQ(depth.at<float>(0, 0), 3.0f);
  const cv::Mat sigma = readExrChannel(out + "/keyframes/1.000000.exr", "sigma");
  EXPECT_NEAR(sigma.at<float>(3, 4), 0.2f, 1e-6);
  const cv::Mat color = cv::imread(out + "/keyframes/1.000000.png", cv::IMREAD_UNCHANGED);
  ASSERT_EQ(color.type(), CV_8UC3);
  EXPECT_EQ(color.at<cv::Vec3b>(3, 4), cv::Vec3b(10, 20, 30));

  const std::string json = readFile(out + "/summary.json");
  for (const char* key : {"\"ate_rmse_m\"", "\"ate_alignment\": \"sim3\"", "\"rpe_trans_m\"",
                          "\"rpe_rot_deg\"", "\"frames\": 30", "\"keyframes\": 1", "\"wall_s\"",
                          "\"tracker\": {\"fps\": 42", "\"peak_rss_mb\": 100"}) {
    EXPECT_NE(json.find(key), std::string::npos) << key << " missing in\n" << json;
  }
  // Sim3 alignment removes the similarity exactly.
  const size_t at = json.find("\"ate_rmse_m\": ");
  EXPECT_LT(std::stod(json.substr(at + 14)), 1e-6);
}

TEST(RunRecorderTest, ExportsTrajectoriesKeyframesAndEvaluation) {
  exportsTrajectoriesKeyframesAndEvaluation(false);
}

TEST(RunRecorderTest, WritesKeyframeExrsAsTheyArrive) {
  exportsTrajectoriesKeyframesAndEvaluation(true);
}

TEST(RunRecorderTest, SummaryWithoutGroundTruthSaysSo) {
  RunRecorder recorder(RecorderParams{});
  recorder.onCameraFrame(0);
  const std::string out = ::testing::TempDir() + "/run_recorder_test_nogt";
  std::filesystem::remove_all(out);
  const std::string summary = recorder.exportRun(out, 0.1, 1, 10);
  EXPECT_NE(summary.find("no ground truth"), std::string::npos) << summary;
  EXPECT_NE(readFile(out + "/summary.json").find("\"ate_rmse_m\": null"), std::string::npos);
}

// Keyframes at sensor times 1, 2, 3 s arrive at wall times 10, 11, 12 s; the mapper reports
// the first handled at 10.5 s and the first two at 13 s; the third never.
TEST(RunRecorderTest, MeasuresHowLongKeyframesWaitForTheMapper) {
  RunRecorder recorder(RecorderParams{});
  Keyframe keyframe;
  for (int k = 0; k < 3; ++k) {
    keyframe.keyframe_id = k;
    keyframe.header.utime = (k + 1) * 1'000'000;
    recorder.onKeyframe(keyframe, (10 + k) * 1'000'000);
  }
  Status mapper;
  mapper.process = "mapper";
  mapper.last_frame_utime = 1'000'000;
  recorder.onStatus(mapper, 10'500'000);
  // A re-sent version of a handled keyframe does not wait again; other processes do not count.
  keyframe.keyframe_id = 0;
  keyframe.header.utime = 1'000'000;
  keyframe.version = 1;
  recorder.onKeyframe(keyframe, 12'500'000);
  Status tracker;
  tracker.process = "tracker";
  tracker.last_frame_utime = 3'000'000;
  recorder.onStatus(tracker, 12'600'000);
  mapper.last_frame_utime = 2'000'000;
  mapper.values = {{"keyframe_psnr_db", 25.456}};  // its final STATUS scores its renders
  recorder.onStatus(mapper, 13'000'000);

  const RunRecorder::MapperLag lag = recorder.mapperLag();
  EXPECT_EQ(lag.keyframes, 2);
  EXPECT_DOUBLE_EQ(lag.max_s, 2.0);     // the second: 11 -> 13 s
  EXPECT_DOUBLE_EQ(lag.median_s, 2.0);  // of {0.5, 2.0}, the upper one
  const std::string out = ::testing::TempDir() + "/run_recorder_test_lag";
  std::filesystem::remove_all(out);
  const std::string summary = recorder.exportRun(out, 4.0, 10, 1000);
  EXPECT_NE(summary.find("mapper lag             median 2.0 s, max 2.0 s from arrival to "
                         "handled, 2 keyframes; 1 never handled"),
            std::string::npos)
      << summary;
  EXPECT_NE(summary.find("map                    25.46 dB PSNR of the keyframe renders"),
            std::string::npos)
      << summary;
  EXPECT_NE(readFile(out + "/summary.json").find("\"mapper_lag_max_s\": 2"), std::string::npos);
  EXPECT_NE(readFile(out + "/summary.json").find("\"keyframe_psnr_db\": 25.456"),
            std::string::npos);
}

TEST(RunRecorderTest, ReportsTrafficPerChannel) {
  RunRecorder recorder(RecorderParams{});
  // FIELD: 1 MB every 0.5 s for 4 s (mean 2 MB/s, any 1 s window holds 2 or 3 messages);
  // POSE: 100 B at 30 Hz.
  for (int k = 0; k <= 8; ++k) recorder.onMessage("FIELD", k * 500'000, 1'000'000);
  for (int k = 0; k <= 120; ++k) recorder.onMessage("POSE", k * 33'333, 100);
  // MAPPER_POSE: a burst of 20 x 1 kB within 10 ms: 20 kB/s over the 1 s minimum span.
  for (int k = 0; k < 20; ++k) recorder.onMessage("MAPPER_POSE", 2'000'000 + k * 500, 1000);
  const std::string out = ::testing::TempDir() + "/run_recorder_test_traffic";
  std::filesystem::remove_all(out);
  const std::string summary = recorder.exportRun(out, 4.0, 130, 9'012'100);
  const std::string json = readFile(out + "/summary.json");
  EXPECT_NE(json.find("\"FIELD\": {\"messages\": 9, \"bytes\": 9000000, \"mean_bytes_per_s\": "
                      "2250000, \"peak_bytes_per_s\": 2000000}"),
            std::string::npos)
      << json;
  EXPECT_NE(json.find("\"POSE\": {\"messages\": 121, \"bytes\": 12100"), std::string::npos) << json;
  EXPECT_NE(json.find("\"MAPPER_POSE\": {\"messages\": 20, \"bytes\": 20000, "
                      "\"mean_bytes_per_s\": 20000,"),
            std::string::npos)
      << json;
  EXPECT_NE(summary.find("FIELD"), std::string::npos) << summary;
}

TEST(LogGuardTest, StopsBeforeTheSizeLimitAndStaysStopped) {
  RecorderParams params;
  params.max_log_mb = 0.001;  // 1000 bytes
  params.min_free_disk_mb = 0;
  LogGuard guard(params, ::testing::TempDir());
  EXPECT_TRUE(guard.admits(0, 600));
  EXPECT_TRUE(guard.admits(600, 400));  // exactly at the limit
  EXPECT_FALSE(guard.admits(1000, 1));
  EXPECT_NE(guard.why().find("max_log_mb"), std::string::npos) << guard.why();
  EXPECT_FALSE(guard.admits(0, 1));  // the log ended: no later event goes in
}

TEST(LogGuardTest, StopsWhenTheDiskRunsLow) {
  RecorderParams params;
  params.min_free_disk_mb = 1e15;  // more than any disk has
  LogGuard guard(params, ::testing::TempDir());
  EXPECT_FALSE(guard.admits(0, 10));
  EXPECT_NE(guard.why().find("min_free_disk_mb"), std::string::npos) << guard.why();
  params.min_free_disk_mb = 0;
  LogGuard relaxed(params, ::testing::TempDir());
  EXPECT_TRUE(relaxed.admits(0, 10));
  EXPECT_TRUE(relaxed.why().empty());
}

}  // namespace
}  // namespace radslam
