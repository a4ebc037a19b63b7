// Dataset readers on calibration and ground truth found or suspected by fuzzing
// the readers (fuzz/dataset_fuzz.cc): non-finite and overflowing numbers get a
// clear error naming the file instead of undefined behaviour or NaN poses.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "common/dataset.h"
#include "fuzz/dataset_layouts.h"

namespace radslam {
namespace {

namespace fs = std::filesystem;

// A folder holding the valid files of the fuzz seed for `kind`, with file
// `replace_index` (of DatasetLayout::files) replaced by `replacement`.
class LayoutFolder {
 public:
  LayoutFolder(const std::string& kind, int replace_index, const std::string& replacement) {
    root_ = fs::path(::testing::TempDir()) /
            ("radslam_dataset_boundary_" + kind + "_" + std::to_string(getpid()));
    fs::remove_all(root_);
    for (const fuzz::DatasetLayout& l : fuzz::datasetLayouts())
      if (l.kind == kind) layout_ = l;
    for (const fuzz::ImageFile& image : layout_.images) {
      fs::create_directories((root_ / image.path).parent_path());
      const int type = image.type == 0 ? CV_8UC3 : image.type == 1 ? CV_8UC1 : CV_16UC1;
      cv::imwrite((root_ / image.path).string(), cv::Mat(6, 8, type, cv::Scalar::all(100)));
    }
    for (size_t i = 0; i < layout_.files.size(); ++i) {
      fs::create_directories((root_ / layout_.files[i]).parent_path());
      const std::string& text =
          static_cast<int>(i) == replace_index ? replacement : layout_.seed[i];
      if (!text.empty()) std::ofstream(root_ / layout_.files[i]) << text;  // empty: absent
    }
  }
  ~LayoutFolder() { fs::remove_all(root_); }
  std::string spec() const { return layout_.kind + ":" + (root_ / layout_.dataset_dir).string(); }

  // The message of the error opening the dataset ("" when it opens).
  std::string openError() const {
    try {
      openDataset(spec());
    } catch (const std::runtime_error& e) {
      return e.what();
    }
    return "";
  }

 private:
  fs::path root_;
  fuzz::DatasetLayout layout_;
};

std::string seedFile(const std::string& kind, int index) {
  for (const fuzz::DatasetLayout& l : fuzz::datasetLayouts())
    if (l.kind == kind) return l.seed.at(index);
  return "";
}

std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

TEST(DatasetBoundary, SeedLayoutsOpenAndPlay) {
  for (const fuzz::DatasetLayout& l : fuzz::datasetLayouts()) {
    LayoutFolder folder(l.kind, -1, "");
    const auto reader = openDataset(folder.spec());
    ASSERT_GE(reader->size(), 1u) << l.kind;
    std::string error;
    EXPECT_TRUE(reader->frame(0, &error)) << l.kind << ": " << error;
    EXPECT_FALSE(reader->groundTruth().empty()) << l.kind;
  }
}

TEST(DatasetBoundary, EurocNonFiniteCalibrationIsRejected) {
  const std::string yaml = seedFile("euroc", 0);
  for (const std::string& bad : {std::string("intrinsics: [.nan, 10.0, 3.5, 2.5]"),
                                 std::string("intrinsics: [10.0, 10.0, .inf, 2.5]")}) {
    LayoutFolder folder("euroc", 0, replaced(yaml, "intrinsics: [10.0, 10.0, 3.5, 2.5]", bad));
    const std::string error = folder.openError();
    EXPECT_NE(error.find("cam0/sensor.yaml: key 'intrinsics' holds a non-finite number"),
              std::string::npos)
        << error;
  }
  LayoutFolder distortion("euroc", 0,
                          replaced(yaml, "[0.01, -0.01, 0.0, 0.0]", "[0.01, -.inf, 0.0, 0.0]"));
  EXPECT_NE(distortion.openError().find("'distortion_coefficients' holds a non-finite"),
            std::string::npos);
  LayoutFolder pose("euroc", 0, replaced(yaml, "data: [1.0, 0.0", "data: [.nan, 0.0"));
  EXPECT_NE(pose.openError().find("'data' holds a non-finite number"), std::string::npos);
  // Converted to int: out of range or fractional sizes are refused first.
  for (const std::string& bad :
       {std::string("resolution: [1e30, 6]"), std::string("resolution: [8.5, 6]")}) {
    LayoutFolder folder("euroc", 0, replaced(yaml, "resolution: [8, 6]", bad));
    EXPECT_NE(folder.openError().find("resolution must be [width, height], integers"),
              std::string::npos)
        << bad;
  }
}

TEST(DatasetBoundary, EurocGroundTruthQuaternionMustNotOverflow) {
  LayoutFolder folder("euroc", 4,
                      "#timestamp,x,y,z,qw,qx,qy,qz\n1000000000,0,0,0,1e200,1e200,0,0\n");
  EXPECT_NE(folder.openError().find("state_groundtruth_estimate0/data.csv:2"), std::string::npos)
      << folder.openError();
}

TEST(DatasetBoundary, ReplicaImageSizeIsCheckedBeforeConversion) {
  const std::string json = seedFile("replica", 0);
  for (const std::string& bad :
       {std::string("\"w\": 1e30"), std::string("\"w\": -3e12"), std::string("\"w\": 8.25")}) {
    LayoutFolder folder("replica", 0, replaced(json, "\"w\": 8", bad));
    EXPECT_NE(folder.openError().find("cam_params.json: w and h must be integers"),
              std::string::npos)
        << bad << ": " << folder.openError();
  }
}

TEST(DatasetBoundary, KittiOverflowingBaselineIsRejected) {
  LayoutFolder folder("kitti", 0,
                      "P0: 10 0 3.5 0 0 10 2.5 0 0 0 1 0\n"
                      "P1: 1e-300 0 3.5 -1e300 0 10 2.5 0 0 0 1 0\n");
  EXPECT_NE(folder.openError().find("calib.txt: P1 gives no finite positive stereo baseline"),
            std::string::npos)
      << folder.openError();
}

TEST(DatasetBoundary, SyntheticObjectQuaternionMustNotOverflow) {
  LayoutFolder folder("synthetic", 3, "0.0 1 2 1 0 3 0 0 1e300 1e300\n");
  EXPECT_NE(folder.openError().find("objects.txt:1: quaternion norm is zero or overflows"),
            std::string::npos)
      << folder.openError();
}

// Found by fuzzing: a non-numeric 'dynamic' was converted from DBL_MAX to int
// (undefined behaviour).
TEST(DatasetBoundary, SyntheticClassFlagsMustBeIntegers) {
  LayoutFolder folder("synthetic", 4,
                      "%YAML:1.0\nclasses:\n  - {id: 1, name: road, dynamic: yes}\n");
  EXPECT_NE(folder.openError().find("classes.yaml: class 0: 'dynamic' must be 0 or 1"),
            std::string::npos)
      << folder.openError();
}

}  // namespace
}  // namespace radslam
