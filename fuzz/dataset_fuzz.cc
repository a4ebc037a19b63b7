// libFuzzer target for one dataset reader (RADSLAM_FUZZ_DATASET_<kind>): the
// input is split into the reader's index, calibration and ground-truth files
// (dataset_layouts.h), written into a private folder beside tiny valid images,
// and the dataset is opened and iterated as radslam-play does. A clear
// exception or a per-frame error is an accepted outcome; a crash, a sanitizer
// report, an allocation past libFuzzer's limit or a hang is a finding.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>

#include <opencv2/imgcodecs.hpp>

#include "common/dataset.h"
#include "fuzz/dataset_layouts.h"

namespace {

namespace fs = std::filesystem;
using radslam::fuzz::DatasetLayout;

#if defined(RADSLAM_FUZZ_DATASET_tum)
constexpr const char* kKind = "tum";
#elif defined(RADSLAM_FUZZ_DATASET_kitti)
constexpr const char* kKind = "kitti";
#elif defined(RADSLAM_FUZZ_DATASET_euroc)
constexpr const char* kKind = "euroc";
#elif defined(RADSLAM_FUZZ_DATASET_replica)
constexpr const char* kKind = "replica";
#elif defined(RADSLAM_FUZZ_DATASET_synthetic)
constexpr const char* kKind = "synthetic";
#else
#error "define RADSLAM_FUZZ_DATASET_<kind>"
#endif

// Frames read per input: enough to reach every per-frame path, few enough to keep
// thousands of inputs per second.
constexpr size_t kMaxFramesPerInput = 3;

struct Workspace {
  DatasetLayout layout;
  fs::path root;
};

void writeImage(const fs::path& path, int type) {
  fs::create_directories(path.parent_path());
  cv::Mat image;
  if (type == 0) image = cv::Mat(6, 8, CV_8UC3, cv::Scalar(40, 120, 200));
  if (type == 1) image = cv::Mat(6, 8, CV_8UC1, cv::Scalar(90));
  if (type == 2) image = cv::Mat(6, 8, CV_16UC1, cv::Scalar(5000));
  if (!cv::imwrite(path.string(), image)) {
    std::fprintf(stderr, "dataset fuzz: cannot write %s\n", path.c_str());
    std::abort();
  }
}

const Workspace& workspace() {
  static const Workspace ws = [] {
    Workspace w;
    for (const DatasetLayout& layout : radslam::fuzz::datasetLayouts())
      if (layout.kind == kKind) w.layout = layout;
    char pattern[] = "/tmp/radslam_fuzz_dataset_XXXXXX";
    if (!mkdtemp(pattern)) {
      std::perror("dataset fuzz: mkdtemp");
      std::abort();
    }
    w.root = pattern;
    for (const auto& image : w.layout.images) writeImage(w.root / image.path, image.type);
    for (const std::string& file : w.layout.files)
      fs::create_directories((w.root / file).parent_path());
    return w;
  }();
  return ws;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const Workspace& ws = workspace();
  const std::string input(reinterpret_cast<const char*>(data), size);
  const std::string separator = radslam::fuzz::kFileSeparator;
  size_t begin = 0;
  for (const std::string& file : ws.layout.files) {
    const fs::path path = ws.root / file;
    size_t end = begin > input.size() ? input.size() : input.find(separator, begin);
    if (end == std::string::npos) end = input.size();
    if (begin >= end) {  // a missing or empty part: no such file
      std::error_code ec;
      fs::remove(path, ec);
    } else {
      std::ofstream(path, std::ios::binary | std::ios::trunc) << input.substr(begin, end - begin);
    }
    begin = end + separator.size();
  }
  try {
    const auto reader =
        radslam::openDataset(std::string(kKind) + ":" + (ws.root / ws.layout.dataset_dir).string());
    for (size_t i = 0; i < reader->size() && i < kMaxFramesPerInput; ++i) {
      (void)reader->timestamp(i);
      std::string error;
      const std::optional<radslam::Frame> frame = reader->frame(i, &error);
      if (!frame && error.empty()) {
        std::fprintf(stderr, "dataset fuzz: frame %zu failed without an error message\n", i);
        std::abort();
      }
    }
    (void)reader->groundTruth();
    (void)reader->objectGroundTruth();
    (void)reader->classes();
  } catch (const std::exception&) {
    // A clear error is an accepted outcome.
  }
  return 0;
}
