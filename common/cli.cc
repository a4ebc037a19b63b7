#include "common/cli.h"

#include <atomic>
#include <csignal>
#include <cstdlib>
#include <iostream>
#include <stdexcept>

namespace radslam {

CommandLine::CommandLine(int argc, char** argv, std::string usage) : usage_(std::move(usage)) {
  for (int i = 1; i < argc; ++i) {
    std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      help_ = true;
      continue;
    }
    if (arg.rfind("--", 0) != 0) {
      positional_.push_back(arg);
      continue;
    }
    arg = arg.substr(2);
    const size_t eq = arg.find('=');
    if (eq != std::string::npos) {
      values_[arg.substr(0, eq)] = arg.substr(eq + 1);
    } else if (i + 1 < argc && std::string(argv[i + 1]).rfind("--", 0) != 0) {
      values_[arg] = argv[++i];
    } else {
      values_[arg] = "";  // a switch
    }
  }
}

bool CommandLine::has(const std::string& name) {
  used_[name] = true;
  return values_.count(name) > 0;
}

std::string CommandLine::get(const std::string& name, const std::string& fallback) {
  used_[name] = true;
  auto it = values_.find(name);
  return it == values_.end() ? fallback : it->second;
}

double CommandLine::getDouble(const std::string& name, double fallback) {
  const std::string text = get(name, "");
  if (!has(name)) return fallback;
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (text.empty() || *end != '\0')
    throw std::runtime_error("--" + name + " expects a number, got '" + text + "'");
  return value;
}

int CommandLine::getInt(const std::string& name, int fallback) {
  const std::string text = get(name, "");
  if (!has(name)) return fallback;
  char* end = nullptr;
  const long value = std::strtol(text.c_str(), &end, 10);
  if (text.empty() || *end != '\0')
    throw std::runtime_error("--" + name + " expects an integer, got '" + text + "'");
  return static_cast<int>(value);
}

bool CommandLine::getBool(const std::string& name, bool fallback) {
  if (!has(name)) return fallback;
  const std::string text = get(name, "");
  if (text.empty() || text == "1" || text == "true") return true;
  if (text == "0" || text == "false") return false;
  throw std::runtime_error("--" + name + " expects true or false, got '" + text + "'");
}

void CommandLine::finish() const {
  std::string unknown;
  for (const auto& [name, value] : values_)
    if (!used_.count(name)) unknown += (unknown.empty() ? "--" : ", --") + name;
  if (!unknown.empty()) throw std::runtime_error("unknown option(s): " + unknown + "\n" + usage_);
}

namespace {
std::atomic<bool> g_stop{false};
extern "C" void onStopSignal(int) { g_stop = true; }
}  // namespace

void installStopSignals() {
  std::signal(SIGINT, onStopSignal);
  std::signal(SIGTERM, onStopSignal);
}

bool stopRequested() { return g_stop; }
void requestStop() { g_stop = true; }

int runMain(const char* program, int (*body)(int, char**), int argc, char** argv) {
  try {
    return body(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << program << ": error: " << e.what() << std::endl;
    return 2;
  }
}

}  // namespace radslam
