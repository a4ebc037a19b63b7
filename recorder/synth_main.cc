// radslam-synth: renders one of radslam's synthetic scenes into a dataset folder
// (format in common/synthetic.h), playable with --dataset synthetic:DIR.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>

#include "common/cli.h"
#include "common/synthetic.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-synth --scene NAME --out DIR [options]
  --scene NAME     room | street | car | door | multi | large (default room)
  --out DIR        dataset folder to write (created)
  --frames N       number of frames (default 300)
  --width W        image width, pixels (default 640)
  --height H       image height, pixels (default 480)
  --seed S         scene, texture and noise seed (default 1); same seed -> same files
  --noise          add sensor noise (colour sigma 2 grey levels, depth sigma 0.0015 z^2)
  --no-stereo      do not render the right images
  --freeze-objects moving objects stay at their last frame's pose (the scene without motion;
                   objects ahead of the camera stay ahead)
  --fps F          frame rate, Hz (default: the scene's, 30 for rooms, 10 for streets)
  --readout S      rolling shutter: s from the first row's exposure to the last's (default 0)
  --threads T      render threads (default 1)
)";

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  SyntheticConfig config;
  config.scene = cli.get("scene", config.scene);
  const std::string out_dir = cli.get("out", "");
  config.frames = cli.getInt("frames", config.frames);
  config.width = cli.getInt("width", config.width);
  config.height = cli.getInt("height", config.height);
  const std::string seed = cli.get("seed", "1");
  char* end = nullptr;
  config.seed = std::strtoull(seed.c_str(), &end, 10);
  if (seed.empty() || *end != '\0' || seed[0] == '-')
    throw std::runtime_error("--seed expects a non-negative integer, got '" + seed + "'");
  if (cli.getBool("noise", false)) {
    config.image_noise_sigma = 2.0;
    config.depth_noise_rel = 0.0015;
  }
  config.stereo = !cli.getBool("no-stereo", false);
  config.freeze_objects = cli.getBool("freeze-objects", false);
  config.fps = cli.getDouble("fps", 0);
  config.readout_s = cli.getDouble("readout", 0);
  config.threads = cli.getInt("threads", config.threads);
  cli.finish();
  if (out_dir.empty()) throw std::runtime_error("--out is required\n" + cli.usage());

  std::printf("radslam-synth: scene %s, %d frames %dx%d, seed %llu, %s, noise %s, %d thread(s)\n",
              config.scene.c_str(), config.frames, config.width, config.height,
              static_cast<unsigned long long>(config.seed), config.stereo ? "stereo" : "mono",
              config.image_noise_sigma > 0 ? "on" : "off", config.threads);
  const auto start = std::chrono::steady_clock::now();
  generateSyntheticDataset(config, out_dir, [](int done, int total) {
    if (done % 10 == 0 || done == total) std::printf("\r  frame %d/%d", done, total);
    std::fflush(stdout);
  });
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf(
      "\nradslam-synth: wrote %s: %d frames (rgb/%s depth/ instance/ class/), camera.yaml, "
      "times.txt, groundtruth.txt, objects.txt, classes.yaml in %.1f s (%.0f ms/frame)\n",
      out_dir.c_str(), config.frames, config.stereo ? " right/" : "", seconds,
      1000.0 * seconds / config.frames);
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-synth", radslam::run, argc, argv);
}
