#include "renderer/viewer_server.h"

#include <httplib.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgcodecs.hpp>

#include "renderer/render_service.h"

namespace radslam {
namespace {

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot read the viewer file");
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

bool parseDouble(const std::string& text, double* v) {
  if (text.empty()) return false;
  char* end = nullptr;
  *v = std::strtod(text.c_str(), &end);
  return end && *end == '\0' && std::isfinite(*v);
}

std::string jsonError(const std::string& error) {
  std::string out = "{\"ok\":false,\"error\":\"";
  for (const char c : error) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) out += c;
  }
  return out + "\"}";
}

}  // namespace

std::string defaultWebDir() { return RADSLAM_SOURCE_DIR "/renderer/web"; }

bool parseRenderQuery(const std::map<std::string, std::string>& q, RenderRequest* r,
                      std::string* kind, std::string* error) {
  auto get = [&](const char* key, double* v, bool required) {
    const auto it = q.find(key);
    if (it == q.end()) {
      if (required) *error = std::string("missing parameter ") + key;
      return !required;
    }
    if (!parseDouble(it->second, v)) {
      *error = std::string("parameter ") + key + " is not a finite number: '" + it->second + "'";
      return false;
    }
    return true;
  };
  const auto pose = q.find("pose");
  if (pose == q.end()) {
    *error = "missing parameter pose (tx,ty,tz,qx,qy,qz,qw)";
    return false;
  }
  double p[7] = {0, 0, 0, 0, 0, 0, 0};
  std::stringstream s(pose->second);
  std::string item;
  int n = 0;
  while (std::getline(s, item, ',')) {
    if (n == 7 || !parseDouble(item, &p[n])) {
      *error = "parameter pose must be 7 finite numbers tx,ty,tz,qx,qy,qz,qw";
      return false;
    }
    ++n;
  }
  // std::hypot: the norm of large finite components must not overflow to inf.
  const double qnorm = n == 7 ? std::hypot(std::hypot(p[3], p[4]), std::hypot(p[5], p[6])) : 0;
  if (n != 7 || !(qnorm > 1e-9)) {
    *error =
        "parameter pose must be 7 finite numbers tx,ty,tz,qx,qy,qz,qw with a non-zero "
        "quaternion";
    return false;
  }
  r->T_world_cam = SE3(Eigen::Quaterniond(p[6] / qnorm, p[3] / qnorm, p[4] / qnorm, p[5] / qnorm),
                       Vec3(p[0], p[1], p[2]));
  double w = 0, h = 0, fx = 0;
  if (!get("w", &w, true) || !get("h", &h, true) || !get("fx", &fx, true)) return false;
  if (w != std::floor(w) || h != std::floor(h) || w > 1e6 || h > 1e6 || w < -1e6 || h < -1e6) {
    *error = "parameters w and h must be integers";
    return false;
  }
  double fy = fx, cx = (w - 1) / 2, cy = (h - 1) / 2;
  if (!get("fy", &fy, false) || !get("cx", &cx, false) || !get("cy", &cy, false)) return false;
  r->camera = CameraModel();
  r->camera.width = static_cast<int>(w);
  r->camera.height = static_cast<int>(h);
  r->camera.fx = fx;
  r->camera.fy = fy;
  r->camera.cx = cx;
  r->camera.cy = cy;
  const auto k = q.find("kind");
  *kind = k == q.end() ? "color" : k->second;
  if (*kind == "color") {
    r->channels = kRenderColor;
  } else if (*kind == "depth") {
    r->channels = kRenderDepth;
  } else if (*kind == "sigma") {
    r->channels = kRenderSigma;
  } else {
    *error = "parameter kind must be color, depth or sigma";
    return false;
  }
  r->client = "http";
  const std::string invalid = validateRenderRequest(*r);
  if (!invalid.empty()) {
    *error = invalid;
    return false;
  }
  return true;
}

ViewerServer::ViewerServer(const ViewerState* state, RenderFunction render,
                           const std::string& web_dir)
    : state_(state), render_(std::move(render)), server_(std::make_unique<httplib::Server>()) {
  const std::string html = readFile(web_dir + "/index.html");
  assets_["/"] = {"text/html; charset=utf-8", html};
  assets_["/index.html"] = {"text/html; charset=utf-8", html};
  assets_["/viewer.js"] = {"text/javascript; charset=utf-8", readFile(web_dir + "/viewer.js")};
  assets_["/style.css"] = {"text/css; charset=utf-8", readFile(web_dir + "/style.css")};
  routes();
}

ViewerServer::~ViewerServer() { stop(); }

void ViewerServer::routes() {
  httplib::Server& s = *server_;
  // Static files: exact whitelist matches only; anything else (including ../) is 404.
  for (const auto& [path, asset] : assets_) {
    const auto* a = &asset;
    s.Get(path, [a](const httplib::Request&, httplib::Response& res) {
      res.set_content(a->second, a->first.c_str());
      res.set_header("Cache-Control", "no-cache");
    });
  }
  s.Get("/state.json", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(state_->stateJson(), "application/json");
    res.set_header("Cache-Control", "no-store");
  });
  s.Get(R"(/image/(camera|render|depth|sigma)\.jpg)",
        [this](const httplib::Request& req, httplib::Response& res) {
          const std::string name = req.matches[1];
          const ViewerImage which = name == "camera"   ? ViewerImage::kCamera
                                    : name == "render" ? ViewerImage::kRender
                                    : name == "depth"  ? ViewerImage::kDepth
                                                       : ViewerImage::kSigma;
          const std::vector<uint8_t> jpg = state_->imageJpeg(which);
          if (jpg.empty()) {
            res.status = 404;
            res.set_content("no " + name + " image yet", "text/plain");
            return;
          }
          res.set_content(std::string(jpg.begin(), jpg.end()), "image/jpeg");
          res.set_header("Cache-Control", "no-store");
        });
  s.Get("/render", [this](const httplib::Request& req, httplib::Response& res) {
    std::map<std::string, std::string> query(req.params.begin(), req.params.end());
    RenderRequest request;
    std::string kind, error;
    if (!parseRenderQuery(query, &request, &kind, &error)) {
      res.status = 400;
      res.set_content(jsonError("/render: " + error), "application/json");
      return;
    }
    const RenderResult result = render_(request);
    if (!result.ok) {
      res.status = 400;
      res.set_content(jsonError("/render: " + result.error), "application/json");
      return;
    }
    cv::Mat image = kind == "color"   ? result.color
                    : kind == "depth" ? colorizeDepth(result.depth)
                                      : colorizeSigma(result.sigma);
    std::vector<uint8_t> png;
    cv::imencode(".png", image, png);
    res.set_content(std::string(png.begin(), png.end()), "image/png");
    res.set_header("Cache-Control", "no-store");
    res.set_header("X-Field-Version", std::to_string(result.field_version));
  });
}

int ViewerServer::start(const std::string& host, int port) {
  if (thread_.joinable()) throw std::runtime_error("viewer server already started");
  if (port == 0) {
    port_ = server_->bind_to_any_port(host);
  } else {
    port_ = server_->bind_to_port(host, port) ? port : -1;
  }
  if (port_ <= 0)
    throw std::runtime_error("viewer: cannot bind http://" + host + ":" + std::to_string(port));
  listen_returned_ = false;
  thread_ = std::thread([this] {
    server_->listen_after_bind();
    listen_returned_ = true;
  });
  // httplib's stop() does nothing before the loop runs: a stop() right after start() would
  // leave the thread listening forever.
  while (!server_->is_running() && !listen_returned_)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  return port_;
}

void ViewerServer::stop() {
  if (server_) server_->stop();
  if (thread_.joinable()) thread_.join();
}

}  // namespace radslam
