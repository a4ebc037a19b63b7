#include "recorder/player.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iostream>
#include <stdexcept>
#include <thread>

#include <opencv2/videoio.hpp>

namespace radslam {
namespace {

double wallSeconds() {
  using Clock = std::chrono::steady_clock;
  return std::chrono::duration<double>(Clock::now().time_since_epoch()).count();
}

WireCompression parseCompression(const std::string& name) {
  if (name == "raw") return WireCompression::kRaw;
  if (name == "png") return WireCompression::kPng;
  if (name == "jpeg" || name == "jpg") return WireCompression::kJpeg;
  throw std::invalid_argument("color_compression must be raw, png or jpeg, not '" + name + "'");
}

// Ground truth is published at its own stamps: the sample nearest to each frame
// (within 20 ms, as the TUM benchmark associates), so evaluation stays exact.
constexpr double kMaxGroundTruthGapS = 0.02;

// The sample of a time-sorted, non-empty trajectory nearest to t.
const StampedPose* nearestSample(const Trajectory& trajectory, double t) {
  auto next = std::lower_bound(trajectory.begin(), trajectory.end(), t,
                               [](const StampedPose& p, double time) { return p.t < time; });
  if (next == trajectory.end()) return &trajectory.back();
  if (next != trajectory.begin() && t - std::prev(next)->t <= next->t - t) return &*std::prev(next);
  return &*next;
}

}  // namespace

Player::Player(PlayerParams params, PlayerSinks sinks)
    : params_(std::move(params)), sinks_(std::move(sinks)) {
  parseCompression(params_.color_compression);
  if (params_.stride < 1) throw std::invalid_argument("stride must be >= 1");
  if (params_.start < 0) throw std::invalid_argument("start must be >= 0");
  if (params_.rate < 0) throw std::invalid_argument("rate must be >= 0");
  if (params_.loops < 1) throw std::invalid_argument("loops must be >= 1");
  if (params_.lockstep && !sinks_.wait_for_ack)
    throw std::invalid_argument("lock-step playback needs an acknowledgement source");
}

void Player::waitUntil(double sensor_t, double first_sensor_t, double wall_start_s) const {
  if (params_.rate <= 0) return;
  const double due = wall_start_s + (sensor_t - first_sensor_t) / params_.rate;
  const double wait = due - wallSeconds();
  if (wait > 0) std::this_thread::sleep_for(std::chrono::duration<double>(wait));
}

void Player::applyWireHints(Frame* frame) const {
  frame->color_compression = parseCompression(params_.color_compression);
  if (params_.depth_wire_scale >= 0) frame->depth_wire_scale = params_.depth_wire_scale;
}

void Player::acknowledge(int64_t frame_index, PlayerStats* stats) {
  if (!params_.lockstep) return;
  if (sinks_.wait_for_ack(frame_index, params_.ack_timeout_s)) return;
  ++stats->acks_missed;
  std::cerr << "radslam-play: warning: no acknowledgement of frame " << frame_index << " from '"
            << params_.ack_process << "' within " << params_.ack_timeout_s
            << " s; continuing without lock-step\n";
  params_.lockstep = false;
}

PlayerStats Player::play(const DatasetReader& dataset) {
  PlayerStats stats;
  const int64_t size = static_cast<int64_t>(dataset.size());
  const int64_t end = params_.end < 0 ? size : std::min<int64_t>(params_.end, size);
  if (params_.start >= end) {
    throw std::invalid_argument(dataset.name() + ": start frame " + std::to_string(params_.start) +
                                " is past the end (" + std::to_string(size) + " frames)");
  }
  const int64_t per_loop = (end - params_.start + params_.stride - 1) / params_.stride;
  const int64_t planned = per_loop * params_.loops;
  const Trajectory& ground_truth = dataset.groundTruth();
  std::vector<ObjectPoseSample> object_truth;
  if (params_.ground_truth) object_truth = dataset.objectGroundTruth();

  const double wall_start = wallSeconds();
  const double first_t = dataset.timestamp(static_cast<size_t>(params_.start));
  const int64_t last = params_.start + (per_loop - 1) * params_.stride;
  // One loop's length in sensor time: first to last frame, plus a frame interval.
  const double interval =
      per_loop > 1 ? (dataset.timestamp(static_cast<size_t>(last)) - first_t) / double(per_loop - 1)
                   : 0.0;
  const double loop_s = dataset.timestamp(static_cast<size_t>(last)) - first_t + interval;
  const double last_t = dataset.timestamp(static_cast<size_t>(last));
  // Frame k of the planned ones: loop k / per_loop, step k % per_loop within it. Odd loops play
  // the range backwards: the camera turns round instead of jumping back to the start, which no
  // tracker follows without relocalising.
  for (int64_t k = 0; k < planned; ++k) {
    if (sinks_.should_stop && sinks_.should_stop()) break;
    const int64_t loop = k / per_loop, step = k % per_loop;
    const bool backwards = loop % 2 == 1;
    const int64_t i = params_.start + (backwards ? per_loop - 1 - step : step) * params_.stride;
    // Increasing; the dataset's own index in the first loop.
    const int64_t index = params_.start + step * params_.stride + loop * (end - params_.start);
    const double t = dataset.timestamp(static_cast<size_t>(i));
    // Sensor time on the wire: the loop's start plus the time into the loop.
    const double shift_s = loop * loop_s + (backwards ? last_t - t - (t - first_t) : 0.0);
    std::string error;
    std::optional<Frame> frame = dataset.frame(static_cast<size_t>(i), &error);
    waitUntil(t + shift_s, first_t, wall_start);
    if (!frame) {
      std::cerr << "radslam-play: warning: skipping frame " << i << ": " << error << "\n";
      ++stats.frames_skipped;
      continue;
    }
    frame->frame_index = index;
    frame->header.utime += static_cast<int64_t>(std::llround(shift_s * 1e6));
    applyWireHints(&*frame);
    sinks_.frame(*frame);
    ++stats.frames_sent;

    if (params_.ground_truth && sinks_.ground_truth && !ground_truth.empty()) {
      const StampedPose* sample = nearestSample(ground_truth, t);
      if (std::abs(sample->t - t) <= kMaxGroundTruthGapS) {
        PoseStamped gt;
        const double dt = backwards ? t - sample->t : sample->t - t;  // from the frame, s
        gt.header.utime = static_cast<int64_t>(std::llround((t + shift_s + dt) * 1e6));
        gt.frame_index = index;
        gt.state = TrackingState::kGroundTruth;
        gt.T_world_cam = sample->T_world_cam;
        sinks_.ground_truth(gt);
      }
    }
    if (!object_truth.empty() && sinks_.ground_truth_objects) {
      ObjectList objects;
      objects.header.utime = frame->header.utime;
      objects.frame_index = index;
      auto sample =
          std::lower_bound(object_truth.begin(), object_truth.end(), t - 1e-6,
                           [](const ObjectPoseSample& s, double time) { return s.t < time; });
      for (; sample != object_truth.end() && std::abs(sample->t - t) <= 1e-6; ++sample) {
        TrackedObject object;
        object.object_id = sample->object_id;
        object.class_id = sample->class_id;
        object.T_world_object = sample->T_world_object;
        objects.objects.push_back(object);
      }
      if (!objects.objects.empty()) sinks_.ground_truth_objects(objects);
    }
    if (sinks_.progress) sinks_.progress(stats.frames_sent, planned);
    acknowledge(index, &stats);
    const int64_t rewind = params_.lockstep && sinks_.take_rewind ? sinks_.take_rewind() : -1;
    if (rewind >= 0 && rewind <= index) {
      // The first planned frame at or after `rewind` (indices increase with k).
      const int64_t span = end - params_.start;
      const int64_t from = std::max<int64_t>(rewind - params_.start, 0);
      const int64_t first =
          (from / span) * per_loop + (from % span + params_.stride - 1) / params_.stride;
      std::cerr << "radslam-play: playing again from frame " << rewind << " (asked by '"
                << params_.ack_process << "')\n";
      ++stats.rewinds;
      k = std::min(first, k) - 1;
    }
  }
  stats.wall_s = wallSeconds() - wall_start;
  return stats;
}

PlayerStats Player::playCamera(int device, const CameraModel& camera) {
  PlayerStats stats;
  cv::VideoCapture capture(device);
  if (!capture.isOpened())
    throw std::runtime_error("cannot open camera device " + std::to_string(device));
  const double wall_start = wallSeconds();
  cv::Mat image;
  for (int64_t i = 0; !(sinks_.should_stop && sinks_.should_stop()); ++i) {
    if (params_.end >= 0 && i >= params_.end) break;
    if (!capture.read(image) || image.empty()) break;
    Frame frame;
    frame.header.utime = std::chrono::duration_cast<std::chrono::microseconds>(
                             std::chrono::system_clock::now().time_since_epoch())
                             .count();
    frame.frame_index = i;
    frame.camera = camera;
    if (frame.camera.width != image.cols || frame.camera.height != image.rows) {
      throw std::runtime_error("camera " + std::to_string(device) + " delivers " +
                               std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                               " images but the intrinsics are for " +
                               std::to_string(camera.width) + "x" + std::to_string(camera.height));
    }
    frame.color = image.clone();
    applyWireHints(&frame);
    sinks_.frame(frame);
    ++stats.frames_sent;
    if (sinks_.progress) sinks_.progress(stats.frames_sent, -1);
    acknowledge(i, &stats);
  }
  stats.wall_s = wallSeconds() - wall_start;
  return stats;
}

}  // namespace radslam
