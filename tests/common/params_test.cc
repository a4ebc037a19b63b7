// ParamReader: defaults, YAML values, overrides, unknown keys, wrong types, dump.
#include "common/params.h"

#include <stdlib.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace radslam {
namespace {

struct TrackerLikeParams {
  double flow_threshold_px = 2.5;
  int window = 8;
  bool stereo = false;
  std::string preset = "fast";
  std::vector<double> weights = {1.0, 0.5};
};

class ParamsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = ::testing::TempDir() + "radslam_params_XXXXXX";
    ASSERT_NE(mkdtemp(dir_.data()), nullptr);
  }
  void TearDown() override {
    for (const auto& f : files_) std::remove(f.c_str());
    rmdir(dir_.c_str());
  }
  std::string write(const std::string& name, const std::string& text) {
    const std::string path = dir_ + "/" + name;
    std::ofstream(path) << text;
    files_.push_back(path);
    return path;
  }

  std::string dir_;
  std::vector<std::string> files_;
};

void readAll(ParamReader& r, TrackerLikeParams* p) {
  r.get("flow_threshold_px", &p->flow_threshold_px);
  r.get("window", &p->window);
  r.get("stereo", &p->stereo);
  r.get("preset", &p->preset);
  r.get("weights", &p->weights);
}

// The message of the runtime_error f throws ("" when it throws none).
template <class F>
std::string errorOf(F f) {
  try {
    f();
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST_F(ParamsTest, DefaultsWhenNoFile) {
  ParamReader r("", "tracker");
  TrackerLikeParams p;
  readAll(r, &p);
  EXPECT_NO_THROW(r.finish());
  const TrackerLikeParams d;
  EXPECT_EQ(p.flow_threshold_px, d.flow_threshold_px);
  EXPECT_EQ(p.window, d.window);
  EXPECT_EQ(p.stereo, d.stereo);
  EXPECT_EQ(p.preset, d.preset);
  EXPECT_EQ(p.weights, d.weights);
  EXPECT_EQ(r.source(), "defaults");
}

TEST_F(ParamsTest, ValuesLoadedFromSection) {
  const std::string path = write("run.yaml",
                                 "# radslam run\n"
                                 "tracker:\n"
                                 "  flow_threshold_px: 3\n"  // an integer for a double
                                 "  window: 12\n"
                                 "  stereo: yes\n"
                                 "  preset: \"medium\"\n"
                                 "  weights: [0.25, 2, 1e-3]\n"
                                 "mapper:\n"
                                 "  anything: 1\n");
  ParamReader r(path, "tracker");
  TrackerLikeParams p;
  readAll(r, &p);
  EXPECT_NO_THROW(r.finish());  // mapper's keys are not ours to judge
  EXPECT_EQ(p.flow_threshold_px, 3.0);
  EXPECT_EQ(p.window, 12);
  EXPECT_TRUE(p.stereo);
  EXPECT_EQ(p.preset, "medium");
  EXPECT_EQ(p.weights, (std::vector<double>{0.25, 2.0, 1e-3}));
  EXPECT_EQ(r.source(), path + " (section 'tracker')");
}

TEST_F(ParamsTest, RootSectionAndYamlDirective) {
  const std::string path = write("root.yaml", "%YAML:1.0\n---\nwindow: 5\nstereo: false\n");
  ParamReader r(path, "");
  TrackerLikeParams p;
  p.stereo = true;
  readAll(r, &p);
  r.finish();
  EXPECT_EQ(p.window, 5);
  EXPECT_FALSE(p.stereo);
  EXPECT_EQ(p.preset, "fast");  // absent: default kept
}

TEST_F(ParamsTest, MissingSectionKeepsDefaults) {
  const std::string path = write("other.yaml", "mapper:\n  lr: 0.1\n");
  ParamReader r(path, "tracker");
  TrackerLikeParams p;
  readAll(r, &p);
  EXPECT_NO_THROW(r.finish());
  EXPECT_EQ(p.window, 8);
  EXPECT_NE(r.source().find("no section 'tracker'"), std::string::npos);
}

TEST_F(ParamsTest, UnknownKeysRejectedByName) {
  const std::string path =
      write("typo.yaml", "tracker:\n  window: 4\n  windw: 5\n  flow_treshold_px: 1.0\n");
  ParamReader r(path, "tracker");
  TrackerLikeParams p;
  readAll(r, &p);
  const std::string error = errorOf([&] { r.finish(); });
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("section 'tracker'"), std::string::npos) << error;
  EXPECT_NE(error.find("unknown keys 'windw', 'flow_treshold_px'"), std::string::npos) << error;
  EXPECT_NE(error.find("known: flow_threshold_px, window"), std::string::npos) << error;
}

TEST_F(ParamsTest, WrongTypesRejectedNamingFileAndKey) {
  struct Case {
    std::string yaml;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"window: 2.5\n", "key 'window': expected an integer, got the number 2.5"},
      {"window: many\n", "key 'window': expected an integer, got the string \"many\""},
      {"flow_threshold_px: fast\n", "key 'flow_threshold_px': expected a number"},
      {"stereo: 2\n", "key 'stereo': expected true or false, got the integer 2"},
      {"stereo: maybe\n", "key 'stereo': expected true or false"},
      {"preset: 7\n", "key 'preset': expected a string, got the integer 7"},
      {"weights: 3\n", "key 'weights': expected a sequence of numbers"},
      {"weights: [1, x]\n", "key 'weights': element 1 of the sequence: expected a number"},
      {"window: [1]\n", "key 'window': expected an integer, got a sequence"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const std::string path = write("bad" + std::to_string(i) + ".yaml", cases[i].yaml);
    const std::string error = errorOf([&] {
      ParamReader r(path, "");
      TrackerLikeParams p;
      readAll(r, &p);
    });
    EXPECT_NE(error.find("params file '" + path + "'"), std::string::npos) << error;
    EXPECT_NE(error.find(cases[i].expected), std::string::npos)
        << "expected '" << cases[i].expected << "' in '" << error << "'";
  }
}

TEST_F(ParamsTest, BadFilesRejected) {
  EXPECT_NE(errorOf([&] {
              ParamReader r(dir_ + "/missing.yaml", "");
            }).find("cannot open params file '" + dir_ + "/missing.yaml'"),
            std::string::npos);
  const std::string broken = write("broken.yaml", "a: [1, 2\nb: ]]\n");
  EXPECT_NE(errorOf([&] { ParamReader r(broken, ""); }).find("'" + broken + "' is not valid YAML"),
            std::string::npos);
  const std::string list = write("list.yaml", "- 1\n- 2\n");
  EXPECT_NE(errorOf([&] { ParamReader r(list, ""); }).find("the top level must be a map"),
            std::string::npos);
  const std::string scalar_section = write("scalar.yaml", "tracker: 3\n");
  EXPECT_NE(errorOf([&] { ParamReader r(scalar_section, "tracker"); }).find("must be a map"),
            std::string::npos);
  const std::string twice = write("twice.yaml", "window: 1\nwindow: 2\n");
  EXPECT_NE(errorOf([&] { ParamReader r(twice, ""); }).find("key 'window' appears twice"),
            std::string::npos);
  const std::string empty = write("empty.yaml", "");
  ParamReader r(empty, "tracker");
  TrackerLikeParams p;
  readAll(r, &p);
  EXPECT_NO_THROW(r.finish());
}

TEST_F(ParamsTest, OverridesBeatTheFileAndAreChecked) {
  const std::string path = write("o.yaml", "tracker:\n  window: 4\n  preset: slow\n");
  ParamReader r(path, "tracker");
  r.addOverride("window=16");
  r.addOverride("weights=[3, 4.5]");
  r.addOverride("stereo = on");
  TrackerLikeParams p;
  readAll(r, &p);
  EXPECT_NO_THROW(r.finish());
  EXPECT_EQ(p.window, 16);
  EXPECT_EQ(p.preset, "slow");
  EXPECT_TRUE(p.stereo);
  EXPECT_EQ(p.weights, (std::vector<double>{3.0, 4.5}));

  ParamReader typed("", "tracker");
  typed.addOverride("window=4.5");
  EXPECT_NE(errorOf([&] {
              typed.get("window", &p.window);
            }).find("command line override 'window=4.5': expected an integer"),
            std::string::npos);
  ParamReader unknown("", "tracker");
  unknown.addOverride("windoww=3");
  readAll(unknown, &p);
  EXPECT_NE(errorOf([&] { unknown.finish(); }).find("override for unknown key 'windoww'"),
            std::string::npos);
  EXPECT_THROW(unknown.addOverride("no_equals_sign"), std::runtime_error);
}

TEST_F(ParamsTest, DumpHasEveryKeyAndReadsBack) {
  ParamReader r("", "");
  TrackerLikeParams p;
  p.flow_threshold_px = 0.1;  // printed in its shortest exact form
  p.preset = "say \"hi\"";
  p.weights = {1.0 / 3.0, -2e-7};
  readAll(r, &p);
  const std::string dump = r.dump();
  EXPECT_NE(dump.find("flow_threshold_px: 0.1\n"), std::string::npos) << dump;
  EXPECT_NE(dump.find("window: 8\n"), std::string::npos) << dump;
  EXPECT_NE(dump.find("stereo: false\n"), std::string::npos) << dump;
  EXPECT_NE(dump.find("preset: \"say \\\"hi\\\"\"\n"), std::string::npos) << dump;
  EXPECT_NE(dump.find("weights: [0.3333333333333333, -2e-07]\n"), std::string::npos) << dump;

  // The dump is a parameter file giving back the same values.
  ParamReader again(write("dump.yaml", dump), "");
  TrackerLikeParams q;
  q.flow_threshold_px = 9;
  q.window = 1;
  q.stereo = true;
  q.preset = "";
  q.weights.clear();
  readAll(again, &q);
  again.finish();
  EXPECT_EQ(q.flow_threshold_px, p.flow_threshold_px);
  EXPECT_EQ(q.window, p.window);
  EXPECT_EQ(q.stereo, p.stereo);
  EXPECT_EQ(q.preset, p.preset);
  EXPECT_EQ(q.weights, p.weights);
}

}  // namespace
}  // namespace radslam
