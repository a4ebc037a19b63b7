#include "tracker/depth_upsampling.h"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace radslam {

UpsampledDepth upsampleDepth(const cv::Mat& grid_inv_depth, const cv::Mat& grid_inv_depth_var,
                             const cv::Mat& guide, int cell,
                             const DepthUpsamplingOptions& options) {
  if (grid_inv_depth.type() != CV_32FC1 || grid_inv_depth_var.type() != CV_32FC1 ||
      grid_inv_depth.size() != grid_inv_depth_var.size() || grid_inv_depth.empty()) {
    throw std::invalid_argument(
        "upsampleDepth: inverse depth and variance must be non-empty CV_32FC1 of one size");
  }
  if (cell < 1 || guide.type() != CV_8UC1 || guide.cols != cell * grid_inv_depth.cols ||
      guide.rows != cell * grid_inv_depth.rows) {
    throw std::invalid_argument("upsampleDepth: guide must be CV_8UC1 of " + std::to_string(cell) +
                                " x the grid size " + std::to_string(grid_inv_depth.cols) + "x" +
                                std::to_string(grid_inv_depth.rows));
  }
  if (!(options.sigma_range > 0)) {
    throw std::invalid_argument("upsampleDepth: sigma_range must be > 0");
  }
  const int gw = grid_inv_depth.cols, gh = grid_inv_depth.rows;
  const int W = guide.cols, H = guide.rows;
  // Guide per cell: its exact mean in float (an 8-bit INTER_AREA result would be rounded).
  cv::Mat guide_f, guide_cells_f;
  guide.convertTo(guide_f, CV_32F);
  cv::resize(guide_f, guide_cells_f, grid_inv_depth.size(), 0, 0, cv::INTER_AREA);

  // Range kernel 1 / (1 + t + t^2 / 2 + t^3 / 6), t = dI^2 / (2 sigma_range^2): exp(-t) to
  // second order near 0 with the same scale, cheap enough for the per-pixel loop (no exp, no
  // table lookup), and decaying as dI^-6, fast enough to keep edges.
  const float range_scale = static_cast<float>(0.5 / (options.sigma_range * options.sigma_range));
  auto range = [range_scale](float dI) {
    const float t = dI * dI * range_scale;
    return 1.0f / (1.0f + t * (1.0f + t * (0.5f + t * (1.0f / 6.0f))));
  };

  UpsampledDepth out;
  out.inv_depth.create(H, W, CV_32FC1);
  out.inv_depth_var.create(H, W, CV_32FC1);
  out.depth.create(H, W, CV_32FC1);
  out.depth_var.create(H, W, CV_32FC1);
  const float inf = std::numeric_limits<float>::infinity();
  const float half = 0.5f * (cell - 1);

  // Bilinear support: output coordinate x sits at g = (x - half) / cell on the grid, between
  // cells base = floor(g) and base + 1 with tent weights 1 - a and a (a = g - base).
  std::vector<int> base_x(W), base_y(H);
  std::vector<float> a_x(W), a_y(H);
  for (int x = 0; x < W; ++x) {
    const float g = (x - half) / cell;
    base_x[x] = static_cast<int>(std::floor(g));
    a_x[x] = g - base_x[x];
  }
  for (int y = 0; y < H; ++y) {
    const float g = (y - half) / cell;
    base_y[y] = static_cast<int>(std::floor(g));
    a_y[y] = g - base_y[y];
  }
  // Grid values padded by one cell of "no information" on each side, so the taps need no
  // bounds checks; uninformed cells carry ok = 0 and zero value and variance.
  constexpr int kPad = 1;
  cv::Mat pd(gh + 2 * kPad, gw + 2 * kPad, CV_32FC1, cv::Scalar(0));
  cv::Mat pv(pd.size(), CV_32FC1, cv::Scalar(0));
  cv::Mat pok(pd.size(), CV_32FC1, cv::Scalar(0));
  cv::Mat pg(pd.size(), CV_32FC1, cv::Scalar(0));
  for (int v = 0; v < gh; ++v) {
    for (int u = 0; u < gw; ++u) {
      const float d = grid_inv_depth.at<float>(v, u), var = grid_inv_depth_var.at<float>(v, u);
      const bool ok = std::isfinite(d) && std::isfinite(var) && var > 0;
      pd.at<float>(v + kPad, u + kPad) = ok ? d : 0;
      pv.at<float>(v + kPad, u + kPad) = ok ? var : 0;
      pok.at<float>(v + kPad, u + kPad) = ok ? 1 : 0;
      pg.at<float>(v + kPad, u + kPad) = guide_cells_f.at<float>(v, u);
    }
  }

  for (int y = 0; y < H; ++y) {
    const uint8_t* gi = guide.ptr<uint8_t>(y);
    float* od = out.inv_depth.ptr<float>(y);
    float* ov = out.inv_depth_var.ptr<float>(y);
    float* oz = out.depth.ptr<float>(y);
    float* ozv = out.depth_var.ptr<float>(y);
    const int row0 = base_y[y] + kPad;
    const float wy[2] = {1 - a_y[y], a_y[y]};
    const float* d0 = pd.ptr<float>(row0);
    const float* d1 = pd.ptr<float>(row0 + 1);
    const float* v0 = pv.ptr<float>(row0);
    const float* v1 = pv.ptr<float>(row0 + 1);
    const float* k0 = pok.ptr<float>(row0);
    const float* k1 = pok.ptr<float>(row0 + 1);
    const float* g0 = pg.ptr<float>(row0);
    const float* g1 = pg.ptr<float>(row0 + 1);
    for (int x = 0; x < W; ++x) {
      const float I = gi[x];
      const int c = base_x[x] + kPad;
      // Bilinear weights of the 4 taps (zero for uninformed cells).
      const float b00 = wy[0] * (1 - a_x[x]) * k0[c], b01 = wy[0] * a_x[x] * k0[c + 1];
      const float b10 = wy[1] * (1 - a_x[x]) * k1[c], b11 = wy[1] * a_x[x] * k1[c + 1];
      const float w00 = b00 * range(I - g0[c]), w01 = b01 * range(I - g0[c + 1]);
      const float w10 = b10 * range(I - g1[c]), w11 = b11 * range(I - g1[c + 1]);
      float sw = w00 + w01 + w10 + w11;
      float sd = w00 * d0[c] + w01 * d0[c + 1] + w10 * d1[c] + w11 * d1[c + 1];
      float sv = w00 * v0[c] + w01 * v0[c + 1] + w10 * v1[c] + w11 * v1[c + 1];
      // A pixel unlike all its neighbours (range weights underflow) falls back to the bilinear
      // weights rather than to "unknown".
      if (!(sw > 1e-12f)) {
        sw = b00 + b01 + b10 + b11;
        sd = b00 * d0[c] + b01 * d0[c + 1] + b10 * d1[c] + b11 * d1[c + 1];
        sv = b00 * v0[c] + b01 * v0[c + 1] + b10 * v1[c] + b11 * v1[c + 1];
      }
      if (!(sw > 0)) {
        od[x] = 0;
        ov[x] = inf;
        oz[x] = 0;
        ozv[x] = inf;
        continue;
      }
      const float inv_sw = 1.0f / sw;
      const float d = sd * inv_sw, var = sv * inv_sw;
      od[x] = d;
      ov[x] = var;
      if (d > 0) {
        const float z = 1.0f / d;
        oz[x] = z;
        ozv[x] = var * (z * z) * (z * z);
      } else {
        oz[x] = 0;
        ozv[x] = inf;
      }
    }
  }
  return out;
}

void addSensorDetail(const cv::Mat& sensor_inv_depth, const cv::Mat& sensor_inv_depth_var,
                     const cv::Mat& correction, UpsampledDepth* estimate) {
  const cv::Size size = estimate->inv_depth.size();
  const cv::Mat* images[] = {&sensor_inv_depth,        &sensor_inv_depth_var, &correction,
                             &estimate->inv_depth_var, &estimate->depth,      &estimate->depth_var};
  for (const cv::Mat* m : images) {
    if (m->type() != CV_32FC1 || m->size() != size) {
      throw std::invalid_argument(
          "addSensorDetail: sensor and estimate images must be CV_32FC1 of one size");
    }
  }
  for (int y = 0; y < size.height; ++y) {
    const float* s = sensor_inv_depth.ptr<float>(y);
    const float* s_var = sensor_inv_depth_var.ptr<float>(y);
    const float* c = correction.ptr<float>(y);
    float* d = estimate->inv_depth.ptr<float>(y);
    float* var = estimate->inv_depth_var.ptr<float>(y);
    float* z = estimate->depth.ptr<float>(y);
    float* z_var = estimate->depth_var.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) {
      if (!(s[x] > 0) || !std::isfinite(s[x]) || !std::isfinite(s_var[x])) continue;
      const bool known = d[x] > 0 && std::isfinite(var[x]);
      const float detailed = s[x] + (std::isfinite(c[x]) ? c[x] : 0.0f);
      if (!(detailed > 0)) continue;
      d[x] = detailed;
      var[x] = (known ? var[x] : 0.0f) + s_var[x];
      z[x] = 1.0f / detailed;
      z_var[x] = var[x] * (z[x] * z[x]) * (z[x] * z[x]);
    }
  }
}

}  // namespace radslam
