// Bilinear interpolation in an image, for the loops that sample single points (cv::remap
// samples whole images).
#pragma once

#include <opencv2/core.hpp>

namespace radslam {

/// The value of a T-valued image at (x0 + ax, y0 + ay), interpolated between the 2 x 2 pixels
/// from (x0, y0) with weights of type W (ax, ay in [0, 1)). The caller keeps x0 in
/// [0, cols - 2] and y0 in [0, rows - 2].
template <typename T, typename W>
auto bilinearAt(const cv::Mat& image, int x0, int y0, W ax, W ay) {
  const T* row0 = image.ptr<T>(y0);
  const T* row1 = image.ptr<T>(y0 + 1);
  return (1 - ay) * ((1 - ax) * row0[x0] + ax * row0[x0 + 1]) +
         ay * ((1 - ax) * row1[x0] + ax * row1[x0 + 1]);
}

}  // namespace radslam
