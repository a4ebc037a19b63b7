// The remote viewer's HTTP server (cpp-httplib): a fixed whitelist of static files read from
// one folder at start, the viewer state as JSON, the latest images, and free-camera renders.
// It runs on its own threads; the pipeline never waits for it.
#pragma once

#include <atomic>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include "common/types.h"
#include "renderer/viewer_state.h"

namespace httplib {
class Server;
}

namespace radslam {

/// Folder of the viewer's files in the source tree.
std::string defaultWebDir();

class ViewerServer {
 public:
  /// Renders a view for GET /render (called on an HTTP thread; must be thread-safe).
  using RenderFunction = std::function<RenderResult(const RenderRequest&)>;

  /// Reads index.html, viewer.js and style.css from web_dir. Throws std::runtime_error
  /// naming the file that is missing.
  ViewerServer(const ViewerState* state, RenderFunction render, const std::string& web_dir);
  ~ViewerServer();
  ViewerServer(const ViewerServer&) = delete;
  ViewerServer& operator=(const ViewerServer&) = delete;

  /// Binds host:port (port 0 = any free port) and serves on a background thread. Returns
  /// the bound port; throws std::runtime_error when the address cannot be bound.
  int start(const std::string& host, int port);
  void stop();
  int port() const { return port_; }

 private:
  void routes();

  const ViewerState* state_;
  RenderFunction render_;
  // URL path -> (content type, bytes): the only files served.
  std::map<std::string, std::pair<std::string, std::string>> assets_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  std::atomic<bool> listen_returned_{false};
  int port_ = -1;
};

/// Parses the query of GET /render into a request: pose = "tx,ty,tz,qx,qy,qz,qw" (T_world_cam,
/// m), w, h (pixels), fx, fy, cx, cy (pixels; fy defaults to fx, cx/cy to the centre) and
/// kind = color|depth|sigma. False with *error naming the bad parameter.
bool parseRenderQuery(const std::map<std::string, std::string>& query, RenderRequest* request,
                      std::string* kind, std::string* error);

}  // namespace radslam
