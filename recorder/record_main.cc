// radslam-record: records every channel into a standard LCM log and, at the
// end (Ctrl-C, SIGTERM or CONTROL STOP), exports the run folder.
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <iostream>

#include "common/bus.h"
#include "common/cli.h"
#include "common/control.h"
#include "common/lcm_log.h"
#include "common/params.h"
#include "common/process_stats.h"
#include "recorder/keyframe_archive.h"
#include "recorder/run_recorder.h"

namespace radslam {
namespace {

const char* kUsage = R"(usage: radslam-record --out DIR [options]
  --out DIR        run folder (created): run.lcmlog, trajectories, summary, ...
  --url URL        LCM URL (default: LCM's default)
  --prefix P       channel prefix
  --config FILE    YAML with a "recorder" section (alignment, mode, max_dt_s, ...)
  --mode M         mono | rgbd | stereo (chooses the evaluation alignment)
  --progress       print a live progress line on stdout
  --resume         continue DIR/run.lcmlog (a recorder restarted in its run folder): what it
                   holds is read back into the exports and new messages are appended to it
)";

RecorderParams loadParams(const std::string& path, const std::string& mode) {
  RecorderParams p;
  ParamReader reader(path, "recorder");
  if (!mode.empty()) reader.addOverride("mode=" + mode);
  reader.get("alignment", &p.alignment);
  reader.get("mode", &p.mode);
  reader.get("max_dt_s", &p.max_dt_s);
  reader.get("export_keyframe_exr", &p.export_keyframe_exr);
  reader.get("max_log_mb", &p.max_log_mb);
  reader.get("min_free_disk_mb", &p.min_free_disk_mb);
  reader.finish();
  if (!(p.max_log_mb >= 0) || !(p.min_free_disk_mb >= 0))
    throw std::runtime_error("recorder: max_log_mb and min_free_disk_mb must be >= 0");
  std::cerr << "radslam-record: parameters from " << reader.source() << "\n" << reader.dump();
  return p;
}

constexpr double kRepublishGapS = 0.2;  // between re-published keyframes (as the tracker)

template <class T>
bool decodeOrWarn(const std::string& channel, const uint8_t* data, size_t size, T* msg) {
  std::string error;
  if (decode(data, size, msg, &error)) return true;
  std::cerr << "radslam-record: warning: channel " << channel << ": " << error
            << " (recorded, not exported)\n";
  return false;
}

int run(int argc, char** argv) {
  CommandLine cli(argc, argv, kUsage);
  if (cli.helpRequested()) {
    std::cout << kUsage;
    return 0;
  }
  const std::string out_dir = cli.get("out", "");
  if (out_dir.empty()) throw std::runtime_error("--out is required\n" + cli.usage());
  const std::string config = cli.get("config", "");
  const std::string mode = cli.get("mode", "");
  const std::string url = cli.get("url", "");
  const std::string prefix = cli.get("prefix", "");
  const bool progress = cli.getBool("progress", false);
  const bool resume = cli.getBool("resume", false);
  cli.finish();
  RecorderParams params = loadParams(config, mode);
  params.keyframe_exr_dir = out_dir + "/keyframes";

  installStopSignals();
  std::filesystem::create_directories(out_dir);
  const std::string log_path = out_dir + "/run.lcmlog";
  Bus bus(url, prefix, "recorder");
  RunRecorder recorder(params);
  StatusReporter reporter("recorder");
  KeyframeArchive archive(log_path);
  auto is = [&](const std::string& channel, const char* base) {
    return channel == bus.fullChannel(base);
  };
  // A message into the exports; offset: of its event in the log (-1: not written).
  auto exportMessage = [&](const std::string& ch, int64_t recv_utime, const uint8_t* data,
                           size_t size, int64_t offset) {
    recorder.onMessage(ch, recv_utime, size);
    if (is(ch, channel::kCamera)) {
      recorder.onCameraFrame(recv_utime);
    } else if (is(ch, channel::kPose)) {
      PoseStamped pose;
      if (decodeOrWarn(ch, data, size, &pose)) recorder.onPose(pose);
    } else if (is(ch, channel::kGroundTruth)) {
      PoseStamped pose;
      if (decodeOrWarn(ch, data, size, &pose)) recorder.onGroundTruth(pose);
    } else if (is(ch, channel::kKeyframe)) {
      Keyframe keyframe;
      if (decodeOrWarn(ch, data, size, &keyframe)) {
        if (offset >= 0) archive.add(keyframe.keyframe_id, keyframe.version, offset);
        recorder.onKeyframe(keyframe, recv_utime);
      }
    } else if (is(ch, channel::kObjects)) {
      ObjectList objects;
      if (decodeOrWarn(ch, data, size, &objects)) recorder.onObjects(objects);
    } else if (is(ch, channel::kGroundTruthObjects)) {
      ObjectList objects;
      if (decodeOrWarn(ch, data, size, &objects)) recorder.onGroundTruthObjects(objects);
    } else if (is(ch, channel::kStatus)) {
      Status status;
      if (decodeOrWarn(ch, data, size, &status)) recorder.onStatus(status, recv_utime);
    }
  };
  // Resuming, what the log holds goes into the exports as if heard now (at its own receive
  // times); its CONTROL requests were served before the restart.
  const bool resuming = resume && std::filesystem::exists(log_path);
  LogWriter log =
      resuming ? LogWriter::append(log_path,
                                   [&](const LogEvent& event, int64_t offset) {
                                     exportMessage(event.channel, event.utime, event.data.data(),
                                                   event.data.size(), offset);
                                   })
               : LogWriter(log_path);
  if (resuming)
    std::cerr << "radslam-record: resuming " << log_path << ": " << log.eventsWritten()
              << " events read back, appending after byte " << log.position() << "\n";
  LogGuard log_guard(params, log_path);
  bus.subscribeRaw(
      ".*", [&](const std::string& ch, int64_t recv_utime, const uint8_t* data, size_t size) {
        BusyTimer::Scope busy(reporter.busy());
        int64_t offset = -1;  // of the event in the log, -1 = not written
        if (log_guard.admits(log.bytesWritten(), size)) {
          offset = log.position();
          log.write(recv_utime, ch, data, size);
          // Into the kernel at once: a recorder killed (SIGKILL, OOM) loses no event it wrote.
          // One write(2) per event; the receive path already costs more syscalls than that.
          log.flush();
        }
        reporter.itemHandled();
        exportMessage(ch, recv_utime, data, size, offset);
        if (is(ch, channel::kControl)) {
          Control control;
          if (!decodeOrWarn(ch, data, size, &control)) return;
          if (control.command == ControlCommand::kStop && control.target == "recorder")
            requestStop();
          // Keyframes the mapper asks the tracker for: from the log once the tracker has
          // finished (while it runs, it answers itself), or when asked directly.
          if (control.command == ControlCommand::kRepublish &&
              (control.target == "recorder" ||
               (control.target == "tracker" &&
                recorder.processState("tracker") == ProcessState::kDone))) {
            std::vector<int32_t> ids;
            if (parseKeyframeRequest(control.argument, &ids) && archive.request(ids) > 0)
              std::cerr << "radslam-record: re-publishing keyframes from " << log_path << " ("
                        << control.argument << ")\n";
          }
        }
      });

  const bool tty = isatty(STDOUT_FILENO);
  const auto start = std::chrono::steady_clock::now();
  auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  double last_line = 0, last_status = 0, last_republish = 0;
  while (!stopRequested()) {
    if (bus.handle(100) < 0) {
      // A file:// URL ends with its log: export what it held.
      if (url.rfind("file://", 0) == 0 || stopRequested()) break;
      throw std::runtime_error("LCM handle failed on " + url);
    }
    const double now = elapsed();
    // One keyframe per kRepublishGapS: a burst would overrun the receivers' socket buffers.
    if (archive.pending() && now - last_republish >= kRepublishGapS) {
      last_republish = now;
      std::string error;
      if (std::optional<LogEvent> event = archive.next(&error)) {
        bus.publishRaw(event->channel, event->data.data(), event->data.size());
      } else {
        std::cerr << "radslam-record: warning: cannot re-publish a keyframe: " << error << "\n";
      }
    }
    if (now - last_status > 0.5) {
      if (!log_guard.why().empty()) reporter.setError(log_guard.why());
      reporter.setState(ProcessState::kRunning);
      reporter.setValue("log_events", static_cast<double>(log.eventsWritten()));
      reporter.setValue("log_mb", static_cast<double>(log.bytesWritten()) / 1e6);
      bus.publish(channel::kStatus, reporter.make());
      last_status = now;
    }
    if (progress && now - last_line > (tty ? 0.25 : 5.0)) {
      std::cout << (tty ? "\r\033[K" : "") << recorder.progressLine(now) << (tty ? "" : "\n")
                << std::flush;
      last_line = now;
    }
  }
  // Drain what is already queued, then export.
  while (bus.handle(0) > 0) {
  }
  log.flush();
  reporter.setState(ProcessState::kDone);
  const Status own = reporter.make();
  recorder.onStatus(own, own.header.utime);
  if (progress) std::cout << (tty ? "\r\033[K" : "") << recorder.progressLine(elapsed()) << "\n";
  const std::string summary =
      recorder.exportRun(out_dir, elapsed(), log.eventsWritten(), log.bytesWritten());
  std::cout << summary << "Run folder: " << out_dir << "\n" << std::flush;
  return 0;
}

}  // namespace
}  // namespace radslam

int main(int argc, char** argv) {
  return radslam::runMain("radslam-record", radslam::run, argc, argv);
}
