#include "mapper/mapper_node.h"

#include <algorithm>
#include <chrono>
#include <deque>
#include <filesystem>
#include <iostream>
#include <limits>
#include <thread>

#include "common/cli.h"
#include "mapper/field_io.h"
#include "mapper/mapper_outputs.h"

namespace radslam {

namespace {
constexpr int kFrameRenderStride = 10;  // every 10th non-keyframe is rendered at the end

size_t payloadBytes(const FieldUpdate& u) {
  size_t bytes = 0;
  for (const FieldBlock& b : u.blocks) bytes += b.data.size();
  return bytes;
}
}  // namespace

// Bounds FIELD traffic in every 1 s window. ready() says whether a message as large as the
// last one would fit now (callers that must not wait skip a turn); waitFor() waits until a
// message of the given size fits (at once when nothing went in the last second, so that a
// message larger than the limit still goes, alone).
class MapperNode::Pacer {
 public:
  explicit Pacer(double mb_per_s) : limit_(mb_per_s * 1e6) {}
  bool ready() {
    forget(Clock::now());
    return window_.empty() || window_bytes_ + last_ <= limit_;
  }
  void wait() { waitFor(last_); }
  void waitFor(double bytes) {
    for (forget(Clock::now()); !window_.empty() && window_bytes_ + bytes > limit_;
         forget(Clock::now()))
      std::this_thread::sleep_until(window_.front().first + kWindow);
  }
  void sent(size_t bytes) {
    window_.emplace_back(Clock::now(), static_cast<double>(bytes));
    window_bytes_ += static_cast<double>(bytes);
    last_ = static_cast<double>(bytes);
    total_ += static_cast<double>(bytes);
  }
  double megabytes() const { return total_ * 1e-6; }

 private:
  using Clock = std::chrono::steady_clock;
  static constexpr std::chrono::seconds kWindow{1};
  void forget(Clock::time_point now) {
    while (!window_.empty() && window_.front().first + kWindow <= now) {
      window_bytes_ -= window_.front().second;
      window_.pop_front();
    }
  }
  double limit_, window_bytes_ = 0, last_ = 0, total_ = 0;
  std::deque<std::pair<Clock::time_point, double>> window_;
};

MapperNode::MapperNode(Bus* bus, const MapperNodeParams& params, std::string out_dir)
    : bus_(bus),
      params_(params),
      out_dir_(std::move(out_dir)),
      mapper_(params.core),
      reporter_("mapper"),
      start_(std::chrono::steady_clock::now()),
      field_pacer_(std::make_unique<Pacer>(params.field_max_mb_per_s)) {
  bus_->subscribe<Keyframe>(channel::kKeyframe, [this](const Keyframe& k) { onKeyframe(k); });
  bus_->subscribe<PoseStamped>(channel::kPose, [this](const PoseStamped& p) { onPose(p); });
  bus_->subscribe<Control>(channel::kControl, [this](const Control& c) { onControl(c); });
  bus_->subscribe<Status>(channel::kStatus, [this](const Status& s) { onStatus(s); });
  reporter_.setState(ProcessState::kIdle);
  snapshot_seq_ = wallClockMicros();
}

MapperNode::~MapperNode() = default;

double MapperNode::now() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

void MapperNode::onKeyframe(const Keyframe& keyframe) {
  // Keep only the newest version per id; the store ignores older ones anyway.
  auto it = queue_.find(keyframe.keyframe_id);
  if (it == queue_.end() || it->second.version < keyframe.version)
    queue_[keyframe.keyframe_id] = keyframe;
  max_keyframe_id_ = std::max(max_keyframe_id_, keyframe.keyframe_id);
}

void MapperNode::requestMissingKeyframes() {
  // The tracker numbers keyframes 0, 1, 2, ...: an id below the highest seen that the mapper
  // does not have was lost. Asked for again every kMissingRequestPeriodS, kMaxMissingRequests
  // times at most per id (the tracker may no longer hold its images, or keeps rejecting it).
  constexpr double kMissingRequestPeriodS = 2.0;
  constexpr int kMaxMissingRequests = 3;
  // The scan itself runs at most once a period too (this is called every training step).
  if (now() - last_missing_request_ < kMissingRequestPeriodS) return;
  last_missing_request_ = now();
  std::string ids;
  for (int32_t id = 0; id < max_keyframe_id_; ++id) {
    if (mapper_.keyframes().find(id) >= 0 || queue_.count(id) || mapper_.retired(id)) continue;
    int& asked = missing_requests_[id];
    if (asked >= kMaxMissingRequests) continue;
    ++asked;
    ids += (ids.empty() ? "" : ",") + std::to_string(id);
  }
  if (ids.empty()) return;
  std::cerr << "radslam-mapper: asking the tracker again for keyframes " << ids << "\n";
  requestKeyframes("keyframes:" + ids);
}

void MapperNode::onPose(const PoseStamped& pose) {
  // Which frames are rendered is known at the end, once the keyframes are (0.5 KB a frame).
  frame_poses_[pose.frame_index] = pose;
}

void MapperNode::onStatus(const Status& status) {
  if (status.process.rfind("renderer", 0) != 0) return;
  ReplicaState& r = replicas_[{status.process, status.pid}];
  r.heard_at = listen_s_;
  r.done = status.state == ProcessState::kDone;
  for (const auto& [key, value] : status.values) {
    if (key == "field_version") r.field_version = static_cast<int64_t>(value);
    if (key == "waiting_for_snapshot") r.waiting_snapshot = value != 0;
  }
}

void MapperNode::onControl(const Control& control) {
  if (!control.target.empty() && control.target != "mapper") return;
  switch (control.command) {
    case ControlCommand::kStop:
      stop_ = true;
      break;
    case ControlCommand::kSave:
      save_requested_ = true;
      save_request_ = control.argument;
      break;
    case ControlCommand::kSnapshot: {
      // A catch-up and lost chunks of the last snapshot go out at once; a whole snapshot waits
      // for its turn.
      int64_t since = -1;
      if (parseCatchUpArgument(control.argument, &since) && since >= catch_up_floor_ &&
          mapper_.field().initialized() && since <= mapper_.field().version()) {
        catch_up_since_ = catch_up_since_ < 0 ? since : std::min(catch_up_since_, since);
        break;
      }
      int64_t id = -1;
      std::vector<int> chunks;
      if (parseSnapshotChunksArgument(control.argument, &id, &chunks)) {
        if (!snapshot_ && sent_snapshot_ && sent_snapshot_->id() == id) {
          snapshot_ = std::move(sent_snapshot_);
          sent_snapshot_.reset();
        }
        // (Another snapshot on its way serves the replica as well.)
        if (snapshot_) {
          if (snapshot_->id() == id) {
            std::cerr << "radslam-mapper: sending " << snapshot_->resend(chunks) << " of "
                      << chunks.size() << " chunk(s) asked for of snapshot " << id << " again\n";
          }
          break;
        }
        std::cerr << "radslam-mapper: chunks of snapshot " << id
                  << " asked for, which is not the last one: a new snapshot\n";
      }
      snapshot_requested_ = true;
      break;
    }
    case ControlCommand::kRepublish:
      snapshot_requested_ = true;
      break;
    case ControlCommand::kReset:
      max_keyframe_id_ = -1;  // the tracker numbers its keyframes from 0 again
      newest_keyframe_utime_ = 0;
      missing_requests_.clear();
      snapshot_.reset();  // its blocks are gone
      sent_snapshot_.reset();
      catch_up_since_ = -1;
      catch_up_floor_ = std::numeric_limits<int64_t>::max();  // replicas hold another field
      mapper_.reset();
      queue_.clear();
      frame_poses_.clear();
      published_poses_.clear();
      unpublished_poses_.clear();
      snapshot_requested_ = true;  // replicas start over from the empty field
      break;
    case ControlCommand::kRewind:  // the player's
      break;
  }
}

void MapperNode::addQueuedKeyframes(int max_refinements) {
  // New keyframes first: they are what the map lags behind on. A refinement costs as much as a
  // new keyframe's seeding of the blocks its new depth adds (up to 0.7 s on fr1/rpy RGB-D),
  // and the tracker re-sends in bursts.
  for (auto it = queue_.begin(); it != queue_.end();) {
    if (mapper_.keyframes().find(it->first) >= 0) {
      ++it;
      continue;
    }
    addKeyframe(it->second);
    it = queue_.erase(it);
  }
  for (auto it = queue_.begin(); it != queue_.end() && max_refinements != 0; --max_refinements) {
    addKeyframe(it->second);
    it = queue_.erase(it);
  }
}

void MapperNode::addKeyframe(const Keyframe& keyframe) {
  try {
    const KeyframeStore::InsertResult r = mapper_.addKeyframe(keyframe);
    if (r != KeyframeStore::InsertResult::kIgnored) {
      // STATUS says how far the map is: a re-sent older keyframe counts as an item but does
      // not move it back.
      const bool newest = keyframe.header.utime > newest_keyframe_utime_;
      if (newest) newest_keyframe_utime_ = keyframe.header.utime;
      reporter_.itemHandled(newest ? keyframe.frame_index : -1, keyframe.header.utime);
    }
  } catch (const std::invalid_argument& e) {
    // A malformed keyframe is skipped; the mapper keeps going.
    std::cerr << "radslam-mapper: warning: skipping " << e.what() << "\n";
    reporter_.setError(e.what());
  }
  heartbeat();  // a burst of keyframes takes a while: report each as it is handled
}

void MapperNode::resume(const std::string& checkpoint) {
  mapper_.loadCheckpoint(checkpoint);
  mapper_.skipVersionsAfterRestart();
  // Replicas are ahead of or apart from the resumed field: the first delta is based on the new
  // version (a gap to them) and a snapshot makes them equal to it.
  delta_base_ = mapper_.field().initialized() ? mapper_.field().version() : 0;
  catch_up_floor_ = delta_base_;
  snapshot_requested_ = true;
  std::cerr << "radslam-mapper: resumed from " << checkpoint << ": " << mapper_.keyframes().size()
            << " keyframes, " << (mapper_.field().initialized() ? mapper_.field().totalBlocks() : 0)
            << " blocks\n";
}

void MapperNode::requestKeyframes(const std::string& which) {
  Control c;
  c.command = ControlCommand::kRepublish;
  c.target = "tracker";
  c.argument = which;
  bus_->publish(channel::kControl, c);
}

void MapperNode::publishUpdate() {
  // Past the FIELD limit the rest waits for the next period (its blocks stay changed).
  int blocks = params_.max_blocks_per_update;
  for (int chunks = snapshot_ ? blocks * 3 / 4 : 0;
       chunks > 0 && snapshot_ && field_pacer_->ready();) {
    const int sent = std::max(1, publishSnapshotChunk());
    chunks -= sent;
    blocks -= sent;
  }
  if (catch_up_since_ >= 0 && field_pacer_->ready()) blocks -= publishCatchUp();
  while (blocks > 0 && field_pacer_->ready()) {
    FieldUpdate u = mapper_.makeUpdate(delta_base_, std::min(blocks, blocksPerMessage()));
    if (u.blocks.empty()) return;
    blocks -= static_cast<int>(u.blocks.size());
    publishField(&u);
    delta_base_ = u.version;
  }
}

bool MapperNode::publishFlushMessage() {
  // The snapshot in progress, every block not yet sent, then a snapshot if one was asked for
  // (a replica that lost an update is exact again only with one) and what changed meanwhile.
  if (snapshot_) {
    publishSnapshotChunk();
    return true;
  }
  if (catch_up_since_ >= 0 && publishCatchUp() > 0) return true;
  FieldUpdate u = mapper_.makeUpdate(delta_base_, blocksPerMessage());
  if (!u.blocks.empty()) {
    publishField(&u);
    delta_base_ = u.version;
    return true;
  }
  if (snapshot_requested_ && mapper_.field().initialized()) {
    startSnapshot();
    return true;
  }
  return false;
}

void MapperNode::flushField(bool to_end) {
  while (flushing_) {
    if (to_end) {
      field_pacer_->wait();
    } else if (!field_pacer_->ready()) {
      return;
    }
    flushing_ = publishFlushMessage();
    heartbeat();
  }
}

int MapperNode::blocksPerMessage() const {
  if (!mapper_.field().initialized()) return params_.max_blocks_per_update;
  const double raw_block_bytes =
      static_cast<double>(Field::kBlockVoxels) * mapper_.field().channels() * sizeof(float);
  const double budget = 0.25 * params_.field_max_mb_per_s * 1e6;  // bytes
  return static_cast<int>(std::clamp(budget / raw_block_bytes, 1.0,
                                     static_cast<double>(params_.max_blocks_per_update)));
}

void MapperNode::publishField(FieldUpdate* u) {
  encodeFieldUpdate(params_.field_encoding, u);
  const size_t bytes = payloadBytes(*u);
  field_pacer_->waitFor(static_cast<double>(bytes));
  u->header.utime = wallClockMicros();
  bus_->publish(channel::kField, *u);
  field_pacer_->sent(bytes);
}

void MapperNode::startSnapshot() {
  snapshot_requested_ = false;
  if (!mapper_.field().initialized()) {
    FieldUpdate u = mapper_.makeSnapshot();
    publishField(&u);
    return;
  }
  // In chunks of one message, 3/4 of each update period's blocks, next to deltas of the rest:
  // a snapshot never outgrows the FIELD rate (a whole one would be one message of the whole
  // field), and the live view of the replicas that do not need it keeps moving.
  sent_snapshot_.reset();
  snapshot_.emplace(mapper_.makeSnapshotSender(++snapshot_seq_, blocksPerMessage()));
}

int MapperNode::publishCatchUp() {
  const int64_t since = catch_up_since_;
  catch_up_since_ = -1;
  FieldUpdate u = mapper_.makeCatchUp(since, blocksPerMessage());
  if (u.blocks.empty()) {
    snapshot_requested_ = true;  // more changed since than one message holds
    return 0;
  }
  std::cerr << "radslam-mapper: sending the " << u.blocks.size()
            << " blocks changed since field version " << since << " (a renderer lost updates)\n";
  publishField(&u);
  delta_base_ = u.version;
  return static_cast<int>(u.blocks.size());
}

int MapperNode::publishSnapshotChunk() {
  FieldUpdate u = snapshot_->next();
  publishField(&u);
  // The deltas go on from delta_base_, the version of the last chunk (SnapshotSender::next
  // marks what the assembled replica lacks as changed): no delta grows past the budget.
  if (snapshot_->done()) {
    sent_snapshot_ = std::move(snapshot_);
    snapshot_.reset();
  }
  return static_cast<int>(u.blocks.size());
}

void MapperNode::publishPoses(bool all) {
  if (!params_.publish_poses) {
    mapper_.takeRefinedPoses();
    return;
  }
  for (const RefinedPose& p : mapper_.takeRefinedPoses()) unpublished_poses_[p.keyframe_id] = p;
  const double min_rad = params_.pose_publish_min_deg * M_PI / 180;
  for (auto it = unpublished_poses_.begin(); it != unpublished_poses_.end();) {
    const RefinedPose& p = it->second;
    // Training moves every pose a little each period: below the deadband it waits (for the
    // final poses, or until it has moved enough).
    auto last = published_poses_.find(p.keyframe_id);
    if (!all && last != published_poses_.end()) {
      const SE3 delta = last->second.inverse() * p.T_world_cam;
      if (delta.translation().norm() < params_.pose_publish_min_m &&
          Eigen::AngleAxisd(delta.quaternion()).angle() < min_rad) {
        ++it;
        continue;
      }
    }
    PoseStamped msg;
    msg.header = p.header;
    const int k = mapper_.keyframes().find(p.keyframe_id);
    msg.frame_index = k >= 0 ? mapper_.keyframes().entry(k).keyframe.frame_index : -1;
    msg.state = TrackingState::kTracking;
    msg.is_keyframe = true;
    msg.T_world_cam = p.T_world_cam;
    if (k >= 0) msg.covariance = mapper_.keyframes().entry(k).keyframe.covariance;
    bus_->publish(kMapperPoseChannel, msg);
    published_poses_[p.keyframe_id] = p.T_world_cam;
    it = unpublished_poses_.erase(it);
  }
}

void MapperNode::publishStatus() {
  const Field& f = mapper_.field();
  reporter_.setQueueDepth(static_cast<int32_t>(queue_.size()));
  reporter_.setValue("keyframes", mapper_.keyframes().size());
  reporter_.setValue("blocks", static_cast<double>(f.initialized() ? f.totalBlocks() : 0));
  reporter_.setValue("field_version", static_cast<double>(f.initialized() ? f.version() : 0));
  reporter_.setValue("rays_per_s", train_s_ > 0 ? rays_ / train_s_ : 0);
  reporter_.setValue("loss", last_stats_.loss);
  reporter_.setValue("loss_rgb", last_stats_.loss_rgb);
  reporter_.setValue("loss_depth", last_stats_.loss_depth);
  reporter_.setValue("train_steps", static_cast<double>(mapper_.trainer().steps()));
  Status s = reporter_.make();
  bus_->publish(channel::kStatus, s);
}

void MapperNode::saveCheckpoint(const std::string& path) {
  try {
    if (path.empty()) return;
    const std::filesystem::path parent = std::filesystem::path(path).parent_path();
    if (!parent.empty()) std::filesystem::create_directories(parent);
    mapper_.saveCheckpoint(path, params_.checkpoint_images);
    std::cerr << "radslam-mapper: checkpoint " << path << "\n";
  } catch (const std::exception& e) {
    std::cerr << "radslam-mapper: warning: " << e.what() << "\n";
    reporter_.setError(e.what());
  }
}

bool MapperNode::spinOnce(int timeout_ms) {
  const bool can_train = mapper_.field().initialized() && mapper_.keyframes().size() > 0;
  // Poll when there is training to do, else wait for a message.
  const int handled = bus_->handle(can_train ? 0 : timeout_ms);
  if (handled < 0) return false;
  addQueuedKeyframes(1);
  requestMissingKeyframes();
  if (mapper_.field().initialized() && mapper_.keyframes().size() > 0) {
    reporter_.setState(ProcessState::kRunning);
    BusyTimer::Scope busy(reporter_.busy());
    const double t0 = now();
    last_stats_ = mapper_.train(1);
    train_s_ += now() - t0;
    rays_ += last_stats_.rays;
  }
  // (A snapshot of no field would mean nothing to a replica: wait until there is one.)
  if (snapshot_requested_ && !snapshot_ && mapper_.field().initialized() &&
      now() - last_snapshot_ >= params_.snapshot_min_period_s) {
    last_snapshot_ = now();
    startSnapshot();
  }
  if (params_.checkpoint_period_s > 0 && !out_dir_.empty() &&
      now() - last_checkpoint_ >= params_.checkpoint_period_s && mapper_.field().initialized()) {
    last_checkpoint_ = now();
    saveCheckpoint(out_dir_ + "/mapper.ckpt");
  }
  if (save_requested_) {
    save_requested_ = false;
    saveCheckpoint(!save_request_.empty() ? save_request_
                   : out_dir_.empty()     ? std::string()
                                          : out_dir_ + "/mapper.ckpt");
  }
  const double t = now();
  if (t - last_update_ >= params_.update_period_s) {
    last_update_ = t;
    publishUpdate();
    publishPoses();
  }
  if (t - last_status_ >= params_.status_period_s) {
    last_status_ = t;
    publishStatus();
  }
  return true;
}

void MapperNode::heartbeat() {
  if (now() - last_status_ < params_.status_period_s) return;
  last_status_ = now();
  publishStatus();
}

void MapperNode::finish() {
  // Take what is still queued, train a last bounded burst, publish everything.
  bus_->handle(0);
  addQueuedKeyframes(-1);
  const double t0 = now();
  if (mapper_.field().initialized() && mapper_.keyframes().size() > 0) {
    mapper_.setTrainingThreads(threadsOrEveryCore(params_.final_training_threads));
    const int64_t rays_wanted =
        int64_t{params_.final_rays_per_keyframe} * mapper_.keyframes().size();
    auto raysTrained = [&] {
      int64_t rays = 0;
      for (int i = 0; i < mapper_.keyframes().size(); ++i)
        rays += mapper_.keyframes().entry(i).rays_trained;
      return rays;
    };
    const int64_t rays_before = raysTrained();
    while (now() - t0 < params_.final_training_s ||
           (raysTrained() < rays_wanted && now() - t0 < params_.final_training_max_s)) {
      last_stats_ = mapper_.train(1);
      rays_ += last_stats_.rays;
      heartbeat();
    }
    std::cerr << "radslam-mapper: final training " << now() - t0 << " s on "
              << mapper_.trainer().params().threads
              << " thread(s): " << (raysTrained() - rays_before) / 1e6 << "M rays, "
              << raysTrained() / 1e6 / mapper_.keyframes().size()
              << "M per keyframe since it arrived (wanted " << params_.final_rays_per_keyframe / 1e6
              << "M)\n";
  }
  train_s_ += now() - t0;
  // The final flush is paced (the sensors are quiet, but receivers' socket buffers are not
  // bigger for it) and goes on between the steps of the outputs, which only read the field:
  // the end of a run takes the longer of the two, not their sum.
  const double flush_t0 = now();
  const double flushed_mb = field_pacer_->megabytes();
  flushing_ = mapper_.field().initialized();
  flushField(false);
  publishPoses(true);
  if (!out_dir_.empty()) {
    try {
      const MapperOutputSummary s = writeMapperOutputs(
          mapper_, out_dir_,
          {params_.checkpoint_images, params_.render_stride, params_.mesh_iso,
           params_.mesh_max_faces, threadsOrEveryCore(params_.final_render_threads),
           [&] {
             flushField(false);
             heartbeat();
           }},
          nonKeyframeViews(frame_poses_, mapper_.keyframes(), kFrameRenderStride));
      std::cerr << "radslam-mapper: wrote " << s.checkpoint << " (" << s.checkpoint_s << " s), "
                << s.mesh << " (" << s.mesh_faces << " faces, lattice step " << s.mesh_stride
                << ", " << s.mesh_s << " s), " << s.renders << " keyframe and " << s.frame_renders
                << " frame renders and " << s.cloud << " (" << s.cloud_points << " points; "
                << s.renders_s << " s), " << s.trajectory << "; keyframe renders "
                << s.keyframe_psnr_db << " dB PSNR against the keyframe images\n";
      reporter_.setValue("keyframe_psnr_db", s.keyframe_psnr_db);
    } catch (const std::exception& e) {
      std::cerr << "radslam-mapper: error: " << e.what() << "\n";
      reporter_.setError(e.what());
      reporter_.setState(ProcessState::kError);
      publishStatus();
      throw;
    }
  }
  flushField(true);
  if (mapper_.field().initialized()) {
    std::cerr << "radslam-mapper: final field version " << mapper_.field().version() << ", "
              << mapper_.field().totalBlocks() << " blocks, " << mapper_.keyframes().size()
              << " keyframes; final flush " << field_pacer_->megabytes() - flushed_mb << " MB in "
              << now() - flush_t0 << " s\n";
  }
  reporter_.setState(ProcessState::kDone);
  publishStatus();
  awaitReplicas();
}

void MapperNode::awaitReplicas() {
  constexpr double kRecentS = 3.0;  // a renderer silent for this much listening time is gone
  if (!mapper_.field().initialized()) return;
  const double t0 = now();
  const int64_t flushed_version = mapper_.field().version();
  const auto lagging = [&] {
    // (A snapshot may leave blocks to send after it: the version to reach is the current one.)
    const int64_t final_version = mapper_.field().version();
    int n = 0;
    for (const auto& [id, r] : replicas_)
      n += !r.done && listen_s_ - r.heard_at < kRecentS &&
           (r.field_version != final_version || r.waiting_snapshot);
    return n;
  };
  while (lagging() > 0 && now() - t0 < params_.final_sync_s) {
    const double t = now();
    const int handled = bus_->handle(50);
    listen_s_ += now() - t;
    if (handled < 0) break;
    if (snapshot_requested_ || snapshot_ || catch_up_since_ >= 0) {
      flushing_ = true;
      flushField(true);
    }
    heartbeat();
  }
  if (const int n = lagging(); n > 0) {
    std::cerr << "radslam-mapper: warning: " << n << " renderer(s) still not at field version "
              << mapper_.field().version() << " after " << params_.final_sync_s << " s\n";
  } else if (now() - t0 > 1.0) {
    std::cerr << "radslam-mapper: the renderers heard from are at the final field version after "
              << now() - t0 << " s\n";
  }
  // Catch-ups, and a snapshot's blocks committed after their chunk went out, take new versions.
  if (mapper_.field().version() != flushed_version) {
    std::cerr << "radslam-mapper: final field version " << mapper_.field().version() << ", "
              << mapper_.field().totalBlocks() << " blocks, after the renderers were served\n";
  }
}

int MapperNode::run() {
  requestKeyframes();
  while (!stop_ && !radslam::stopRequested()) {
    if (!spinOnce(100)) break;  // end of a file:// log or a bus error
  }
  finish();
  return 0;
}

}  // namespace radslam
