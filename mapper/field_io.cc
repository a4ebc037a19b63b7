#include "mapper/field_io.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <sstream>
#include <stdexcept>

#include <zstd.h>

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

constexpr const char* kRawName = "f32le";
constexpr const char* kZstdName = "f32le+zstd";
constexpr int kZstdLevel = 1;  // the fastest: higher levels gain a few percent at 2-5x the time

}  // namespace

std::string fieldLayout(const FieldGeometry& g, FieldEncoding encoding) {
  char bias[64];
  std::snprintf(bias, sizeof(bias), "%a", double(g.density_bias));
  return std::string("rsvox1 ") + (encoding == FieldEncoding::kZstd ? kZstdName : kRawName) +
         " ch=" + std::to_string(g.channels()) + " sh=" + std::to_string(g.sh_degree) +
         " bias=" + bias;
}

bool parseFieldLayout(const std::string& layout, const std::vector<double>& voxel_size,
                      FieldGeometry* geometry, std::string* error, FieldEncoding* encoding) {
  std::istringstream in(layout);
  std::string name, encoding_name, ch, sh, bias;
  in >> name >> encoding_name >> ch >> sh >> bias;
  if (name != "rsvox1" || (encoding_name != kRawName && encoding_name != kZstdName) ||
      ch.rfind("ch=", 0) != 0 || sh.rfind("sh=", 0) != 0 || bias.rfind("bias=", 0) != 0) {
    *error = "unknown field layout '" + layout + "' (this build reads rsvox1 " + kRawName +
             " and " + kZstdName + ")";
    return false;
  }
  if (encoding) *encoding = encoding_name == kZstdName ? FieldEncoding::kZstd : FieldEncoding::kRaw;
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

void encodeFieldUpdate(FieldEncoding encoding, FieldUpdate* u) {
  if (encoding == FieldEncoding::kRaw) return;
  FieldGeometry g;
  std::string error;
  FieldEncoding current;
  if (!parseFieldLayout(u->layout, u->voxel_size, &g, &error, &current))
    throw std::invalid_argument("encodeFieldUpdate: " + error);
  if (current != FieldEncoding::kRaw)
    throw std::invalid_argument("encodeFieldUpdate: the update is encoded already");
  std::unique_ptr<ZSTD_CCtx, size_t (*)(ZSTD_CCtx*)> context(ZSTD_createCCtx(), ZSTD_freeCCtx);
  std::vector<uint8_t> packed;
  for (FieldBlock& b : u->blocks) {
    packed.resize(ZSTD_compressBound(b.data.size()));
    const size_t n = ZSTD_compressCCtx(context.get(), packed.data(), packed.size(), b.data.data(),
                                       b.data.size(), kZstdLevel);
    if (ZSTD_isError(n))
      throw std::runtime_error(std::string("encodeFieldUpdate: ") + ZSTD_getErrorName(n));
    b.data.assign(packed.begin(), packed.begin() + n);
  }
  u->layout = fieldLayout(g, encoding);
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

FieldUpdate makeFieldCatchUp(Field* field, int64_t since_version, int max_blocks) {
  checkHost();
  int changed = 0;
  std::pair<int, int> any{-1, -1}, changed_one{-1, -1};  // (level, block)
  for (int l = 0; l < field->numLevels(); ++l) {
    for (int b = 0; b < field->numBlocks(l); ++b) {
      if (any.first < 0) any = {l, b};
      if (field->blockVersion(l, b) <= since_version) continue;
      if (changed++ == 0) changed_one = {l, b};
    }
  }
  if (changed > max_blocks) {
    FieldUpdate u = header(*field);
    u.base_version = since_version;
    return u;
  }
  // A new version even when nothing is pending: the replica may be at the current one.
  const std::pair<int, int> mark = changed > 0 ? changed_one : any;
  if (mark.first >= 0) field->markChanged(mark.first, mark.second);
  return makeFieldUpdate(field, since_version, max_blocks);
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
  for (int i = 0; i < chunk_count_; ++i) pending_.push_back(i);
}

FieldUpdate SnapshotSender::next() {
  if (done()) throw std::logic_error("SnapshotSender::next: the snapshot was sent");
  const int chunk = pending_.front();
  pending_.pop_front();
  version_ = field_->version();
  FieldUpdate u = header(*field_);
  u.version = version_;
  u.base_version = 0;
  u.is_snapshot = true;
  u.snapshot_id = snapshot_id_;
  u.chunk_index = chunk;
  u.chunk_count = chunk_count_;
  const size_t begin = size_t(chunk) * max_blocks_;
  const size_t end = std::min(blocks_.size(), begin + max_blocks_);
  for (size_t i = begin; i < end; ++i) {
    u.blocks.push_back(blockOf(*field_, blocks_[i].first, blocks_[i].second));
    sent_at_[i] = version_;
  }
  if (done()) {
    for (size_t i = 0; i < blocks_.size(); ++i) {
      const auto [l, b] = blocks_[i];
      if (field_->blockVersion(l, b) > sent_at_[i]) field_->markChanged(l, b);
    }
  }
  return u;
}

int SnapshotSender::resend(const std::vector<int>& chunks) {
  int queued = 0;
  for (int c : chunks) {
    if (c < 0 || c >= chunk_count_ ||
        std::find(pending_.begin(), pending_.end(), c) != pending_.end())
      continue;
    pending_.push_back(c);
    ++queued;
  }
  return queued;
}

void SnapshotAssembler::reset() {
  field_ = Field();
  snapshot_id_ = -1;
  received_.clear();
  received_count_ = 0;
}

SnapshotAssembler::Result SnapshotAssembler::add(const FieldUpdate& chunk, std::string* error) {
  if (!chunk.is_snapshot) {
    *error = "field update " + std::to_string(chunk.version) + " is not a snapshot chunk";
    return Result::kInvalid;
  }
  if (chunk.snapshot_id < 0 || chunk.chunk_count < 1 || chunk.chunk_index < 0 ||
      chunk.chunk_index >= chunk.chunk_count) {
    *error = "snapshot " + std::to_string(chunk.snapshot_id) + ": chunk " +
             std::to_string(chunk.chunk_index) + " of " + std::to_string(chunk.chunk_count) +
             " is not a chunk of a snapshot";
    return Result::kInvalid;
  }
  if (chunk.snapshot_id != snapshot_id_ ||
      static_cast<int>(received_.size()) != chunk.chunk_count) {
    reset();  // a newer snapshot (or another mapper's) replaces the one in progress
    snapshot_id_ = chunk.snapshot_id;
    received_.assign(chunk.chunk_count, false);
  }
  // The first chunk to arrive makes the staging field; the others add their blocks to it (a
  // chunk sent again brings its blocks' newer content).
  const int64_t version = std::max(field_.initialized() ? field_.version() : 0, chunk.version);
  const ApplyResult r = field_.initialized() ? repairFromSnapshotChunk(chunk, &field_, error)
                                             : applyFieldUpdate(chunk, &field_, error);
  if (r != ApplyResult::kApplied) {
    reset();
    return Result::kInvalid;
  }
  field_.setVersion(version);
  if (!received_[chunk.chunk_index]) {
    received_[chunk.chunk_index] = true;
    ++received_count_;
  }
  if (received_count_ < chunk.chunk_count) return Result::kIncomplete;
  snapshot_id_ = -1;
  received_.clear();
  received_count_ = 0;
  return Result::kComplete;
}

std::vector<int> SnapshotAssembler::missing() const {
  std::vector<int> out;
  for (size_t i = 0; i < received_.size(); ++i)
    if (!received_[i]) out.push_back(static_cast<int>(i));
  return out;
}

std::string catchUpArgument(int64_t since_version) {
  return "since " + std::to_string(since_version);
}

bool parseCatchUpArgument(const std::string& argument, int64_t* since_version) {
  std::istringstream in(argument);
  std::string word;
  long long version = -1;
  if (!(in >> word >> version) || word != "since" || version < 0 || !(in >> std::ws).eof())
    return false;
  *since_version = version;
  return true;
}

std::string snapshotChunksArgument(int64_t snapshot_id, const std::vector<int>& chunks) {
  std::string s = "chunks " + std::to_string(snapshot_id) + " ";
  for (size_t i = 0; i < chunks.size(); ++i) s += (i ? "," : "") + std::to_string(chunks[i]);
  return s;
}

bool parseSnapshotChunksArgument(const std::string& argument, int64_t* snapshot_id,
                                 std::vector<int>* chunks) {
  std::istringstream in(argument);
  std::string word, list;
  long long id = -1;
  if (!(in >> word >> id >> list) || word != "chunks" || id < 0 || !(in >> std::ws).eof())
    return false;
  std::vector<int> parsed;
  std::istringstream items(list);
  for (std::string item; std::getline(items, item, ',');) {
    char* end = nullptr;
    const long value = std::strtol(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0' || value < 0 || value > 1000000) return false;
    parsed.push_back(static_cast<int>(value));
  }
  if (parsed.empty()) return false;
  *snapshot_id = id;
  *chunks = std::move(parsed);
  return true;
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

// The update's geometry in *g and its blocks' raw values (pointers into the update, or into
// *decoded for compressed blocks), or false with *error saying what does not fit.
bool checkUpdate(const FieldUpdate& u, FieldGeometry* g, std::vector<const uint8_t*>* values,
                 std::vector<uint8_t>* decoded, std::string* error) {
  std::string why;
  FieldEncoding encoding;
  if (!parseFieldLayout(u.layout, u.voxel_size, g, &why, &encoding)) {
    *error = "field update " + std::to_string(u.version) + ": " + why;
    return false;
  }
  if (u.block_dim != Field::kBlockDim) {
    *error = "field update " + std::to_string(u.version) + ": block_dim " +
             std::to_string(u.block_dim) + ", this build uses " + std::to_string(Field::kBlockDim);
    return false;
  }
  const size_t bytes = size_t(Field::kBlockVoxels) * g->channels() * sizeof(float);
  const bool zstd = encoding == FieldEncoding::kZstd;
  for (const FieldBlock& b : u.blocks) {
    // A zstd frame states its decoded size: checked before anything is allocated.
    const size_t size =
        zstd ? static_cast<size_t>(ZSTD_getFrameContentSize(b.data.data(), b.data.size()))
             : b.data.size();
    if (b.level < 0 || b.level >= g->numLevels() || size != bytes ||
        !Field::blockIndexInRange(b.index)) {
      *error = "field update " + std::to_string(u.version) + ": block (level " +
               std::to_string(b.level) + ", " + std::to_string(b.data.size()) + " bytes" +
               (zstd ? ", not a zstd frame of " + std::to_string(bytes) + " bytes" : "") +
               ") does not fit the layout (" + std::to_string(g->numLevels()) + " levels, " +
               std::to_string(bytes) + " bytes per block)";
      return false;
    }
  }
  values->clear();
  if (!zstd) {
    for (const FieldBlock& b : u.blocks) values->push_back(b.data.data());
    return true;
  }
  decoded->resize(u.blocks.size() * bytes);
  std::unique_ptr<ZSTD_DCtx, size_t (*)(ZSTD_DCtx*)> context(ZSTD_createDCtx(), ZSTD_freeDCtx);
  for (size_t i = 0; i < u.blocks.size(); ++i) {
    uint8_t* out = decoded->data() + i * bytes;
    const size_t n = ZSTD_decompressDCtx(context.get(), out, bytes, u.blocks[i].data.data(),
                                         u.blocks[i].data.size());
    if (ZSTD_isError(n) || n != bytes) {
      *error = "field update " + std::to_string(u.version) + ": block " + std::to_string(i) +
               " does not decompress (" +
               (ZSTD_isError(n) ? ZSTD_getErrorName(n) : std::to_string(n) + " bytes") + ")";
      return false;
    }
    values->push_back(out);
  }
  return true;
}

void writeBlocks(const FieldUpdate& u, const std::vector<const uint8_t*>& values, Field* replica) {
  const size_t bytes = size_t(Field::kBlockVoxels) * replica->channels() * sizeof(float);
  for (size_t i = 0; i < u.blocks.size(); ++i) {
    const FieldBlock& b = u.blocks[i];
    const int id = replica->allocateBlock(b.level, b.index);
    std::memcpy(replica->blockData(b.level, id), values[i], bytes);
  }
}

}  // namespace

ApplyResult applyFieldUpdate(const FieldUpdate& u, Field* replica, std::string* error,
                             GapPolicy gap_policy) {
  checkHost();
  ApplyResult result = ApplyResult::kApplied;
  FieldGeometry g;
  std::vector<const uint8_t*> values;
  std::vector<uint8_t> decoded;
  if (!checkUpdate(u, &g, &values, &decoded, error)) return ApplyResult::kInvalid;
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
  writeBlocks(u, values, replica);
  replica->setVersion(u.version);
  return result;
}

ApplyResult repairFromSnapshotChunk(const FieldUpdate& chunk, Field* replica, std::string* error) {
  checkHost();
  FieldGeometry g;
  std::vector<const uint8_t*> values;
  std::vector<uint8_t> decoded;
  if (!checkUpdate(chunk, &g, &values, &decoded, error)) return ApplyResult::kInvalid;
  if (!replica->initialized() || replica->geometry() != g) {
    *error = "snapshot chunk: geometry differs from the replica's";
    return ApplyResult::kInvalid;
  }
  writeBlocks(chunk, values, replica);
  return ApplyResult::kApplied;
}

}  // namespace radslam
