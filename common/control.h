// Arguments of CONTROL commands (channel CONTROL, types.h), parsed the same way by every
// process that serves them.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace radslam {

/// A REPUBLISH argument naming keyframes: "" or "keyframes" = all (*ids empty),
/// "keyframes:3,7" = those ids (unusable entries are dropped). False for any other argument,
/// and for a list with no usable id.
bool parseKeyframeRequest(const std::string& argument, std::vector<int32_t>* ids);

/// A REWIND argument: "FRAME:TOKEN", the frame index to play again from and the requester's
/// token (one request may arrive several times: it is repeated until served). False when
/// malformed or the frame is negative.
bool parseRewindRequest(const std::string& argument, int64_t* frame_index, std::string* token);
std::string rewindRequest(int64_t frame_index, const std::string& token);

}  // namespace radslam
