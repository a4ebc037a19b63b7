// Huge-page storage for the per-voxel arrays, and the field's reservation: growth within it
// never moves the parameters (nor the optimiser's and gradient's arrays that follow it).
#include "mapper/large_vector.h"

#include <cstdint>

#include <gtest/gtest.h>

#include "mapper/field.h"
#include "mapper/sparse_adam.h"
#include "mapper/volume_renderer.h"

namespace radslam {
namespace {

TEST(LargeVector, LargeArraysStartOnHugePagesAndKeepTheirValuesWhenTheyGrow) {
  constexpr size_t kHugePage = HugePageAllocator<float>::kHugePage;
  LargeVector<float> v(3 * kHugePage / sizeof(float) + 5);  // not a whole number of pages
  EXPECT_EQ(reinterpret_cast<uintptr_t>(v.data()) % kHugePage, 0u);
  for (size_t i = 0; i < v.size(); ++i) v[i] = static_cast<float>(i % 1000);
  v.resize(2 * v.size(), -1.f);  // moves to a larger mapping
  EXPECT_EQ(reinterpret_cast<uintptr_t>(v.data()) % kHugePage, 0u);
  for (size_t i = 0; i < v.size() / 2; ++i) ASSERT_EQ(v[i], static_cast<float>(i % 1000)) << i;
  EXPECT_EQ(v.back(), -1.f);
  LargeVector<int32_t> small(10, 7);  // below a huge page: the ordinary heap
  small.push_back(8);
  EXPECT_EQ(small[9], 7);
  EXPECT_EQ(small[10], 8);
}

TEST(Field, GrowthWithinTheReservationDoesNotMoveTheParameters) {
  Field field(FieldGeometry::make(0.05, 2, 4, 0, -4.6f));
  field.reserveBlocks(300);
  for (int l = 0; l < field.numLevels(); ++l) EXPECT_GE(field.blockCapacity(l), 300);
  SparseAdam adam;
  FieldGradient grad;
  grad.resize(field);
  adam.resize(field);
  const float* params = field.levelData(1);
  const float* moments = adam.firstMoments()[1].data();
  const float* gradient = grad.data(1);
  for (int i = 0; i < 300; ++i)
    field.allocateBlock(1, Eigen::Vector3i(i % 10, (i / 10) % 10, i / 100));
  grad.resize(field);
  adam.resize(field);
  EXPECT_EQ(field.numBlocks(1), 300);
  EXPECT_EQ(field.levelData(1), params);
  EXPECT_EQ(adam.firstMoments()[1].data(), moments);
  EXPECT_EQ(grad.data(1), gradient);
  EXPECT_EQ(adam.firstMoments()[1].size(), field.levelSize(1));
  // Past the reservation the arrays move, and the field stays consistent.
  field.allocateBlock(1, Eigen::Vector3i(20, 20, 20));
  EXPECT_EQ(field.numBlocks(1), 301);
  EXPECT_EQ(field.findBlock(1, Eigen::Vector3i(20, 20, 20)), 300);
}

}  // namespace
}  // namespace radslam
