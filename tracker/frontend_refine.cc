#include "tracker/frontend_refine.h"

#include "tracker/dense_ba.h"

#include <cmath>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>
#include <opencv2/imgproc.hpp>

namespace radslam {

cv::Mat imageGradients(const cv::Mat& grey) {
  CV_Assert(grey.type() == CV_8UC1);
  cv::Mat gx, gy, out;
  // The 3x3 Sobel sums 8 x the central difference: scale 1/8 gives grey levels per pixel.
  cv::Sobel(grey, gx, CV_32F, 1, 0, 3, 0.125, 0, cv::BORDER_REPLICATE);
  cv::Sobel(grey, gy, CV_32F, 0, 1, 3, 0.125, 0, cv::BORDER_REPLICATE);
  cv::merge(std::vector<cv::Mat>{gx, gy}, out);
  return out;
}

namespace {

// Affine Lucas-Kanade on one cell from the translation (dx, dy) found: pixel x of a's window
// (offset q from the window centre) is matched at x + d + G q in b, so d is the flow at the
// centre itself, where BA puts it. Leaves (dx, dy) unchanged when the window leaves b or the
// system is singular. grey_b_float: image b as CV_32FC1; descent: scratch of 7 x side^2; res:
// side^2 floats of scratch.
void refineAffine(const cv::Mat& grey_b_float, int side, int xa, int ya, const float* ia,
                  const float* gxs, const float* gys, const float* used, bool offset,
                  const RefineOptions& options, std::vector<float>* descent, float* res, float* dx,
                  float* dy) {
  using Mat7f = Eigen::Matrix<float, 7, 7>;
  const int n = side * side;
  const float centre = 0.5f * (side - 1);
  // Steepest-descent images (g, g_x q, g_y q, 1) at the identity warp, one row of n each.
  descent->resize(7 * n);
  float* sd = descent->data();
  for (int j = 0, k = 0; j < side; ++j) {
    for (int i = 0; i < side; ++i, ++k) {
      const float qx = i - centre, qy = j - centre;
      sd[k] = gxs[k];
      sd[n + k] = gys[k];
      sd[2 * n + k] = gxs[k] * qx;
      sd[3 * n + k] = gxs[k] * qy;
      sd[4 * n + k] = gys[k] * qx;
      sd[5 * n + k] = gys[k] * qy;
      sd[6 * n + k] = offset ? used[k] : 0.f;
    }
  }
  // Each entry a vectorised dot product of two rows; only the lower triangle is read.
  const auto row = [&](int c) { return Eigen::Map<const Eigen::VectorXf>(sd + c * n, n); };
  Mat7f H;
  for (int a = 0; a < 7; ++a) {
    for (int b = 0; b <= a; ++b) H(a, b) = row(a).dot(row(b));
  }
  if (!offset) H(6, 6) = 1;
  const Eigen::LLT<Mat7f> llt(H);
  if (llt.info() != Eigen::Success) return;
  const float max_x = grey_b_float.cols - 1.001f, max_y = grey_b_float.rows - 1.001f;
  const size_t step_b = grey_b_float.step[0] / sizeof(float);
  const float* b = grey_b_float.ptr<float>();
  float d[2] = {*dx, *dy}, G[4] = {0, 0, 0, 0};
  for (int it = 0; it < options.affine_iterations; ++it) {
    for (int j = 0, k = 0; j < side; ++j) {
      const float qy = j - centre;
      // Row start and per-pixel step of the warped position.
      float x = xa + d[0] - centre * G[0] + G[1] * qy;
      float y = ya + j + d[1] - centre * G[2] + G[3] * qy;
      const float step_x = 1 + G[0], step_y = G[2];
      for (int i = 0; i < side; ++i, ++k, x += step_x, y += step_y) {
        if (!(x >= 0 && y >= 0 && x < max_x && y < max_y)) return;
        const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
        const float ax = x - x0, ay = y - y0;
        const float* r0 = b + y0 * step_b + x0;
        const float* r1 = r0 + step_b;
        res[k] = (1 - ay) * ((1 - ax) * r0[0] + ax * r0[1]) + ay * ((1 - ax) * r1[0] + ax * r1[1]) -
                 ia[k];
      }
    }
    const Eigen::Map<const Eigen::VectorXf> r(res, n);
    Eigen::Matrix<float, 7, 1> rhs;
    for (int c = 0; c < 7; ++c) rhs(c) = row(c).dot(r);
    const Eigen::Matrix<float, 7, 1> step = llt.solve(rhs);
    d[0] -= step(0);
    d[1] -= step(1);
    for (int c = 0; c < 4; ++c) G[c] -= step(2 + c);
    if (!std::isfinite(d[0]) || !std::isfinite(d[1])) return;
    if (step.head<2>().squaredNorm() < options.converged_px * options.converged_px) break;
  }
  *dx = d[0];
  *dy = d[1];
}

}  // namespace

int refineTargets(const cv::Mat& grey_a, const cv::Mat& gradients_a, const cv::Mat& grey_b,
                  int cell, const RefineOptions& options, cv::Mat* target, cv::Mat* weight,
                  const cv::Mat& moving_a, cv::Mat* leaning) {
  CV_Assert(grey_a.type() == CV_8UC1 && grey_b.type() == CV_8UC1 &&
            grey_a.size() == grey_b.size() && gradients_a.type() == CV_32FC2 &&
            gradients_a.size() == grey_a.size() && cell >= 1);
  CV_Assert(target && target->type() == CV_32FC2 && target->cols * cell == grey_a.cols &&
            target->rows * cell == grey_a.rows && weight && weight->type() == kFlowWeightType &&
            weight->size() == target->size());
  CV_Assert(moving_a.empty() || (moving_a.type() == CV_8UC1 && moving_a.size() == grey_a.size()));
  const int W = grey_a.cols, H = grey_a.rows;
  const float max_shift2 = static_cast<float>(options.max_shift_px * options.max_shift_px);
  const int m = options.margin;
  const int side = cell + 2 * m;
  const int n = side * side;
  std::vector<float> ia(n), gxs(n), gys(n), used(n), descent, residual(n);
  // b in float: the residuals of a window are sums of shifted blocks of it, vectorised.
  cv::Mat grey_b_float;
  grey_b.convertTo(grey_b_float, CV_32F);
  const Eigen::Index step_b = static_cast<Eigen::Index>(grey_b_float.step[0] / sizeof(float));
  using Block =
      Eigen::Map<const Eigen::Array<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>, 0,
                 Eigen::OuterStride<>>;
  using Window = Eigen::Map<Eigen::Array<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>;
  using ConstWindow =
      Eigen::Map<const Eigen::Array<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>;
  using Row = Eigen::Map<const Eigen::ArrayXf>;
  const ConstWindow ia_window(ia.data(), side, side);
  const Row gx_row(gxs.data(), n), gy_row(gys.data(), n), used_row(used.data(), n),
      r(residual.data(), n);
  const bool offset = options.brightness_offset;
  if (leaning) *leaning = cv::Mat::zeros(target->size(), CV_8UC1);
  int refined = 0;
  for (int v = 0; v < target->rows; ++v) {
    cv::Vec2f* t = target->ptr<cv::Vec2f>(v);
    cv::Vec3f* w = weight->ptr<cv::Vec3f>(v);
    for (int u = 0; u < target->cols; ++u) {
      if (!(w[u][0] > 0 || w[u][2] > 0) || !std::isfinite(t[u][0]) || !std::isfinite(t[u][1])) {
        continue;
      }
      // The cell's pixels, gradients and the constant Hessian of (dx, dy, offset).
      float sxx = 0, sxy = 0, syy = 0, sx = 0, sy = 0, n_used = 0;
      int k = 0;
      const int xa = u * cell - m, ya = v * cell - m;  // window corner in a
      if (xa < 0 || ya < 0 || xa + side > W || ya + side > H) {
        if (options.reject_failures) w[u] = cv::Vec3f(0, 0, 0);
        continue;
      }
      for (int j = 0; j < side; ++j) {
        const uint8_t* ra = grey_a.ptr<uint8_t>(ya + j) + xa;
        const cv::Vec2f* rg = gradients_a.ptr<cv::Vec2f>(ya + j) + xa;
        const uint8_t* rm = moving_a.empty() ? nullptr : moving_a.ptr<uint8_t>(ya + j) + xa;
        for (int i = 0; i < side; ++i, ++k) {
          // Pixels of moving objects take no part (zero gradient, no offset term).
          used[k] = rm && rm[i] ? 0.f : 1.f;
          n_used += used[k];
          ia[k] = ra[i];
          gxs[k] = used[k] * rg[i][0];
          gys[k] = used[k] * rg[i][1];
          sxx += gxs[k] * gxs[k];
          sxy += gxs[k] * gys[k];
          syy += gys[k] * gys[k];
          sx += gxs[k];
          sy += gys[k];
        }
      }
      Eigen::Matrix3d Hm;
      Hm << sxx, sxy, sx, sxy, syy, sy, sx, sy, n_used;
      if (!offset) {
        Hm.row(2).setZero();
        Hm.col(2).setZero();
        Hm(2, 2) = 1;
      }
      if (!(Hm.topLeftCorner<2, 2>().determinant() > options.min_det)) {
        if (options.reject_failures) w[u] = cv::Vec3f(0, 0, 0);
        continue;
      }
      const Eigen::Matrix3d Hinv = Hm.inverse();
      // Displacement of the cell (working px) from its grid target.
      const float dx0 = cell * (t[u][0] - u), dy0 = cell * (t[u][1] - v);
      // Translation Lucas-Kanade from (*dx, *dy); false when the window leaves b.
      const auto translate = [&](int iterations, float* dx, float* dy) {
        for (int it = 0; it < iterations; ++it) {
          // A translation: every pixel of the window shares the bilinear weights.
          const float xs = xa + *dx, ys = ya + *dy;
          if (!(xs >= 0 && ys >= 0 && xs + side - 1 <= W - 1 && ys + side - 1 <= H - 1)) {
            return false;
          }
          const int x0 = std::min(static_cast<int>(xs), W - side - 1);
          const int y0 = std::min(static_cast<int>(ys), H - side - 1);
          const float ax = xs - x0, ay = ys - y0;
          const float w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay,
                      w11 = ax * ay;
          const float* p = grey_b_float.ptr<float>(y0) + x0;
          const Eigen::OuterStride<> stride(step_b);
          Window(residual.data(), side, side) =
              w00 * Block(p, side, side, stride) + w01 * Block(p + 1, side, side, stride) +
              w10 * Block(p + step_b, side, side, stride) +
              w11 * Block(p + step_b + 1, side, side, stride) - ia_window;
          const float b0 = (gx_row * r).sum(), b1 = (gy_row * r).sum();
          const float b2 = offset ? (used_row * r).sum() : 0.f;
          const Eigen::Vector3d step = Hinv * Eigen::Vector3d(b0, b1, b2);
          *dx -= static_cast<float>(step(0));
          *dy -= static_cast<float>(step(1));
          if (step.head<2>().squaredNorm() < options.converged_px * options.converged_px) break;
        }
        return true;
      };
      float dx = dx0, dy = dy0;
      bool ok = translate(options.iterations, &dx, &dy);
      bool leans = false;
      if (ok && options.start_check_px > 0) {
        // The same cell from further along its flow must end where the first run did.
        const float length = std::hypot(dx0, dy0);
        const float along = static_cast<float>(options.start_check_px);
        float cx = dx0 + (length > 1e-3f ? along * dx0 / length : along);
        float cy = dy0 + (length > 1e-3f ? along * dy0 / length : 0.f);
        const float tolerance = static_cast<float>(options.start_check_tolerance_px);
        leans = !translate(options.start_check_iterations, &cx, &cy) ||
                (cx - dx) * (cx - dx) + (cy - dy) * (cy - dy) > tolerance * tolerance;
      }
      if (ok && !leans && options.affine_iterations > 0) {
        refineAffine(grey_b_float, side, xa, ya, ia.data(), gxs.data(), gys.data(), used.data(),
                     offset, options, &descent, residual.data(), &dx, &dy);
      }
      const float mx = dx - dx0, my = dy - dy0;
      if (!ok || !std::isfinite(dx) || !std::isfinite(dy) || mx * mx + my * my > max_shift2) {
        if (options.reject_failures) w[u] = cv::Vec3f(0, 0, 0);
        continue;
      }
      t[u] = cv::Vec2f(u + dx / cell, v + dy / cell);
      if (leans) {
        w[u] = cv::Vec3f(0, 0, 0);
        if (leaning) leaning->at<uint8_t>(v, u) = 255;
        continue;
      }
      ++refined;
    }
  }
  return refined;
}

}  // namespace radslam
