// libFuzzer target for the viewer's GET /render parameters: the input is a URL
// query string ("pose=...&w=...&kind=depth"), split and unescaped by cpp-httplib
// as the server does, then given to parseRenderQuery (renderer/viewer_server.h).
// A request it accepts must pass the renderer's own validation.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>

#include "renderer/render_service.h"
#include "renderer/viewer_server.h"

// After Eigen (through the radslam headers): clang 14 rejects Eigen's product
// kernels when cpp-httplib's headers come first.
#include <httplib.h>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  httplib::Params params;
  httplib::detail::parse_query_text(text, params);
  const std::map<std::string, std::string> query(params.begin(), params.end());
  radslam::RenderRequest request;
  std::string kind, error;
  if (!radslam::parseRenderQuery(query, &request, &kind, &error)) {
    if (error.empty()) {
      std::fprintf(stderr, "viewer fuzz: rejected without an error message\n");
      std::abort();
    }
    return 0;
  }
  const std::string invalid = radslam::validateRenderRequest(request);
  if (!invalid.empty() || (kind != "color" && kind != "depth" && kind != "sigma")) {
    std::fprintf(stderr, "viewer fuzz: accepted an invalid request: %s\n", invalid.c_str());
    std::abort();
  }
  return 0;
}
