#include "tracker/depth_upsampling.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

namespace radslam {
namespace {

constexpr int kCell = 8;

TEST(DepthUpsampling, ConstantInConstantOut) {
  const cv::Mat d(6, 8, CV_32FC1, cv::Scalar(0.5f));
  const cv::Mat var(6, 8, CV_32FC1, cv::Scalar(0.01f));
  cv::Mat guide(48, 64, CV_8UC1);
  cv::randu(guide, 0, 255);  // any guide: the weights are normalised
  const UpsampledDepth out = upsampleDepth(d, var, guide, kCell);
  ASSERT_EQ(out.inv_depth.size(), guide.size());
  for (int y = 0; y < guide.rows; ++y) {
    for (int x = 0; x < guide.cols; ++x) {
      EXPECT_NEAR(out.inv_depth.at<float>(y, x), 0.5f, 1e-6);
      EXPECT_NEAR(out.inv_depth_var.at<float>(y, x), 0.01f, 1e-8);
      EXPECT_NEAR(out.depth.at<float>(y, x), 2.0f, 1e-5);
      // var(z) = var(d) / d^4 = 0.01 / 0.0625.
      EXPECT_NEAR(out.depth_var.at<float>(y, x), 0.16f, 1e-5);
    }
  }
}

TEST(DepthUpsampling, VarianceIsTheWeightedMeanOfTheVariances) {
  // Flat guide: the weights are spatial only, so the value and the variance are interpolated
  // with the same normalised weights a_k: var(x) = sum a_k var_k, d(x) = sum a_k d_k. With
  // d_k = var_k the two outputs must agree everywhere; and var(x) lies between the extremes.
  cv::Mat d(5, 7, CV_32FC1), var(5, 7, CV_32FC1);
  cv::randu(d, 0.2, 2.0);
  d.copyTo(var);
  const cv::Mat guide(40, 56, CV_8UC1, cv::Scalar(100));
  const UpsampledDepth out = upsampleDepth(d, var, guide, kCell);
  double lo, hi;
  cv::minMaxLoc(var, &lo, &hi);
  for (int y = 0; y < guide.rows; ++y) {
    for (int x = 0; x < guide.cols; ++x) {
      EXPECT_NEAR(out.inv_depth_var.at<float>(y, x), out.inv_depth.at<float>(y, x), 1e-5);
      EXPECT_GE(out.inv_depth_var.at<float>(y, x), lo - 1e-6);
      EXPECT_LE(out.inv_depth_var.at<float>(y, x), hi + 1e-6);
    }
  }
  // At a cell centre between neighbours of different variance the rule is the mean, not the
  // independent-pixel rule sum a_k^2 var_k (which would be smaller than every var_k).
  cv::Mat two_d(1, 2, CV_32FC1), two_var(1, 2, CV_32FC1);
  two_d.at<float>(0, 0) = 1;
  two_d.at<float>(0, 1) = 1;
  two_var.at<float>(0, 0) = 1;
  two_var.at<float>(0, 1) = 3;
  const cv::Mat flat(8, 16, CV_8UC1, cv::Scalar(50));
  const UpsampledDepth mid = upsampleDepth(two_d, two_var, flat, kCell);
  // Working pixels 7 and 8 sit symmetrically between the two cell centres 3.5 and 11.5.
  EXPECT_NEAR(mid.inv_depth_var.at<float>(4, 7) + mid.inv_depth_var.at<float>(4, 8), 4.0, 1e-4);
  EXPECT_GT(mid.inv_depth_var.at<float>(4, 7), 1.0);
}

TEST(DepthUpsampling, EdgeStaysSharp) {
  // Left half near (d = 1, bright), right half far (d = 0.25, dark); the edge falls on a cell
  // boundary. Bilinear interpolation would blur over a full cell; the guide keeps it sharp.
  const int gw = 8, gh = 4;
  cv::Mat d(gh, gw, CV_32FC1), var(gh, gw, CV_32FC1, cv::Scalar(1e-4f));
  for (int v = 0; v < gh; ++v) {
    for (int u = 0; u < gw; ++u) d.at<float>(v, u) = u < gw / 2 ? 1.0f : 0.25f;
  }
  cv::Mat guide(gh * kCell, gw * kCell, CV_8UC1);
  for (int y = 0; y < guide.rows; ++y) {
    for (int x = 0; x < guide.cols; ++x) {
      guide.at<uint8_t>(y, x) = x < guide.cols / 2 ? 200 : 40;
    }
  }
  const UpsampledDepth out = upsampleDepth(d, var, guide, kCell);
  const int edge = guide.cols / 2;
  for (int y = 0; y < guide.rows; ++y) {
    EXPECT_NEAR(out.inv_depth.at<float>(y, edge - 1), 1.0f, 1e-3) << "row " << y;
    EXPECT_NEAR(out.inv_depth.at<float>(y, edge), 0.25f, 1e-3) << "row " << y;
    EXPECT_NEAR(out.depth.at<float>(y, edge), 4.0f, 2e-2);
  }
  // Without the guide (a flat one) the same data is blurred across the edge.
  const cv::Mat flat(guide.size(), CV_8UC1, cv::Scalar(128));
  const UpsampledDepth blurred = upsampleDepth(d, var, flat, kCell);
  EXPECT_GT(std::abs(blurred.inv_depth.at<float>(0, edge) - 0.25f), 0.1f);
}

TEST(DepthUpsampling, UninformedPixelsAreUnknownAndIgnored) {
  const float inf = std::numeric_limits<float>::infinity();
  cv::Mat d(4, 4, CV_32FC1, cv::Scalar(0.5f)), var(4, 4, CV_32FC1, cv::Scalar(inf));
  // One informed cell: everything within reach takes its value; the far corner is unknown.
  var.at<float>(0, 0) = 0.02f;
  d.at<float>(0, 0) = 0.8f;
  const cv::Mat guide(32, 32, CV_8UC1, cv::Scalar(90));
  const UpsampledDepth out = upsampleDepth(d, var, guide, kCell);
  EXPECT_NEAR(out.inv_depth.at<float>(2, 2), 0.8f, 1e-6);
  EXPECT_NEAR(out.inv_depth_var.at<float>(2, 2), 0.02f, 1e-7);
  EXPECT_EQ(out.depth.at<float>(31, 31), 0.0f);
  EXPECT_TRUE(std::isinf(out.depth_var.at<float>(31, 31)));
  EXPECT_TRUE(std::isinf(out.inv_depth_var.at<float>(31, 31)));
}

TEST(DepthUpsampling, RejectsMismatchedInput) {
  const cv::Mat d(4, 4, CV_32FC1, cv::Scalar(1)), var(4, 4, CV_32FC1, cv::Scalar(1));
  EXPECT_THROW(upsampleDepth(d, var, cv::Mat(30, 32, CV_8UC1), kCell), std::invalid_argument);
  EXPECT_THROW(upsampleDepth(d, cv::Mat(4, 5, CV_32FC1), cv::Mat(32, 32, CV_8UC1), kCell),
               std::invalid_argument);
  EXPECT_THROW(upsampleDepth(d, var, cv::Mat(32, 32, CV_8UC3), kCell), std::invalid_argument);
}

TEST(DepthUpsampling, SensorDetailKeepsAnEdgeInsideACellAndTheCorrectionOfBa) {
  // A depth edge at x = 20, in the middle of grid column 2, that the image does not show: the
  // grid (cell medians) blurs it, the sensor's pixels have it. BA moved every cell by +0.05 1/m
  // from the sensor's grid.
  const int gw = 6, gh = 3, edge = 20;
  cv::Mat sensor(gh * kCell, gw * kCell, CV_32FC1);
  const cv::Mat guide(sensor.size(), CV_8UC1, cv::Scalar(128));
  for (int y = 0; y < sensor.rows; ++y) {
    for (int x = 0; x < sensor.cols; ++x) sensor.at<float>(y, x) = x < edge ? 1.0f : 0.25f;
  }
  sensor.at<float>(5, 30) = std::numeric_limits<float>::quiet_NaN();  // no measurement here
  cv::Mat sensor_grid(gh, gw, CV_32FC1);
  for (int v = 0; v < gh; ++v) {
    for (int u = 0; u < gw; ++u) sensor_grid.at<float>(v, u) = u * kCell + 4 < edge ? 1.0f : 0.25f;
  }
  const cv::Mat grid_var(gh, gw, CV_32FC1, cv::Scalar(1e-3f));
  const cv::Mat pixel_var(sensor.size(), CV_32FC1, cv::Scalar(4e-4f));
  const cv::Mat estimate_grid = sensor_grid + 0.05f;
  UpsampledDepth out = upsampleDepth(estimate_grid, grid_var, guide, kCell);
  const UpsampledDepth before{out.inv_depth.clone(), out.inv_depth_var.clone(), out.depth.clone(),
                              out.depth_var.clone()};
  const cv::Mat correction =
      upsampleDepth(estimate_grid - sensor_grid, grid_var, guide, kCell).inv_depth;
  addSensorDetail(sensor, pixel_var, correction, &out);
  for (int y = 0; y < sensor.rows; ++y) {
    for (int x = 0; x < sensor.cols; ++x) {
      if (y == 5 && x == 30) continue;
      const float expected = sensor.at<float>(y, x) + 0.05f;
      ASSERT_NEAR(out.inv_depth.at<float>(y, x), expected, 1e-5) << x << ", " << y;
      ASSERT_NEAR(out.depth.at<float>(y, x), 1.0f / expected, 1e-4);
      ASSERT_NEAR(out.inv_depth_var.at<float>(y, x), before.inv_depth_var.at<float>(y, x) + 4e-4f,
                  1e-7);
    }
  }
  // The grid alone put the edge's near side at the far depth over part of the cell.
  EXPECT_GT(std::abs(before.inv_depth.at<float>(8, edge - 1) - 1.05f), 0.2f);
  // Where the sensor has nothing the estimate stays.
  EXPECT_EQ(out.inv_depth.at<float>(5, 30), before.inv_depth.at<float>(5, 30));
  EXPECT_EQ(out.depth_var.at<float>(5, 30), before.depth_var.at<float>(5, 30));
  EXPECT_THROW(addSensorDetail(sensor, cv::Mat(3, 3, CV_32FC1), correction, &out),
               std::invalid_argument);
}

}  // namespace
}  // namespace radslam
