#include "tracker/keyframe_graph.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <stdexcept>
#include <string>
#include <utility>

namespace radslam {

double medianPositive(const cv::Mat& image, double fallback) {
  CV_Assert(image.empty() || image.type() == CV_32FC1);
  std::vector<float> values;
  values.reserve(image.total());
  for (int v = 0; v < image.rows; ++v) {
    const float* p = image.ptr<float>(v);
    for (int u = 0; u < image.cols; ++u) {
      if (std::isfinite(p[u]) && p[u] > 0) values.push_back(p[u]);
    }
  }
  if (values.empty()) return fallback;
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  return values[mid];
}

namespace {

void releaseImages(KeyframeData* kf) {
  kf->color.release();
  kf->moving.release();
  kf->depth.release();
  kf->grey.release();
  kf->structure.release();
  kf->sensor_inv_depth.release();
  kf->sensor_inv_depth_var.release();
  kf->stereo_target.release();
  kf->stereo_weight.release();
  kf->sent_inv_depth.release();
}

}  // namespace

KeyframeGraph::KeyframeGraph(int window_size, int max_kept_images, bool departed_edges_as_anchors)
    : window_size_(window_size),
      max_kept_images_(max_kept_images),
      departed_edges_as_anchors_(departed_edges_as_anchors) {
  if (window_size < 2) {
    throw std::invalid_argument("keyframe window size must be >= 2, got " +
                                std::to_string(window_size));
  }
  if (max_kept_images < 0) {
    throw std::invalid_argument("number of kept keyframe images must be >= 0, got " +
                                std::to_string(max_kept_images));
  }
}

KeyframeData& KeyframeGraph::add(KeyframeData keyframe) {
  keyframe.id = size();
  keyframe.in_window = true;
  window_.push_back(keyframe.id);
  keyframes_.push_back(std::move(keyframe));
  return keyframes_.back();
}

std::vector<int> KeyframeGraph::windowIds() const { return window_; }

std::vector<int> KeyframeGraph::leaving() const {
  const int excess = static_cast<int>(window_.size()) - window_size_;
  return excess > 0 ? std::vector<int>(window_.begin(), window_.begin() + excess)
                    : std::vector<int>();
}

std::vector<int> KeyframeGraph::slideWindow() {
  std::vector<int> left;
  while (static_cast<int>(window_.size()) > window_size_) {
    left.push_back(window_.front());
    window_.erase(window_.begin());
  }
  for (int id : left) {
    KeyframeData& kf = keyframes_[id];
    kf.in_window = false;
    // Pose, covariance and inverse depth stay; as an anchor of loop edges the keyframe is
    // fixed and its depths are held by its last estimate and marginal variance.
    anchor(id);
    kf.right_grey.release();
    kf.gradients.release();
    // The last max_kept_images keep what loop edges and global BA need (grey image, structure
    // tensor, sensor depth, stereo correspondences) and what a re-send needs (colour, mask).
    if (max_kept_images_ > 0) {
      kept_images_.push_back(id);
    } else {
      releaseImages(&kf);
    }
  }
  while (static_cast<int>(kept_images_.size()) > max_kept_images_) {
    releaseImages(&keyframes_[kept_images_.front()]);
    kept_images_.erase(kept_images_.begin());
  }
  if (!left.empty()) {
    auto gone = [&](int id) { return id >= 0 && !keyframes_[id].in_window; };
    std::vector<GraphEdge> kept;
    for (GraphEdge& e : edges_) {
      if (e.anchor >= 0) {
        // A loop edge goes with its window endpoint.
        if (!gone(e.anchor == e.i ? e.j : e.i)) kept.push_back(std::move(e));
        continue;
      }
      const bool i_gone = gone(e.i), j_gone = gone(e.j);
      if (!i_gone && !j_gone) {
        kept.push_back(std::move(e));
      } else if (departed_edges_as_anchors_ && !e.T_i_other && i_gone != j_gone) {
        // The keyframe that left still constrains the window through this edge.
        e.anchor = i_gone ? e.i : e.j;
        kept.push_back(std::move(e));
      }
    }
    edges_ = std::move(kept);
  }
  return left;
}

void KeyframeGraph::restartWindowAtLast() {
  if (window_.size() <= 1) return;
  const int keep = window_.back();
  const int saved = window_size_;
  const bool saved_anchors = departed_edges_as_anchors_;
  // A restarted window has no known relation to the old one: no edges survive.
  window_size_ = 1;
  departed_edges_as_anchors_ = false;
  slideWindow();
  window_size_ = saved;
  departed_edges_as_anchors_ = saved_anchors;
  window_ = {keep};
}

void KeyframeGraph::setEdge(GraphEdge edge) {
  for (GraphEdge& e : edges_) {
    const bool same = e.i == edge.i &&
                      (edge.T_i_other ? e.T_i_other.has_value() : (!e.T_i_other && e.j == edge.j));
    if (same) {
      e = std::move(edge);
      return;
    }
  }
  edges_.push_back(std::move(edge));
}

double KeyframeGraph::overlap(int a, int b, const CameraModel& grid, double min_depth_ratio) const {
  const KeyframeData& ka = keyframes_.at(a);
  const KeyframeData& kb = keyframes_.at(b);
  const cv::Mat p = reprojectKeyframe(grid, ka.ba, kb.ba.T_world_cam, min_depth_ratio);
  int inside = 0;
  for (int v = 0; v < p.rows; ++v) {
    const cv::Vec2f* q = p.ptr<cv::Vec2f>(v);
    for (int u = 0; u < p.cols; ++u) {
      inside += q[u][0] >= -0.5f && q[u][1] >= -0.5f && q[u][0] <= grid.width - 0.5f &&
                q[u][1] <= grid.height - 0.5f;  // NaN compares false
    }
  }
  return p.total() > 0 ? static_cast<double>(inside) / p.total() : 0;
}

std::vector<int> KeyframeGraph::edgePartners(int id, const CameraModel& grid, double min_overlap,
                                             int max_partners, double min_depth_ratio) const {
  std::vector<int> partners;
  const auto it = std::find(window_.begin(), window_.end(), id);
  if (it == window_.end() || it == window_.begin() || max_partners < 1) return partners;
  partners.push_back(*(it - 1));
  for (auto p = it - 1; p != window_.begin() && static_cast<int>(partners.size()) < max_partners;) {
    --p;
    if (overlap(id, *p, grid, min_depth_ratio) > min_overlap) partners.push_back(*p);
  }
  return partners;
}

std::vector<int> KeyframeGraph::loopPartners(int id, const CameraModel& grid, double min_overlap,
                                             int max_partners, double min_depth_ratio) const {
  std::vector<std::pair<double, int>> candidates;  // (overlap, id), oldest first
  for (int old : kept_images_) {
    if (old == id || keyframes_[old].grey.empty()) continue;
    const double o = overlap(id, old, grid, min_depth_ratio);
    if (o > min_overlap) candidates.emplace_back(o, old);
    if (max_partners == 1 && !candidates.empty()) break;  // the oldest is the one wanted
  }
  if (candidates.empty() || max_partners < 1) return {};
  std::sort(candidates.begin() + 1, candidates.end(), std::greater<>());
  std::vector<int> partners;
  for (size_t n = 0; n < candidates.size() && static_cast<int>(n) < max_partners; ++n)
    partners.push_back(candidates[n].second);
  return partners;
}

void KeyframeGraph::anchor(int id) {
  KeyframeData& kf = keyframes_.at(id);
  if (!kf.inv_depth_var.empty()) {
    kf.ba.prior_inv_depth = kf.ba.inv_depth.clone();
    kf.ba.prior_inv_depth_var = kf.inv_depth_var.clone();
    kf.ba.prior_level_var = 0;  // the marginals already hold the level
  }
  kf.ba.fixed_pose = true;
}

DenseBaProblem KeyframeGraph::buildProblem(const CameraModel& grid, std::vector<int>* ids) const {
  DenseBaProblem problem;
  problem.camera = grid;
  ids->assign(window_.begin(), window_.end());
  std::vector<int> index(keyframes_.size(), -1);
  for (size_t n = 0; n < window_.size(); ++n) {
    index[window_[n]] = static_cast<int>(n);
    problem.keyframes.push_back(keyframes_[window_[n]].ba);
  }
  for (const GraphEdge& e : edges_) {
    if (e.anchor < 0 || index[e.anchor] >= 0) continue;
    index[e.anchor] = static_cast<int>(problem.keyframes.size());
    problem.keyframes.push_back(keyframes_[e.anchor].ba);
  }
  for (const GraphEdge& e : edges_) {
    const int i = index[e.i];
    const int j = e.T_i_other ? 0 : (e.j >= 0 ? index[e.j] : -1);
    if (i < 0 || j < 0) continue;
    DenseBaEdge be;
    be.i = i;
    be.j = e.T_i_other ? i : j;
    be.target = e.target;
    be.weight = e.weight;
    be.T_i_other = e.T_i_other;
    problem.edges.push_back(std::move(be));
  }
  return problem;
}

std::vector<std::pair<int, int>> KeyframeGraph::globalPairs(const CameraModel& grid,
                                                            double min_overlap, int max_partners,
                                                            double min_depth_ratio) const {
  std::vector<int> with_image;
  for (const KeyframeData& k : keyframes_) {
    if (!k.grey.empty()) with_image.push_back(k.id);
  }
  std::vector<std::pair<int, int>> pairs;
  auto add = [&](int a, int b) {
    const std::pair<int, int> p(std::min(a, b), std::max(a, b));
    if (std::find(pairs.begin(), pairs.end(), p) == pairs.end()) pairs.push_back(p);
  };
  for (size_t n = 0; n < with_image.size(); ++n) {
    const int a = with_image[n];
    if (n + 1 < with_image.size()) add(a, with_image[n + 1]);
    std::vector<std::pair<double, int>> candidates;
    for (int b : with_image) {
      if (std::abs(b - a) <= 1) continue;
      const double o =
          std::min(overlap(a, b, grid, min_depth_ratio), overlap(b, a, grid, min_depth_ratio));
      if (o > min_overlap) candidates.emplace_back(o, b);
    }
    std::sort(candidates.rbegin(), candidates.rend());
    for (size_t k = 0; k < candidates.size() && static_cast<int>(k) < max_partners; ++k) {
      add(a, candidates[k].second);
    }
  }
  std::sort(pairs.begin(), pairs.end());
  return pairs;
}

DenseBaProblem KeyframeGraph::buildProblem(const CameraModel& grid,
                                           const std::vector<GraphEdge>& edges,
                                           std::vector<int>* ids) const {
  DenseBaProblem problem;
  problem.camera = grid;
  ids->clear();
  for (const GraphEdge& e : edges) {
    ids->push_back(e.i);
    if (!e.T_i_other) ids->push_back(e.j);
  }
  std::sort(ids->begin(), ids->end());
  ids->erase(std::unique(ids->begin(), ids->end()), ids->end());
  std::vector<int> index(keyframes_.size(), -1);
  for (size_t n = 0; n < ids->size(); ++n) {
    index[(*ids)[n]] = static_cast<int>(n);
    problem.keyframes.push_back(keyframes_[(*ids)[n]].ba);
    problem.keyframes.back().fixed_pose = false;
  }
  for (const GraphEdge& e : edges) {
    DenseBaEdge be;
    be.i = index[e.i];
    be.j = e.T_i_other ? be.i : index[e.j];
    be.target = e.target;
    be.weight = e.weight;
    be.T_i_other = e.T_i_other;
    problem.edges.push_back(std::move(be));
  }
  return problem;
}

void KeyframeGraph::writeBack(const DenseBaProblem& problem, const std::vector<int>& ids) {
  for (size_t n = 0; n < ids.size(); ++n) {
    KeyframeData& kf = keyframes_.at(ids[n]);
    kf.ba.T_world_cam = problem.keyframes[n].T_world_cam;
    kf.ba.inv_depth = problem.keyframes[n].inv_depth;
  }
}

void KeyframeGraph::setMarginals(const DenseBaMarginals& marginals, const std::vector<int>& ids) {
  if (!marginals.ok) return;
  for (size_t n = 0; n < ids.size(); ++n) {
    KeyframeData& kf = keyframes_.at(ids[n]);
    if (n < marginals.pose_covariance.size()) kf.covariance = marginals.pose_covariance[n];
    if (n < marginals.inv_depth_var.size()) kf.inv_depth_var = marginals.inv_depth_var[n];
  }
}

bool KeyframeGraph::changed(int id, const ResendTolerance& tol) const {
  const KeyframeData& kf = keyframes_.at(id);
  if (kf.version < 0 || kf.sent_inv_depth.empty()) return true;
  const SE3 delta = kf.sent_pose.inverse() * kf.ba.T_world_cam;
  const double depth_scale = 1.0 / medianPositive(kf.ba.inv_depth, 1.0);
  if (delta.so3().log().norm() > tol.rotation_rad) return true;
  if (delta.translation().norm() / depth_scale > tol.translation_rel) return true;
  cv::Mat rel;
  cv::absdiff(kf.ba.inv_depth, kf.sent_inv_depth, rel);
  cv::divide(rel, cv::max(kf.sent_inv_depth, 1e-9), rel);
  return cv::mean(rel)[0] > tol.inv_depth_rel;
}

std::vector<int> KeyframeGraph::toSend(const ResendTolerance& tol, bool now) const {
  std::vector<int> out;
  for (int id : window_) {
    const KeyframeData& kf = keyframes_[id];
    const bool due = now || kf.version < 0 || size() - kf.sent_at >= tol.min_keyframes_between;
    if (due && changed(id, tol)) out.push_back(id);
  }
  return out;
}

int KeyframeGraph::markSent(int id) {
  KeyframeData& kf = keyframes_.at(id);
  kf.version += 1;
  kf.sent_at = size();
  kf.sent_pose = kf.ba.T_world_cam;
  kf.sent_inv_depth = kf.ba.inv_depth.clone();
  return kf.version;
}

void KeyframeGraph::save(BinaryWriter* out) const {
  BinaryWriter& w = *out;
  w.put<uint32_t>(keyframes_.size());
  for (const KeyframeData& k : keyframes_) {
    w.put<int32_t>(k.id);
    w.put<int64_t>(k.frame_index);
    w.header(k.header);
    for (const auto& image : keyframeImages(k)) w.mat(*image.image);
    w.se3(k.ba.T_world_cam);
    w.put<uint8_t>(k.ba.fixed_pose);
    w.matrix(k.covariance);
    w.put<uint8_t>(k.in_window);
    w.put<int32_t>(k.version);
    w.put<int32_t>(k.sent_at);
    w.se3(k.sent_pose);
  }
  w.vec(kept_images_);
  w.vec(window_);
  w.put<uint32_t>(edges_.size());
  for (const GraphEdge& e : edges_) {
    w.put<int32_t>(e.i);
    w.put<int32_t>(e.j);
    w.put<int32_t>(e.anchor);
    w.mat(e.target);
    w.mat(e.weight);
    w.put<uint8_t>(e.T_i_other.has_value());
    if (e.T_i_other) w.se3(*e.T_i_other);
  }
}

void KeyframeGraph::load(BinaryReader* in) {
  BinaryReader& r = *in;
  std::vector<KeyframeData> keyframes(r.count(64));
  for (size_t id = 0; id < keyframes.size(); ++id) {
    KeyframeData& k = keyframes[id];
    k.id = r.get<int32_t>();
    if (k.id != static_cast<int>(id)) r.fail("keyframe ids out of order");
    k.frame_index = r.get<int64_t>();
    k.header = r.header();
    for (const auto& image : keyframeImages(k)) *image.image = r.mat();
    if (k.ba.inv_depth.type() != CV_32FC1) r.fail("keyframe " + std::to_string(id) + ": no depths");
    k.ba.T_world_cam = r.se3();
    k.ba.fixed_pose = r.get<uint8_t>() != 0;
    r.matrix(&k.covariance);
    k.in_window = r.get<uint8_t>() != 0;
    k.version = r.get<int32_t>();
    k.sent_at = r.get<int32_t>();
    k.sent_pose = r.se3();
  }
  const auto valid_id = [&](int id) { return id >= 0 && id < static_cast<int>(keyframes.size()); };
  std::vector<int> kept_images, window;
  r.vec(&kept_images);
  r.vec(&window);
  for (const std::vector<int>* ids : {&kept_images, &window})
    for (int id : *ids)
      if (!valid_id(id)) r.fail("keyframe id " + std::to_string(id) + " out of range");
  std::vector<GraphEdge> edges(r.count(16));
  for (GraphEdge& e : edges) {
    e.i = r.get<int32_t>();
    e.j = r.get<int32_t>();
    e.anchor = r.get<int32_t>();
    e.target = r.mat();
    e.weight = r.mat();
    if (r.get<uint8_t>()) e.T_i_other = r.se3();
    if (!valid_id(e.i) || (!e.T_i_other && !valid_id(e.j)) ||
        (e.anchor != -1 && !valid_id(e.anchor)))
      r.fail("edge with a keyframe id out of range");
    const cv::Mat& grid = keyframes[e.i].ba.inv_depth;
    if (e.target.size != grid.size || e.weight.size != grid.size || e.target.type() != CV_32FC2 ||
        e.weight.type() != kFlowWeightType)
      r.fail("edge " + std::to_string(e.i) + "-" + std::to_string(e.j) + ": bad grid images");
  }
  keyframes_ = std::move(keyframes);
  kept_images_ = std::move(kept_images);
  window_ = std::move(window);
  edges_ = std::move(edges);
}

}  // namespace radslam
