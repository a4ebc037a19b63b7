// libFuzzer target for the renderer's side of FIELD: the LCM bytes of one update are decoded
// and applied to a replica (applyFieldUpdate, field_io.h), raw or zstd-compressed blocks.
//
// Checked beyond "no crash, no sanitizer report": a rejected update says why and leaves the
// replica as it was; an applied one moves the replica to the update's version.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "common/bus.h"
#include "common/types.h"
#include "mapper/field_io.h"

namespace {

[[noreturn]] void failCheck(const char* what, const std::string& detail) {
  std::fprintf(stderr, "field apply fuzz: %s: %s\n", what, detail.c_str());
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  radslam::FieldUpdate update;
  std::string error;
  if (!radslam::decode(data, size, &update, &error)) return 0;
  // A replica that already holds a field of its own, as a running renderer does.
  radslam::Field replica(radslam::FieldGeometry::make(0.05, 2, 2, 0, -4.f));
  replica.allocateBlock(0, Eigen::Vector3i(1, 2, 3));
  replica.setVersion(3);
  const radslam::Field before = replica;
  const radslam::ApplyResult result =
      radslam::applyFieldUpdate(update, &replica, &error, radslam::GapPolicy::kApply);
  switch (result) {
    case radslam::ApplyResult::kInvalid:
      if (error.empty()) failCheck("rejected without an error message", "");
      [[fallthrough]];
    case radslam::ApplyResult::kStale:
      if (replica.version() != before.version() || !replica.sameContent(before))
        failCheck("a rejected or stale update changed the replica", error);
      break;
    case radslam::ApplyResult::kApplied:
    case radslam::ApplyResult::kGap:
      if (replica.version() != update.version)
        failCheck("an applied update left the replica at another version", error);
      break;
    case radslam::ApplyResult::kPartial:
      break;
  }
  return 0;
}
