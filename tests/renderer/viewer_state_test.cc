#include "renderer/viewer_state.h"

#include <string>

#include <gtest/gtest.h>

#include "common/lie.h"

namespace radslam {
namespace {

TEST(ViewerState, ObjectTracksAreInTheStateJson) {
  ViewerState state;
  EXPECT_NE(state.stateJson().find("\"objects\":[]"), std::string::npos);
  for (int frame = 0; frame < 3; ++frame) {
    ObjectList list;
    list.frame_index = frame;
    TrackedObject car;
    car.object_id = 100;
    car.class_id = 10;
    car.joint_type = JointType::kPlanar;
    car.T_world_object = SE3(SO3(), Vec3(frame, 0.5, 2 * frame));
    list.objects.push_back(car);
    state.addObjects(list);
  }
  const std::string json = state.stateJson();
  EXPECT_NE(
      json.find("{\"id\":100,\"class\":10,\"joint\":\"planar\",\"track\":[[0,0],[1,2],[2,4]]}"),
      std::string::npos)
      << json;
}

// The JSON array that follows "key":.
std::string jsonArray(const std::string& json, const std::string& key) {
  const size_t start = json.find("\"" + key + "\":[");
  if (start == std::string::npos) return "";
  const size_t open = start + key.size() + 3;
  int depth = 0;
  for (size_t i = open; i < json.size(); ++i) {
    depth += json[i] == '[' ? 1 : json[i] == ']' ? -1 : 0;
    if (depth == 0) return json.substr(open, i + 1 - open);
  }
  return "";
}

TEST(ViewerState, GroundTruthIsPlottedAlignedToTheEstimate) {
  // Ground truth in another world frame and at another scale (a monocular run).
  const Sim3 T_gt_est(SO3::exp(Vec3(0.3, -1.2, 0.4)), Vec3(4, -2, 7), 2.5);
  ViewerState state;
  const Vec3 centres[] = {{1.5, 0.1, 2.5}, {1.25, 0.2, 3.5}, {-0.5, 0.3, 4.25}, {-2.5, 0.5, 1.5}};
  for (int frame = 0; frame < 4; ++frame) {
    PoseStamped gt;
    gt.frame_index = frame;
    gt.T_world_cam = SE3(SO3(), T_gt_est * centres[frame]);
    state.addGroundTruth(gt);
    PoseStamped est;
    est.frame_index = frame;
    est.T_world_cam = SE3(SO3(), centres[frame]);
    state.addPose(est);
  }
  const std::string json = state.stateJson();
  EXPECT_EQ(jsonArray(json, "trajectory"), "[[1.5,2.5],[1.25,3.5],[-0.5,4.25],[-2.5,1.5]]");
  EXPECT_EQ(jsonArray(json, "ground_truth"), jsonArray(json, "trajectory")) << json;
}

}  // namespace
}  // namespace radslam
