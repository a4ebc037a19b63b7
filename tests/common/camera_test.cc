// Pinhole projection, camera scaling and undistortion into a pinhole camera.
#include "common/camera.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "common/lie.h"

namespace radslam {
namespace {

// TUM fr1 colour camera (TUM website), a strongly distorted real lens.
CameraModel tumFr1() {
  CameraModel cam;
  cam.width = 640;
  cam.height = 480;
  cam.type = CameraModel::Type::kRadTan;
  cam.fx = 517.3;
  cam.fy = 516.5;
  cam.cx = 318.6;
  cam.cy = 255.3;
  cam.distortion = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
  return cam;
}

// A wide-angle equidistant camera (EuRoC-like coefficients).
CameraModel fisheye() {
  CameraModel cam;
  cam.width = 752;
  cam.height = 480;
  cam.type = CameraModel::Type::kEquidistant;
  cam.fx = 350.0;
  cam.fy = 352.0;
  cam.cx = 371.0;
  cam.cy = 242.0;
  cam.distortion = {-0.01, 0.02, -0.015, 0.003};
  return cam;
}

CameraModel pinhole() {
  CameraModel cam;
  cam.width = 1226;
  cam.height = 370;
  cam.fx = cam.fy = 707.0912;
  cam.cx = 601.8873;
  cam.cy = 183.1104;
  return cam;
}

// Where a point in the camera frame lands in the raw (distorted) image.
cv::Point2d distortedPixel(const CameraModel& cam, const Vec3& p) {
  const std::vector<cv::Point3d> object = {cv::Point3d(p.x(), p.y(), p.z())};
  std::vector<cv::Point2d> image;
  const cv::Mat D(cam.distortion, true);
  if (cam.type == CameraModel::Type::kEquidistant) {
    cv::fisheye::projectPoints(object, image, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0),
                               cameraMatrix(cam), D);
  } else {
    cv::projectPoints(object, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cameraMatrix(cam), D, image);
  }
  return image[0];
}

TEST(Camera, ProjectionJacobianMatchesFiniteDifferences) {
  const CameraModel cam = tumFr1();
  std::mt19937 gen(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0), z(0.3, 8.0);
  for (int trial = 0; trial < 20; ++trial) {
    const Vec3 p(u(gen), u(gen), z(gen));
    Eigen::Matrix<double, 2, 3> H;
    project(cam, p, &H);
    Eigen::Matrix<double, 2, 3> H_num;
    const double h = 1e-6;
    for (int i = 0; i < 3; ++i) {
      Vec3 d = Vec3::Zero();
      d[i] = h;
      H_num.col(i) = (project(cam, p + d) - project(cam, p - d)) / (2 * h);
    }
    EXPECT_LT((H - H_num).norm(), 1e-5 * H.norm()) << p.transpose();
  }
}

TEST(Camera, ProjectUnprojectRoundTrip) {
  const CameraModel cam = pinhole();
  std::mt19937 gen(4);
  std::uniform_real_distribution<double> u(0.0, 1225.0), v(0.0, 369.0), d(0.1, 80.0);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector2d px(u(gen), v(gen));
    const double depth = d(gen);
    const Vec3 p = unproject(cam, px, depth);
    EXPECT_NEAR(p.z(), depth, 1e-12);
    EXPECT_LT((project(cam, p) - px).norm(), 1e-9);
  }
  EXPECT_LT((project(cam, Vec3(0, 0, 1)) - Eigen::Vector2d(cam.cx, cam.cy)).norm(), 1e-12);
}

TEST(Camera, ScaleCameraUsesPixelCentres) {
  const CameraModel cam = pinhole();
  const CameraModel half = scaleCamera(cam, 613, 185);
  EXPECT_DOUBLE_EQ(half.fx, cam.fx * 0.5);
  EXPECT_DOUBLE_EQ(half.cx, (cam.cx + 0.5) * 0.5 - 0.5);
  EXPECT_DOUBLE_EQ(half.cy, (cam.cy + 0.5) * 0.5 - 0.5);
  // Any point projects to the same place in pixel-edge coordinates (u + 0.5) / width.
  const Vec3 p(1.0, -0.3, 5.0);
  const Eigen::Vector2d a = project(cam, p), b = project(half, p);
  EXPECT_NEAR((a.x() + 0.5) / cam.width, (b.x() + 0.5) / half.width, 1e-12);
  EXPECT_NEAR((a.y() + 0.5) / cam.height, (b.y() + 0.5) / half.height, 1e-12);
  EXPECT_EQ(scaleCamera(tumFr1(), 320, 240).distortion, tumFr1().distortion);
  EXPECT_THROW(scaleCamera(cam, 0, 100), std::invalid_argument);
  EXPECT_THROW(scaleCamera(CameraModel(), 10, 10), std::invalid_argument);
}

TEST(Camera, CameraMatrix) {
  const cv::Matx33d K = cameraMatrix(tumFr1());
  EXPECT_EQ(K(0, 0), 517.3);
  EXPECT_EQ(K(1, 1), 516.5);
  EXPECT_EQ(K(0, 2), 318.6);
  EXPECT_EQ(K(1, 2), 255.3);
  EXPECT_EQ(K(2, 2), 1.0);
  EXPECT_EQ(K(0, 1), 0.0);
}

TEST(Camera, ValidateRejectsBadModels) {
  EXPECT_NO_THROW(validateCamera(tumFr1()));
  EXPECT_NO_THROW(validateCamera(fisheye()));
  EXPECT_NO_THROW(validateCamera(pinhole()));
  CameraModel bad = tumFr1();
  bad.distortion = {0.1, 0.2, 0.3};
  EXPECT_THROW(validateCamera(bad), std::invalid_argument);
  bad = fisheye();
  bad.distortion.pop_back();
  EXPECT_THROW(validateCamera(bad), std::invalid_argument);
  bad = pinhole();
  bad.fx = 0;
  EXPECT_THROW(validateCamera(bad), std::invalid_argument);
  bad = pinhole();
  bad.distortion = {0.1, 0, 0, 0};
  EXPECT_THROW(validateCamera(bad), std::invalid_argument);
  bad = pinhole();
  bad.readout_s = -0.01;
  EXPECT_THROW(validateCamera(bad), std::invalid_argument);
  bad.readout_s = 1.0;
  EXPECT_THROW(validateCamera(bad), std::invalid_argument);
  bad = pinhole();
  bad.height = -1;
  EXPECT_THROW(Undistorter(bad, 10, 10), std::invalid_argument);
  EXPECT_THROW(Undistorter(pinhole(), 0, 10), std::invalid_argument);
}

// Renders a Gaussian blob (sigma in px) centred at c into a float image.
cv::Mat blobImage(const cv::Size& size, const cv::Point2d& c, double sigma) {
  cv::Mat image(size, CV_32FC1, cv::Scalar(0.0f));
  const int r = static_cast<int>(std::ceil(8 * sigma));  // exp(-32) is below float resolution
  for (int y = std::max(0, static_cast<int>(c.y) - r);
       y < std::min(size.height, static_cast<int>(c.y) + r); ++y) {
    for (int x = std::max(0, static_cast<int>(c.x) - r);
         x < std::min(size.width, static_cast<int>(c.x) + r); ++x) {
      const double d2 = (x - c.x) * (x - c.x) + (y - c.y) * (y - c.y);
      image.at<float>(y, x) = static_cast<float>(std::exp(-0.5 * d2 / (sigma * sigma)));
    }
  }
  return image;
}

// Sub-pixel location of the brightest pixel: a 2D quadratic fitted to the log
// intensities of its 5x5 neighbourhood (exact for any, also sheared, Gaussian).
// The maximum of the rectified blob is exactly where the warp sends the raw
// blob's centre however the warp stretches the blob; a centroid would be biased.
cv::Point2d blobPeak(const cv::Mat& image) {
  cv::Point m;
  cv::minMaxLoc(image, nullptr, nullptr, nullptr, &m);
  Eigen::Matrix<double, 25, 6> A;
  Eigen::Matrix<double, 25, 1> b;
  int row = 0;
  for (int dy = -2; dy <= 2; ++dy) {
    for (int dx = -2; dx <= 2; ++dx) {
      const int x = std::clamp(m.x + dx, 0, image.cols - 1);
      const int y = std::clamp(m.y + dy, 0, image.rows - 1);
      A.row(row) << 1.0, dx, dy, dx * dx, dx * dy, dy * dy;
      b[row] = std::log(std::max(1e-30f, image.at<float>(y, x)));
      ++row;
    }
  }
  const Eigen::Matrix<double, 6, 1> c = A.colPivHouseholderQr().solve(b);
  // Stationary point of c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2.
  Eigen::Matrix2d H;
  H << 2 * c[3], c[4], c[4], 2 * c[5];
  const Eigen::Vector2d d = H.lu().solve(-Eigen::Vector2d(c[1], c[2]));
  return cv::Point2d(m.x + d.x(), m.y + d.y());
}

// cv::remap quantises source coordinates to 1/32 px, which the fisheye's
// stretched corners magnify to ~0.04 px in the output: tol_px says how much.
void expectUndistortsKnownPoints(const CameraModel& cam, int target_w, int target_h,
                                 double tol_px) {
  const Undistorter undistorter(cam, target_w, target_h);
  const CameraModel& target = undistorter.target();
  EXPECT_EQ(target.type, CameraModel::Type::kPinhole);
  EXPECT_TRUE(target.distortion.empty());
  EXPECT_EQ(target.width, target_w);
  EXPECT_EQ(target.height, target_h);
  // Points spread over the output image, including near its corners.
  for (double fx : {0.1, 0.5, 0.85}) {
    for (double fy : {0.15, 0.5, 0.9}) {
      const Eigen::Vector2d px_target(fx * (target_w - 1), fy * (target_h - 1));
      const Vec3 p = unproject(target, px_target, 2.0);
      const cv::Point2d px_raw = distortedPixel(cam, p);
      const cv::Mat raw = blobImage(cv::Size(cam.width, cam.height), px_raw, 4.0);
      const cv::Mat rectified = undistorter.apply(raw);
      ASSERT_EQ(rectified.size(), cv::Size(target_w, target_h));
      const cv::Point2d found = blobPeak(rectified);
      EXPECT_NEAR(found.x, px_target.x(), tol_px) << "at " << px_target.transpose();
      EXPECT_NEAR(found.y, px_target.y(), tol_px) << "at " << px_target.transpose();
    }
  }
}

TEST(Undistorter, RadTanMovesAKnownPointWherePinholeModelSays) {
  expectUndistortsKnownPoints(tumFr1(), 640, 480, 0.03);
  expectUndistortsKnownPoints(tumFr1(), 320, 256, 0.03);  // resize and aspect change at once
}

TEST(Undistorter, EquidistantMovesAKnownPointWherePinholeModelSays) {
  expectUndistortsKnownPoints(fisheye(), 752, 480, 0.06);
  expectUndistortsKnownPoints(fisheye(), 400, 300, 0.06);
}

// Every output pixel must see the scene: its ray lands inside the raw image
// (within the one-pixel margin the border replication covers), and the
// rectangle is tight (some edge pixel lands near the raw border).
void expectNoBlackBorders(const CameraModel& cam, int target_w, int target_h) {
  const Undistorter undistorter(cam, target_w, target_h);
  const CameraModel& target = undistorter.target();
  double closest_to_raw_border = 1e9;
  const auto check = [&](double x, double y) {
    const cv::Point2d raw = distortedPixel(cam, unproject(target, Eigen::Vector2d(x, y), 1.0));
    EXPECT_GE(raw.x, -1.0) << x << "," << y;
    EXPECT_LE(raw.x, cam.width) << x << "," << y;
    EXPECT_GE(raw.y, -1.0) << x << "," << y;
    EXPECT_LE(raw.y, cam.height) << x << "," << y;
    closest_to_raw_border = std::min({closest_to_raw_border, raw.x + 0.5, cam.width - 0.5 - raw.x,
                                      raw.y + 0.5, cam.height - 0.5 - raw.y});
  };
  for (int x = 0; x < target_w; ++x) {
    check(x, 0);
    check(x, target_h - 1);
  }
  for (int y = 0; y < target_h; ++y) {
    check(0, y);
    check(target_w - 1, y);
  }
  EXPECT_LT(closest_to_raw_border, 3.0);
}

TEST(Undistorter, NoBlackBorders) {
  expectNoBlackBorders(tumFr1(), 640, 480);
  expectNoBlackBorders(fisheye(), 752, 480);
  expectNoBlackBorders(fisheye(), 320, 240);
}

TEST(Undistorter, NearestKeepsLabelsAndDepthsUnmixed) {
  const CameraModel cam = tumFr1();
  const Undistorter undistorter(cam, 320, 240);
  cv::Mat depth(cam.height, cam.width, CV_32FC1, cv::Scalar(0.0f));
  cv::Mat labels(cam.height, cam.width, CV_16UC1, cv::Scalar(0));
  for (int y = 0; y < cam.height; ++y) {
    for (int x = 0; x < cam.width; ++x) {
      if ((x / 7 + y / 5) % 2) depth.at<float>(y, x) = 2.5f;
      labels.at<uint16_t>(y, x) = static_cast<uint16_t>((x / 13) * 100 + y / 11);
    }
  }
  const cv::Mat depth_out = undistorter.apply(depth, cv::INTER_NEAREST);
  const cv::Mat labels_out = undistorter.apply(labels, cv::INTER_NEAREST);
  ASSERT_EQ(depth_out.type(), CV_32FC1);
  ASSERT_EQ(labels_out.type(), CV_16UC1);
  std::set<uint16_t> source_labels(labels.begin<uint16_t>(), labels.end<uint16_t>());
  for (int y = 0; y < depth_out.rows; ++y) {
    for (int x = 0; x < depth_out.cols; ++x) {
      const float d = depth_out.at<float>(y, x);
      EXPECT_TRUE(d == 0.0f || d == 2.5f) << d;
      EXPECT_TRUE(source_labels.count(labels_out.at<uint16_t>(y, x)));
    }
  }
  // Linear interpolation does mix them: the check above is not vacuous.
  const cv::Mat depth_linear = undistorter.apply(depth, cv::INTER_LINEAR);
  int mixed = 0;
  for (auto it = depth_linear.begin<float>(); it != depth_linear.end<float>(); ++it) {
    mixed += (*it != 0.0f && *it != 2.5f);
  }
  EXPECT_GT(mixed, 100);
}

// A tilted plane n . X = 2 m seen by the depth camera, turned by a small rotation: the result
// is the same plane seen by the turned camera, (R n) . X = 2 m.
// Rolling shutter: each target pixel's exposure time follows its source row (the middle row
// at 0); a global shutter has none. The map of a turning camera is tested with the tracker's
// image preparation (tests/tracker/rolling_shutter_test.cc).
TEST(Undistorter, ExposureTimesFollowTheSourceRows) {
  CameraModel cam = pinhole();
  EXPECT_TRUE(Undistorter(cam, 613, 185).exposureTimes().empty());
  EXPECT_TRUE(Undistorter(cam, 613, 185).rollingShutterMap(Vec3(0, 1, 0), 8).empty());
  cam.readout_s = 0.03;
  const Undistorter halved(cam, 613, 185);
  const cv::Mat times = halved.exposureTimes();
  ASSERT_EQ(times.type(), CV_32FC1);
  ASSERT_EQ(times.size(), cv::Size(613, 185));
  for (int v : {0, 92, 184}) {
    const double source_row = (v + 0.5) * 2 - 0.5;  // scaleCamera's pixel centres
    EXPECT_NEAR(times.at<float>(v, 300), (source_row / (cam.height - 1) - 0.5) * 0.03, 1e-6);
  }
  EXPECT_TRUE(halved.rollingShutterMap(Vec3::Zero(), 8).empty());
  const cv::Mat map = halved.rollingShutterMap(Vec3(0.1, 2.0, -0.3), 8);
  ASSERT_EQ(map.size(), cv::Size(613, 185));  // not a multiple of the step
  EXPECT_THROW(halved.apply(cv::Mat(370, 1226, CV_8UC1), cv::INTER_LINEAR, map.colRange(0, 600)),
               std::invalid_argument);
  EXPECT_THROW(halved.rollingShutterMap(Vec3(0, 1, 0), 0), std::invalid_argument);
  // With a turning camera the top and bottom rows move in opposite directions; the middle row
  // stays.
  cv::Mat global_x, global_y;
  halved.sourcePixels(0, &global_x, &global_y);
  const float top = map.at<cv::Vec2f>(0, 300)[0] - global_x.at<float>(0, 300);
  const float middle = map.at<cv::Vec2f>(92, 300)[0] - global_x.at<float>(92, 300);
  const float bottom = map.at<cv::Vec2f>(184, 300)[0] - global_x.at<float>(184, 300);
  EXPECT_GT(std::abs(top), 5);
  EXPECT_LT(top * bottom, 0);
  EXPECT_LT(std::abs(middle), 0.1 * std::abs(top));
}

TEST(RotateDepth, ATurnedPlaneIsThePlaneSeenByTheTurnedCamera) {
  const CameraModel cam = pinhole();
  const Vec3 n_depth(0.2, 0.1, 1.0);
  const auto planeDepth = [&](const Vec3& n, int x, int y) {
    return 2.0 / n.dot(Vec3((x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0));
  };
  cv::Mat depth(cam.height, cam.width, CV_32FC1);
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x)
      depth.at<float>(y, x) = static_cast<float>(planeDepth(n_depth, x, y));
  EXPECT_EQ(cv::norm(rotateDepth(depth, cam, Mat3::Identity()), depth, cv::NORM_INF), 0.0);

  const Mat3 R_colour_depth = SO3::exp(Vec3(0.02, -0.035, 0.01)).matrix();
  const cv::Mat turned = rotateDepth(depth, cam, R_colour_depth);
  const Vec3 n_colour = R_colour_depth * n_depth;
  int covered = 0, empty_at_border = 0;
  const auto nearBorder = [&](int x, int y) {
    return std::min({x, y, cam.width - 1 - x, cam.height - 1 - y}) < 60;
  };
  for (int y = 0; y < cam.height; ++y)
    for (int x = 0; x < cam.width; ++x) {
      const float z = turned.at<float>(y, x);
      if (z == 0) {
        // A turn of 1-2 degrees moves the image by 10-40 pixels: only a band along the border
        // sees what the depth camera did not.
        empty_at_border += nearBorder(x, y);
        continue;
      }
      ++covered;
      // Nearest lookup: up to half a pixel's worth of plane slope.
      EXPECT_NEAR(z, planeDepth(n_colour, x, y), 0.003 * z) << x << "," << y;
    }
  EXPECT_GT(covered, cam.width * cam.height * 8 / 10);
  EXPECT_EQ(covered + empty_at_border, cam.width * cam.height);
}

TEST(Undistorter, PinholeInputIsAPureResize) {
  const CameraModel cam = pinhole();
  cv::Mat image(cam.height, cam.width, CV_8UC3);
  cv::randu(image, cv::Scalar::all(0), cv::Scalar::all(255));

  const Undistorter same(cam, cam.width, cam.height);
  EXPECT_EQ(cv::norm(same.apply(image), image, cv::NORM_INF), 0.0);
  EXPECT_EQ(same.target().fx, cam.fx);
  EXPECT_EQ(same.target().cx, cam.cx);

  const int w = 409, h = 124;  // about 1/3
  const Undistorter third(cam, w, h);
  const CameraModel expected = scaleCamera(cam, w, h);
  EXPECT_EQ(third.target().fx, expected.fx);
  EXPECT_EQ(third.target().fy, expected.fy);
  EXPECT_EQ(third.target().cx, expected.cx);
  EXPECT_EQ(third.target().cy, expected.cy);
  for (int interpolation : {cv::INTER_LINEAR, cv::INTER_AREA, cv::INTER_CUBIC}) {
    cv::Mat resized;
    cv::resize(image, resized, cv::Size(w, h), 0, 0, interpolation);
    EXPECT_EQ(cv::norm(third.apply(image, interpolation), resized, cv::NORM_INF), 0.0);
  }
  // Nearest picks the source pixel whose centre is nearest: (x + 0.5) * 3 - 0.5 = 3x + 1
  // for an exact factor of 3.
  const CameraModel cam3 = scaleCamera(cam, 1227, 369);
  cv::Mat columns(cam3.height, cam3.width, CV_16UC1);
  for (int y = 0; y < columns.rows; ++y) {
    for (int x = 0; x < columns.cols; ++x) columns.at<uint16_t>(y, x) = static_cast<uint16_t>(x);
  }
  const cv::Mat nearest = Undistorter(cam3, 409, 123).apply(columns, cv::INTER_NEAREST);
  for (int x = 0; x < nearest.cols; ++x) EXPECT_EQ(nearest.at<uint16_t>(60, x), 3 * x + 1) << x;
  // A RadTan camera with zero coefficients is a pinhole camera too.
  CameraModel zero = cam;
  zero.type = CameraModel::Type::kRadTan;
  zero.distortion = {0, 0, 0, 0, 0};
  EXPECT_EQ(cv::norm(Undistorter(zero, w, h).apply(image), third.apply(image), cv::NORM_INF), 0.0);
}

TEST(Undistorter, RejectsImagesOfTheWrongSize) {
  const Undistorter undistorter(tumFr1(), 320, 240);
  EXPECT_THROW(undistorter.apply(cv::Mat(240, 320, CV_8UC1)), std::invalid_argument);
  EXPECT_THROW(undistorter.apply(cv::Mat()), std::invalid_argument);
  try {
    undistorter.apply(cv::Mat(100, 200, CV_8UC1));
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("200x100"), std::string::npos) << e.what();
  }
}

// A rolling-shutter camera whose padded maps would not fit in memory (an implausible focal
// length or size, e.g. from a damaged checkpoint) is refused before anything is allocated.
TEST(Undistorter, RefusesRollingShutterMapsBeyondTheLimit) {
  CameraModel camera = pinhole();
  camera.readout_s = 0.03;
  EXPECT_NO_THROW(Undistorter(camera, 320, 240));
  camera.fx = camera.fy = 1e12;
  EXPECT_NO_THROW(Undistorter(camera, 320, 240));  // the pad stops at half the image
  camera.width = camera.height = 8000;
  EXPECT_THROW(Undistorter(camera, 320, 240), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
