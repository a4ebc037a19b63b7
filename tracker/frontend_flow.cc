#include "tracker/frontend_flow.h"

#include "tracker/dense_ba.h"
#include "tracker/frontend_refine.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace radslam {
namespace {

// Confidence statistics use every kSampleStride-th pixel of every kSampleStride-th row.
constexpr int kSampleStride = 2;

int presetOf(const std::string& name) {
  if (name == "ultrafast") return cv::DISOpticalFlow::PRESET_ULTRAFAST;
  if (name == "fast") return cv::DISOpticalFlow::PRESET_FAST;
  if (name == "medium") return cv::DISOpticalFlow::PRESET_MEDIUM;
  throw std::invalid_argument("flow preset '" + name + "' is unknown (ultrafast, fast, medium)");
}

}  // namespace

cv::Mat flowTargetMap(const cv::Mat& flow, cv::Point origin) {
  CV_Assert(flow.type() == CV_32FC2);
  cv::Mat map(flow.size(), CV_32FC2);
  for (int y = 0; y < flow.rows; ++y) {
    const cv::Vec2f* f = flow.ptr<cv::Vec2f>(y);
    cv::Vec2f* m = map.ptr<cv::Vec2f>(y);
    const float yf = static_cast<float>(y + origin.y);
    for (int x = 0; x < flow.cols; ++x) {
      const bool known = std::isfinite(f[x][0]) && std::isfinite(f[x][1]);
      m[x] = known ? cv::Vec2f(static_cast<float>(x + origin.x) + f[x][0], yf + f[x][1])
                   : cv::Vec2f(-1e4f, -1e4f);
    }
  }
  return map;
}

DenseFlow::DenseFlow(const FlowOptions& options) : options_(options) {
  presetOf(options.preset);  // throws on an unknown preset
  if (options.finest_scale < 0 || options.finest_scale > 6) {
    throw std::invalid_argument("flow finest_scale must be in [0, 6], got " +
                                std::to_string(options.finest_scale));
  }
  if (options.variational_iterations < 0 || options.patch_size < 4 || options.patch_stride < 1 ||
      options.patch_stride > options.patch_size) {
    throw std::invalid_argument(
        "flow options: need variational_iterations >= 0, patch_size >= 4, 1 <= patch_stride <= "
        "patch_size");
  }
}

cv::Ptr<cv::DISOpticalFlow> DenseFlow::makeDis() const {
  cv::Ptr<cv::DISOpticalFlow> dis = cv::DISOpticalFlow::create(presetOf(options_.preset));
  dis->setFinestScale(options_.finest_scale);
  dis->setVariationalRefinementIterations(options_.variational_iterations);
  dis->setPatchSize(options_.patch_size);
  dis->setPatchStride(options_.patch_stride);
  dis->setUseSpatialPropagation(options_.spatial_propagation);
  return dis;
}

cv::Mat DenseFlow::compute(const cv::Mat& grey_a, const cv::Mat& grey_b, const cv::Mat& init,
                           WarmStart warm_start) {
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 && grey_a.size() == grey_b.size());
  const cv::Mat a = grey_a.isContinuous() ? grey_a : grey_a.clone();
  const cv::Mat b = grey_b.isContinuous() ? grey_b : grey_b.clone();
  const cv::Ptr<cv::DISOpticalFlow> dis = makeDis();
  if (init.empty()) {
    cv::Mat flow;
    dis->calc(a, b, flow);
    return flow;
  }
  CV_Assert(init.type() == CV_32FC2 && init.size() == grey_a.size());
  if (warm_start == WarmStart::kCoarse) {
    cv::Mat flow = init.clone();
    dis->calc(a, b, flow);
    return flow;
  }
  // b warped by the (smoothed) prediction, the residual flow from zero, composed with the
  // prediction: a(x) ~ b_w(x + r(x)) = b(x + r(x) + init(x + r(x))).
  cv::Mat smooth_init = init;
  if (options_.warp_smoothing_px > 0) {
    smooth_init = wideGaussianBlur(init, options_.warp_smoothing_px);
  }
  cv::Mat warped;
  cv::remap(b, warped, flowTargetMap(smooth_init), cv::noArray(), cv::INTER_LINEAR,
            cv::BORDER_REPLICATE);
  cv::Mat residual;
  dis->calc(a, warped, residual);
  cv::Mat init_at_target;
  cv::remap(smooth_init, init_at_target, flowTargetMap(residual), cv::noArray(), cv::INTER_LINEAR,
            cv::BORDER_REPLICATE);
  return residual + init_at_target;
}

namespace {

/// grey with its moving pixels taken from source where flow sends them; grey itself without a
/// mask.
cv::Mat paintFrom(const cv::Mat& grey, const cv::Mat& moving, const cv::Mat& source,
                  const cv::Mat& flow) {
  if (moving.empty()) return grey;
  CV_Assert(moving.type() == CV_8UC1 && moving.size() == grey.size());
  // Only the mask's bounding box is sampled: objects cover a small part of most frames.
  const cv::Rect box = cv::boundingRect(moving);
  if (box.empty()) return grey;
  cv::Mat sampled;
  cv::remap(source, sampled, flowTargetMap(flow(box), box.tl()), cv::noArray(), cv::INTER_LINEAR,
            cv::BORDER_REPLICATE);
  cv::Mat painted = grey.clone();
  sampled.copyTo(painted(box), moving(box));
  return painted;
}

}  // namespace

std::pair<cv::Mat, cv::Mat> paintOutMoving(const cv::Mat& grey_a, const cv::Mat& moving_a,
                                           const cv::Mat& grey_b, const cv::Mat& moving_b,
                                           const cv::Mat& flow_ab, const cv::Mat& flow_ba) {
  if ((moving_a.empty() && moving_b.empty()) || flow_ab.empty() || flow_ba.empty())
    return {grey_a, grey_b};
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 && grey_a.size() == grey_b.size());
  CV_Assert(flow_ab.type() == CV_32FC2 && flow_ab.size() == grey_a.size() &&
            flow_ba.type() == CV_32FC2 && flow_ba.size() == grey_a.size());
  // b first: an object that keeps its place in the image (a car ahead driving with the camera)
  // then shows a's view of it carried by the static flow, in both images.
  const cv::Mat painted_b = paintFrom(grey_b, moving_b, grey_a, flow_ba);
  return {paintFrom(grey_a, moving_a, painted_b, flow_ab), painted_b};
}

cv::Mat wideGaussianBlur(const cv::Mat& field, double sigma_px) {
  CV_Assert(sigma_px > 0 && !field.empty());
  const int k = std::clamp(static_cast<int>(sigma_px / 3), 1, 4);
  if (k == 1) {
    cv::Mat out;
    cv::GaussianBlur(field, out, cv::Size(0, 0), sigma_px);
    return out;
  }
  // Padded by the kernel's reach (and to a multiple of k), so that the reflected border is the
  // full-resolution one and the blocks tile the image exactly.
  const int pad = k * static_cast<int>(std::ceil(3 * sigma_px / k));
  cv::Mat padded, blocks, up;
  cv::copyMakeBorder(field, padded, pad, pad + (k - field.rows % k) % k, pad,
                     pad + (k - field.cols % k) % k, cv::BORDER_REFLECT_101);
  cv::resize(padded, blocks, cv::Size(padded.cols / k, padded.rows / k), 0, 0, cv::INTER_AREA);
  // The block mean adds a variance of k^2 / 12 (working px^2), the bilinear upsampling k^2 / 6;
  // k <= sigma / 3 leaves plenty.
  const double block_sigma = std::sqrt(sigma_px * sigma_px - 0.25 * k * k) / k;
  cv::GaussianBlur(blocks, blocks, cv::Size(0, 0), block_sigma);
  cv::resize(blocks, up, padded.size(), 0, 0, cv::INTER_LINEAR);
  return up(cv::Rect(pad, pad, field.cols, field.rows)).clone();
}

cv::Mat predictedFlow(const cv::Mat& grid_targets, const GridGeometry& geometry) {
  if (grid_targets.empty()) return {};
  CV_Assert(grid_targets.type() == CV_32FC2 && grid_targets.size() == geometry.gridSize());
  const float cell = static_cast<float>(geometry.cell);
  cv::Mat flow(grid_targets.size(), CV_32FC2);
  std::vector<float> fu, fv;
  for (int v = 0; v < flow.rows; ++v) {
    const cv::Vec2f* t = grid_targets.ptr<cv::Vec2f>(v);
    cv::Vec2f* f = flow.ptr<cv::Vec2f>(v);
    for (int u = 0; u < flow.cols; ++u) {
      f[u] = cv::Vec2f(cell * (t[u][0] - u), cell * (t[u][1] - v));
      if (std::isfinite(f[u][0]) && std::isfinite(f[u][1])) {
        fu.push_back(f[u][0]);
        fv.push_back(f[u][1]);
      }
    }
  }
  cv::Vec2f fill(0, 0);
  if (!fu.empty()) {
    const size_t mid = fu.size() / 2;
    std::nth_element(fu.begin(), fu.begin() + mid, fu.end());
    std::nth_element(fv.begin(), fv.begin() + mid, fv.end());
    fill = cv::Vec2f(fu[mid], fv[mid]);
  }
  for (int v = 0; v < flow.rows; ++v) {
    cv::Vec2f* f = flow.ptr<cv::Vec2f>(v);
    for (int u = 0; u < flow.cols; ++u) {
      if (!std::isfinite(f[u][0]) || !std::isfinite(f[u][1])) f[u] = fill;
    }
  }
  cv::Mat out;
  cv::resize(flow, out, geometry.workingSize(), 0, 0, cv::INTER_LINEAR);
  return out;
}

cv::Mat cellStructureTensor(const cv::Mat& gradients, int cell, const cv::Mat& moving) {
  CV_Assert(gradients.type() == CV_32FC2 && gradients.cols % cell == 0 &&
            gradients.rows % cell == 0);
  CV_Assert(moving.empty() || (moving.type() == CV_8UC1 && moving.size() == gradients.size()));
  cv::Mat g[2];
  cv::split(gradients, g);
  if (!moving.empty()) {
    g[0].setTo(0, moving);
    g[1].setTo(0, moving);
  }
  // Cell means of the three products, then one small merge (cheaper than a 3-channel resize).
  const cv::Size grid(gradients.cols / cell, gradients.rows / cell);
  cv::Mat xx, xy, yy, out;
  cv::resize(g[0].mul(g[0]), xx, grid, 0, 0, cv::INTER_AREA);
  cv::resize(g[0].mul(g[1]), xy, grid, 0, 0, cv::INTER_AREA);
  cv::resize(g[1].mul(g[1]), yy, grid, 0, 0, cv::INTER_AREA);
  cv::merge(std::vector<cv::Mat>{xx, xy, yy}, out);
  return out;
}

Correspondences flowToCorrespondences(const cv::Mat& grey_a, const cv::Mat& grey_b,
                                      const cv::Mat& flow_ab, const cv::Mat& flow_ba,
                                      const GridGeometry& geometry, const FlowOptions& options) {
  return flowToCorrespondences(grey_a, grey_b, flow_ab, flow_ba,
                               cellStructureTensor(imageGradients(grey_a), geometry.cell), geometry,
                               options);
}

Correspondences flowToCorrespondences(const cv::Mat& grey_a, const cv::Mat& grey_b,
                                      const cv::Mat& flow_ab, const cv::Mat& flow_ba,
                                      const cv::Mat& structure_a, const GridGeometry& geometry,
                                      const FlowOptions& options, const cv::Mat& moving_a,
                                      const cv::Mat& moving_b) {
  const cv::Size work = geometry.workingSize();
  const cv::Size grid = geometry.gridSize();
  const int c = geometry.cell;
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 && grey_a.size() == work &&
            grey_b.size() == work);
  CV_Assert(flow_ab.type() == CV_32FC2 && flow_ab.size() == work);
  CV_Assert(flow_ba.empty() || (flow_ba.type() == CV_32FC2 && flow_ba.size() == work));
  CV_Assert(structure_a.type() == CV_32FC3 && structure_a.size() == grid);
  CV_Assert(moving_a.empty() || (moving_a.type() == CV_8UC1 && moving_a.size() == work));
  CV_Assert(moving_b.empty() || (moving_b.type() == CV_8UC1 && moving_b.size() == work));

  // Per-cell statistics from every other pixel of every other row (16 of a cell's 64): the
  // photometric residual after warping b onto a, the forward-backward error and the pixels
  // whose match lands inside b. The mean flow uses every pixel.
  const int n_cells = grid.area();
  std::vector<float> n_in(n_cells, 0), n_all(n_cells, 0), sum_r(n_cells, 0), sum_r2(n_cells, 0),
      sum_fb_uu(n_cells, 0), sum_fb_uv(n_cells, 0), sum_fb_vv(n_cells, 0);
  const float x_hi = work.width - 0.5f, y_hi = work.height - 0.5f;
  const int wmax = work.width - 1, hmax = work.height - 1;
  const bool with_fb = !flow_ba.empty();
  for (int y = 0; y < work.height; y += kSampleStride) {
    const cv::Vec2f* f = flow_ab.ptr<cv::Vec2f>(y);
    const uint8_t* ia = grey_a.ptr<uint8_t>(y);
    const uint8_t* ma = moving_a.empty() ? nullptr : moving_a.ptr<uint8_t>(y);
    const int row = (y / c) * grid.width;
    for (int x = 0; x < work.width; x += kSampleStride) {
      if (ma && ma[x]) continue;  // moving objects say nothing of the camera
      const int k = row + x / c;
      n_all[k] += 1;
      const float xb = x + f[x][0], yb = y + f[x][1];
      if (!(xb >= -0.5f && yb >= -0.5f && xb <= x_hi && yb <= y_hi)) continue;  // NaN: out
      if (!moving_b.empty() && moving_b.at<uint8_t>(std::min(static_cast<int>(yb + 0.5f), hmax),
                                                    std::min(static_cast<int>(xb + 0.5f), wmax))) {
        continue;  // lands on a moving object in b: counts as not matched
      }
      // Bilinear sample at (xb, yb), clamped to the border.
      const float xc = std::min(std::max(xb, 0.0f), static_cast<float>(wmax));
      const float yc = std::min(std::max(yb, 0.0f), static_cast<float>(hmax));
      const int x0 = std::min(static_cast<int>(xc), wmax - 1);
      const int y0 = std::min(static_cast<int>(yc), hmax - 1);
      const float ax = xc - x0, ay = yc - y0;
      const float w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay,
                  w11 = ax * ay;
      const uint8_t* b0 = grey_b.ptr<uint8_t>(y0) + x0;
      const uint8_t* b1 = grey_b.ptr<uint8_t>(y0 + 1) + x0;
      const float r = ia[x] - (w00 * b0[0] + w01 * b0[1] + w10 * b1[0] + w11 * b1[1]);
      n_in[k] += 1;
      sum_r[k] += r;
      sum_r2[k] += r * r;
      if (with_fb) {
        const cv::Vec2f* f0 = flow_ba.ptr<cv::Vec2f>(y0) + x0;
        const cv::Vec2f* f1 = flow_ba.ptr<cv::Vec2f>(y0 + 1) + x0;
        const float eu =
            f[x][0] + w00 * f0[0][0] + w01 * f0[1][0] + w10 * f1[0][0] + w11 * f1[1][0];
        const float ev =
            f[x][1] + w00 * f0[0][1] + w01 * f0[1][1] + w10 * f1[0][1] + w11 * f1[1][1];
        sum_fb_uu[k] += eu * eu;
        sum_fb_uv[k] += eu * ev;
        sum_fb_vv[k] += ev * ev;
      }
    }
  }
  // The cell's mean flow: INTER_AREA averages exactly its pixels (its static ones, with a mask).
  cv::Mat m_flow, static_fraction;
  if (moving_a.empty()) {
    cv::resize(flow_ab, m_flow, grid, 0, 0, cv::INTER_AREA);
  } else {
    cv::Mat is_static, static2, masked_flow;
    cv::compare(moving_a, 0, is_static, cv::CMP_EQ);
    is_static.convertTo(is_static, CV_32F, 1.0 / 255);
    cv::merge(std::vector<cv::Mat>{is_static, is_static}, static2);
    cv::multiply(flow_ab, static2, masked_flow);
    cv::resize(masked_flow, m_flow, grid, 0, 0, cv::INTER_AREA);
    cv::resize(is_static, static_fraction, grid, 0, 0, cv::INTER_AREA);
  }

  Correspondences out;
  out.target.create(grid, CV_32FC2);
  out.weight.create(grid, kFlowWeightType);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const double sigma0_sq = options.sigma0_px * options.sigma0_px;
  std::vector<float> fb_valid;
  int valid = 0;
  for (int v = 0; v < grid.height; ++v) {
    cv::Vec2f* t = out.target.ptr<cv::Vec2f>(v);
    cv::Vec3f* w = out.weight.ptr<cv::Vec3f>(v);
    const cv::Vec2f* mf = m_flow.ptr<cv::Vec2f>(v);
    const float* sf = static_fraction.empty() ? nullptr : static_fraction.ptr<float>(v);
    for (int u = 0; u < grid.width; ++u) {
      w[u] = cv::Vec3f(0, 0, 0);
      const int k = v * grid.width + u;
      // With a mask, a cell needs most of its pixels static; its flow is theirs.
      const double static_share = sf ? sf[u] : 1.0;
      const double frac_in = n_all[k] > 0 ? n_in[k] / n_all[k] : 0;
      const double none = std::numeric_limits<double>::quiet_NaN();
      const double tu = u + (static_share > 0 ? mf[u][0] / static_share : none) / c;
      const double tv = v + (static_share > 0 ? mf[u][1] / static_share : none) / c;
      // A cell counts only when its mean flow is finite and most of its pixels land inside b.
      if (!std::isfinite(tu) || !std::isfinite(tv)) {
        t[u] = cv::Vec2f(nan, nan);
        continue;
      }
      t[u] = cv::Vec2f(static_cast<float>(tu), static_cast<float>(tv));
      if (static_share < 0.5 || frac_in < 0.5 || tu < -0.5 || tv < -0.5 || tu > grid.width - 0.5 ||
          tv > grid.height - 0.5) {
        continue;
      }
      const double mean_r = sum_r[k] / n_in[k];
      const double e_ph = std::sqrt(std::max(0.0, sum_r2[k] / n_in[k] - mean_r * mean_r));
      // The forward-backward error's second moments (grid px^2): a flow that slides along a
      // stripe errs along it only.
      const double fb_uu = sum_fb_uu[k] / (n_in[k] * c * c),
                   fb_uv = sum_fb_uv[k] / (n_in[k] * c * c),
                   fb_vv = sum_fb_vv[k] / (n_in[k] * c * c);
      const double e_fb = std::sqrt(std::max(0.0, fb_uu + fb_vv));
      if (e_fb > options.fb_max_px || e_ph > options.photo_max) continue;
      // Aperture: the flow covariance of a Lucas-Kanade window is proportional to J^-1 (J
      // regularised by grad_floor I), so flow along a stripe, at any angle, gets no weight
      // while flow across it keeps its full weight. Sigma = common I + grad_gain J^-1.
      const cv::Vec3f J = structure_a.at<cv::Vec3f>(v, u);
      const double jxx = J[0] + options.grad_floor, jxy = J[1], jyy = J[2] + options.grad_floor;
      const double det = jxx * jyy - jxy * jxy;
      const double ph = e_ph / options.photo_scale;
      const double common = sigma0_sq + ph * ph;
      // 2 fb_gain M: an isotropic error adds fb_gain e_fb^2 to each component's variance.
      const double fb = 2 * options.fb_gain;
      const double s_uu = common + fb * fb_uu + options.grad_gain * jyy / det;
      const double s_uv = fb * fb_uv - options.grad_gain * jxy / det;
      const double s_vv = common + fb * fb_vv + options.grad_gain * jxx / det;
      const double s_det = s_uu * s_vv - s_uv * s_uv;
      w[u] = cv::Vec3f(static_cast<float>(s_vv / s_det), static_cast<float>(-s_uv / s_det),
                       static_cast<float>(s_uu / s_det));
      fb_valid.push_back(static_cast<float>(e_fb));
      ++valid;
    }
  }
  out.valid_fraction = n_cells > 0 ? static_cast<double>(valid) / n_cells : 0;
  if (!fb_valid.empty()) {
    const size_t mid = fb_valid.size() / 2;
    std::nth_element(fb_valid.begin(), fb_valid.begin() + mid, fb_valid.end());
    out.median_fb_px = fb_valid[mid];
  }
  return out;
}

}  // namespace radslam
