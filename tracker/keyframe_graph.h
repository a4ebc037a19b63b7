// The tracker's keyframes and the flow edges between them: the active window that dense BA
// optimises, the edge selection for a new keyframe, and what has been published of each
// keyframe (so only changed keyframes are re-sent). DESIGN.md section 3.
//
/// Keyframes are identified by their id (0, 1, 2... in creation order). The window holds the
/// newest window_size keyframes; a keyframe leaving it keeps its last pose, covariance and
/// inverse depth (the images are released to bound memory) and its edges are removed.
#pragma once

#include <array>
#include <optional>
#include <type_traits>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "common/binary_io.h"
#include "common/lie.h"
#include "common/types.h"
#include "tracker/dense_ba.h"

namespace radslam {

struct KeyframeData {
  int id = 0;
  int64_t frame_index = 0;
  Header header;       // of the frame it was made from (utime = sensor time)
  cv::Mat color;       // working resolution (released when the keyframe leaves the window)
  cv::Mat grey;        // CV_8UC1 working resolution (released likewise)
  cv::Mat structure;   // CV_32FC3 grid: structure tensor of grey (flow confidence)
  cv::Mat gradients;   // CV_32FC2 working resolution: (gx, gy) of grey (refinement)
  cv::Mat right_grey;  // CV_8UC1 working resolution, stereo only
  cv::Mat stereo_target, stereo_weight;  // the last stereo edge's correspondences (stereo only)
  cv::Mat moving;  // CV_8UC1 working resolution, 255 = moving object; empty: none (released
                   // with the colour)
  cv::Mat depth;   // CV_32FC1 working resolution, m, 0 = invalid; motion segmentation with
                   // depth (RGB-D, stereo) only (released with the colour)
  /// Pose, BA-grid inverse depth (1/m, monocular: 1/scene unit) and the priors of the last BA.
  DenseBaKeyframe ba;
  /// RGB-D: sensor inverse depth (1/m) and its variance (1/m^2) on the grid; empty otherwise.
  cv::Mat sensor_inv_depth, sensor_inv_depth_var;
  /// Marginals of the last BA that included the keyframe: pose covariance ((v, w), right
  /// perturbation; zero while the pose is a gauge) and inverse-depth variance (grid, 1/m^2,
  /// +inf where unknown; empty before the first BA).
  Mat6 covariance = Mat6::Zero();
  cv::Mat inv_depth_var;
  bool in_window = true;
  /// Publication state: version last sent (-1 = never), the number of keyframes that existed
  /// then, and the estimate it carried.
  int version = -1;
  int sent_at = 0;
  SE3 sent_pose;
  cv::Mat sent_inv_depth;
};

/// One of a keyframe's images, with the resolution it is used at and the types it may have.
template <class Mat>  // cv::Mat or const cv::Mat
struct KeyframeImageRef {
  const char* name;
  Mat* image;  // may be empty (released, or not used in this mode)
  bool grid;   // BA grid size, else working size
  std::array<int, 2> types;
};

/// Every image of a keyframe, in the order checkpoints store them. K: KeyframeData or const
/// KeyframeData.
template <class K>
auto keyframeImages(K& k) {
  using Ref = KeyframeImageRef<std::conditional_t<std::is_const_v<K>, const cv::Mat, cv::Mat>>;
  return std::array<Ref, 18>{{
      {"colour", &k.color, false, {CV_8UC1, CV_8UC3}},
      {"grey", &k.grey, false, {CV_8UC1, CV_8UC1}},
      {"structure tensor", &k.structure, true, {CV_32FC3, CV_32FC3}},
      {"gradients", &k.gradients, false, {CV_32FC2, CV_32FC2}},
      {"right image", &k.right_grey, false, {CV_8UC1, CV_8UC1}},
      {"stereo targets", &k.stereo_target, true, {CV_32FC2, CV_32FC2}},
      {"stereo weights", &k.stereo_weight, true, {kFlowWeightType, kFlowWeightType}},
      {"moving mask", &k.moving, false, {CV_8UC1, CV_8UC1}},
      {"depth", &k.depth, false, {CV_32FC1, CV_32FC1}},
      {"inverse depth", &k.ba.inv_depth, true, {CV_32FC1, CV_32FC1}},
      {"inverse-depth prior", &k.ba.prior_inv_depth, true, {CV_32FC1, CV_32FC1}},
      {"inverse-depth prior variance", &k.ba.prior_inv_depth_var, true, {CV_32FC1, CV_32FC1}},
      {"sensor inverse depth", &k.sensor_inv_depth, true, {CV_32FC1, CV_32FC1}},
      {"sensor inverse-depth variance", &k.sensor_inv_depth_var, true, {CV_32FC1, CV_32FC1}},
      {"measured inverse depth", &k.ba.measured_inv_depth, true, {CV_32FC1, CV_32FC1}},
      {"measured inverse-depth variance", &k.ba.measured_inv_depth_var, true, {CV_32FC1, CV_32FC1}},
      {"inverse-depth variance", &k.inv_depth_var, true, {CV_32FC1, CV_32FC1}},
      {"inverse depth sent", &k.sent_inv_depth, true, {CV_32FC1, CV_32FC1}},
  }};
}

/// Flow edge between two keyframes (ids), or a stereo edge (j = -1, T_i_other set).
struct GraphEdge {
  int i = 0;
  int j = 0;
  cv::Mat target;  // CV_32FC2 grid: location in j's grid
  cv::Mat weight;  // kFlowWeightType grid: information matrices (1/grid px^2)
  std::optional<SE3> T_i_other;
  /// Loop edge: the id of its endpoint outside the window (the anchor), -1 otherwise.
  int anchor = -1;
};

/// Tolerances for re-sending a keyframe after BA moved it.
struct ResendTolerance {
  double rotation_rad = 1e-3;
  /// Camera-centre motion relative to the keyframe's median depth (scale-free for monocular).
  double translation_rel = 1e-3;
  /// Mean over the grid of |d - d_sent| / d_sent.
  double inv_depth_rel = 1e-2;
  /// A keyframe already sent is re-sent only once this many keyframes were created since (each
  /// message is megabytes; the final state is always sent when it leaves the window).
  int min_keyframes_between = 3;
};

class KeyframeGraph {
 public:
  /// Throws std::invalid_argument unless window_size >= 2.
  /// Keyframes that left the window keep their grey image (for loop edges) until more than
  /// max_kept_images of them have one. With departed_edges_as_anchors, the edges between a
  /// keyframe that leaves and the window stay (the keyframe becomes their fixed anchor) until
  /// their window endpoint leaves too: the window keeps the older keyframes' information.
  explicit KeyframeGraph(int window_size, int max_kept_images = 0,
                         bool departed_edges_as_anchors = false);

  /// Appends a keyframe (its id is set to the next id) to the window and returns it.
  KeyframeData& add(KeyframeData keyframe);
  int size() const { return static_cast<int>(keyframes_.size()); }
  bool empty() const { return keyframes_.empty(); }
  KeyframeData& keyframe(int id) { return keyframes_.at(id); }
  const KeyframeData& keyframe(int id) const { return keyframes_.at(id); }
  KeyframeData& last() { return keyframes_.back(); }
  const KeyframeData& last() const { return keyframes_.back(); }
  const std::vector<KeyframeData>& all() const { return keyframes_; }

  /// Ids of the keyframes in the window, oldest first.
  std::vector<int> windowIds() const;
  /// Ids slideWindow() would take out of the window now.
  std::vector<int> leaving() const;
  /// Removes the oldest keyframes beyond window_size from the window (and their edges) and
  /// releases their images. Returns the ids that left.
  std::vector<int> slideWindow();
  /// Takes every keyframe but the newest out of the window (re-initialisation after loss).
  void restartWindowAtLast();

  /// Adds the edge or replaces the one with the same (i, j) (or the stereo edge of i).
  void setEdge(GraphEdge edge);
  const std::vector<GraphEdge>& edges() const { return edges_; }

  /// Fraction of keyframe a's grid pixels that its current pose and inverse depth project
  /// inside keyframe b's image (by the current estimate).
  double overlap(int a, int b, const CameraModel& grid, double min_depth_ratio) const;
  /// Keyframes the new keyframe `id` gets edges with: the previous window keyframe always, and
  /// earlier window keyframes (newest first) whose overlap with it exceeds min_overlap, up to
  /// max_partners in all.
  std::vector<int> edgePartners(int id, const CameraModel& grid, double min_overlap,
                                int max_partners, double min_depth_ratio) const;
  /// Loop partners of keyframe `id`: keyframes outside the window that still have their image
  /// and that `id` overlaps by more than min_overlap (by the current estimate). The oldest
  /// first (it has drifted least from the gauge), then the others by decreasing overlap; at
  /// most max_partners.
  std::vector<int> loopPartners(int id, const CameraModel& grid, double min_overlap,
                                int max_partners, double min_depth_ratio) const;

  /// The window as a dense BA problem: keyframes oldest first (so index 0 is the gauge), then
  /// the anchors of loop edges with fixed poses and their last inverse depths and marginal
  /// variances as priors; the edges among them. *ids receives the keyframe id of each window
  /// keyframe's problem index (anchors follow them and are never written back).
  DenseBaProblem buildProblem(const CameraModel& grid, std::vector<int>* ids) const;
  /// Pairs (a < b) of keyframes that still have their grey image, for global BA: each keyframe
  /// with its max_partners most overlapping others (by the current estimate, both ways above
  /// min_overlap), consecutive keyframes always.
  std::vector<std::pair<int, int>> globalPairs(const CameraModel& grid, double min_overlap,
                                               int max_partners, double min_depth_ratio) const;
  /// A dense BA problem over the keyframes the given edges join (ids ascending, so the oldest
  /// is index 0, the gauge), all poses free, with their current priors; *ids receives the
  /// keyframe id of each problem index.
  DenseBaProblem buildProblem(const CameraModel& grid, const std::vector<GraphEdge>& edges,
                              std::vector<int>* ids) const;
  /// Makes a keyframe outside the window a fixed anchor: its pose fixed, its inverse depths held
  /// by their current estimate and marginal variance (what a departing keyframe becomes).
  void anchor(int id);
  /// Copies optimised poses and inverse depths back.
  void writeBack(const DenseBaProblem& problem, const std::vector<int>& ids);
  /// Stores the marginals of a problem built by buildProblem.
  void setMarginals(const DenseBaMarginals& marginals, const std::vector<int>& ids);

  /// True when keyframe id was never sent or moved beyond the tolerance since it was.
  bool changed(int id, const ResendTolerance& tolerance) const;
  /// Window keyframes never sent, or changed and (unless `now`) last sent at least
  /// min_keyframes_between keyframes ago.
  std::vector<int> toSend(const ResendTolerance& tolerance, bool now) const;
  /// Records that keyframe id was sent now (version + 1) with its current estimate; returns
  /// the version sent.
  int markSent(int id);

  /// The whole state (tracker checkpoints). load() checks the ids, the window and the edges
  /// against the keyframes (BinaryReader::fail on a mismatch) and replaces the state; the
  /// window size and the other options stay the constructor's.
  void save(BinaryWriter* out) const;
  void load(BinaryReader* in);

 private:
  int window_size_;
  int max_kept_images_;
  bool departed_edges_as_anchors_;
  std::vector<int> kept_images_;  // ids outside the window that keep their grey image
  std::vector<KeyframeData> keyframes_;
  std::vector<int> window_;  // ids, oldest first
  std::vector<GraphEdge> edges_;
};

/// Median of the finite, positive values of a CV_32FC1 image (fallback when there are none).
double medianPositive(const cv::Mat& image, double fallback);

}  // namespace radslam
