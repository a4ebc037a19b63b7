#include "common/control.h"

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

}  // namespace radslam
