#include "renderer/renderer_node.h"

#include <algorithm>
#include <chrono>
#include <iostream>
#include <mutex>
#include <stdexcept>

#include "common/cli.h"
#include "common/params.h"
#include "common/trajectory.h"
#include "renderer/render_service.h"

namespace radslam {
namespace {

// A snapshot asked for that makes no progress for this long (s) is asked for again (its lost
// chunks, when some arrived). The mapper serves whole snapshots at most every
// snapshot_min_period_s and lost chunks at once; asking twice costs nothing.
constexpr double kSnapshotStallS = 5.0;

// Warn about the first few of a kind, then every 100th, so a bad stream cannot flood the log.
bool shouldWarn(int64_t count) { return count <= 5 || count % 100 == 0; }

void validate(const RendererParams& p) {
  if (!(p.render_step_fine > 0)) throw std::invalid_argument("render_step_fine must be > 0");
  if (!(p.near_voxels >= 0)) throw std::invalid_argument("near_voxels must be >= 0");
  if (p.render_threads < 1) throw std::invalid_argument("render_threads must be >= 1");
  if (!(p.preview_step_fine > 0)) throw std::invalid_argument("preview_step_fine must be > 0");
  if (!(p.preview_skip_thickness >= 0) || !(p.preview_max_sample_thickness >= 0) ||
      !(p.preview_max_step_fine >= 1))
    throw std::invalid_argument(
        "preview_skip_thickness and preview_max_sample_thickness must be >= 0, "
        "preview_max_step_fine >= 1");
  if (!(p.preview_min_transmittance >= 0 && p.preview_min_transmittance < 1))
    throw std::invalid_argument("preview_min_transmittance must be in [0, 1)");
  if (!(p.preview_refresh_s >= 0)) throw std::invalid_argument("preview_refresh_s must be >= 0");
  if (p.follow_width < 0 || p.follow_width > kMaxRenderSize)
    throw std::invalid_argument("follow_width must be in [0, 4096] (0 = off)");
  if (!(p.follow_rate_hz > 0)) throw std::invalid_argument("follow_rate_hz must be > 0");
  if (!(p.status_rate_hz > 0)) throw std::invalid_argument("status_rate_hz must be > 0");
  if (p.final_width < 0 || p.final_width > kMaxRenderSize)
    throw std::invalid_argument("final_width must be in [0, 4096]");
  if (p.video_width < 1 || p.video_width > kMaxRenderSize)
    throw std::invalid_argument("video_width must be in [1, 4096]");
  if (!(p.video_fps > 0)) throw std::invalid_argument("video_fps must be > 0");
  if (p.video_max_frames < 1) throw std::invalid_argument("video_max_frames must be >= 1");
  if (p.final_max_renders < 1) throw std::invalid_argument("final_max_renders must be >= 1");
  if (p.final_render_threads < 0)
    throw std::invalid_argument("final_render_threads must be >= 0 (0 = every core)");
}

}  // namespace

RendererParams loadRendererParams(const std::string& yaml_path,
                                  const std::vector<std::string>& overrides, std::string* dump,
                                  std::string* source) {
  RendererParams p;
  ParamReader r(yaml_path, "renderer");
  for (const std::string& o : overrides) r.addOverride(o);
  double step = p.render_step_fine, near = p.near_voxels;
  r.get("render_step_fine", &step);
  r.get("near_voxels", &near);
  p.render_step_fine = static_cast<float>(step);
  p.near_voxels = static_cast<float>(near);
  r.get("render_threads", &p.render_threads);
  r.get("preview_step_fine", &p.preview_step_fine);
  r.get("preview_min_transmittance", &p.preview_min_transmittance);
  r.get("preview_skip_thickness", &p.preview_skip_thickness);
  r.get("preview_max_sample_thickness", &p.preview_max_sample_thickness);
  r.get("preview_max_step_fine", &p.preview_max_step_fine);
  r.get("preview_refresh_s", &p.preview_refresh_s);
  r.get("follow_width", &p.follow_width);
  r.get("follow_rate_hz", &p.follow_rate_hz);
  r.get("status_rate_hz", &p.status_rate_hz);
  r.get("final_renders", &p.final_renders);
  r.get("final_max_renders", &p.final_max_renders);
  r.get("final_render_threads", &p.final_render_threads);
  r.get("final_width", &p.final_width);
  r.get("video", &p.video);
  r.get("video_width", &p.video_width);
  r.get("video_fps", &p.video_fps);
  r.get("video_max_frames", &p.video_max_frames);
  r.finish();
  try {
    validate(p);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(r.source() + ": renderer." + e.what());
  }
  if (dump) *dump = r.dump();
  if (source) *source = r.source();
  return p;
}

RendererNode::RendererNode(Bus* bus, RendererParams params, std::string out_dir)
    : bus_(bus),
      params_(params),
      out_dir_(std::move(out_dir)),
      replica_([&] {
        ReplicaRenderParams rp;
        rp.step_fine = params.render_step_fine;
        rp.near_voxels = params.near_voxels;
        rp.threads = params.render_threads;
        return rp;
      }()),
      reporter_("renderer") {
  validate(params_);
  replica_.setSnapshotRequest([this](const FieldReplica::SnapshotAsk& ask) {
    Control c;
    c.command = ControlCommand::kSnapshot;
    c.target = "mapper";
    if (ask.chunks.empty()) {
      ++snapshots_requested_;
      if (ask.since_version >= 0) {
        c.argument = catchUpArgument(ask.since_version);
        std::cerr << "radslam-renderer: asking the mapper for the field since version "
                  << ask.since_version << ": " << ask.reason << "\n";
      } else {
        c.argument = "renderer";
        std::cerr << "radslam-renderer: asking the mapper for a snapshot: " << ask.reason << "\n";
      }
    } else {
      ++chunks_requested_;
      c.argument = snapshotChunksArgument(ask.snapshot_id, ask.chunks);
      std::cerr << "radslam-renderer: asking the mapper again for " << ask.chunks.size()
                << " chunk(s) of snapshot " << ask.snapshot_id << ": " << ask.reason << "\n";
    }
    bus_->publish(channel::kControl, c);
  });
  bus_->subscribe<FieldUpdate>(channel::kField, [this](const FieldUpdate& u) { onField(u); });
  bus_->subscribe<RenderRequest>(channel::kRenderRequest,
                                 [this](const RenderRequest& r) { onRenderRequest(r); });
  bus_->subscribe<PoseStamped>(channel::kPose, [this](const PoseStamped& p) { onPose(p); });
  bus_->subscribe<Frame>(channel::kCamera, [this](const Frame& f) {
    last_camera_ = f.camera;
    viewer_.setCamera(f);
  });
  bus_->subscribe<Keyframe>(channel::kKeyframe, [this](const Keyframe& k) { onKeyframe(k); });
  bus_->subscribe<PoseStamped>(channel::kGroundTruth,
                               [this](const PoseStamped& p) { viewer_.addGroundTruth(p); });
  bus_->subscribe<Status>(channel::kStatus, [this](const Status& s) { onStatus(s); });
  bus_->subscribe<ObjectList>(channel::kObjects,
                              [this](const ObjectList& o) { viewer_.addObjects(o); });
  bus_->subscribe<Control>(channel::kControl, [this](const Control& c) { onControl(c); });
  if (params_.follow_width > 0) follow_thread_ = std::thread([this] { followLoop(); });
  reporter_.setState(ProcessState::kRunning);
}

RendererNode::~RendererNode() {
  stop_follow_ = true;
  if (follow_thread_.joinable()) follow_thread_.join();
}

int64_t RendererNode::fieldVersion() const {
  std::shared_lock<std::shared_mutex> lock(field_mutex_);
  return replica_.version();
}

bool RendererNode::waitingForSnapshot() const {
  std::shared_lock<std::shared_mutex> lock(field_mutex_);
  return replica_.waitingForSnapshot();
}

namespace {
constexpr int kDrainQuietPolls = 4;  // of 50 ms: the bus is quiet after 200 ms without messages
// FIELD payload queued while renders hold the replica (bytes): a bound in bytes, not messages,
// so that small messages arriving fast (a log replayed at rate 0) do not stall the bus thread
// after a few MB while the socket buffer overflows.
constexpr size_t kMaxPendingBytes = size_t(64) << 20;
}  // namespace

void applyPreview(const RendererParams& params, MarchParams* mp) {
  mp->step_fine = static_cast<float>(params.preview_step_fine);
  mp->min_transmittance = static_cast<float>(params.preview_min_transmittance);
  mp->skip_thickness = static_cast<float>(params.preview_skip_thickness);
  mp->max_sample_thickness = static_cast<float>(params.preview_max_sample_thickness);
  mp->max_step_fine = static_cast<float>(params.preview_max_step_fine);
}

RenderResult RendererNode::render(const RenderRequest& request, bool preview) const {
  std::shared_lock<std::shared_mutex> lock(field_mutex_);
  if (!preview) return renderView(replica_, request);
  PreviewOptions options;
  options.march = replica_.marchParams();
  applyPreview(params_, &options.march);
  options.refresh_budget_s = params_.preview_refresh_s;
  return renderView(replica_, request, &options);
}

void RendererNode::onField(const FieldUpdate& update) {
  field_received_version_ = update.version;
  pending_updates_.push_back(update);
  for (const FieldBlock& b : update.blocks) pending_bytes_ += b.data.size();
  // A bounded queue: past it the bus thread waits for the renders (reader-preferring locks
  // could otherwise keep it waiting while the queue grows).
  applyPendingUpdates(pending_bytes_ >= kMaxPendingBytes);
}

void RendererNode::applyPendingUpdates(bool wait) {
  if (pending_updates_.empty()) return;
  std::unique_lock<std::shared_mutex> lock(field_mutex_, std::defer_lock);
  if (wait) {
    lock.lock();
  } else if (!lock.try_lock()) {
    return;
  }
  BusyTimer::Scope busy(reporter_.busy());
  pending_bytes_ = 0;
  for (; !pending_updates_.empty(); pending_updates_.pop_front()) {
    std::string error;
    if (replica_.apply(pending_updates_.front(), &error) == ApplyResult::kInvalid) {
      reporter_.setError(bus_->fullChannel(channel::kField) + ": " + error);
      std::cerr << "radslam-renderer: warning: " << bus_->fullChannel(channel::kField)
                << ": skipped update: " << error << "\n";
    }
  }
  const Field& f = replica_.field();
  viewer_.setField(replica_.version(), f.initialized() ? f.totalBlocks() : 0,
                   f.initialized() ? f.boundsMin() : Eigen::Vector3f::Zero(),
                   f.initialized() ? f.boundsMax() : Eigen::Vector3f::Zero());
}

void RendererNode::onRenderRequest(const RenderRequest& request) {
  RenderResult result;
  {
    BusyTimer::Scope busy(reporter_.busy());
    result = render(request);
  }
  if (result.ok) {
    ++renders_;
    reporter_.itemHandled();
  } else {
    ++bad_requests_;
    reporter_.setError(result.error);
    if (shouldWarn(bad_requests_))
      std::cerr << "radslam-renderer: warning: " << result.error << "\n";
  }
  bus_->publish(channel::kRender, result);
}

void RendererNode::onPose(const PoseStamped& pose) {
  viewer_.addPose(pose);
  ViewPose& v = trajectory_[pose.frame_index];
  v.utime = pose.header.utime;
  v.T_world_cam = pose.T_world_cam;
  v.camera = last_camera_;
}

void RendererNode::onKeyframe(const Keyframe& keyframe) {
  auto it = keyframe_versions_.find(keyframe.keyframe_id);
  if (it != keyframe_versions_.end() && it->second > keyframe.version) return;
  keyframe_versions_[keyframe.keyframe_id] = keyframe.version;
  ViewPose& v = keyframes_[keyframe.keyframe_id];
  v.utime = keyframe.header.utime;
  v.T_world_cam = keyframe.T_world_cam;
  v.camera = keyframe.camera;
  viewer_.addKeyframe(keyframe.keyframe_id);
}

void RendererNode::onStatus(const Status& status) {
  viewer_.setStatus(status);
  if (status.process != "mapper") return;
  for (const auto& [key, value] : status.values) {
    if (key != "field_version") continue;
    if (mapper_reported_version_ > field_received_version_)
      missed_update_ = "the mapper reported field version " +
                       std::to_string(mapper_reported_version_) + ", the last update received is " +
                       std::to_string(field_received_version_);
    mapper_reported_version_ = static_cast<int64_t>(value);
  }
}

void RendererNode::onControl(const Control& control) {
  if (!control.target.empty() && control.target != "renderer") return;
  if (control.command == ControlCommand::kStop) control_stop_ = true;
}

void RendererNode::followLoop() {
  using Clock = std::chrono::steady_clock;
  int64_t rendered_seq = -1, rendered_version = -1;
  const auto period = std::chrono::duration<double>(1.0 / params_.follow_rate_hz);
  while (!stop_follow_) {
    const auto t0 = Clock::now();
    PoseStamped pose;
    CameraModel camera;
    int64_t seq = 0;
    const int64_t version = fieldVersion();
    // Also while the preview copy is behind the replica: each view brings it further.
    if (viewer_.latestPose(&pose, &camera, &seq) &&
        (seq != rendered_seq || version != rendered_version || replica_.previewStaleBlocks() > 0)) {
      RenderRequest request;
      request.T_world_cam = pose.T_world_cam;
      request.camera = scaledCamera(camera, params_.follow_width);
      request.channels = kRenderColor | kRenderDepth | kRenderSigma;
      const RenderResult r = render(request, true);
      if (r.ok) viewer_.setRender(r.color, r.depth, r.sigma);
      rendered_seq = seq;
      rendered_version = version;
    }
    // At least as long as the render took: the replica is free half the time or more for
    // updates, and the view costs at most half a core. In short slices, so that the
    // destructor does not wait for a whole period.
    const auto pause = std::max<Clock::duration>(
        std::chrono::duration_cast<Clock::duration>(period), 2 * (Clock::now() - t0));
    while (!stop_follow_ && Clock::now() - t0 < pause)
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

void RendererNode::publishStatus(ProcessState state) {
  reporter_.setState(state);
  reporter_.setValue("field_version", static_cast<double>(fieldVersion()));
  reporter_.setValue("renders", static_cast<double>(renders_));
  reporter_.setValue("bad_requests", static_cast<double>(bad_requests_));
  reporter_.setValue("snapshots_requested", static_cast<double>(snapshots_requested_));
  reporter_.setValue("snapshot_chunks_requested", static_cast<double>(chunks_requested_));
  reporter_.setValue("waiting_for_snapshot", waitingForSnapshot() ? 1 : 0);
  reporter_.setValue("keyframes", static_cast<double>(keyframes_.size()));
  reporter_.setValue("preview_stale_blocks", static_cast<double>(replica_.previewStaleBlocks()));
  const Status s = reporter_.make();
  viewer_.setStatus(s);
  bus_->publish(channel::kStatus, s);
}

void RendererNode::heartbeat(ProcessState state) {
  const int64_t now = wallClockMicros();
  if (now - last_status_us_ < static_cast<int64_t>(1e6 / params_.status_rate_hz)) return;
  last_status_us_ = now;
  publishStatus(state);
}

int RendererNode::spinOnce(int timeout_ms) {
  const int handled = bus_->handle(timeout_ms);
  applyPendingUpdates(false);
  const int64_t now = wallClockMicros();
  {
    // A periodic check: skipped while a render holds the replica (the bus thread never waits).
    std::unique_lock<std::shared_mutex> lock(field_mutex_, std::try_to_lock);
    if (lock) {
      replica_.retryStalledSnapshot(now * 1e-6, kSnapshotStallS);
      if (!missed_update_.empty()) replica_.missedUpdate(missed_update_);
      missed_update_.clear();
    }
  }
  heartbeat(ProcessState::kRunning);
  return handled;
}

int RendererNode::run(bool linger) {
  bool log_ended = false;
  while (!stopRequested() && !control_stop_) {
    if (spinOnce(50) < 0) {  // end of a file:// log
      log_ended = true;
      break;
    }
  }
  // What is still on its way (the mapper's final flush ends just before the stop) goes in
  // first: until the bus has been quiet for a moment.
  for (int quiet = 0; !log_ended && quiet < kDrainQuietPolls;) {
    const int handled = spinOnce(50);
    if (handled < 0) log_ended = true;
    quiet = handled > 0 ? 0 : quiet + 1;
  }
  applyPendingUpdates(true);
  publishStatus(ProcessState::kIdle);
  viewer_.setRunEnded(true);
  writeFinal();
  publishStatus(ProcessState::kDone);
  if (linger) {
    std::cerr << "radslam-renderer: run ended; still serving the final map (Ctrl-C to quit)\n";
    while (!stopRequested()) {
      if (log_ended || spinOnce(100) < 0) {
        log_ended = true;
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
    }
  }
  return 0;
}

void RendererNode::writeFinal() {
  if (out_dir_.empty()) return;
  std::shared_lock<std::shared_mutex> lock(field_mutex_);
  if (!replica_.field().initialized()) {
    std::cerr << "radslam-renderer: no field received: no final renders\n";
    return;
  }
  std::cerr << "radslam-renderer: final field version " << replica_.version() << ", "
            << replica_.field().totalBlocks() << " blocks, "
            << (replica_.waitingForSnapshot() ? "missed updates since the last snapshot"
                                              : "every update applied")
            << " (" << replica_.gaps() << " gaps)\n";
  // The heartbeat goes on, so that a supervisor sees a renderer at work, not a hung one.
  const auto progress = [this] { heartbeat(ProcessState::kIdle); };
  const int threads = threadsOrEveryCore(params_.final_render_threads);
  try {
    if (params_.final_renders) {
      std::vector<ViewPose> views;
      for (const auto& [id, v] : keyframes_) {
        ViewPose view = v;
        view.camera = scaledCamera(v.camera, params_.final_width);
        views.push_back(view);
      }
      views = evenlySpread(views, static_cast<size_t>(params_.final_max_renders));
      const int n =
          writeFinalRenders(replica_, views, out_dir_ + "/renders/final", threads, progress);
      std::cerr << "radslam-renderer: wrote " << n << " keyframe renders to " << out_dir_
                << "/renders/final\n";
    }
    if (params_.video && !trajectory_.empty()) {
      std::vector<ViewPose> views;
      const size_t step = (trajectory_.size() + params_.video_max_frames - 1) /
                          static_cast<size_t>(params_.video_max_frames);
      size_t i = 0;
      for (const auto& [index, v] : trajectory_) {
        if (i++ % step != 0 || v.camera.width <= 0) continue;
        ViewPose view = v;
        view.camera = scaledCamera(v.camera, params_.video_width);
        views.push_back(view);
      }
      const std::string path = out_dir_ + "/renders/flythrough.avi";
      const int n = writeFlyThrough(replica_, views, path, params_.video_fps, threads, progress);
      std::cerr << "radslam-renderer: wrote " << n << " frames to " << path << "\n";
    }
  } catch (const std::exception& e) {
    reporter_.setError(e.what());
    std::cerr << "radslam-renderer: error: " << e.what() << "\n";
  }
}

}  // namespace radslam
