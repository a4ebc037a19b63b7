#include "tracker/keyframe_graph.h"

#include <gtest/gtest.h>

namespace radslam {
namespace {

CameraModel gridCamera() {
  CameraModel c;
  c.width = 16;
  c.height = 12;
  c.fx = c.fy = 20;
  c.cx = 7.5;
  c.cy = 5.5;
  return c;
}

/// A keyframe at camera centre x (m) looking along +z at a plane 2 m away.
KeyframeData keyframeAt(double x) {
  const CameraModel grid = gridCamera();
  KeyframeData k;
  k.grey = cv::Mat(grid.height * 8, grid.width * 8, CV_8UC1, cv::Scalar(100));
  k.structure = cv::Mat(grid.height, grid.width, CV_32FC3, cv::Scalar(1, 0, 1));
  k.ba.T_world_cam = SE3(SO3(), Vec3(x, 0, 0));
  k.ba.inv_depth = cv::Mat(grid.height, grid.width, CV_32FC1, cv::Scalar(0.5));
  k.inv_depth_var = cv::Mat(grid.height, grid.width, CV_32FC1, cv::Scalar(0.01));
  return k;
}

GraphEdge edge(int i, int j, int anchor = -1) {
  const CameraModel grid = gridCamera();
  return GraphEdge{i,
                   j,
                   cv::Mat(grid.height, grid.width, CV_32FC2, cv::Scalar(0, 0)),
                   cv::Mat(grid.height, grid.width, CV_32FC2, cv::Scalar(1, 1)),
                   std::nullopt,
                   anchor};
}

TEST(KeyframeGraph, LoopPartnersAreTheOldestThenTheMostOverlapping) {
  const CameraModel grid = gridCamera();
  KeyframeGraph graph(2, 4);
  for (double x : {0.5, 0.0, 1.0, 3.0, 4.0, 0.1}) {
    graph.add(keyframeAt(x));
    graph.slideWindow();
  }
  // Keyframe 5 (x = 0.1) overlaps 1 (x = 0) most, then 0 (x = 0.5), then 2 (x = 1); not 3.
  EXPECT_EQ(graph.windowIds(), (std::vector<int>{4, 5}));
  const double overlap0 = graph.overlap(5, 0, grid, 0.2);
  const double overlap1 = graph.overlap(5, 1, grid, 0.2);
  const double overlap2 = graph.overlap(5, 2, grid, 0.2);
  EXPECT_GT(overlap1, overlap0);
  EXPECT_GT(overlap0, overlap2);
  EXPECT_GT(overlap2, 0.3);
  EXPECT_LT(graph.overlap(5, 3, grid, 0.2), 0.3);
  EXPECT_EQ(graph.loopPartners(5, grid, 0.3, 3, 0.2), (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(graph.loopPartners(5, grid, 0.3, 2, 0.2), (std::vector<int>{0, 1}));
  EXPECT_EQ(graph.loopPartners(5, grid, 0.5 * (overlap0 + overlap1), 3, 0.2), std::vector<int>{1});
  EXPECT_TRUE(graph.loopPartners(5, grid, 0.99, 3, 0.2).empty());
}

TEST(KeyframeGraph, LoopEdgesAnchorOldKeyframesAsFixedPoses) {
  const CameraModel grid = gridCamera();
  KeyframeGraph graph(2, 2);
  // Keyframes 0..3 move away along x, keyframe 4 comes back next to keyframe 0.
  for (double x : {0.0, 1.0, 2.0, 3.0}) {
    graph.add(keyframeAt(x));
    graph.slideWindow();
  }
  // Window {2, 3}; 0 and 1 left it and keep their grey images (at most 2 kept).
  EXPECT_EQ(graph.windowIds(), (std::vector<int>{2, 3}));
  EXPECT_FALSE(graph.keyframe(0).grey.empty());
  EXPECT_TRUE(graph.keyframe(0).ba.fixed_pose);
  // Leaving the window turns the last estimate and its marginal variance into the prior.
  EXPECT_FLOAT_EQ(graph.keyframe(0).ba.prior_inv_depth.at<float>(3, 3), 0.5f);
  EXPECT_FLOAT_EQ(graph.keyframe(0).ba.prior_inv_depth_var.at<float>(3, 3), 0.01f);

  graph.add(keyframeAt(0.05));
  graph.slideWindow();  // window {3, 4}; 2 leaves, 0 loses its image (kept: 1, 2)
  EXPECT_TRUE(graph.keyframe(0).grey.empty());
  // Keyframes 1 and 2 are outside the window with their images; the oldest one that keyframe
  // 4 overlaps by more than the threshold is its loop partner.
  const double overlap1 = graph.overlap(4, 1, grid, 0.2);
  EXPECT_GT(overlap1, 0.3);
  EXPECT_EQ(graph.loopPartners(4, grid, 0.3, 1, 0.2), std::vector<int>{1});
  EXPECT_TRUE(graph.loopPartners(4, grid, 0.99, 1, 0.2).empty());

  graph.setEdge(edge(3, 4));
  graph.setEdge(edge(4, 3));
  graph.setEdge(edge(1, 4, 1));
  graph.setEdge(edge(4, 1, 1));
  std::vector<int> ids;
  const DenseBaProblem problem = graph.buildProblem(grid, &ids);
  EXPECT_EQ(ids, (std::vector<int>{3, 4}));  // only window keyframes are written back
  ASSERT_EQ(problem.keyframes.size(), 3u);   // window + anchor
  EXPECT_TRUE(problem.keyframes[2].fixed_pose);
  EXPECT_NEAR(problem.keyframes[2].T_world_cam.translation().x(), 1.0, 1e-12);
  EXPECT_EQ(problem.edges.size(), 4u);

  // The loop edges stay while keyframe 4 is in the window and go with it.
  graph.add(keyframeAt(0.1));
  graph.slideWindow();  // window {4, 5}: 3 leaves
  EXPECT_EQ(graph.edges().size(), 2u);
  graph.add(keyframeAt(0.2));
  graph.slideWindow();  // window {5, 6}: 4 leaves
  EXPECT_TRUE(graph.edges().empty());
}

TEST(KeyframeGraph, DepartedKeyframesCanStayAsAnchorsOfTheirEdges) {
  const CameraModel grid = gridCamera();
  KeyframeGraph graph(2, 0, true);
  for (double x : {0.0, 0.1, 0.2}) graph.add(keyframeAt(x));
  graph.setEdge(edge(0, 1));
  graph.setEdge(edge(1, 2));
  graph.setEdge(edge(2, 0));
  graph.slideWindow();  // window {1, 2}: 0 leaves; its edges to the window stay, anchored at 0
  ASSERT_EQ(graph.edges().size(), 3u);
  EXPECT_EQ(graph.edges()[0].anchor, 0);
  EXPECT_EQ(graph.edges()[1].anchor, -1);
  EXPECT_EQ(graph.edges()[2].anchor, 0);
  std::vector<int> ids;
  const DenseBaProblem problem = graph.buildProblem(grid, &ids);
  ASSERT_EQ(problem.keyframes.size(), 3u);
  EXPECT_TRUE(problem.keyframes[2].fixed_pose);
  // When 1 leaves, the edge 0 -> 1 goes (its window endpoint left) and 1 -> 2 becomes anchored
  // at 1; 2 -> 0 stays while 2 is in the window.
  graph.add(keyframeAt(0.3));
  graph.slideWindow();
  ASSERT_EQ(graph.edges().size(), 2u);
  EXPECT_EQ(graph.edges()[0].anchor, 1);
  EXPECT_EQ(graph.edges()[1].anchor, 0);
  // A restarted window keeps no edge.
  graph.restartWindowAtLast();
  EXPECT_TRUE(graph.edges().empty());
}

TEST(KeyframeGraph, GlobalPairsAndProblemSpanEveryKeptKeyframe) {
  const CameraModel grid = gridCamera();
  KeyframeGraph graph(2, 2);
  // Keyframes 0..4 along x: 0 loses its image once three have left the window.
  for (double x : {0.0, 0.1, 0.2, 3.0, 0.15}) {
    graph.add(keyframeAt(x));
    graph.slideWindow();
  }
  EXPECT_TRUE(graph.keyframe(0).grey.empty());
  const auto pairs = graph.globalPairs(grid, 0.5, 4, 0.2);
  // Consecutive keyframes with images are always paired; 4 overlaps 1 and 2 (not 3, 3 m away).
  const std::vector<std::pair<int, int>> expected = {{1, 2}, {1, 4}, {2, 3}, {2, 4}, {3, 4}};
  EXPECT_EQ(pairs, expected);
  std::vector<GraphEdge> edges;
  for (const auto& [a, b] : pairs) {
    edges.push_back(edge(a, b));
    edges.push_back(edge(b, a));
  }
  std::vector<int> ids;
  const DenseBaProblem problem = graph.buildProblem(grid, edges, &ids);
  EXPECT_EQ(ids, (std::vector<int>{1, 2, 3, 4}));
  ASSERT_EQ(problem.keyframes.size(), 4u);
  // Departed keyframes are anchors in the window's BA, free here.
  EXPECT_TRUE(graph.keyframe(1).ba.fixed_pose);
  for (const DenseBaKeyframe& k : problem.keyframes) EXPECT_FALSE(k.fixed_pose);
  ASSERT_EQ(problem.edges.size(), edges.size());
  EXPECT_EQ(problem.edges[0].i, 0);  // keyframe 1
  EXPECT_EQ(problem.edges[0].j, 1);  // keyframe 2
  EXPECT_EQ(problem.edges[2].j, 3);  // keyframe 4
}

TEST(KeyframeGraph, RejectsInvalidSizes) {
  EXPECT_THROW(KeyframeGraph(1), std::invalid_argument);
  EXPECT_THROW(KeyframeGraph(4, -1), std::invalid_argument);
}

}  // namespace
}  // namespace radslam
