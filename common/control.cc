#include "common/control.h"

#include <cerrno>
#include <cstdlib>
#include <sstream>

namespace radslam {

bool parseKeyframeRequest(const std::string& argument, std::vector<int32_t>* ids) {
  ids->clear();
  if (argument.empty() || argument == "keyframes") return true;
  if (argument.rfind("keyframes:", 0) != 0) return false;
  std::stringstream list(argument.substr(10));
  std::string id;
  while (std::getline(list, id, ',')) {
    char* end = nullptr;
    const long v = std::strtol(id.c_str(), &end, 10);
    if (end && !*end && !id.empty() && v >= 0 && v <= INT32_MAX)
      ids->push_back(static_cast<int32_t>(v));
  }
  return !ids->empty();
}

bool parseRewindRequest(const std::string& argument, int64_t* frame_index, std::string* token) {
  const size_t colon = argument.find(':');
  if (colon == 0 || colon == std::string::npos) return false;
  const std::string number = argument.substr(0, colon);
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(number.c_str(), &end, 10);
  if (errno != 0 || !end || *end || v < 0) return false;
  *frame_index = v;
  *token = argument.substr(colon + 1);
  return true;
}

std::string rewindRequest(int64_t frame_index, const std::string& token) {
  return std::to_string(frame_index) + ":" + token;
}

}  // namespace radslam
