// The renderer process on the bus: FIELD updates into the replica, RENDER_REQUEST answered on
// RENDER, the viewer state fed from POSE, CAMERA, KEYFRAME, GROUND_TRUTH and STATUS, a follow
// view rendered on a worker thread, STATUS at about 2 Hz, and the final renders at the end.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <shared_mutex>
#include <string>
#include <thread>
#include <vector>

#include "common/bus.h"
#include "common/process_stats.h"
#include "renderer/field_replica.h"
#include "renderer/final_outputs.h"
#include "renderer/viewer_state.h"

namespace radslam {

struct RendererParams {
  float render_step_fine = 0.5f;  // march step, fine voxels (as the mapper's)
  float near_voxels = 5;          // as the mapper trainer's near_voxels
  int render_threads = 1;
  // Live viewer views (follow and free camera) trade exactness for speed: a coarser step and
  // an earlier stop. RENDER_REQUEST answers and the final renders use the mapper's march.
  double preview_step_fine = 1.0;  // fine voxels
  double preview_min_transmittance = 0.01;
  // Empty-space skipping and adaptive steps of the preview (MarchParams): sub-blocks whose
  // density bound gives less than this optical thickness per fine voxel are stepped over; steps
  // grow up to preview_max_step_fine fine voxels while one keeps below the sample thickness.
  double preview_skip_thickness = 0.05;
  double preview_max_sample_thickness = 0.05;
  double preview_max_step_fine = 4;
  // Live views render a baked single-level copy of the replica (PreviewField), brought up to
  // date for at most this long before each view (s, 0 = fully): parts still stale show the
  // field as it was.
  double preview_refresh_s = 0.05;
  int follow_width = 320;     // pixels; the follow view's camera is scaled to this width
  double follow_rate_hz = 5;  // follow views per second at most
  double status_rate_hz = 2;
  bool final_renders = true;    // renders/final/ at keyframe poses at the end
  int final_max_renders = 100;  // keyframes evenly spread beyond (a long run has hundreds)
  int final_width = 0;          // pixels, 0 = the keyframes' own size
  // Threads of the final renders and the video, 0 = every core: the run is over, and on one
  // thread a large map takes minutes (a 62k-block street: 2.4 s per keyframe render).
  int final_render_threads = 0;
  bool video = true;      // fly-through video at the end
  int video_width = 320;  // pixels
  double video_fps = 15;
  // Trajectory poses subsampled to at most this many (about 0.5 s each at 320 px on one core:
  // the launcher gives the renderer 120 s to finish).
  int video_max_frames = 60;
};
/// The live-view march: the mapper's (`mp`, from the replica) with the preview settings.
void applyPreview(const RendererParams& params, MarchParams* mp);

/// Loads the "renderer" section (unknown keys are errors); *dump/*source for the banner.
RendererParams loadRendererParams(const std::string& yaml_path,
                                  const std::vector<std::string>& overrides, std::string* dump,
                                  std::string* source);

class RendererNode {
 public:
  /// out_dir: run folder for the final outputs ("" = none).
  RendererNode(Bus* bus, RendererParams params, std::string out_dir);
  ~RendererNode();

  /// Thread-safe render of any view from the replica (RENDER_REQUEST: the mapper's march;
  /// preview: the faster live-view march).
  RenderResult render(const RenderRequest& request, bool preview = false) const;
  const ViewerState& viewer() const { return viewer_; }
  int64_t fieldVersion() const;
  /// True while the replica is not known to equal the mapper's field (a snapshot is asked for).
  bool waitingForSnapshot() const;

  /// Handles the bus until a signal (stopRequested()), CONTROL STOP or the end of a log
  /// (file://); then writes the final outputs. With linger, goes on handling the bus (renders,
  /// viewer) until a signal. Returns 0.
  int run(bool linger = false);
  /// Writes renders/final/ and renders/flythrough.avi under out_dir (no-op without out_dir).
  void writeFinal();
  /// One pass: waits at most timeout_ms for bus messages, then follow rendering and STATUS.
  /// Returns Bus::handle's result.
  int spinOnce(int timeout_ms);

 private:
  void onField(const FieldUpdate& update);
  /// Applies the queued FIELD updates in order; without wait, only when no render holds the
  /// replica (the bus thread must keep draining the socket while renders run).
  void applyPendingUpdates(bool wait);
  void onRenderRequest(const RenderRequest& request);
  void onPose(const PoseStamped& pose);
  void onKeyframe(const Keyframe& keyframe);
  void onStatus(const Status& status);
  void onControl(const Control& control);
  void followLoop();
  void publishStatus(ProcessState state);
  void heartbeat(ProcessState state);  // publishStatus at most status_rate_hz

  Bus* bus_;
  RendererParams params_;
  std::string out_dir_;
  mutable std::shared_mutex field_mutex_;  // replica_: written by the bus thread only
  FieldReplica replica_;
  std::deque<FieldUpdate> pending_updates_;  // received, not yet applied (bus thread only)
  size_t pending_bytes_ = 0;                 // their block payload
  ViewerState viewer_;
  StatusReporter reporter_;
  std::map<int64_t, ViewPose> trajectory_;  // frame index -> tracked pose (bus thread only)
  std::map<int32_t, ViewPose> keyframes_;   // keyframe id -> latest version's pose
  std::map<int32_t, int32_t> keyframe_versions_;
  CameraModel last_camera_;
  int64_t renders_ = 0, bad_requests_ = 0, snapshots_requested_ = 0, chunks_requested_ = 0;
  int64_t last_status_us_ = 0;
  // Lost-update check against the mapper's STATUS (bus thread): a version the mapper reported
  // on its previous STATUS must have arrived by its next one (FIELD goes out before it).
  int64_t field_received_version_ = 0;   // of the last FIELD message received
  int64_t mapper_reported_version_ = 0;  // on the mapper's last STATUS
  std::string missed_update_;            // why an update is missing ("" = none), to report
  bool control_stop_ = false;
  std::atomic<bool> stop_follow_{false};
  std::thread follow_thread_;
};

}  // namespace radslam
