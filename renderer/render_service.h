// Answers RENDER_REQUEST messages from the field replica: checks the request, renders colour,
// depth and depth sigma at any pose and intrinsics, and never throws on bad input.
#pragma once

#include <string>

#include "common/types.h"
#include "renderer/field_replica.h"

namespace radslam {

/// Largest width or height of a requested view (pixels).
inline constexpr int kMaxRenderSize = 4096;

/// "" when the request can be rendered, else what is wrong with it (size zero or above
/// kMaxRenderSize, non-finite pose or intrinsics, fx or fy <= 0, unknown channel bits).
std::string validateRenderRequest(const RenderRequest& request);

/// The view a request asks for: ok=false with the error text for a bad request; otherwise
/// colour (CV_8UC3 BGR), depth and sigma (CV_32FC1, m; 0 = unknown) as the channels ask,
/// with the replica's field version. request_id and client are copied back. preview: a live
/// view (FieldReplica::renderPreview) instead of the mapper's march.
struct PreviewOptions {
  MarchParams march;
  double refresh_budget_s = 0;
};
RenderResult renderView(const FieldReplica& replica, const RenderRequest& request,
                        const PreviewOptions* preview = nullptr);

/// Colour-mapped views for display (CV_8UC3 BGR): depth with TURBO over [0, max_m] (max_m <= 0:
/// the 98th percentile of the valid depths) and sigma with INFERNO over [0, max_m] likewise;
/// unknown pixels (0 or non-finite) are black.
cv::Mat colorizeDepth(const cv::Mat& depth, double max_m = 0);
cv::Mat colorizeSigma(const cv::Mat& sigma, double max_m = 0);

}  // namespace radslam
