// radslam-renderer: field replica, render service and web viewer on the bus (FIELD,
// RENDER_REQUEST, POSE, CAMERA, KEYFRAME, GROUND_TRUTH, STATUS, CONTROL in; RENDER, STATUS out).
#include <iostream>

#include "common/bus.h"
#include "common/cli.h"
#include "renderer/renderer_node.h"
#include "renderer/viewer_server.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-renderer [options]
  --url URL         LCM URL (default: LCM's default)
  --prefix P        channel prefix
  --config FILE     YAML with a "renderer" section (every key optional; unknown keys are errors)
  --set KEY=VALUE   override renderer parameters (comma-separate several: a=1,b=2)
  --mode M          accepted for the launcher (the renderer does not depend on it)
  --out DIR         run folder: renders/final/ and renders/flythrough.avi at the end
  --http-host H     viewer address (default 127.0.0.1)
  --http-port N     viewer port (default 8080; 0 = any free port, printed; -1 = no viewer)
  --web-dir DIR     viewer files (default: renderer/web in the source tree)
  --linger          after the run ends (CONTROL STOP, end of log), keep serving until Ctrl-C
)";

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string url = cli.get("url", "");
  const std::string prefix = cli.get("prefix", "");
  const std::string config = cli.get("config", "");
  const std::string set = cli.get("set", "");
  cli.get("mode", "");
  const std::string out = cli.get("out", "");
  const std::string host = cli.get("http-host", "127.0.0.1");
  const int port = cli.getInt("http-port", 8080);
  const std::string web_dir = cli.get("web-dir", defaultWebDir());
  const bool linger = cli.getBool("linger", false);
  cli.finish();

  std::vector<std::string> overrides;
  size_t start = 0;
  while (start < set.size()) {
    const size_t comma = set.find(',', start);
    const std::string item =
        set.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    if (!item.empty()) overrides.push_back(item);
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  std::string dump, source;
  const RendererParams params = loadRendererParams(config, overrides, &dump, &source);
  std::cerr << "radslam-renderer: parameters from " << source << "\n" << dump;

  installStopSignals();
  Bus bus(url, prefix, "renderer");
  RendererNode node(&bus, params, out);
  std::unique_ptr<ViewerServer> server;
  if (port >= 0) {
    server = std::make_unique<ViewerServer>(
        &node.viewer(), [&node](const RenderRequest& r) { return node.render(r, true); }, web_dir);
    const int bound = server->start(host, port);
    // The launcher and `radslam view` read this line for the URL.
    std::cout << "radslam-renderer: viewer at http://" << host << ":" << bound << "/" << std::endl;
  }
  std::cerr << "radslam-renderer: listening on " << bus.fullChannel(channel::kField) << "\n";
  const int rc = node.run(linger);
  if (server) server->stop();
  return rc;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-renderer", radslam::run, argc, argv);
}
