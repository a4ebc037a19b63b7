// Command-line flags of the radslam executables: "--name value" or
// "--name=value", and bare "--switch". Unknown flags are an error.
#pragma once

#include <map>
#include <string>
#include <vector>

namespace radslam {

class CommandLine {
 public:
  /// usage: printed with --help and after an error.
  CommandLine(int argc, char** argv, std::string usage);

  bool has(const std::string& name);
  std::string get(const std::string& name, const std::string& fallback);
  double getDouble(const std::string& name, double fallback);
  int getInt(const std::string& name, int fallback);
  /// A switch: present without value, or with true/false/1/0.
  bool getBool(const std::string& name, bool fallback);
  /// Throws std::runtime_error naming every flag given but never asked for.
  void finish() const;
  /// True when --help was given (the caller prints usage() and exits 0).
  bool helpRequested() const { return help_; }
  const std::string& usage() const { return usage_; }
  const std::vector<std::string>& positional() const { return positional_; }

 private:
  std::map<std::string, std::string> values_;
  std::map<std::string, bool> used_;
  std::vector<std::string> positional_;
  std::string usage_;
  bool help_ = false;
};

/// SIGINT and SIGTERM set a flag instead of killing the process, so every
/// process can finish its work and write its outputs before it exits.
void installStopSignals();
bool stopRequested();
void requestStop();

/// Runs body, turning any exception into "PROGRAM: error: what" on stderr and
/// exit code 2, so every main reports bad input the same way.
int runMain(const char* program, int (*body)(int, char**), int argc, char** argv);

}  // namespace radslam
