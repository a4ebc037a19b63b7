#include "tracker/frontend.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/synthetic.h"
#include "tracker/dense_ba.h"
#include "tracker/frontend_depth.h"
#include "tracker/frontend_flow.h"
#include "tracker/frontend_refine.h"
#include "tracker/motion_only.h"

namespace radslam {
namespace {

constexpr int kCell = 8;

CameraModel pinhole(int w, int h, double f) {
  CameraModel c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = f;
  c.cx = 0.5 * (w - 1);
  c.cy = 0.5 * (h - 1);
  return c;
}

double quantile(std::vector<double> values, double q) {
  if (values.empty()) return std::numeric_limits<double>::infinity();
  std::sort(values.begin(), values.end());
  return values[static_cast<size_t>(q * (values.size() - 1))];
}

TEST(GridGeometry, PixelCentreConvention) {
  CameraModel work = pinhole(512, 384, 400);
  work.cx = 260.25;
  work.cy = 190.5;
  const GridGeometry g = makeGridGeometry(work, kCell);
  EXPECT_EQ(g.grid.width, 64);
  EXPECT_EQ(g.grid.height, 48);
  // Grid pixel u is working pixel 8 u + 3.5: the principal point maps accordingly.
  EXPECT_DOUBLE_EQ(g.grid.cx, (work.cx - 3.5) / 8);
  EXPECT_DOUBLE_EQ(g.grid.cy, (work.cy - 3.5) / 8);
  EXPECT_DOUBLE_EQ(g.grid.fx, work.fx / 8);
  // A 3-d point projects consistently at both resolutions.
  const Vec3 p(0.3, -0.2, 2.0);
  const Eigen::Vector2d pw = project(work, p), pg = project(g.grid, p);
  EXPECT_NEAR(8 * pg.x() + 3.5, pw.x(), 1e-9);
  EXPECT_NEAR(8 * pg.y() + 3.5, pw.y(), 1e-9);
  EXPECT_THROW(makeGridGeometry(pinhole(500, 384, 400), kCell), std::invalid_argument);
}

TEST(GridGeometry, WorkingSizeKeepsAspectInCellMultiples) {
  EXPECT_EQ(workingSize(640, 480, 512, kCell), cv::Size(512, 384));
  EXPECT_EQ(workingSize(1226, 370, 512, kCell), cv::Size(512, 152));
  EXPECT_EQ(workingSize(320, 240, 512, kCell), cv::Size(320, 240));  // never upsampled
  EXPECT_EQ(workingSize(1200, 680, 0, kCell), cv::Size(1200, 680));
  EXPECT_THROW(workingSize(10, 10, 512, kCell), std::invalid_argument);
}

TEST(ImagePreparer, UndistortsAndHalvesLargeInput) {
  // TUM fr1: distorted 640x480 -> pinhole 512x384.
  CameraModel tum = pinhole(640, 480, 517.3);
  tum.type = CameraModel::Type::kRadTan;
  tum.distortion = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
  const ImagePreparer prep(tum, 512, kCell);
  EXPECT_EQ(prep.geometry().working.width, 512);
  EXPECT_EQ(prep.geometry().working.height, 384);
  EXPECT_EQ(prep.geometry().working.type, CameraModel::Type::kPinhole);
  Frame frame;
  frame.camera = tum;
  frame.color = cv::Mat(480, 640, CV_8UC3, cv::Scalar(10, 20, 30));
  const PreparedImage out = prep.prepare(frame, true);
  EXPECT_EQ(out.grey.size(), cv::Size(512, 384));
  EXPECT_EQ(out.color.type(), CV_8UC3);

  // KITTI-like: 1226x370 pinhole -> 512x152; a vertical bar keeps its place.
  const CameraModel kitti = pinhole(1226, 370, 707.09);
  const ImagePreparer kp(kitti, 512, kCell);
  Frame kf;
  kf.camera = kitti;
  kf.color = cv::Mat(370, 1226, CV_8UC1, cv::Scalar(0));
  kf.color.colRange(600, 640).setTo(255);
  const PreparedImage ko = kp.prepare(kf, false);
  ASSERT_EQ(ko.grey.size(), cv::Size(512, 152));
  const CameraModel& w = kp.geometry().working;
  const double bar_centre = (619.5 + 0.5) * w.width / 1226.0 - 0.5;
  cv::Moments m = cv::moments(ko.grey.row(70), false);
  EXPECT_NEAR(m.m10 / m.m00, bar_centre, 0.3);
}

TEST(ImagePreparer, RejectsBadFrames) {
  const CameraModel cam = pinhole(64, 48, 50);
  const ImagePreparer prep(cam, 64, kCell);
  Frame f;
  f.camera = cam;
  EXPECT_THROW(prep.prepare(f, false), std::invalid_argument);  // empty
  f.color = cv::Mat(40, 64, CV_8UC1, cv::Scalar(0));
  EXPECT_THROW(prep.prepare(f, false), std::invalid_argument);  // size differs
  f.color = cv::Mat(48, 64, CV_8UC1, cv::Scalar(0));
  f.depth = cv::Mat(48, 64, CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  EXPECT_THROW(prep.prepare(f, false), std::invalid_argument);  // NaN depth
  f.depth.setTo(1.0f);
  EXPECT_NO_THROW(prep.prepare(f, false));
  f.depth_time_offset_s = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(prep.prepare(f, false), std::invalid_argument);  // depth taken at no known time
  f.depth_time_offset_s = 0;
  f.depth.release();
  f.camera.fx = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(prep.prepare(f, false), std::invalid_argument);  // NaN intrinsics
  f.camera = cam;
  f.right = f.color.clone();
  EXPECT_THROW(prep.prepare(f, false), std::invalid_argument);  // right without baseline
}

TEST(SensorDepthToGrid, ASlantedPlaneGivesEachCellItsCentresDepth) {
  // Inverse depth is linear in the pixel across a plane (here a road-like slope down the rows
  // and a facade-like one along them); each cell must get the depth at its centre, working
  // pixel 8 u + 3.5, which neither middle value of its 64 depths has on its own.
  const auto inv_depth = [](double x, double y) { return 0.02 + 0.002 * y + 0.0005 * x; };
  cv::Mat depth(64, 96, CV_32FC1);
  for (int y = 0; y < depth.rows; ++y)
    for (int x = 0; x < depth.cols; ++x) depth.at<float>(y, x) = 1.0 / inv_depth(x, y);
  depth.at<float>(5, 83) = 0;   // one invalid pixel: the odd count's plain median
  for (int y = 8; y < 16; ++y)  // a cell with too few valid pixels
    for (int x = 0; x < 6; ++x) depth.at<float>(y, x) = 0;
  const cv::Mat grid = sensorDepthToGrid(depth, kCell, 0.5, 0.1, 1000);
  ASSERT_EQ(grid.size(), cv::Size(12, 8));
  EXPECT_EQ(grid.at<float>(1, 0), 0.0f);
  for (int v = 0; v < grid.rows; ++v) {
    for (int u = 0; u < grid.cols; ++u) {
      if (v == 1 && u == 0) continue;
      const double centre = inv_depth(kCell * u + 3.5, kCell * v + 3.5);
      // The odd cell's median lies within half a pixel's slope of the centre.
      const double tolerance = (v == 0 && u == 10) ? 0.5 * 0.0025 : 1e-6;
      EXPECT_NEAR(1.0 / grid.at<float>(v, u), centre, tolerance) << "cell " << u << "," << v;
    }
  }
}

TEST(DepthPrior, VarianceMatchesSampledInverseDepths) {
  // Depths with the Kinect-like noise of the tracker's defaults, inverted: the sampled variance
  // of 1/z matches the first-order sigma_z^2 / z^4 where sigma_z / z is small.
  const double a = 0.0012, b = 0.0019, z0 = 0.4;
  cv::Mat z(1, 4, CV_32FC1);
  z.at<float>(0) = 0.8f;
  z.at<float>(1) = 2.5f;
  z.at<float>(2) = 4.0f;
  z.at<float>(3) = 0.0f;  // no depth
  cv::Mat inv_depth, inv_depth_var;
  depthPrior(z, a, b, z0, &inv_depth, &inv_depth_var);
  EXPECT_TRUE(std::isnan(inv_depth.at<float>(3)));
  EXPECT_EQ(inv_depth_var.at<float>(3), 0.0f);
  cv::RNG rng(7);
  for (int i = 0; i < 3; ++i) {
    const double zi = z.at<float>(i), sigma_z = a + b * (zi - z0) * (zi - z0);
    EXPECT_NEAR(inv_depth.at<float>(i), 1.0 / zi, 1e-6);
    double sum = 0, sum2 = 0;
    const int n = 200000;
    for (int k = 0; k < n; ++k) {
      const double d = 1.0 / (zi + rng.gaussian(sigma_z));
      sum += d;
      sum2 += d * d;
    }
    const double sampled = sum2 / n - (sum / n) * (sum / n);
    EXPECT_NEAR(inv_depth_var.at<float>(i) / sampled, 1.0, 0.03) << "z = " << zi;
  }
}

TEST(Keyframes, SelectionTriggersAtTheThreshold) {
  const cv::Size grid(64, 48);
  const cv::Mat weight(grid, kFlowWeightType, cv::Scalar(1, 0, 1));
  auto shifted = [&](double du, double dv) {
    cv::Mat t(grid, CV_32FC2);
    for (int v = 0; v < grid.height; ++v) {
      for (int u = 0; u < grid.width; ++u) {
        t.at<cv::Vec2f>(v, u) = cv::Vec2f(static_cast<float>(u + du), static_cast<float>(v + dv));
      }
    }
    return t;
  };
  const FlowMotion below = measureFlowMotion(shifted(1.44, 1.92), weight);  // |(1.44, 1.92)| = 2.4
  const FlowMotion above = measureFlowMotion(shifted(1.56, 2.08), weight);  // 2.6
  EXPECT_NEAR(below.mean_flow_px, 2.4, 1e-5);
  EXPECT_NEAR(above.mean_flow_px, 2.6, 1e-5);
  EXPECT_DOUBLE_EQ(below.valid_fraction, 1.0);
  KeyframePolicy policy;
  policy.flow_px = 2.5;
  policy.min_valid_fraction = 0.3;
  EXPECT_FALSE(isNewKeyframe(below, policy));
  EXPECT_TRUE(isNewKeyframe(above, policy));
  // Zero-weight pixels do not count; losing most of them forces a keyframe.
  cv::Mat sparse(grid, kFlowWeightType, cv::Scalar(0, 0, 0));
  sparse.rowRange(0, 10).setTo(cv::Scalar(1, 0, 1));
  const FlowMotion lost = measureFlowMotion(shifted(0.5, 0), sparse);
  EXPECT_NEAR(lost.valid_fraction, 10.0 / 48, 1e-9);
  EXPECT_TRUE(isNewKeyframe(lost, policy));
}

TEST(Keyframes, ParallaxSplitsRotationFromTranslation) {
  const GridGeometry g = makeGridGeometry(pinhole(512, 384, 400), kCell);
  const CameraModel& cam = g.grid;
  const cv::Mat weight(g.gridSize(), kFlowWeightType, cv::Scalar(1, 0, 1));
  // Targets of a pure rotation about y: all of the flow is rotation, no parallax.
  const Mat3 R = SO3::exp(Vec3(0, 0.03, 0)).matrix();
  cv::Mat rotated(g.gridSize(), CV_32FC2), shifted(g.gridSize(), CV_32FC2);
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      const Vec3 q = R * Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1);
      rotated.at<cv::Vec2f>(v, u) = cv::Vec2f(static_cast<float>(cam.fx * q.x() / q.z() + cam.cx),
                                              static_cast<float>(cam.fy * q.y() / q.z() + cam.cy));
      shifted.at<cv::Vec2f>(v, u) = cv::Vec2f(u + 3.0f, static_cast<float>(v));
    }
  }
  const FlowMotion r = measureFlowMotion(rotated, weight, cam, R);
  EXPECT_NEAR(r.mean_parallax_px, 0, 1e-3);
  EXPECT_NEAR(r.mean_rotation_px, r.mean_flow_px, 1e-3);
  EXPECT_GT(r.mean_flow_px, 1.4);  // 0.03 rad x fx 50 = 1.5 grid px
  // The same displacement field measured without rotation is all parallax.
  const FlowMotion t = measureFlowMotion(shifted, weight, cam, Mat3::Identity());
  EXPECT_NEAR(t.mean_parallax_px, 3.0, 1e-5);
  EXPECT_NEAR(t.mean_rotation_px, 0, 1e-9);
  KeyframePolicy policy;
  policy.flow_px = 5;
  policy.rotation_px = 2;
  EXPECT_FALSE(isNewKeyframe(t, policy)) << "3 px of parallax < 5: wait for a baseline";
  policy.flow_px = 2.5;
  EXPECT_TRUE(isNewKeyframe(t, policy));
  // 1.5 px of pure rotation is below rotation_px: no keyframe, however large flow_px is not.
  policy.flow_px = 1;
  EXPECT_FALSE(isNewKeyframe(r, policy)) << "rotation alone does not condition depths";
  // Pure rotation beyond rotation_px makes a keyframe whatever the parallax.
  const Mat3 R2 = SO3::exp(Vec3(0, 0.06, 0)).matrix();
  cv::Mat rotated2(g.gridSize(), CV_32FC2);
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      const Vec3 q = R2 * Vec3((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1);
      rotated2.at<cv::Vec2f>(v, u) = cv::Vec2f(static_cast<float>(cam.fx * q.x() / q.z() + cam.cx),
                                               static_cast<float>(cam.fy * q.y() / q.z() + cam.cy));
    }
  }
  policy.flow_px = 100;
  EXPECT_TRUE(isNewKeyframe(measureFlowMotion(rotated2, weight, cam, R2), policy));
}

TEST(Flow, PredictedFlowFollowsTheGridConvention) {
  const GridGeometry g = makeGridGeometry(pinhole(64, 48, 50), kCell);
  cv::Mat targets(g.gridSize(), CV_32FC2);
  for (int v = 0; v < targets.rows; ++v) {
    for (int u = 0; u < targets.cols; ++u)
      targets.at<cv::Vec2f>(v, u) = cv::Vec2f(u + 1.5f, v - 0.5f);
  }
  targets.at<cv::Vec2f>(2, 3) = cv::Vec2f(std::numeric_limits<float>::quiet_NaN(), 0);
  const cv::Mat flow = predictedFlow(targets, g);
  ASSERT_EQ(flow.size(), g.workingSize());
  for (int y = 0; y < flow.rows; ++y) {
    for (int x = 0; x < flow.cols; ++x) {
      EXPECT_NEAR(flow.at<cv::Vec2f>(y, x)[0], 12.0f, 1e-4);  // 8 x 1.5 working px
      EXPECT_NEAR(flow.at<cv::Vec2f>(y, x)[1], -4.0f, 1e-4);
    }
  }
  EXPECT_TRUE(predictedFlow(cv::Mat(), g).empty());
}

TEST(Flow, WideGaussianBlurMatchesTheFullResolutionBlur) {
  // A predicted flow with zoom and 4 px of noise per grid cell (a prediction from noisy
  // depths), at working sizes that are and are not multiples of the block size.
  for (const cv::Size size : {cv::Size(384, 288), cv::Size(250, 187)}) {
    cv::Mat grid(size.height / kCell, size.width / kCell, CV_32FC2);
    cv::RNG rng(3);
    for (int v = 0; v < grid.rows; ++v) {
      for (int u = 0; u < grid.cols; ++u) {
        grid.at<cv::Vec2f>(v, u) = cv::Vec2f(0.4 * (u - grid.cols / 2) + rng.gaussian(4),
                                             0.6 * (v - grid.rows / 2) + rng.gaussian(4));
      }
    }
    cv::Mat flow;
    cv::resize(grid, flow, size, 0, 0, cv::INTER_LINEAR);
    for (const double sigma : {2.0, 7.0, 12.0, 20.0}) {
      cv::Mat reference;
      cv::GaussianBlur(flow, reference, cv::Size(0, 0), sigma);
      const cv::Mat fast = wideGaussianBlur(flow, sigma);
      ASSERT_EQ(fast.size(), flow.size());
      ASSERT_EQ(fast.type(), flow.type());
      cv::Mat diff = cv::abs(fast - reference);
      double max_diff = 0;
      cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
      EXPECT_LT(max_diff, 0.03) << size << " sigma " << sigma;  // working px
    }
  }
}

// Textured images with a textured square that moves over the background: the background the
// square covers in b has no match (occlusion), everything else is a pure translation.
struct OcclusionPair {
  cv::Mat a, b;
  cv::Rect covered_in_b;  // region of a's background hidden in b
};

cv::Mat texture(cv::Size size, int seed) {
  cv::RNG rng(seed);
  cv::Mat noise(size, CV_32FC1);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::Mat smooth;
  cv::GaussianBlur(noise, smooth, cv::Size(0, 0), 2.0);
  cv::normalize(smooth, smooth, 0, 255, cv::NORM_MINMAX);
  cv::Mat out;
  smooth.convertTo(out, CV_8U);
  return out;
}

OcclusionPair makeOcclusionPair() {
  const cv::Size size(256, 192);
  const cv::Mat bg = texture(cv::Size(size.width + 64, size.height + 64), 1);
  const cv::Mat fg = texture(cv::Size(64, 64), 2);
  OcclusionPair p;
  // Background shifts by 4 px right between a and b; the square jumps 40 px left.
  p.a = bg(cv::Rect(32, 32, size.width, size.height)).clone();
  p.b = bg(cv::Rect(28, 32, size.width, size.height)).clone();
  fg.copyTo(p.a(cv::Rect(136, 64, 64, 64)));
  fg.copyTo(p.b(cv::Rect(96, 64, 64, 64)));
  // In a, background at x in [96 - 4, 136 - 4) is covered in b (x_b = x_a + 4 in [96, 136)).
  p.covered_in_b = cv::Rect(92, 64, 40, 64);
  return p;
}

// The background moves 6 px right; a textured square (a car ahead driving with the camera)
// keeps its place in the image and is masked as moving in both images.
TEST(Flow, PaintingOutTheMovingObjectKeepsItsMotionOffTheStaticPixelsAroundIt) {
  const cv::Size size(256, 192);
  const int shift = 6;
  const cv::Mat bg = texture(cv::Size(size.width + 64, size.height + 64), 1);
  const cv::Mat fg = texture(cv::Size(80, 80), 2);
  const cv::Rect square(88, 56, 80, 80);
  cv::Mat a = bg(cv::Rect(32, 32, size.width, size.height)).clone();
  cv::Mat b = bg(cv::Rect(32 - shift, 32, size.width, size.height)).clone();
  fg.copyTo(a(square));
  fg.copyTo(b(square));
  cv::Mat moving(size, CV_8UC1, cv::Scalar(0));
  moving(square).setTo(255);
  const cv::Mat static_ab(size, CV_32FC2, cv::Scalar(shift, 0));
  const cv::Mat static_ba(size, CV_32FC2, cv::Scalar(-shift, 0));

  const auto [painted_a, painted_b] = paintOutMoving(a, moving, b, moving, static_ab, static_ba);
  // Unmasked pixels are untouched; masked ones follow the static motion from one image to the
  // other (exactly, for a whole-pixel shift away from the border).
  EXPECT_EQ(cv::norm(painted_a, a, cv::NORM_INF, ~moving), 0);
  EXPECT_EQ(cv::norm(painted_b, b, cv::NORM_INF, ~moving), 0);
  const cv::Rect inner(square.x + shift, square.y, square.width - shift, square.height);
  EXPECT_EQ(cv::norm(painted_a(inner - cv::Point(shift, 0)), painted_b(inner), cv::NORM_INF), 0);
  // Without masks or a predicted flow the images are returned as they are.
  EXPECT_EQ(paintOutMoving(a, cv::Mat(), b, cv::Mat(), static_ab, static_ba).first.data, a.data);
  EXPECT_EQ(paintOutMoving(a, moving, b, moving, cv::Mat(), static_ba).second.data, b.data);

  // The flow of the static pixels 4-32 px from the square (its mask grown by 3 px is what the
  // tracker leaves out), a -> b.
  cv::Mat ring(size, CV_8UC1, cv::Scalar(0));
  ring(cv::Rect(square.x - 32, square.y - 32, square.width + 64, square.height + 64)).setTo(255);
  ring(cv::Rect(square.x - 4, square.y - 4, square.width + 8, square.height + 8)).setTo(0);
  const auto ring_error = [&](const cv::Mat& dis_a, const cv::Mat& dis_b) {
    DenseFlow flow{FlowOptions()};
    const cv::Mat f = flow.compute(dis_a, dis_b);
    std::vector<double> errors;
    for (int y = 0; y < size.height; ++y) {
      for (int x = 0; x < size.width; ++x) {
        if (!ring.at<uint8_t>(y, x)) continue;
        const cv::Vec2f v = f.at<cv::Vec2f>(y, x);
        errors.push_back(std::hypot(v[0] - shift, v[1]));
      }
    }
    return quantile(errors, 0.9);
  };
  const double plain = ring_error(a, b), painted = ring_error(painted_a, painted_b);
  EXPECT_GT(plain, 0.6) << "the square's zero flow spreads over the ring";
  EXPECT_LT(painted, 0.25) << "plain " << plain;
}

TEST(Flow, ForwardBackwardFailureLowersConfidence) {
  const OcclusionPair p = makeOcclusionPair();
  const GridGeometry g = makeGridGeometry(pinhole(256, 192, 200), kCell);
  FlowOptions options;
  DenseFlow flow(options);
  const cv::Mat f_ab = flow.compute(p.a, p.b);
  const cv::Mat f_ba = flow.compute(p.b, p.a);
  const Correspondences c = flowToCorrespondences(p.a, p.b, f_ab, f_ba, g, options);
  double w_occ = 0, w_bg = 0;
  int n_occ = 0, n_bg = 0;
  for (int v = 0; v < c.weight.rows; ++v) {
    for (int u = 0; u < c.weight.cols; ++u) {
      const cv::Rect cell(kCell * u, kCell * v, kCell, kCell);
      const double w = c.weight.at<cv::Vec3f>(v, u)[0];
      if ((cell & p.covered_in_b) == cell) {
        w_occ += w;
        ++n_occ;
      } else if ((cell & cv::Rect(92, 56, 112, 80)).area() == 0 && u > 1 && u < c.weight.cols - 2) {
        w_bg += w;  // background well away from the square and from the image border
        ++n_bg;
      }
    }
  }
  ASSERT_GT(n_occ, 10);
  ASSERT_GT(n_bg, 100);
  w_occ /= n_occ;
  w_bg /= n_bg;
  EXPECT_LT(w_occ, 0.2 * w_bg) << "occluded mean weight " << w_occ << ", background " << w_bg;
  // The background is a 4 px = 0.5 grid px translation and is found as such.
  int good = 0, total = 0;
  for (int v = 2; v < c.target.rows - 2; ++v) {
    for (int u = 2; u < c.target.cols - 2; ++u) {
      const cv::Rect cell(kCell * u, kCell * v, kCell, kCell);
      if ((cell & cv::Rect(84, 56, 124, 80)).area() > 0) continue;
      if (c.weight.at<cv::Vec3f>(v, u)[0] <= 0) continue;
      ++total;
      const cv::Vec2f t = c.target.at<cv::Vec2f>(v, u);
      good += std::hypot(t[0] - (u + 0.5), t[1] - v) < 0.1;
    }
  }
  EXPECT_GT(good, 0.95 * total);
}

TEST(Flow, DiagonalStripesConstrainOnlyTheFlowAcrossThem) {
  // Stripes along (1, -1): a shift along them is invisible (aperture), one across them is not.
  // The information matrix keeps the constraint across the stripes at any angle.
  const int w = 256, h = 192;
  cv::Mat a(h, w, CV_8UC1), b(h, w, CV_8UC1);
  const double period = 11.0, shift = 1.5;  // working px; b is a shifted across the stripes
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double s = (x + y) / std::sqrt(2.0);
      a.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(128 + 80 * std::sin(2 * M_PI * s / period));
      b.at<uint8_t>(y, x) =
          cv::saturate_cast<uint8_t>(128 + 80 * std::sin(2 * M_PI * (s - shift) / period));
    }
  }
  const GridGeometry g = makeGridGeometry(pinhole(w, h, 200), kCell);
  FlowOptions options;
  DenseFlow flow(options);
  const Correspondences c =
      flowToCorrespondences(a, b, flow.compute(a, b), flow.compute(b, a), g, options);
  const Eigen::Vector2d across(1 / std::sqrt(2.0), 1 / std::sqrt(2.0));
  const Eigen::Vector2d along(1 / std::sqrt(2.0), -1 / std::sqrt(2.0));
  int cells = 0, anisotropic = 0;
  for (int v = 2; v < c.weight.rows - 2; ++v) {
    for (int u = 2; u < c.weight.cols - 2; ++u) {
      Eigen::Matrix2d W;
      if (!flowInformation(c.weight.at<cv::Vec3f>(v, u), &W(0, 0), &W(0, 1), &W(1, 1))) continue;
      W(1, 0) = W(0, 1);
      ++cells;
      EXPECT_GT(across.dot(W * across), 3 * along.dot(W * along)) << "cell " << u << ", " << v;
      anisotropic += across.dot(W * across) > 20 * along.dot(W * along);
      // Weights from the per-axis variances alone, diag(1 / Sigma_uu, 1 / Sigma_vv), would lose
      // most of it: both variances hold the stripes' large one.
      const Eigen::Matrix2d S = W.inverse();
      EXPECT_GT(across.dot(W * across), 5 * 0.5 * (1 / S(0, 0) + 1 / S(1, 1)));
    }
  }
  // DIS slides along the stripes: most cells' forward-backward errors exceed fb_max_px and
  // fail. Those errors lie along the stripes and leave the constraint across them (a few cells'
  // flow errs across as well).
  EXPECT_GT(cells, 30);
  EXPECT_GT(anisotropic, 0.9 * cells) << anisotropic << " of " << cells << " cells";
}

TEST(Flow, CellRefinementRemovesTheZoomBias) {
  // b is a zoomed by 3% about the image centre: the flow at working pixel x is 0.03 (x - c),
  // so the true grid target of cell (u, v) is c_g + 1.03 ((u, v) - c_g).
  const GridGeometry g = makeGridGeometry(pinhole(256, 192, 200), kCell);
  const cv::Mat a = texture(cv::Size(256, 192), 3);
  const double s = 1.03, cx = 127.5, cy = 95.5;
  const cv::Mat M = (cv::Mat_<double>(2, 3) << s, 0, (1 - s) * cx, 0, s, (1 - s) * cy);
  cv::Mat b;
  cv::warpAffine(a, b, M, a.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
  FlowOptions options;
  DenseFlow flow(options);
  const cv::Mat f_ab = flow.compute(a, b), f_ba = flow.compute(b, a);
  Correspondences c = flowToCorrespondences(a, b, f_ab, f_ba, g, options);
  // Least-squares zoom factor of the targets, and the median error.
  auto measure = [&](const Correspondences& corr, double* zoom, double* median) {
    double num = 0, den = 0;
    std::vector<double> errors;
    for (int v = 2; v < corr.target.rows - 2; ++v) {
      for (int u = 2; u < corr.target.cols - 2; ++u) {
        if (corr.weight.at<cv::Vec3f>(v, u)[0] <= 0) continue;
        const double pu = u - (cx - 3.5) / kCell, pv = v - (cy - 3.5) / kCell;
        const cv::Vec2f t = corr.target.at<cv::Vec2f>(v, u);
        const double tu = t[0] - (cx - 3.5) / kCell, tv = t[1] - (cy - 3.5) / kCell;
        num += tu * pu + tv * pv;
        den += pu * pu + pv * pv;
        errors.push_back(std::hypot(tu - s * pu, tv - s * pv));
      }
    }
    ASSERT_GT(errors.size(), 200u);
    *zoom = num / den;
    std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
    *median = errors[errors.size() / 2];
  };
  double zoom_dis, median_dis, zoom_lk, median_lk;
  measure(c, &zoom_dis, &median_dis);
  const int refined =
      refineTargets(a, imageGradients(a), b, kCell, RefineOptions(), &c.target, &c.weight);
  EXPECT_GT(refined, 0.8 * c.target.total());
  measure(c, &zoom_lk, &median_lk);
  RecordProperty("zoom_dis", std::to_string(zoom_dis));
  RecordProperty("zoom_refined", std::to_string(zoom_lk));
  EXPECT_NEAR(zoom_lk, s, 0.002) << "DIS alone: " << zoom_dis;
  EXPECT_LT(std::abs(zoom_lk - s), std::abs(zoom_dis - s));
  EXPECT_LT(median_lk, 0.01) << "grid px";
  EXPECT_LE(median_lk, median_dis);
}

TEST(Flow, AffineRefinementFollowsATurningZoom) {
  // b is a turned by 4 deg and zoomed by 4 % about the image centre: the flow changes across
  // each cell, so a translation fitted to a cell lands off the centre's flow by the flow
  // gradient times the offset of the cell's gradient-weighted point; the affine fit does not.
  const GridGeometry g = makeGridGeometry(pinhole(256, 192, 200), kCell);
  const cv::Mat a = texture(cv::Size(256, 192), 7);
  const cv::Point2f centre(127.5f, 95.5f);
  const cv::Mat M = cv::getRotationMatrix2D(centre, 4.0, 1.04);
  cv::Mat b;
  cv::warpAffine(a, b, M, a.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
  FlowOptions options;
  DenseFlow flow(options);
  auto warped = [&](double x, double y) {  // where working pixel (x, y) of a lands in b
    return cv::Vec2d(M.at<double>(0, 0) * x + M.at<double>(0, 1) * y + M.at<double>(0, 2),
                     M.at<double>(1, 0) * x + M.at<double>(1, 1) * y + M.at<double>(1, 2));
  };
  cv::Mat init(a.size(), CV_32FC2);  // DIS starts from the true flow
  for (int y = 0; y < init.rows; ++y)
    for (int x = 0; x < init.cols; ++x) {
      const cv::Vec2d p = warped(x, y);
      init.at<cv::Vec2f>(y, x) = cv::Vec2f(p[0] - x, p[1] - y);
    }
  const Correspondences c =
      flowToCorrespondences(a, b, flow.compute(a, b, init), flow.compute(b, a, -init), g, options);
  auto medianError = [&](int affine_iterations) {
    RefineOptions refine;
    refine.affine_iterations = affine_iterations;
    cv::Mat target = c.target.clone(), weight = c.weight.clone();
    refineTargets(a, imageGradients(a), b, kCell, refine, &target, &weight);
    std::vector<double> errors;
    for (int v = 2; v < target.rows - 2; ++v) {
      for (int u = 2; u < target.cols - 2; ++u) {
        if (!(weight.at<cv::Vec3f>(v, u)[0] > 0)) continue;
        const cv::Vec2d p = warped(kCell * u + 3.5, kCell * v + 3.5);
        const cv::Vec2f t = target.at<cv::Vec2f>(v, u);
        errors.push_back(std::hypot(kCell * t[0] + 3.5 - p[0], kCell * t[1] + 3.5 - p[1]));
      }
    }
    EXPECT_GT(errors.size(), 400u);
    return quantile(errors, 0.5);
  };
  const double translation = medianError(0), affine = medianError(2);
  RecordProperty("translation_median_px", std::to_string(translation));
  RecordProperty("affine_median_px", std::to_string(affine));
  EXPECT_LT(affine, 0.35 * translation) << "translation " << translation << ", affine " << affine;
  EXPECT_LT(affine, 0.06) << "working px";
}

TEST(Flow, StartCheckDropsTheCellsThatLeanOnTheirStart) {
  // b is a shifted 2 px right. Each cell starts 0 to 2 px short of that and gets one
  // Lucas-Kanade iteration, which leaves the cells that start far off short of the truth, by
  // a share of where they started. The start check, run from 1 px further along, finds them.
  const cv::Size size(128, 96);
  const cv::Mat a = texture(size, 3);
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, 2, 0, 1, 0);
  cv::Mat b;
  cv::warpAffine(a, b, shift, size, cv::INTER_NEAREST, cv::BORDER_REFLECT);
  struct Result {
    int kept = 0, cells = 0;
    double max_error = 0;  // working px, over the kept cells
  };
  auto refine = [&](double start_check_px) {
    cv::Mat target(size.height / kCell, size.width / kCell, CV_32FC2);
    cv::Mat weight(target.size(), kFlowWeightType, cv::Scalar(1, 0, 1));
    cv::RNG rng(7);
    for (int v = 0; v < target.rows; ++v)
      for (int u = 0; u < target.cols; ++u)
        target.at<cv::Vec2f>(v, u) = cv::Vec2f(u + rng.uniform(0.f, 2.f) / kCell, v);
    RefineOptions options;
    options.iterations = 1;
    options.start_check_px = start_check_px;
    refineTargets(a, imageGradients(a), b, kCell, options, &target, &weight);
    Result r;
    for (int v = 1; v < target.rows - 1; ++v) {
      for (int u = 1; u < target.cols - 1; ++u) {
        ++r.cells;
        if (!(weight.at<cv::Vec3f>(v, u)[0] > 0)) continue;
        ++r.kept;
        const cv::Vec2f t = target.at<cv::Vec2f>(v, u);
        r.max_error =
            std::max<double>(r.max_error, std::hypot(kCell * (t[0] - u) - 2.0, kCell * (t[1] - v)));
      }
    }
    return r;
  };
  const Result off = refine(0), on = refine(1.0);
  RecordProperty("kept_with_check", on.kept);
  RecordProperty("cells", on.cells);
  EXPECT_EQ(off.kept, off.cells);
  EXPECT_GT(off.max_error, 0.5) << "working px";
  // The kept cells are within the tolerance (0.3 px) of the truth, which the check's
  // 8 iterations reach.
  EXPECT_LT(on.max_error, 0.32) << "working px";
  EXPECT_GT(on.kept, on.cells / 4);
  EXPECT_LT(on.kept, on.cells);
}

// Forward along the noise-free street with the true depth on each keyframe's grid: the
// translation of a frame aligned motion-only against the keyframe comes out short with
// translation-only refinement (the road's flow grows across each cell, and a translation
// measures it off the cell's centre); the affine refinement measures the centres.
TEST(Flow, AffineRefinementKeepsTheStreetsTranslationLength) {
  SyntheticConfig config;
  config.scene = "large";
  config.width = 512;
  config.height = 384;
  config.frames = 150;
  config.seed = 3;
  config.fps = 30;
  config.stereo = false;
  config.freeze_objects = true;
  const SyntheticScene scene = SyntheticScene::make(config);
  const CameraModel cam = scene.camera();
  const GridGeometry g = makeGridGeometry(cam, kCell);
  FlowOptions flow_options;
  flow_options.finest_scale = 1;  // the tracker's
  DenseFlow flow(flow_options);
  MotionOnlyOptions align_options;
  align_options.robust_kernel = RobustKernel::kCauchy;
  align_options.max_iterations = 30;
  const MotionOnlyAligner aligner(align_options);
  double error_translation = 0, error_affine = 0;
  const std::vector<int> firsts = {23, 36, 62, 75, 101};
  for (const int fa : firsts) {
    const int fb = fa + 3;
    const SE3 T_world_a = scene.cameraPose(fa), T_world_b = scene.cameraPose(fb);
    const RenderedView va = scene.render(T_world_a, cam, fa);
    const cv::Mat a = toGrey(va.color), b = toGrey(scene.render(T_world_b, cam, fb).color);
    DenseBaKeyframe keyframe;
    cv::Mat unused_var;
    depthPrior(sensorDepthToGrid(va.depth, kCell, 0.5, 0.1, 20.0), 1, 0, 0, &keyframe.inv_depth,
               &unused_var);
    const SE3 T_b_a = T_world_b.inverse() * T_world_a;
    // DIS warm-started from the true flow, as the tracker starts it from its prediction.
    const cv::Mat predicted =
        predictedFlow(reprojectKeyframe(g.grid, keyframe, T_b_a.inverse(), 0.2), g);
    const Correspondences c = flowToCorrespondences(
        a, b, flow.compute(a, b, predicted), flow.compute(b, a, -predicted), g, flow_options);
    for (const int affine_iterations : {0, 2}) {
      RefineOptions refine;
      refine.affine_iterations = affine_iterations;
      MotionOnlyEdge edge;
      edge.target = c.target.clone();
      edge.weight = c.weight.clone();
      refineTargets(a, imageGradients(a), b, kCell, refine, &edge.target, &edge.weight);
      const MotionOnlyResult r = aligner.align(g.grid, {keyframe}, {edge}, T_b_a.inverse());
      ASSERT_TRUE(r.ok) << r.error;
      const double ratio = r.T_world_frame.translation().norm() / T_b_a.translation().norm();
      (affine_iterations ? error_affine : error_translation) += (ratio - 1) / firsts.size();
    }
  }
  RecordProperty("translation_length_error", std::to_string(error_translation));
  RecordProperty("affine_length_error", std::to_string(error_affine));
  EXPECT_LT(error_translation, -0.003) << "the street should show the bias";
  EXPECT_LT(std::abs(error_affine), 0.5 * std::abs(error_translation))
      << "translation-only " << error_translation << ", affine " << error_affine;
}

// True grid target of each cell of a: the mean over the cell of the exact reprojection of its
// working pixels (rendered depth) into b.
cv::Mat trueTargets(const cv::Mat& depth_a, const SE3& T_b_a, const GridGeometry& g) {
  cv::Mat flow(depth_a.size(), CV_32FC2, cv::Scalar(0, 0));
  cv::Mat valid(depth_a.size(), CV_32FC1, cv::Scalar(0));
  for (int y = 0; y < depth_a.rows; ++y) {
    for (int x = 0; x < depth_a.cols; ++x) {
      const float z = depth_a.at<float>(y, x);
      if (!(z > 0)) continue;
      const Vec3 p = T_b_a * unproject(g.working, Eigen::Vector2d(x, y), z);
      if (p.z() <= 0) continue;
      const Eigen::Vector2d q = project(g.working, p);
      flow.at<cv::Vec2f>(y, x) =
          cv::Vec2f(static_cast<float>(q.x() - x), static_cast<float>(q.y() - y));
      valid.at<float>(y, x) = 1;
    }
  }
  cv::Mat mean_flow, mean_valid;
  cv::resize(flow, mean_flow, g.gridSize(), 0, 0, cv::INTER_AREA);
  cv::resize(valid, mean_valid, g.gridSize(), 0, 0, cv::INTER_AREA);
  cv::Mat t(g.gridSize(), CV_32FC2);
  for (int v = 0; v < t.rows; ++v) {
    for (int u = 0; u < t.cols; ++u) {
      const cv::Vec2f f = mean_flow.at<cv::Vec2f>(v, u);
      t.at<cv::Vec2f>(v, u) = mean_valid.at<float>(v, u) > 0.999f
                                  ? cv::Vec2f(u + f[0] / kCell, v + f[1] / kCell)
                                  : cv::Vec2f(std::numeric_limits<float>::quiet_NaN(), 0);
    }
  }
  return t;
}

TEST(Flow, TargetsMatchTrueReprojectionOnSyntheticRoom) {
  SyntheticConfig config;
  config.scene = "room";
  config.width = 320;
  config.height = 240;
  config.frames = 10;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);
  const CameraModel cam = scene.camera();
  const GridGeometry g = makeGridGeometry(cam, kCell);
  const int fa = 0, fb = 6;  // ~9 cm and a few degrees apart
  const RenderedView va = scene.render(scene.cameraPose(fa), cam, fa);
  const RenderedView vb = scene.render(scene.cameraPose(fb), cam, fb);
  const cv::Mat a = toGrey(va.color), b = toGrey(vb.color);
  const SE3 T_b_a = scene.cameraPose(fb).inverse() * scene.cameraPose(fa);
  const cv::Mat truth = trueTargets(va.depth, T_b_a, g);

  FlowOptions options;
  DenseFlow flow(options);
  // Warm start from a slightly wrong prediction (the truth shifted by 0.3 grid px).
  cv::Mat predicted = truth.clone();
  predicted += cv::Scalar(0.3, -0.3);
  // The backward flow starts from the negated prediction (what the tracker does for frames,
  // whose depth is unknown).
  const cv::Mat init = predictedFlow(predicted, g);
  const cv::Mat f_ab = flow.compute(a, b, init);
  const cv::Mat f_ba = flow.compute(b, a, -init);
  const Correspondences c = flowToCorrespondences(a, b, f_ab, f_ba, g, options);
  EXPECT_GT(c.valid_fraction, 0.6);

  // Among confident pixels (weight above the median of the valid ones), most errors are
  // small compared to the 2-3 px flow.
  std::vector<float> weights;
  for (int v = 0; v < c.weight.rows; ++v) {
    for (int u = 0; u < c.weight.cols; ++u) {
      const float w = c.weight.at<cv::Vec3f>(v, u)[0];
      if (w > 0 && std::isfinite(truth.at<cv::Vec2f>(v, u)[0])) weights.push_back(w);
    }
  }
  ASSERT_GT(weights.size(), 500u);
  std::nth_element(weights.begin(), weights.begin() + weights.size() / 2, weights.end());
  const float w_median = weights[weights.size() / 2];
  std::vector<double> errors, all_errors;
  double whitened = 0;
  for (int v = 0; v < c.weight.rows; ++v) {
    for (int u = 0; u < c.weight.cols; ++u) {
      const cv::Vec2f t = truth.at<cv::Vec2f>(v, u), m = c.target.at<cv::Vec2f>(v, u);
      const float w = c.weight.at<cv::Vec3f>(v, u)[0];
      if (!(w > 0) || !std::isfinite(t[0])) continue;
      const double e = std::hypot(t[0] - m[0], t[1] - m[1]);
      all_errors.push_back(e);
      whitened += w * e * e;
      if (w >= w_median) errors.push_back(e);
    }
  }
  std::sort(errors.begin(), errors.end());
  std::sort(all_errors.begin(), all_errors.end());
  const double p50 = errors[errors.size() / 2], p90 = errors[errors.size() * 9 / 10];
  RecordProperty("confident_median_error_px", std::to_string(p50));
  RecordProperty("confident_p90_error_px", std::to_string(p90));
  EXPECT_LT(p50, 0.1) << "grid px";
  EXPECT_LT(p90, 0.3) << "grid px";
  // The confident half is at least as accurate as all valid pixels.
  EXPECT_LE(p50, all_errors[all_errors.size() / 2] + 1e-9);
  // Weights are inverse variances of the right order: the mean whitened squared error of a
  // 2-d residual is 2 for a calibrated model; accept a factor 5 either way.
  const double mean_whitened = whitened / all_errors.size();
  EXPECT_GT(mean_whitened, 2.0 / 5) << mean_whitened;
  EXPECT_LT(mean_whitened, 2.0 * 5) << mean_whitened;
}

// Forward motion along the synthetic street: the near road's flow varies fast across the image.
// Started coarse from the true flow, DIS shrinks it (downsampled to its coarsest level, the
// prediction is lost there); warped by the prediction it measures the small residual instead.
// OpenCV's DIS kept a warm start for the calls after it: the same pair, computed without one,
// moved by 34 px after a warm-started call on another pair. A flow must depend on its inputs
// (up to 1e-6 px: OpenCV's vector code differs with the buffers' alignment).
TEST(Flow, AFlowDependsOnItsInputsAlone) {
  SyntheticConfig config;
  config.scene = "room";
  config.width = 320;
  config.height = 240;
  config.frames = 30;
  const SyntheticScene scene = SyntheticScene::make(config);
  const cv::Mat a = toGrey(scene.frame(0).color), b = toGrey(scene.frame(8).color);
  const cv::Mat c = toGrey(scene.frame(16).color), d = toGrey(scene.frame(24).color);
  DenseFlow fresh(FlowOptions{}), used(FlowOptions{});
  const cv::Mat warm_start(a.size(), CV_32FC2, cv::Scalar(3.f, -2.f));
  for (WarmStart mode : {WarmStart::kCoarse, WarmStart::kWarp}) {
    used.compute(c, d, warm_start, WarmStart::kCoarse);
    const cv::Mat expected = fresh.compute(a, b, {}, mode);
    const cv::Mat again = used.compute(a, b, {}, mode);
    EXPECT_LT(cv::norm(expected, again, cv::NORM_INF), 1e-4);
    const cv::Mat warm_expected = fresh.compute(a, b, warm_start, mode);
    used.compute(c, d, {}, mode);
    EXPECT_LT(cv::norm(warm_expected, used.compute(a, b, warm_start, mode), cv::NORM_INF), 1e-4);
  }
}

TEST(Flow, WarpedWarmStartKeepsTheNearGroundFlow) {
  SyntheticConfig config;
  config.scene = "street";
  config.width = 320;
  config.height = 240;
  config.frames = 3;
  config.stereo = false;
  const SyntheticScene scene = SyntheticScene::make(config);
  const CameraModel cam = scene.camera();
  const GridGeometry g = makeGridGeometry(cam, kCell);
  const RenderedView va = scene.render(scene.cameraPose(0), cam, 0);
  const RenderedView vb = scene.render(scene.cameraPose(1), cam, 1);
  const cv::Mat a = toGrey(va.color), b = toGrey(vb.color);
  const SE3 T_b_a = scene.cameraPose(1).inverse() * scene.cameraPose(0);
  const cv::Mat truth = trueTargets(va.depth, T_b_a, g);
  const cv::Mat init = predictedFlow(truth, g);
  FlowOptions options;
  DenseFlow flow(options);
  // Mean error and flow scale (measured flow projected on the true one) over cells nearer than
  // 8 m whose truth stays in b.
  auto score = [&](const cv::Mat& f, double* error, double* scale) {
    const Correspondences c = flowToCorrespondences(a, b, f, cv::Mat(), g, options);
    double sum = 0, num = 0, den = 0;
    int n = 0;
    for (int v = 0; v < truth.rows; ++v) {
      for (int u = 0; u < truth.cols; ++u) {
        const cv::Vec2f t = truth.at<cv::Vec2f>(v, u), m = c.target.at<cv::Vec2f>(v, u);
        const float z = va.depth.at<float>(kCell * v + kCell / 2, kCell * u + kCell / 2);
        if (!std::isfinite(t[0]) || !(z > 0 && z < 8) || t[0] < 0 || t[1] < 0 ||
            t[0] > truth.cols - 1 || t[1] > truth.rows - 1) {
          continue;
        }
        const double tx = t[0] - u, ty = t[1] - v;
        sum += std::hypot(m[0] - t[0], m[1] - t[1]);
        num += (m[0] - u) * tx + (m[1] - v) * ty;
        den += tx * tx + ty * ty;
        ++n;
      }
    }
    ASSERT_GT(n, 50);
    *error = sum / n;
    *scale = num / den;
  };
  double e_coarse, s_coarse, e_warp, s_warp;
  score(flow.compute(a, b, init, WarmStart::kCoarse), &e_coarse, &s_coarse);
  score(flow.compute(a, b, init, WarmStart::kWarp), &e_warp, &s_warp);
  RecordProperty("near_error_coarse_px", std::to_string(e_coarse));
  RecordProperty("near_error_warp_px", std::to_string(e_warp));
  EXPECT_LT(e_warp, 0.5 * e_coarse) << "grid px";
  // (Measured: coarse 0.66 grid px mean error, flow scale 0.87; warped 0.25 px, 1.10. Warped by
  // the exact per-pixel flow without smoothing: 0.16 px, 1.05.)
  EXPECT_LT(std::abs(s_warp - 1.0), std::abs(s_coarse - 1.0));
}

// A uniform shift of a textured image with a moving patch: cells mostly on the patch, and
// cells whose pixels land on it in b, get no weight; a cell a quarter on the patch keeps its
// weight and the flow of its static pixels.
TEST(MovingMasks, KeepMovingPixelsOutOfTheCorrespondences) {
  CameraModel working;
  working.width = 64;
  working.height = 32;
  working.fx = working.fy = 40;
  working.cx = 31.5;
  working.cy = 15.5;
  const GridGeometry g = makeGridGeometry(working, 8);
  cv::Mat a(32, 64, CV_8UC1);
  cv::randu(a, 0, 255);
  cv::GaussianBlur(a, a, cv::Size(0, 0), 1.0);
  cv::Mat b;
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, 8, 0, 1, 0);  // b = a moved 8 px right
  cv::warpAffine(a, b, shift, a.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  // The static scene's flow is +8 px; the patch's pixels flow elsewhere (-5 px).
  cv::Mat flow(a.size(), CV_32FC2, cv::Scalar(8, 0));
  cv::Mat moving_a(a.size(), CV_8UC1, cv::Scalar(0)), moving_b = moving_a.clone();
  moving_a(cv::Rect(8, 8, 8, 8)).setTo(255);   // cell (1, 1)
  moving_a(cv::Rect(24, 8, 2, 8)).setTo(255);  // a quarter of cell (3, 1)
  flow.setTo(cv::Scalar(-5, 0), moving_a);
  moving_b(cv::Rect(48, 16, 8, 8)).setTo(255);  // where cell (5, 2) lands in b
  const FlowOptions options;
  const Correspondences c =
      flowToCorrespondences(a, b, flow, cv::Mat(), cellStructureTensor(imageGradients(a), 8), g,
                            options, moving_a, moving_b);
  auto weighted = [&](int u, int v) { return c.weight.at<cv::Vec3f>(v, u)[0] > 0; };
  EXPECT_FALSE(weighted(1, 1));  // on the patch
  EXPECT_FALSE(weighted(5, 2));  // lands on the patch in b
  EXPECT_TRUE(weighted(4, 2));
  ASSERT_TRUE(weighted(3, 1));  // a quarter moving: the static pixels' flow
  EXPECT_NEAR(c.target.at<cv::Vec2f>(1, 3)[0], 3 + 1.0, 1e-4);
  // Without masks the patch's wrong flow stays in.
  const Correspondences unmasked = flowToCorrespondences(
      a, b, flow, cv::Mat(), cellStructureTensor(imageGradients(a), 8), g, options);
  EXPECT_NEAR(unmasked.target.at<cv::Vec2f>(1, 3)[0], 3 + (0.75 * 8 - 0.25 * 5) / 8, 1e-4);
}

// Semi-global matching on a rendered frame against its true depth: disparity errors (px) over
// the pixels with depth, and over columns 16-63 (the left border).
struct StereoDepthErrors {
  std::vector<double> all, border;
  double measured = 0, border_measured = 0;  // fractions of the pixels with depth
};

StereoDepthErrors semiGlobalErrors(const std::string& scene_name, double baseline_m, int frame) {
  SyntheticConfig config;
  config.scene = scene_name;
  config.width = 384;
  config.height = 288;
  config.frames = 30;
  config.image_noise_sigma = 2;
  config.baseline_m = baseline_m;
  const SyntheticScene scene = SyntheticScene::make(config);
  const Frame f = scene.frame(frame);
  const double fx = scene.camera().fx;
  const cv::Mat depth =
      semiGlobalStereoDepth(toGrey(f.color), toGrey(f.right), fx, baseline_m, 0.5);
  EXPECT_EQ(depth.type(), CV_32FC1);
  EXPECT_EQ(depth.size(), f.color.size());
  const RenderedView truth = scene.render(scene.cameraPose(frame), scene.camera(), frame);
  StereoDepthErrors out;
  int total = 0, border_total = 0;
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      const float z_true = truth.depth.at<float>(y, x), z = depth.at<float>(y, x);
      if (!(z_true > 0)) continue;
      const bool border = x >= 16 && x < 64;
      ++total;
      border_total += border;
      if (!(z > 0)) continue;
      const double error = std::abs(fx * baseline_m * (1 / z - 1 / z_true));
      out.all.push_back(error);
      if (border) out.border.push_back(error);
    }
  }
  out.measured = static_cast<double>(out.all.size()) / std::max(total, 1);
  out.border_measured = static_cast<double>(out.border.size()) / std::max(border_total, 1);
  return out;
}

TEST(SemiGlobalStereoDepth, MatchesTheTrueDepthUpToTheLeftBorder) {
  // The door scene at frame 20 has the door near the left border, where a disparity search
  // without padding finds nothing.
  const StereoDepthErrors e = semiGlobalErrors("door", 0.1, 20);
  EXPECT_GT(e.measured, 0.9);
  EXPECT_GT(e.border_measured, 0.8);
  EXPECT_LT(quantile(e.all, 0.5), 0.25);
  EXPECT_LT(quantile(e.all, 0.95), 1.0);
  EXPECT_LT(quantile(e.border, 0.5), 0.25);
}

TEST(SemiGlobalStereoDepth, MatchesAStreetWithAWideRig) {
  // KITTI's 0.54 m baseline: disparities up to tens of pixels on the road near the car.
  const StereoDepthErrors e = semiGlobalErrors("car", 0.54, 10);
  EXPECT_GT(e.measured, 0.85);
  EXPECT_LT(quantile(e.all, 0.5), 0.3);
  EXPECT_LT(quantile(e.all, 0.95), 1.5);
}

}  // namespace
}  // namespace radslam
