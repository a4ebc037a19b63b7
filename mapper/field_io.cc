#include "mapper/field_io.h"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <sstream>

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
  }
  return "?";
}

ApplyResult applyFieldUpdate(const FieldUpdate& u, Field* replica, std::string* error) {
  checkHost();
  std::string why;
  FieldGeometry g;
  if (!parseFieldLayout(u.layout, u.voxel_size, &g, &why)) {
    *error = "field update " + std::to_string(u.version) + ": " + why;
    return ApplyResult::kInvalid;
  }
  if (u.block_dim != Field::kBlockDim) {
    *error = "field update " + std::to_string(u.version) + ": block_dim " +
             std::to_string(u.block_dim) + ", this build uses " + std::to_string(Field::kBlockDim);
    return ApplyResult::kInvalid;
  }
  const size_t bytes = size_t(Field::kBlockVoxels) * g.channels() * sizeof(float);
  for (const FieldBlock& b : u.blocks) {
    if (b.level < 0 || b.level >= g.numLevels() || b.data.size() != bytes ||
        b.index.cwiseAbs().maxCoeff() > Field::kMaxBlockIndex) {
      *error = "field update " + std::to_string(u.version) + ": block (level " +
               std::to_string(b.level) + ", " + std::to_string(b.data.size()) +
               " bytes) does not fit the layout (" + std::to_string(g.numLevels()) + " levels, " +
               std::to_string(bytes) + " bytes per block)";
      return ApplyResult::kInvalid;
    }
  }
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
      return ApplyResult::kGap;
    }
    if (!replica->initialized()) *replica = Field(g);
  } else {
    *replica = Field(g);
  }
  for (const FieldBlock& b : u.blocks) {
    const int id = replica->allocateBlock(b.level, b.index);
    std::memcpy(replica->blockData(b.level, id), b.data.data(), bytes);
  }
  replica->setVersion(u.version);
  return ApplyResult::kApplied;
}

}  // namespace radslam
