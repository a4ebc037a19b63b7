// radslam-status: listens to STATUS and prints one line per process with the age of its last
// heartbeat, once (for a person) or continuously into a file (for the launcher's supervision).
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "common/bus.h"
#include "common/cli.h"
#include "recorder/heartbeat_table.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-status [options]
  --url URL        LCM URL (default: LCM's default)
  --prefix P       channel prefix
  --listen S       listen S seconds, print the table and exit (default 1.5)
  --out FILE       instead, rewrite FILE every --period seconds until stopped (SIGINT/SIGTERM)
  --period S       rewrite period for --out (default 0.5)
Each line: NAME PID STATE AGE_S HEARTBEATS ITEMS FPS (AGE_S = seconds since its last STATUS,
measured on this host).
)";

// Replaces FILE atomically so that a reader never sees half a table.
void writeAtomically(const std::string& path, const std::string& text) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) throw std::runtime_error("cannot write " + tmp);
    out << text;
    if (!out) throw std::runtime_error("cannot write " + tmp);
  }
  std::filesystem::rename(tmp, path);
}

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string url = cli.get("url", "");
  const std::string prefix = cli.get("prefix", "");
  const double listen_s = cli.getDouble("listen", 1.5);
  const std::string out_path = cli.get("out", "");
  const double period_s = cli.getDouble("period", 0.5);
  cli.finish();
  if (!(listen_s > 0)) throw std::runtime_error("--listen must be > 0 seconds");
  if (!(period_s > 0)) throw std::runtime_error("--period must be > 0 seconds");

  installStopSignals();
  Bus bus(url, prefix, "status");
  HeartbeatTable table;
  const auto start = std::chrono::steady_clock::now();
  auto now = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  bus.subscribe<Status>(channel::kStatus, [&](const Status& s) { table.onStatus(s, now()); });

  if (out_path.empty()) {
    while (now() < listen_s && !stopRequested())
      if (bus.handle(50) < 0) break;
    std::cout << table.table(now()) << std::flush;
    return 0;
  }
  double last_write = -1e9;
  while (!stopRequested()) {
    if (bus.handle(50) < 0) throw std::runtime_error("LCM handle failed on " + url);
    if (now() - last_write >= period_s) {
      writeAtomically(out_path, table.table(now()));
      last_write = now();
    }
  }
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-status", radslam::run, argc, argv);
}
