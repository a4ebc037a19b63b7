// Writes the seed corpora of the fuzz targets: valid encoded messages (raw, PNG
// and JPEG images), valid dataset files (dataset_layouts.h), an LCM log holding
// a few messages, viewer queries and a tracker checkpoint. Usage: radslam_fuzz_seeds OUT_DIR
// (one folder per target below OUT_DIR, named as the target without its prefix).
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "common/bus.h"
#include "common/lcm_log.h"
#include "common/types.h"
#include "fuzz/dataset_layouts.h"
#include "fuzz/tracker_sequence.h"
#include "mapper/field_io.h"

namespace {

namespace fs = std::filesystem;
using namespace radslam;

void writeSeed(const fs::path& dir, const std::string& name, const std::string& bytes) {
  fs::create_directories(dir);
  std::ofstream out(dir / name, std::ios::binary | std::ios::trunc);
  out << bytes;
  if (!out) throw std::runtime_error("cannot write " + (dir / name).string());
}

std::string asString(const std::vector<uint8_t>& bytes) {
  return std::string(bytes.begin(), bytes.end());
}

Header header(int64_t utime) {
  Header h;
  h.utime = utime;
  h.seq = 3;
  h.sender = "seed";
  return h;
}

SE3 pose(double a) {
  return SE3(Eigen::Quaterniond(Eigen::AngleAxisd(a, Vec3(0.2, 1.0, 0.1).normalized())),
             Vec3(a, -2 * a, 0.5));
}

CameraModel camera(int w, int h, bool distorted) {
  CameraModel c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = 10;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  if (distorted) {
    c.type = CameraModel::Type::kRadTan;
    c.distortion = {0.01, -0.02, 0.001, 0.0};
  }
  return c;
}

Mat6 covariance() { return Mat6::Identity() * 1e-4; }

cv::Mat image(int type) {
  cv::Mat m(6, 8, type);
  cv::randu(m, 0, type == CV_32FC1 ? 5 : 200);
  return m;
}

template <class T>
void writeMessage(const fs::path& dir, const std::string& name, const T& msg) {
  writeSeed(dir, name, asString(encode(msg)));
}

void writeDecoderSeeds(const fs::path& out) {
  for (WireCompression c : {WireCompression::kRaw, WireCompression::kPng, WireCompression::kJpeg}) {
    Frame f;
    f.header = header(1000);
    f.frame_index = 7;
    f.camera = camera(8, 6, c == WireCompression::kPng);
    f.color = image(CV_8UC3);
    f.right = image(CV_8UC3);
    f.baseline_m = 0.1;
    f.depth = image(CV_32FC1);
    f.color_compression = c;
    f.depth_wire_scale = c == WireCompression::kRaw ? 0.0 : 0.001;
    if (c == WireCompression::kPng) {
      f.instance = image(CV_16UC1);
      f.class_id = image(CV_16UC1);
    }
    writeMessage(out / "decode_frame", "frame_" + std::to_string(static_cast<int>(c)), f);
  }
  Frame grey;
  grey.camera = camera(8, 6, false);
  grey.color = image(CV_8UC1);
  grey.color_compression = WireCompression::kJpeg;
  writeMessage(out / "decode_frame", "frame_grey_jpeg", grey);

  PoseStamped p;
  p.header = header(2000);
  p.T_world_cam = pose(0.3);
  p.covariance = covariance();
  p.is_keyframe = true;
  writeMessage(out / "decode_pose", "pose", p);

  Keyframe k;
  k.header = header(3000);
  k.keyframe_id = 2;
  k.version = 1;
  k.T_world_cam = pose(0.1);
  k.covariance = covariance();
  k.camera = camera(8, 6, false);
  k.color = image(CV_8UC3);
  k.inv_depth = image(CV_32FC1);
  k.inv_depth_var = image(CV_32FC1);
  k.depth = image(CV_32FC1);
  k.depth_var = image(CV_32FC1);
  k.dynamic_mask = image(CV_8UC1);
  writeMessage(out / "decode_keyframe", "keyframe", k);

  ObjectList objects;
  objects.header = header(4000);
  for (int i = 0; i < 2; ++i) {
    TrackedObject o;
    o.object_id = i;
    o.class_id = 2;
    o.class_name = "car";
    o.T_world_object = pose(0.2 * i);
    o.twist << 1, 0, 0, 0, 0, 0.1;
    o.joint_type = static_cast<JointType>(i + 1);
    o.T_world_joint = pose(0.05);
    o.covariance = covariance();
    objects.objects.push_back(o);
  }
  writeMessage(out / "decode_objects", "objects", objects);

  FieldUpdate field;
  field.header = header(5000);
  field.version = 4;
  writeMessage(out / "decode_field", "field_empty", field);
  // Updates a replica applies: two blocks of a small field, raw and compressed.
  Field small(FieldGeometry::make(0.05, 2, 2, 0, -4.f));
  small.allocateBlock(0, Eigen::Vector3i(1, 2, 3));
  small.allocateBlock(1, Eigen::Vector3i(0, -1, 0));
  FieldUpdate blocks = makeFieldUpdate(&small, 0);
  blocks.version = 5;
  writeMessage(out / "field_apply", "field_raw", blocks);
  encodeFieldUpdate(FieldEncoding::kZstd, &blocks);
  writeMessage(out / "field_apply", "field_zstd", blocks);

  RenderRequest request;
  request.header = header(6000);
  request.request_id = 9;
  request.client = "viewer";
  request.T_world_cam = pose(0.4);
  request.camera = camera(8, 6, false);
  writeMessage(out / "decode_render_request", "render_request", request);

  RenderResult render;
  render.header = header(7000);
  render.request_id = 9;
  render.client = "viewer";
  render.ok = true;
  render.field_version = 4;
  render.color = image(CV_8UC3);
  render.depth = image(CV_32FC1);
  render.sigma = image(CV_32FC1);
  writeMessage(out / "decode_render", "render", render);

  Status status;
  status.header = header(8000);
  status.process = "tracker";
  status.pid = 42;
  status.state = ProcessState::kRunning;
  status.fps = 9.5;
  status.values = {{"keyframes", 3}, {"ba_ms", 12.5}};
  writeMessage(out / "decode_status", "status", status);

  Control control;
  control.header = header(9000);
  control.command = ControlCommand::kSave;
  control.target = "mapper";
  control.argument = "/tmp/out";
  writeMessage(out / "decode_control", "control", control);
}

void writeDatasetSeeds(const fs::path& out) {
  for (const fuzz::DatasetLayout& layout : fuzz::datasetLayouts()) {
    std::string text;
    for (size_t i = 0; i < layout.seed.size(); ++i) {
      if (i > 0) text += fuzz::kFileSeparator;
      text += layout.seed[i];
    }
    writeSeed(out / ("dataset_" + layout.kind), "valid", text);
  }
}

void writeLogSeed(const fs::path& out) {
  fs::create_directories(out / "lcm_log");
  const fs::path path = out / "lcm_log" / "two_events";
  LogWriter writer(path.string());
  Control control;
  control.command = ControlCommand::kStop;
  const std::vector<uint8_t> bytes = encode(control);
  writer.write(100, "CONTROL", bytes.data(), bytes.size());
  writer.write(200, "X", bytes.data(), 1);
}

// A checkpoint of the tracker that the fuzz target resumes (fuzz/tracker_sequence.h).
void writeTrackerCheckpointSeed(const fs::path& out) {
  fs::create_directories(out / "tracker_checkpoint");
  Tracker tracker(fuzz::trackerParams());
  for (int i = 0; i < fuzz::kCheckpointFrames; ++i) tracker.process(fuzz::trackerSequence()[i]);
  tracker.saveCheckpoint((out / "tracker_checkpoint" / "after_8_frames").string());
}

void writeViewerSeeds(const fs::path& out) {
  const fs::path dir = out / "viewer_query";
  writeSeed(dir, "color", "pose=0,0,0,0,0,0,1&w=64&h=48&fx=50");
  writeSeed(dir, "depth",
            "pose=1.5,-0.2,3,0,0.7071068,0,0.7071068&w=8&h=6&fx=10&fy=11&cx=3.5&cy=2.5&kind=depth");
  writeSeed(dir, "sigma", "pose=0%2C0%2C0%2C0%2C0%2C0%2C1&w=2&h=2&fx=1e2&kind=sigma");
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUT_DIR\n", argv[0]);
    return 2;
  }
  try {
    const fs::path out = argv[1];
    writeDecoderSeeds(out);
    writeDatasetSeeds(out);
    writeLogSeed(out);
    writeViewerSeeds(out);
    writeTrackerCheckpointSeed(out);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "radslam_fuzz_seeds: %s\n", e.what());
    return 1;
  }
  return 0;
}
