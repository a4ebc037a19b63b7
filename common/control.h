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

}  // namespace radslam
