#include "renderer/viewer_state.h"

#include <string>

#include <gtest/gtest.h>

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

}  // namespace
}  // namespace radslam
