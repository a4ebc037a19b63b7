#include "renderer/demo_field.h"

#include "common/synthetic.h"

namespace radslam {

std::unique_ptr<Mapper> makeDemoMapper(const DemoFieldOptions& options,
                                       std::vector<Keyframe>* keyframes) {
  SyntheticConfig config;
  config.scene = "room";
  config.width = options.width;
  config.height = options.width * 3 / 4;
  config.frames = options.keyframes * 10;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);
  MapperParams params;
  params.trainer.batch_rays = options.batch_rays;
  auto mapper = std::make_unique<Mapper>(params);
  for (int i = 0; i < options.keyframes; ++i) {
    const Frame frame = scene.frame(i * 10);
    Keyframe kf;
    kf.header = frame.header;
    kf.keyframe_id = i;
    kf.frame_index = frame.frame_index;
    kf.T_world_cam = scene.cameraPose(i * 10);
    kf.camera = frame.camera;
    kf.color = frame.color;
    kf.depth = frame.depth;
    kf.depth_var = cv::Mat(frame.depth.size(), CV_32FC1, cv::Scalar(1e-4));  // (1 cm)^2
    mapper->addKeyframe(kf);
    if (keyframes) keyframes->push_back(kf);
  }
  if (options.train_steps > 0) mapper->train(options.train_steps);
  return mapper;
}

}  // namespace radslam
