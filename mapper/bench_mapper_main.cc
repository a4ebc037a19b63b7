// radslam-bench-mapper: mapping fidelity and throughput of the mapper core on a dataset.
// Keyframes are either oracle (ground-truth poses, sensor depth with a sensor-noise variance)
// or a monocular tracker run (its keyframe poses and depths, brought into the ground-truth frame
// by a similarity). The field trains for a fixed budget of rays on one thread (`--set
// threads=N` for more), then is evaluated: PSNR on the keyframes (at the mapper's poses and
// exposures) and on held-out frames (every 10th non-keyframe, at ground-truth poses, with the
// exposure interpolated in time between the keyframes around them), depth L1 against the
// sensor depth, training rays per CPU second (wall second on several threads), the training
// time to come within 0.5 dB of the final PSNR, peak memory. Prints a report and one
// tab-separated RESULT line (scripts/bench mapper builds its table from them).
//
// A rolling-shutter camera (TUM's Kinect) is modelled as the tracker does (docs/tracker.md,
// "Rolling shutter"): keyframe images are resampled as seen at their middle row, with the
// ground truth's angular velocity, and every evaluation renders each pixel's ray turned to
// the time its row was exposed, against the input image as it is.
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <set>

#include <opencv2/imgproc.hpp>

#include "common/camera.h"
#include "common/cli.h"
#include "common/dataset.h"
#include "common/process_stats.h"
#include "mapper/mapper.h"
#include "mapper/mapper_outputs.h"
#include "mapper/mapper_params.h"
#include "mapper/mapping_eval.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-bench-mapper --dataset KIND:PATH [options]
  --keyframes K      oracle (ground-truth poses + sensor depth) or tracker:DIR (a run folder of
                     radslam-bench-tracker --out DIR); default oracle
  --depth-loss M     weighted | raw | none (default weighted)
  --rays N           training budget in rays (default 1000000)
  --width W          keyframe width (default 256; the height keeps the aspect ratio; tracker
                     keyframes are resized to it)
  --kf-stride S      oracle keyframes: every S-th frame (default 5)
  --frames N         use the first N frames (default all)
  --checkpoints C    PSNR evaluations during training, for the time to the final PSNR (default 10)
  --name NAME        row name in the RESULT line (default the dataset kind)
  --set KEY=VALUE    mapper overrides as radslam-mapper's (comma-separated)
  --edge-px P        oracle keyframes: depth within P pixels of the source image (scaled to
                     the keyframe width) of a pixel more than 10 % deeper is not used (Kinect
                     foreground edges, docs/mapper.md); default 8, 0 keeps it
  --fit-camera-frame tracker keyframes: fit a constant rotation between the ground truth's
                     camera frame and the images' into the alignment too (a hand-eye
                     calibration error; the tracker's benchmark reports it) and render the
                     held-out frames in the images' frame
  --sync-colour S    s added to the colour images' stamps where ground truth is looked up
  --sync-depth S     the same for the depth images' stamps (default 0 both; TUM fr1/rpy measured
                     -0.005 and -0.020, docs/mapper.md)
)";

// Training time: the CPU time of this thread when it trains alone (other load on the machine
// does not count), the wall time when training runs on several threads.
double trainingSeconds(int threads) {
  timespec ts;
  clock_gettime(threads > 1 ? CLOCK_MONOTONIC : CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

// A dataset frame undistorted to the keyframe camera, with its ground-truth pose.
struct EvalFrame {
  size_t index = 0;
  int64_t utime = 0;
  SE3 T_world_cam;  // ground truth
  cv::Mat color;    // BGR, as the camera saw it
  cv::Mat depth;    // m, 0 = none
  // Rolling shutter: the ground truth's angular velocity, and the images resampled as seen at
  // the middle row (what the mapper trains on; color and depth for a global shutter).
  RollingShutterView rolling_shutter;
  cv::Mat training_color, training_depth;
};

// Where each sensor's images meet the ground-truth clock: s added to an image's own stamp to
// look its pose up (the TUM tools' --offset). Kinect colour and depth images are each stamped
// with a delay of their own; docs/mapper.md has how they were measured.
struct SensorSync {
  double colour_s = 0;
  double depth_s = 0;
};

class FrameSource {
 public:
  FrameSource(const DatasetReader& dataset, int width, int height, SensorSync sync)
      : dataset_(dataset), sync_(sync) {
    std::string error;
    const std::optional<Frame> first = dataset.frame(0, &error);
    if (!first) throw std::runtime_error(error);
    undistorter_ = std::make_unique<Undistorter>(first->camera, width, height);
    exposure_s_ = undistorter_->exposureTimes();
  }
  const CameraModel& camera() const { return undistorter_->target(); }
  std::optional<EvalFrame> load(size_t i) const {
    const double t_colour = dataset_.timestamp(i);
    const std::optional<SE3> gt = poseAt(dataset_.groundTruth(), t_colour + sync_.colour_s);
    if (!gt) return std::nullopt;
    std::string error;
    const std::optional<Frame> f = dataset_.frame(i, &error);
    if (!f) {
      std::cerr << "radslam-bench-mapper: warning: " << error << "\n";
      return std::nullopt;
    }
    EvalFrame e;
    e.index = i;
    e.utime = f->header.utime;
    e.T_world_cam = *gt;
    cv::Mat color = f->color;
    if (color.type() == CV_8UC1) cv::cvtColor(color, color, cv::COLOR_GRAY2BGR);
    e.color = undistorter_->apply(color);
    cv::Mat rolling_shutter_map;
    if (!exposure_s_.empty()) {
      // Angular velocity by central differences of the ground truth over 30 ms.
      constexpr double kHalfSpanS = 0.015;
      const std::optional<SE3> a =
          poseAt(dataset_.groundTruth(), t_colour + sync_.colour_s - kHalfSpanS);
      const std::optional<SE3> b =
          poseAt(dataset_.groundTruth(), t_colour + sync_.colour_s + kHalfSpanS);
      if (a && b) {
        e.rolling_shutter.omega_cam = (a->so3().inverse() * b->so3()).log() / (2 * kHalfSpanS);
        e.rolling_shutter.exposure_s = exposure_s_;
        rolling_shutter_map = undistorter_->rollingShutterMap(e.rolling_shutter.omega_cam, 4);
      }
    }
    e.training_color = undistorter_->apply(color, cv::INTER_LINEAR, rolling_shutter_map);
    if (!f->depth.empty()) {
      // Depth seen from where the camera was at another time: turned to the colour image's pose
      // by the ground truth's rotation in between.
      const double t_depth = t_colour + f->depth_time_offset_s + sync_.depth_s;
      const std::optional<SE3> at_depth = poseAt(dataset_.groundTruth(), t_depth);
      auto toColourTime = [&](const cv::Mat& depth) {
        if (t_depth == t_colour + sync_.colour_s || !at_depth) return depth;
        return rotateDepth(depth, camera(), (gt->so3().inverse() * at_depth->so3()).matrix());
      };
      e.depth = toColourTime(undistorter_->apply(f->depth, cv::INTER_NEAREST));
      // Training: as seen by the colour image's middle row, through the same resampling.
      e.training_depth =
          rolling_shutter_map.empty()
              ? e.depth
              : toColourTime(undistorter_->apply(f->depth, cv::INTER_NEAREST, rolling_shutter_map));
    }
    return e;
  }

 private:
  const DatasetReader& dataset_;
  SensorSync sync_;
  std::unique_ptr<Undistorter> undistorter_;
  cv::Mat exposure_s_;  // rolling shutter: each pixel's exposure after the middle row, s
};

// One line per reference-depth bin: share of the pixels, L1 and mean signed error.
void printDepthBins(const char* what, const DepthError& e) {
  std::printf("  %s depth error by sensor depth:", what);
  for (int b = 0; b < DepthError::kBins; ++b) {
    const double n = double(std::max<int64_t>(1, e.bin_pixels[b]));
    std::printf(" %d%s m %.0f%% L1 %.3f bias %+.3f;", b,
                b + 1 < DepthError::kBins ? ("-" + std::to_string(b + 1)).c_str() : "+",
                100.0 * e.bin_pixels[b] / std::max<int64_t>(1, e.pixels), e.bin_abs[b] / n,
                e.bin_signed[b] / n);
  }
  std::printf("\n");
}

// Is an input depth's variance informative? Its errors against the sensor (as seen at the middle
// row, like the input) by thirds of the relative sigma, and the share within 2 sigma (the
// sensor's own noise not counted).
void printVarianceRanking(const std::vector<EvalFrame>& frames, const std::vector<cv::Mat>& depth,
                          const std::vector<cv::Mat>& var) {
  std::vector<std::pair<float, float>> rel_sigma_error;
  int64_t inside = 0;
  for (size_t k = 0; k < frames.size(); ++k) {
    const cv::Mat& ref = frames[k].training_depth;
    if (ref.empty()) continue;
    for (int y = 0; y < ref.rows; ++y)
      for (int x = 0; x < ref.cols; ++x) {
        const float r = ref.at<float>(y, x), d = depth[k].at<float>(y, x);
        const float v = var[k].at<float>(y, x);
        if (!(r > 0) || !(d > 0) || !std::isfinite(v)) continue;
        const float e = std::abs(d - r), sigma = std::sqrt(v);
        rel_sigma_error.emplace_back(sigma / d, e);
        inside += e <= 2 * sigma;
      }
  }
  std::sort(rel_sigma_error.begin(), rel_sigma_error.end());
  const size_t n3 = rel_sigma_error.size() / 3;
  std::printf("  input depth within 2 sigma: %.1f%%; L1 by thirds of sigma/depth:",
              100.0 * inside / std::max<size_t>(1, rel_sigma_error.size()));
  for (int t = 0; t < 3 && n3 > 0; ++t) {
    double sum = 0;
    for (size_t i = t * n3; i < (t + 1) * n3; ++i) sum += rel_sigma_error[i].second;
    std::printf(" %.3f (sigma/depth <= %.3f)", sum / n3, rel_sigma_error[(t + 1) * n3 - 1].first);
  }
  std::printf("\n");
}

// Pixels with a positive finite depth, over all images.
double validDepthPixels(const std::vector<cv::Mat>& depths) {
  double n = 0;
  for (const cv::Mat& d : depths) n += cv::countNonZero(d > 0);
  return n;
}

// Renders under exposures[i] when given (the keyframes' or ones interpolated between them).
double meanPsnr(const Mapper& mapper, const std::vector<EvalFrame>& frames,
                const std::vector<SE3>& poses, const CameraModel& camera, DepthError* depth,
                const std::vector<Vec6>* exposures = nullptr) {
  double sum = 0;
  for (size_t i = 0; i < frames.size(); ++i) {
    RenderImages r = mapper.render(poses[i], camera, 0, frames[i].rolling_shutter);
    if (exposures) applyExposure((*exposures)[i], &r.color);
    sum += psnr(frames[i].color, r.color);
    if (depth && !frames[i].depth.empty()) *depth += depthError(r.depth, frames[i].depth);
  }
  return frames.empty() ? 0 : sum / frames.size();
}

int run(int argc, char** argv) {
  CommandLine cl(argc, argv, kUsage);
  if (cl.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string spec = cl.get("dataset", "");
  const std::string source = cl.get("keyframes", "oracle");
  const std::string depth_loss = cl.get("depth-loss", "weighted");
  const double budget = cl.getDouble("rays", 1e6);
  const int width = cl.getInt("width", 256);
  const int kf_stride = cl.getInt("kf-stride", 5);
  const int max_frames = cl.getInt("frames", 0);
  const int checkpoints = cl.getInt("checkpoints", 10);
  std::string name = cl.get("name", spec.substr(0, spec.find(':')));
  const std::string set = cl.get("set", "");
  const int edge_px = cl.getInt("edge-px", 8);
  const SensorSync sync{cl.getDouble("sync-colour", 0), cl.getDouble("sync-depth", 0)};
  const bool fit_camera_frame = cl.getBool("fit-camera-frame", false);
  cl.finish();
  if (spec.empty()) throw std::runtime_error("--dataset KIND:PATH is required");
  if (source != "oracle" && source.rfind("tracker:", 0) != 0)
    throw std::runtime_error("--keyframes must be oracle or tracker:DIR, got '" + source + "'");
  if (!(budget > 0) || width < 16 || kf_stride < 1 || checkpoints < 1)
    throw std::runtime_error("--rays, --width, --kf-stride and --checkpoints must be positive");
  if (edge_px < 0) throw std::runtime_error("--edge-px must be 0 or more");
  if (fit_camera_frame && source == "oracle")
    throw std::runtime_error("--fit-camera-frame needs tracker keyframes");

  MapperParams params;
  {
    std::vector<std::string> overrides;
    for (size_t start = 0; start < set.size();) {
      const size_t comma = set.find(',', start);
      const std::string item =
          set.substr(start, comma == std::string::npos ? comma : comma - start);
      if (!item.empty()) overrides.push_back(item);
      if (comma == std::string::npos) break;
      start = comma + 1;
    }
    std::string dump, where;
    params = loadMapperParams("", overrides, &dump, &where).core;
  }
  params.trainer.depth_loss = parseDepthLoss(depth_loss);

  const std::unique_ptr<DatasetReader> dataset = openDataset(spec);
  if (dataset->groundTruth().empty())
    throw std::runtime_error(dataset->name() + " has no ground truth: nothing to evaluate");
  const size_t n = max_frames > 0 ? std::min<size_t>(max_frames, dataset->size()) : dataset->size();

  // Keyframes: frame indices, poses and depths.
  std::vector<size_t> kf_index;
  std::vector<SE3> kf_pose;
  std::vector<cv::Mat> kf_depth, kf_var;
  std::vector<cv::Mat> kf_color;  // tracker keyframes: their own images (empty: the dataset's)
  int kf_width = width;
  std::unique_ptr<FrameSource> frames;
  double align_scale = 1;
  SO3 camera_offset;  // --fit-camera-frame: the ground truth's camera frame from the images'
  if (source == "oracle") {
    std::string error;
    const std::optional<Frame> first = dataset->frame(0, &error);
    if (!first) throw std::runtime_error(error);
    const int height =
        static_cast<int>(std::lround(double(width) * first->camera.height / first->camera.width));
    frames = std::make_unique<FrameSource>(*dataset, width, height, sync);
    const int edge_kf_px =
        static_cast<int>(std::lround(double(edge_px) * width / first->camera.width));
    for (size_t i = 0; i < n; i += kf_stride) {
      const std::optional<EvalFrame> f = frames->load(i);
      if (!f || f->depth.empty()) continue;
      kf_index.push_back(i);
      kf_pose.push_back(f->T_world_cam);
      kf_depth.push_back(f->training_depth);
      kf_var.push_back(sensorDepthVariance(f->training_depth, edge_kf_px));
    }
  } else {
    TrackerRun tracked = readTrackerRun(source.substr(8));
    // The tracker's keyframes, resized to --width (the undistorted camera of the dataset at
    // that size is the tracker's camera scaled).
    const cv::Size full = tracked.keyframes.front().depth.size();
    const cv::Size size(std::min(width, full.width),
                        static_cast<int>(std::lround(double(std::min(width, full.width)) *
                                                     full.height / full.width)));
    for (TrackerKeyframe& kf : tracked.keyframes) {
      if (kf.depth.size() != full)
        throw std::runtime_error(source + ": keyframe depth maps differ in size");
      cv::resize(kf.depth, kf.depth, size, 0, 0, cv::INTER_NEAREST);
      cv::resize(kf.sigma, kf.sigma, size, 0, 0, cv::INTER_NEAREST);
      if (!kf.color.empty()) cv::resize(kf.color, kf.color, size, 0, 0, cv::INTER_AREA);
    }
    kf_width = size.width;
    frames = std::make_unique<FrameSource>(*dataset, size.width, size.height, sync);
    std::vector<double> times(n);
    for (size_t i = 0; i < n; ++i) times[i] = dataset->timestamp(i);
    // Scale: median ratio of sensor to tracker depth when the dataset has depth (fr1/rpy barely
    // translates, so positions alone fix the scale poorly), else Umeyama on the positions.
    std::vector<float> ratios;
    std::vector<size_t> matched(tracked.keyframes.size(), SIZE_MAX);
    for (size_t k = 0; k < tracked.keyframes.size(); ++k) {
      const TrackerKeyframe& kf = tracked.keyframes[k];
      const auto pairs = associateTimes({kf.t}, times, 0.005);
      if (pairs.empty()) continue;
      matched[k] = pairs[0].second;
      if (!dataset->hasDepth()) continue;
      const std::optional<EvalFrame> f = frames->load(matched[k]);
      if (!f || f->depth.empty()) continue;
      for (int y = 0; y < size.height; y += 4)
        for (int x = 0; x < size.width; x += 4) {
          const float a = f->training_depth.at<float>(y, x), b = kf.depth.at<float>(y, x);
          if (a > 0 && b > 0 && std::isfinite(b)) ratios.push_back(a / b);
        }
    }
    double scale = 0;
    if (!ratios.empty()) {
      std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
      scale = ratios[ratios.size() / 2];
    }
    Trajectory on_ground_truth_clock = tracked.trajectory;
    for (StampedPose& pose : on_ground_truth_clock) pose.t += sync.colour_s;
    const Sim3 S = alignToGroundTruth(on_ground_truth_clock, dataset->groundTruth(), scale, 0.05,
                                      fit_camera_frame ? &camera_offset : nullptr);
    align_scale = S.scale();
    for (size_t k = 0; k < tracked.keyframes.size(); ++k) {
      if (matched[k] == SIZE_MAX) continue;
      const TrackerKeyframe& kf = tracked.keyframes[k];
      kf_index.push_back(matched[k]);
      kf_pose.push_back(S.transformPose(kf.T_world_cam));
      cv::Mat depth = kf.depth * S.scale(), var;
      cv::Mat sigma = kf.sigma * S.scale();
      cv::multiply(sigma, sigma, var);
      var.setTo(INFINITY, ~(sigma > 0));  // unknown sigma: no depth weight
      kf_depth.push_back(depth);
      kf_var.push_back(var);
      kf_color.push_back(kf.color);
    }
  }
  if (kf_index.size() < 2) throw std::runtime_error("fewer than 2 keyframes with ground truth");

  Mapper mapper(params);
  std::vector<EvalFrame> kf_frames;
  std::vector<int32_t> kf_ids;          // of kf_frames
  std::vector<cv::Mat> kf_input_depth;  // of kf_frames: the depth the mapper was given
  std::vector<cv::Mat> kf_input_var;    // and its variance
  for (size_t k = 0; k < kf_index.size(); ++k) {
    std::optional<EvalFrame> f = frames->load(kf_index[k]);
    if (!f) continue;
    Keyframe kf;
    kf.header.utime = f->utime;
    kf.keyframe_id = static_cast<int32_t>(k);
    kf.frame_index = static_cast<int64_t>(kf_index[k]);
    kf.T_world_cam = kf_pose[k];
    kf.camera = frames->camera();
    // The tracker's own image when its run has one (resampled with its own angular velocity).
    kf.color = k < kf_color.size() && !kf_color[k].empty() ? kf_color[k] : f->training_color;
    kf.depth = kf_depth[k];
    kf.depth_var = kf_var[k];
    mapper.addKeyframe(kf);
    kf_ids.push_back(kf.keyframe_id);
    kf_input_depth.push_back(kf.depth);
    kf_input_var.push_back(kf.depth_var);
    // Sensor depth as the reference for the keyframes' depth error.
    kf_frames.push_back(std::move(*f));
  }
  // Held out: every 10th frame that is not a keyframe.
  const std::set<size_t> is_kf(kf_index.begin(), kf_index.end());
  std::vector<EvalFrame> held;
  int non_kf = 0;
  for (size_t i = 0; i < n; ++i) {
    if (is_kf.count(i)) continue;
    if (non_kf++ % 10 != 5) continue;  // the middle of each run of 10
    std::optional<EvalFrame> f = frames->load(i);
    if (f) held.push_back(std::move(*f));
  }
  std::vector<SE3> held_poses;
  for (const EvalFrame& f : held)
    held_poses.push_back(f.T_world_cam * SE3(camera_offset.inverse(), Vec3::Zero()));
  const CameraModel& camera = frames->camera();
  const Field& field = mapper.field();
  if (!field.initialized()) throw std::runtime_error("no keyframe depth: the field is empty");
  std::printf("%s: %s keyframes (%zu, %dx%d), %zu held-out frames, depth loss %s\n",
              dataset->name().c_str(), source == "oracle" ? "oracle" : "tracker", kf_frames.size(),
              camera.width, camera.height, held.size(), depth_loss.c_str());
  if (source != "oracle") std::printf("  tracker scale to ground truth: %.4f\n", align_scale);
  if (fit_camera_frame)
    std::printf("  camera frame fitted: the ground truth's is %.2f deg from the images'\n",
                camera_offset.log().norm() * 180 / M_PI);
  std::printf("  keyframe pixels with depth: %.1f%%\n",
              100.0 * validDepthPixels(kf_depth) /
                  (double(camera.width) * camera.height * kf_depth.size()));
  std::printf("  fine voxel %.4f m, %zu blocks (%d fine)\n", field.geometry().fineVoxelSize(),
              field.totalBlocks(), field.numBlocks(field.numLevels() - 1));

  // Progress set: 4 keyframes spread over the sequence.
  std::vector<EvalFrame> progress;
  std::vector<int> progress_kf;
  for (int j = 0; j < 4; ++j) {
    const int k = static_cast<int>((kf_frames.size() - 1) * j / 3);
    progress.push_back(kf_frames[k]);
    progress_kf.push_back(k);
  }
  auto progressPsnr = [&] {
    std::vector<SE3> poses;
    std::vector<Vec6> exposures;
    for (int k : progress_kf) {
      const KeyframeEntry& e = mapper.keyframes().entry(mapper.keyframes().find(kf_ids[k]));
      poses.push_back(e.T_world_cam);
      exposures.push_back(e.exposure);
    }
    return meanPsnr(mapper, progress, poses, camera, nullptr, &exposures);
  };

  int64_t rays = 0, samples = 0;
  const int threads = params.trainer.threads;
  const char* clock_name = threads > 1 ? "wall s" : "CPU s";
  double train_s = 0;
  std::vector<std::pair<double, double>> curve = {{0.0, progressPsnr()}};  // (s, dB)
  TrainStats stats;
  for (int c = 1; c <= checkpoints; ++c) {
    const int64_t target = static_cast<int64_t>(budget * c / checkpoints);
    const double t0 = trainingSeconds(threads);
    while (rays < target) {
      stats = mapper.train(1);
      if (stats.rays == 0) throw std::runtime_error("training drew no rays");
      rays += stats.rays;
      samples += stats.samples;
    }
    train_s += trainingSeconds(threads) - t0;
    curve.emplace_back(train_s, progressPsnr());
  }
  const double final_progress = curve.back().second;
  double t_final = train_s;
  for (const auto& [t, p] : curve)
    if (p >= final_progress - 0.5) {
      t_final = t;
      break;
    }

  std::vector<SE3> kf_poses;
  std::vector<Vec6> kf_exposures;
  std::vector<const KeyframeEntry*> kf_entries;
  for (size_t k = 0; k < kf_frames.size(); ++k) {
    const KeyframeEntry& e = mapper.keyframes().entry(mapper.keyframes().find(kf_ids[k]));
    kf_entries.push_back(&e);
    kf_poses.push_back(e.T_world_cam);
    kf_exposures.push_back(e.exposure);
  }
  // Held-out frames: the exposure interpolated in time between the keyframes around them (the
  // frame's own image is not used); kf_frames are in time order. Also each pose as the mapper
  // renders tracked frames (nonKeyframeViews): moved with the refinement of the keyframe
  // nearest in time.
  std::vector<Vec6> held_exposures;
  std::vector<SE3> held_poses_following;
  for (size_t i = 0; i < held.size(); ++i) {
    const EvalFrame& f = held[i];
    size_t b = 0;
    while (b + 1 < kf_frames.size() && kf_frames[b].utime < f.utime) ++b;
    const size_t a = b > 0 && kf_frames[b].utime > f.utime ? b - 1 : b;
    held_exposures.push_back(interpolateExposure(double(f.utime), double(kf_frames[a].utime),
                                                 kf_exposures[a], double(kf_frames[b].utime),
                                                 kf_exposures[b]));
    const size_t nearest =
        std::abs(kf_frames[a].utime - f.utime) <= std::abs(kf_frames[b].utime - f.utime) ? a : b;
    held_poses_following.push_back(followRefinement(*kf_entries[nearest], held_poses[i]));
  }
  DepthError kf_depth_err, held_depth_err;
  const double psnr_kf =
      meanPsnr(mapper, kf_frames, kf_poses, camera, &kf_depth_err, &kf_exposures);
  const double psnr_held =
      meanPsnr(mapper, held, held_poses, camera, &held_depth_err, &held_exposures);
  const double psnr_held_field = meanPsnr(mapper, held, held_poses, camera, nullptr);
  const double psnr_held_following =
      meanPsnr(mapper, held, held_poses_following, camera, nullptr, &held_exposures);
  const double rate = rays / std::max(1e-9, train_s);
  const double rss = peakRssMb();

  std::printf("  training: %lld rays in %.1f %s on %d thread(s): %.0f rays/s, %.2f M samples/s\n",
              static_cast<long long>(rays), train_s, clock_name, threads, rate,
              samples / train_s / 1e6);
  std::printf("  last loss %.4f (rgb %.4f, depth %.4f)\n", stats.loss, stats.loss_rgb,
              stats.loss_depth);
  std::printf("  PSNR of 4 keyframes during training:");
  for (const auto& [t, p] : curve) std::printf(" %.1fs:%.2f", t, p);
  std::printf("\n  within 0.5 dB of the final after %.1f %s\n", t_final, clock_name);
  std::printf("  keyframes: PSNR %.2f dB, depth L1 %.4f m (coverage %.1f%%)\n", psnr_kf,
              kf_depth_err.l1(), 100 * kf_depth_err.coverage());
  std::printf("  held out:  PSNR %.2f dB, depth L1 %.4f m (coverage %.1f%%)\n", psnr_held,
              held_depth_err.l1(), 100 * held_depth_err.coverage());
  printDepthBins("keyframe", kf_depth_err);
  if (source != "oracle") {
    // The keyframe depth the mapper was given, against the sensor's as seen at the middle row.
    DepthError input_err;
    for (size_t k = 0; k < kf_frames.size(); ++k)
      if (!kf_frames[k].training_depth.empty())
        input_err += depthError(kf_input_depth[k], kf_frames[k].training_depth);
    std::printf("  input keyframe depth: L1 %.4f m (coverage %.1f%%)\n", input_err.l1(),
                100 * input_err.coverage());
    printDepthBins("input", input_err);
    printVarianceRanking(kf_frames, kf_input_depth, kf_input_var);
  }
  std::printf("  held out at the field's own exposure (the gauge keyframe's): PSNR %.2f dB\n",
              psnr_held_field);
  std::printf(
      "  held out moved with the refinement of the nearest keyframe (as the mapper renders "
      "frames): PSNR %.2f dB\n",
      psnr_held_following);
  std::printf("  peak RSS %.0f MB\n", rss);
  // name, source, mode, keyframes, held, psnr_kf, psnr_held, l1_kf, l1_held, coverage_held,
  // rays/s, t_final, rss, width
  std::printf("RESULT\t%s\t%s\t%s\t%zu\t%zu\t%.2f\t%.2f\t%.4f\t%.4f\t%.1f\t%.0f\t%.1f\t%.0f\t%d\n",
              name.c_str(), source == "oracle" ? "oracle" : "tracker", depth_loss.c_str(),
              kf_frames.size(), held.size(), psnr_kf, psnr_held, kf_depth_err.l1(),
              held_depth_err.l1(), 100 * held_depth_err.coverage(), rate, t_final, rss, kf_width);
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-bench-mapper", radslam::run, argc, argv);
}
