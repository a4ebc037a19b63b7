// The files a dataset fuzz input fills, per dataset kind, and valid contents for
// the seed corpus. An input is the files' texts joined by kFileSeparator, in the
// order of `files`; a missing or empty part leaves that file absent. Images are not
// fuzzed: tiny valid ones are written once at the paths in `images`.
#pragma once

#include <string>
#include <vector>

namespace radslam::fuzz {

inline constexpr const char* kFileSeparator = "\n====\n";

struct ImageFile {
  std::string path;  // relative to the fuzz folder
  int type;          // 0 = BGR8, 1 = GREY8, 2 = UINT16
};

struct DatasetLayout {
  std::string kind;                // openDataset kind
  std::string dataset_dir;         // relative to the fuzz folder
  std::vector<std::string> files;  // fuzzed text files, relative to the fuzz folder
  std::vector<std::string> seed;   // valid contents of `files`
  std::vector<ImageFile> images;
};

// Images are 8x6 pixels.
inline std::vector<DatasetLayout> datasetLayouts() {
  const std::string kCamera8x6 =
      "%YAML:1.0\nwidth: 8\nheight: 6\nfx: 10.0\nfy: 10.0\ncx: 3.5\ncy: 2.5\n";
  return {
      {"tum",
       "seq",
       {"seq/rgb.txt", "seq/depth.txt", "seq/groundtruth.txt", "seq/associations.txt",
        "seq/camera.yaml"},
       {"# color images\n1.000 rgb/1.png\n1.100 rgb/1.png\n",
        "# depth maps\n1.005 depth/1.png\n1.105 depth/1.png\n",
        "# timestamp tx ty tz qx qy qz qw\n1.0 0 0 0 0 0 0 1\n1.1 0.1 0 0 0 0 0.0499792 "
        "0.9987503\n",
        "1.000 rgb/1.png 1.005 depth/1.png\n1.100 rgb/1.png 1.105 depth/1.png\n", kCamera8x6},
       {{"seq/rgb/1.png", 0}, {"seq/depth/1.png", 2}}},
      {"kitti",
       "sequences/07",
       {"sequences/07/calib.txt", "sequences/07/times.txt", "poses/07.txt"},
       {"P0: 10 0 3.5 0 0 10 2.5 0 0 0 1 0\nP1: 10 0 3.5 -5 0 10 2.5 0 0 0 1 0\n",
        "0.000000e+00\n1.000000e-01\n", "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.5 0 1 0 0 0 0 1 0.1\n"},
       {{"sequences/07/image_0/000000.png", 1},
        {"sequences/07/image_0/000001.png", 1},
        {"sequences/07/image_1/000000.png", 1},
        {"sequences/07/image_1/000001.png", 1}}},
      {"euroc",
       "seq",
       {"seq/mav0/cam0/sensor.yaml", "seq/mav0/cam0/data.csv", "seq/mav0/cam1/sensor.yaml",
        "seq/mav0/cam1/data.csv", "seq/mav0/state_groundtruth_estimate0/data.csv",
        "seq/groundtruth.txt"},
       {"%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, "
        "0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\nresolution: [8, 6]\ncamera_model: "
        "pinhole\nintrinsics: [10.0, 10.0, 3.5, 2.5]\ndistortion_model: "
        "radial-tangential\ndistortion_coefficients: [0.01, -0.01, 0.0, 0.0]\n",
        "#timestamp [ns],filename\n1000000000,1.png\n1050000000,1.png\n",
        "%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1.0, 0.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, "
        "0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]\nresolution: [8, 6]\ncamera_model: "
        "pinhole\nintrinsics: [10.0, 10.0, 3.5, 2.5]\ndistortion_model: "
        "radial-tangential\ndistortion_coefficients: [0.01, -0.01, 0.0, 0.0]\n",
        "#timestamp [ns],filename\n1000000000,1.png\n1050000000,1.png\n",
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
        "q_RS_z []\n1000000000,0,0,0,1,0,0,0\n1050000000,0.1,0,0,1,0,0,0\n",
        ""},
       {{"seq/mav0/cam0/data/1.png", 1}, {"seq/mav0/cam1/data/1.png", 1}}},
      {"replica",
       "scene",
       {"cam_params.json", "scene/traj.txt"},
       {"{\"camera\": {\"w\": 8, \"h\": 6, \"fx\": 10.0, \"fy\": 10.0, \"cx\": 3.5, \"cy\": 2.5, "
        "\"scale\": 6553.5}}\n",
        "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0.1 0 1 0 0 0 0 1 0 0 0 0 1\n"},
       {{"scene/results/frame000000.jpg", 0},
        {"scene/results/depth000000.png", 2},
        {"scene/results/frame000001.jpg", 0},
        {"scene/results/depth000001.png", 2}}},
      {"synthetic",
       "synth",
       {"synth/camera.yaml", "synth/times.txt", "synth/groundtruth.txt", "synth/objects.txt",
        "synth/classes.yaml"},
       {kCamera8x6 + "baseline_m: 0.1\ndepth_scale: 0.001\n", "0.0\n0.1\n",
        "0.0 0 0 0 0 0 0 1\n0.1 0.1 0 0 0 0 0 1\n",
        "# t object_id class_id tx ty tz qx qy qz qw\n0.0 1 2 1 0 3 0 0 0 1\n0.1 1 2 1.1 0 3 0 0 0 "
        "1\n",
        "%YAML:1.0\nclasses:\n  - {id: 1, name: road, dynamic: 0}\n  - {id: 2, name: car, "
        "dynamic: 1, joint: planar, parent: road}\n"},
       {{"synth/rgb/000000.png", 0},
        {"synth/rgb/000001.png", 0},
        {"synth/right/000000.png", 0},
        {"synth/right/000001.png", 0},
        {"synth/depth/000000.png", 2},
        {"synth/depth/000001.png", 2}}},
  };
}

}  // namespace radslam::fuzz
