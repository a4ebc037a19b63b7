#include "mapper/field_io.h"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>

namespace radslam {

namespace {

bool littleEndianHost() {
  const uint32_t one = 1;
  uint8_t first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

void checkHost() {
  if (!littleEndianHost())
    throw std::runtime_error(
        "field updates: payloads are little-endian float32; big-endian "
        "hosts are not supported");
}

FieldUpdate header(const Field& field) {
  FieldUpdate u;
  u.layout = fieldLayout(field.geometry());
  u.voxel_size = field.geometry().voxel_size;
  u.block_dim = Field::kBlockDim;
  u.version = field.version();
  return u;
}

FieldBlock blockOf(const Field& field, int level, int block) {
  FieldBlock fb;
  fb.level = static_cast<int8_t>(level);
  fb.index = field.blockIndex(level, block);
  const size_t bytes = size_t(Field::kBlockVoxels) * field.channels() * sizeof(float);
  fb.data.resize(bytes);
  std::memcpy(fb.data.data(), field.blockData(level, block), bytes);
  return fb;
}

}  // namespace

std::string fieldLayout(const FieldGeometry& g) {
  char bias[64];
  std::snprintf(bias, sizeof(bias), "%a", double(g.density_bias));
  return "rsvox1 f32le ch=" + std::to_string(g.channels()) + " sh=" + std::to_string(g.sh_degree) +
         " bias=" + bias;
}

bool parseFieldLayout(const std::string& layout, const std::vector<double>& voxel_size,
                      FieldGeometry* geometry, std::string* error) {
  std::istringstream in(layout);
  std::string name, encoding, ch, sh, bias;
  in >> name >> encoding >> ch >> sh >> bias;
  if (name != "rsvox1" || encoding != "f32le" || ch.rfind("ch=", 0) != 0 ||
      sh.rfind("sh=", 0) != 0 || bias.rfind("bias=", 0) != 0) {
    *error = "unknown field layout '" + layout + "' (this build reads rsvox1 f32le)";
    return false;
  }
  FieldGeometry g;
  g.voxel_size = voxel_size;
  g.sh_degree = std::atoi(sh.c_str() + 3);
  g.density_bias = static_cast<float>(std::strtod(bias.c_str() + 5, nullptr));
  try {
    g.validate();
  } catch (const std::exception& e) {
    *error = e.what();
    return false;
  }
  if (std::atoi(ch.c_str() + 3) != g.channels()) {
    *error = "field layout '" + layout + "': channel count does not match the SH degree";
    return false;
  }
  *geometry = g;
  return true;
}

FieldUpdate makeFieldUpdate(Field* field, int64_t since_version, int max_blocks) {
  checkHost();
  field->commit(max_blocks);
  FieldUpdate u = header(*field);
  u.base_version = since_version;
  u.is_snapshot = false;
  for (int l = 0; l < field->numLevels(); ++l)
    for (int b = 0; b < field->numBlocks(l); ++b)
      if (field->blockVersion(l, b) > since_version) u.blocks.push_back(blockOf(*field, l, b));
  return u;
}

FieldUpdate makeFieldSnapshot(Field* field) {
  checkHost();
  field->commit();
  FieldUpdate u = header(*field);
  u.base_version = 0;
  u.is_snapshot = true;
  for (int l = 0; l < field->numLevels(); ++l)
    for (int b = 0; b < field->numBlocks(l); ++b) u.blocks.push_back(blockOf(*field, l, b));
  return u;
}

SnapshotSender::SnapshotSender(Field* field, int64_t snapshot_id, int max_blocks)
    : field_(field), snapshot_id_(snapshot_id), max_blocks_(std::max(1, max_blocks)) {
  checkHost();
  // No commit here: blocks changed and not yet committed go out with their current content
  // and stay changed, so bounded deltas commit them later (a commit of all of them would
  // make the next delta the whole backlog).
  version_ = field->version();
  for (int l = 0; l < field->numLevels(); ++l)
    for (int b = 0; b < field->numBlocks(l); ++b) blocks_.emplace_back(l, b);
  sent_at_.assign(blocks_.size(), 0);
  chunk_count_ = std::max<int>(1, (blocks_.size() + max_blocks_ - 1) / max_blocks_);
}

FieldUpdate SnapshotSender::next() {
  if (done()) throw std::logic_error("SnapshotSender::next: the snapshot was sent");
  version_ = field_->version();
  FieldUpdate u = header(*field_);
  u.version = version_;
  u.base_version = 0;
  u.is_snapshot = true;
  u.snapshot_id = snapshot_id_;
  u.chunk_index = sent_;
  u.chunk_count = chunk_count_;
  const size_t end = std::min(blocks_.size(), next_ + max_blocks_);
  for (; next_ < end; ++next_) {
    u.blocks.push_back(blockOf(*field_, blocks_[next_].first, blocks_[next_].second));
    sent_at_[next_] = version_;
  }
  ++sent_;
  if (done()) {
    for (size_t i = 0; i < blocks_.size(); ++i) {
      const auto [l, b] = blocks_[i];
      if (field_->blockVersion(l, b) > sent_at_[i]) field_->markChanged(l, b);
    }
  }
  return u;
}

SnapshotAssembler::Result SnapshotAssembler::add(const FieldUpdate& chunk, std::string* error) {
  if (!chunk.is_snapshot) {
    *error = "field update " + std::to_string(chunk.version) + " is not a snapshot chunk";
    return Result::kInvalid;
  }
  if (chunk.chunk_index == 0) {
    snapshot_id_ = chunk.snapshot_id;
    expected_ = 0;
  } else if (chunk.snapshot_id != snapshot_id_ || chunk.chunk_index != expected_) {
    *error = "snapshot " + std::to_string(chunk.snapshot_id) + ": chunk " +
             std::to_string(chunk.chunk_index) + " of " + std::to_string(chunk.chunk_count) +
             (expected_ > 0 ? ", expected chunk " + std::to_string(expected_)
                            : ", its first chunk was missed");
    expected_ = 0;
    field_ = Field();
    return Result::kLost;
  }
  // Chunk 0 replaces the staging field; later chunks add to it (as an update at its version).
  FieldUpdate part = chunk;
  if (chunk.chunk_index > 0) {
    part.is_snapshot = false;
    part.base_version = field_.version();
    part.version = field_.version() + 1;
  }
  const ApplyResult r = applyFieldUpdate(part, &field_, error);
  if (r != ApplyResult::kApplied) {
    expected_ = 0;
    field_ = Field();
    return Result::kInvalid;
  }
  field_.setVersion(chunk.version);
  expected_ = chunk.chunk_index + 1;
  if (expected_ < chunk.chunk_count) return Result::kIncomplete;
  expected_ = 0;
  return Result::kComplete;
}

const char* applyResultName(ApplyResult result) {
  switch (result) {
    case ApplyResult::kApplied:
      return "applied";
    case ApplyResult::kStale:
      return "stale";
    case ApplyResult::kGap:
      return "gap";
    case ApplyResult::kInvalid:
      return "invalid";
    case ApplyResult::kPartial:
      return "partial";
  }
  return "?";
}

namespace {

// The update's geometry in *g, or false with *error saying what does not fit.
bool checkUpdate(const FieldUpdate& u, FieldGeometry* g, std::string* error) {
  std::string why;
  if (!parseFieldLayout(u.layout, u.voxel_size, g, &why)) {
    *error = "field update " + std::to_string(u.version) + ": " + why;
    return false;
  }
  if (u.block_dim != Field::kBlockDim) {
    *error = "field update " + std::to_string(u.version) + ": block_dim " +
             std::to_string(u.block_dim) + ", this build uses " + std::to_string(Field::kBlockDim);
    return false;
  }
  const size_t bytes = size_t(Field::kBlockVoxels) * g->channels() * sizeof(float);
  for (const FieldBlock& b : u.blocks) {
    if (b.level < 0 || b.level >= g->numLevels() || b.data.size() != bytes ||
        b.index.cwiseAbs().maxCoeff() > Field::kMaxBlockIndex) {
      *error = "field update " + std::to_string(u.version) + ": block (level " +
               std::to_string(b.level) + ", " + std::to_string(b.data.size()) +
               " bytes) does not fit the layout (" + std::to_string(g->numLevels()) + " levels, " +
               std::to_string(bytes) + " bytes per block)";
      return false;
    }
  }
  return true;
}

void writeBlocks(const FieldUpdate& u, Field* replica) {
  for (const FieldBlock& b : u.blocks) {
    const int id = replica->allocateBlock(b.level, b.index);
    std::memcpy(replica->blockData(b.level, id), b.data.data(), b.data.size());
  }
}

}  // namespace

ApplyResult applyFieldUpdate(const FieldUpdate& u, Field* replica, std::string* error,
                             GapPolicy gap_policy) {
  checkHost();
  ApplyResult result = ApplyResult::kApplied;
  FieldGeometry g;
  if (!checkUpdate(u, &g, error)) return ApplyResult::kInvalid;
  if (!u.is_snapshot) {
    if (replica->initialized() && replica->geometry() != g) {
      *error = "field update " + std::to_string(u.version) +
               ": geometry differs from the replica's (needs a snapshot)";
      return ApplyResult::kInvalid;
    }
    const int64_t r = replica->initialized() ? replica->version() : 0;
    if (u.version <= r) return ApplyResult::kStale;
    if (u.base_version > r) {
      *error = "field update " + std::to_string(u.version) + " applies to version " +
               std::to_string(u.base_version) + ", the replica is at " + std::to_string(r);
      result = ApplyResult::kGap;
      if (gap_policy == GapPolicy::kReject) return result;
    }
    if (!replica->initialized()) *replica = Field(g);
  } else {
    *replica = Field(g);
  }
  writeBlocks(u, replica);
  replica->setVersion(u.version);
  return result;
}

ApplyResult repairFromSnapshotChunk(const FieldUpdate& chunk, Field* replica, std::string* error) {
  checkHost();
  FieldGeometry g;
  if (!checkUpdate(chunk, &g, error)) return ApplyResult::kInvalid;
  if (!replica->initialized() || replica->geometry() != g) {
    *error = "snapshot chunk: geometry differs from the replica's";
    return ApplyResult::kInvalid;
  }
  writeBlocks(chunk, replica);
  return ApplyResult::kApplied;
}

}  // namespace radslam
