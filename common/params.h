// One parameter struct per process: defaults in code, values from a YAML file
// (read with cv::FileStorage), optional "key=value" overrides from the command
// line, every value in force printed at start, unknown keys an error.
//
// Usage, in a process's params loader:
//   ParamReader reader(yaml_path, "tracker");   // "" path = defaults only
//   reader.get("window_size", &params.window_size);
//   reader.get("flow_preset", &params.flow_preset);
//   reader.finish();                             // throws on unknown keys
//   std::cout << reader.dump();
#pragma once

#include <memory>
#include <string>
#include <vector>

namespace radslam {

class ParamReader {
 public:
  /// yaml_path: "" = defaults only. section: the top-level map holding this
  /// process's keys ("" = the root map). A file without the section leaves the
  /// defaults in force (one file may configure several processes). The
  /// "%YAML:1.0" first line OpenCV wants is optional. Throws
  /// std::runtime_error naming the file when it cannot be read or parsed, when
  /// the section is not a map, or when a key appears twice.
  ParamReader(const std::string& yaml_path, const std::string& section);
  ~ParamReader();
  ParamReader(const ParamReader&) = delete;
  ParamReader& operator=(const ParamReader&) = delete;

  /// Overrides "key=value" (command line), applied over the file. The value is
  /// parsed as the type get() asks for: numbers, true/false/yes/no/on/off/1/0,
  /// text as is, "1,2,3" or "[1, 2, 3]" for lists. Throws when there is no '='.
  void addOverride(const std::string& assignment);

  /// Each get() leaves *v unchanged (the default) when the key is absent, and
  /// records the key and the value in force for dump(). Throws
  /// std::runtime_error naming the file (or "command line") and the key when the
  /// value has the wrong type: double takes integers and reals; int integers
  /// only; bool true/false, yes/no, on/off or 0/1; std::string strings only
  /// (quote numbers); std::vector<double> a sequence of numbers.
  void get(const std::string& key, double* v);
  void get(const std::string& key, int* v);
  void get(const std::string& key, bool* v);
  void get(const std::string& key, std::string* v);
  void get(const std::string& key, std::vector<double>* v);

  /// Throws std::runtime_error naming the file, the section and every key of
  /// the section (and every override) that no get() asked for.
  void finish() const;

  /// "key: value" lines, in get() order, of every parameter asked for with the
  /// value in force; valid YAML that this class reads back to the same values.
  std::string dump() const;

  /// Where the values come from, for the start-up banner: "FILE (section
  /// 'tracker')", "FILE (no section 'tracker': defaults)" or "defaults".
  std::string source() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace radslam
