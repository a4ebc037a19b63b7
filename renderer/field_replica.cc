#include "renderer/field_replica.h"

#include <algorithm>
#include <stdexcept>

#include "mapper/field_io.h"

namespace radslam {

ApplyResult FieldReplica::apply(const FieldUpdate& update, std::string* error) {
  std::string why;
  // A mapper without a field yet sends updates with no layout and no blocks.
  if (update.layout.empty() && update.blocks.empty()) {
    if (update.is_snapshot) {
      waiting_snapshot_ = false;
      field_ = Field();
      version_empty_ = update.version;
      exact_version_ = update.version;
      return ApplyResult::kApplied;
    }
    return ApplyResult::kStale;
  }
  if (update.is_snapshot && update.chunk_count > 1) {
    // Only a replica that needs it assembles a snapshot (it costs a copy of the field).
    if (!waiting_snapshot_ && field_.initialized() && !assembler_.inProgress()) {
      return ApplyResult::kStale;
    }
    last_progress_s_ = now_s_;
    // The chunk's blocks repair the live field now; the whole snapshot makes it exact.
    if (field_.initialized()) repairFromSnapshotChunk(update, &field_, &why);
    const int64_t snapshot_in_progress = assembler_.snapshotId();
    const SnapshotAssembler::Result added = assembler_.add(update, &why);
    if (assembler_.snapshotId() != snapshot_in_progress) asked_order_.clear();
    switch (added) {
      case SnapshotAssembler::Result::kIncomplete:
        requestLostChunks(update);
        return ApplyResult::kPartial;
      case SnapshotAssembler::Result::kComplete:
        field_ = std::move(assembler_.field());
        assembler_.field() = Field();
        waiting_snapshot_ = false;
        exact_version_ = field_.version();
        asked_order_.clear();
        return ApplyResult::kApplied;
      case SnapshotAssembler::Result::kInvalid:
        if (error) *error = why;
        return ApplyResult::kInvalid;
    }
  }
  // A delta past a gap is applied all the same (the view stays live) while the snapshot that
  // makes the replica exact again is on its way.
  const ApplyResult result = applyFieldUpdate(update, &field_, &why, GapPolicy::kApply);
  switch (result) {
    case ApplyResult::kApplied:
      // An update based where the replica was last exact (the next one, or a catch-up after
      // lost ones) leaves it exact.
      if (update.is_snapshot || (exact_version_ >= 0 && update.base_version <= exact_version_)) {
        exact_version_ = update.version;
        waiting_snapshot_ = false;
        if (assembler_.inProgress()) assembler_.reset();  // that snapshot is not needed now
      }
      break;
    case ApplyResult::kGap:
      ++gaps_;
      if (!waiting_snapshot_) requestRepair(why);
      break;
    case ApplyResult::kInvalid:
      // A geometry change (mapper restarted with other voxel sizes) needs a snapshot too.
      if (why.find("needs a snapshot") != std::string::npos) {
        exact_version_ = -1;
        if (!waiting_snapshot_) requestRepair(why);
      }
      break;
    case ApplyResult::kStale:
    case ApplyResult::kPartial:
      break;
  }
  if (error) *error = why;
  return result;
}

void FieldReplica::requestRepair(const std::string& reason) {
  waiting_snapshot_ = true;
  last_progress_s_ = now_s_;
  SnapshotAsk ask;
  ask.reason = reason;
  ask.since_version = exact_version_;
  if (request_snapshot_) request_snapshot_(ask);
}

void FieldReplica::requestLostChunks(const FieldUpdate& chunk) {
  // The mapper sends a snapshot's chunks in order, then those asked for again in the order
  // asked: a chunk still missing that should have come before this one was lost.
  const auto asked = asked_order_.find(chunk.chunk_index);
  std::vector<int> lost;
  for (int c : assembler_.missing()) {
    const auto it = asked_order_.find(c);
    if (asked == asked_order_.end() ? (c < chunk.chunk_index && it == asked_order_.end())
                                    : (it != asked_order_.end() && it->second < asked->second))
      lost.push_back(c);
  }
  if (lost.empty()) return;
  requestChunks(lost, "chunk " + std::to_string(chunk.chunk_index) + " of " +
                          std::to_string(chunk.chunk_count) + " came after a lost one");
}

void FieldReplica::requestChunks(const std::vector<int>& chunks, const std::string& reason) {
  ++gaps_;
  last_progress_s_ = now_s_;
  for (int c : chunks) asked_order_[c] = ++asked_count_;
  SnapshotAsk ask;
  ask.reason = reason;
  ask.snapshot_id = assembler_.snapshotId();
  ask.chunks = chunks;
  if (request_snapshot_) request_snapshot_(ask);
}

void FieldReplica::missedUpdate(const std::string& reason) {
  ++gaps_;
  if (!waiting_snapshot_) requestRepair(reason);
}

void FieldReplica::retryStalledSnapshot(double now_s, double stall_s) {
  now_s_ = now_s;
  if (!waiting_snapshot_ || now_s - last_progress_s_ <= stall_s) return;
  const std::string reason =
      "nothing came within " + std::to_string(static_cast<int>(stall_s)) + " s of asking";
  if (assembler_.inProgress()) {
    requestChunks(assembler_.missing(), reason);
  } else {
    requestRepair(reason);
  }
}

MarchParams FieldReplica::marchParams() const {
  MarchParams mp;
  mp.step_fine = params_.step_fine;
  if (field_.initialized()) {
    const float s = static_cast<float>(field_.geometry().fineVoxelSize());
    mp.near = params_.near_voxels * s;
    mp.far = params_.far_voxels * s;
  }
  return mp;
}

namespace {
// What render() gives before any field exists: background colour, depth and sigma 0.
RenderImages emptyRender(const CameraModel& camera) {
  RenderImages out;
  out.color = cv::Mat(camera.height, camera.width, CV_32FC3, cv::Scalar::all(0));
  out.depth = cv::Mat::zeros(camera.height, camera.width, CV_32FC1);
  out.sigma = cv::Mat::zeros(camera.height, camera.width, CV_32FC1);
  out.weight = cv::Mat::zeros(camera.height, camera.width, CV_32FC1);
  return out;
}

void checkCamera(const CameraModel& camera) {
  if (camera.width <= 0 || camera.height <= 0 || !(camera.fx > 0) || !(camera.fy > 0))
    throw std::invalid_argument("render: camera needs a positive size and focal lengths");
}
}  // namespace

RenderImages FieldReplica::render(const SE3& T_world_cam, const CameraModel& camera,
                                  const MarchParams* params, int threads) const {
  checkCamera(camera);
  if (!field_.initialized()) return emptyRender(camera);
  return renderer_.render(field_, T_world_cam, camera, params ? *params : marchParams(),
                          threads > 0 ? threads : params_.threads);
}

RenderImages FieldReplica::renderPreview(const SE3& T_world_cam, const CameraModel& camera,
                                         const MarchParams& params, double refresh_budget_s) const {
  checkCamera(camera);
  if (!field_.initialized()) return emptyRender(camera);
  std::lock_guard<std::mutex> lock(preview_mutex_);
  if (preview_.skipThickness() != std::max(0.f, params.skip_thickness))
    preview_ = PreviewField(params.skip_thickness);
  preview_stale_.store(preview_.refresh(field_, refresh_budget_s), std::memory_order_relaxed);
  return preview_.render(field_, T_world_cam, camera, params, renderer_.background(),
                         params_.threads);
}

}  // namespace radslam
