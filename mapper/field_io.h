// Field updates (channel FIELD): how the renderer's replica stays bitwise identical to the
// mapper's field.
//
/// Protocol: the mapper commits its changed blocks as a new version (Field::commit) and sends
/// the blocks committed after the replica's version (base_version) with their current values.
/// A replica at version r applies an update (base b, version v) when b <= r < v: every block
/// that changed in (b, v] is in it, every other block is as it was at b. A snapshot carries
/// every block and replaces the replica. Applying a mapper's updates in version order, then
/// one made after its last change, reproduces its field bitwise.
///
/// Payload layout "rsvox1": per block, kBlockVoxels * channels float32 values, little-endian,
/// voxel-major (x fastest, then y, then z) and channel-minor as in Field. The layout string
/// also names the channel count, the SH degree and the density bias (C99 hex float, exact).
#pragma once

#include <cstdint>
#include <string>

#include "common/types.h"
#include "mapper/field.h"

namespace radslam {

/// "rsvox1 f32le ch=C sh=S bias=HEX".
std::string fieldLayout(const FieldGeometry& geometry);
/// Parses a layout and the update's voxel sizes into a geometry; false with *error on a
/// layout this code does not understand.
bool parseFieldLayout(const std::string& layout, const std::vector<double>& voxel_size,
                      FieldGeometry* geometry, std::string* error);

/// Commits up to max_blocks pending changes (<= 0: all), then returns the blocks committed
/// after since_version (not a snapshot). An empty block list means nothing changed.
FieldUpdate makeFieldUpdate(Field* field, int64_t since_version, int max_blocks = 0);
/// Commits every pending change and returns all blocks.
FieldUpdate makeFieldSnapshot(Field* field);

enum class ApplyResult {
  kApplied,  // the replica is at update.version now
  kStale,    // update.version <= replica version: nothing to do
  kGap,      // base_version > replica version: updates are missing, ask for a snapshot
  kInvalid,  // malformed or incompatible (error says what); the replica is unchanged
};
const char* applyResultName(ApplyResult result);

/// Applies an update to a replica (an uninitialised replica takes the update's geometry).
ApplyResult applyFieldUpdate(const FieldUpdate& update, Field* replica, std::string* error);

}  // namespace radslam
