#include "common/params.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <utility>

#include <opencv2/core.hpp>

namespace radslam {
namespace {

std::string trim(const std::string& s) {
  const auto not_space = [](unsigned char c) { return !std::isspace(c); };
  const auto b = std::find_if(s.begin(), s.end(), not_space);
  const auto e = std::find_if(s.rbegin(), s.rend(), not_space).base();
  return b < e ? std::string(b, e) : std::string();
}

std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// OpenCV refuses YAML without a "%YAML" directive; plain YAML files are the
// friendlier norm, so add one when the file has none.
bool hasYamlDirective(const std::string& text) {
  std::istringstream lines(text);
  std::string line;
  while (std::getline(lines, line)) {
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    return t[0] == '%';
  }
  return false;
}

std::optional<double> parseDouble(const std::string& text) {
  const std::string t = trim(text);
  if (t.empty()) return std::nullopt;
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(t.c_str(), &end);
  if (*end != '\0' || errno == ERANGE) return std::nullopt;
  return v;
}

std::optional<int> parseInt(const std::string& text) {
  const std::string t = trim(text);
  if (t.empty()) return std::nullopt;
  char* end = nullptr;
  errno = 0;
  const long v = std::strtol(t.c_str(), &end, 10);
  if (*end != '\0' || errno == ERANGE || v < INT_MIN || v > INT_MAX) return std::nullopt;
  return static_cast<int>(v);
}

std::optional<bool> parseBool(const std::string& text) {
  const std::string t = lower(trim(text));
  if (t == "true" || t == "yes" || t == "on" || t == "1") return true;
  if (t == "false" || t == "no" || t == "off" || t == "0") return false;
  return std::nullopt;
}

std::optional<std::vector<double>> parseList(const std::string& text) {
  std::string t = trim(text);
  if (!t.empty() && t.front() == '[') {
    if (t.back() != ']') return std::nullopt;
    t = trim(t.substr(1, t.size() - 2));
  }
  std::vector<double> out;
  if (t.empty()) return out;
  std::istringstream items(t);
  std::string item;
  while (std::getline(items, item, ',')) {
    const auto v = parseDouble(item);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  if (t.back() == ',') return std::nullopt;
  return out;
}

// Shortest text that reads back to exactly v.
std::string formatDouble(double v) {
  if (std::isnan(v)) return ".nan";
  if (std::isinf(v)) return v > 0 ? ".inf" : "-.inf";
  char buf[40];
  for (int precision = 6; precision <= 17; ++precision) {
    std::snprintf(buf, sizeof(buf), "%.*g", precision, v);
    if (std::strtod(buf, nullptr) == v) break;
  }
  return buf;
}

std::string quote(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}

std::string describe(const cv::FileNode& n) {
  if (n.isInt()) return "the integer " + std::to_string(static_cast<int>(n));
  if (n.isReal()) return "the number " + formatDouble(n.real());
  if (n.isString()) return "the string " + quote(n.string());
  if (n.isSeq()) return "a sequence";
  if (n.isMap()) return "a map";
  return "an empty value";
}

std::string joinQuoted(const std::vector<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "'" : ", '") + n + "'";
  return out;
}

}  // namespace

struct ParamReader::Impl {
  std::string path;
  std::string section;
  cv::FileStorage storage;  // owns the nodes below
  cv::FileNode map;         // the section (none when absent)
  bool section_found = false;
  std::vector<std::string> file_keys;
  std::map<std::string, std::string> overrides;
  std::set<std::string> asked;
  std::vector<std::pair<std::string, std::string>> in_force;  // key, YAML text

  std::string where() const {
    std::string w = "params file '" + path + "'";
    if (!section.empty()) w += " section '" + section + "'";
    return w;
  }

  [[noreturn]] void fileError(const std::string& key, const std::string& what) const {
    throw std::runtime_error(where() + ": key '" + key + "': " + what);
  }

  [[noreturn]] void overrideError(const std::string& key, const std::string& what) const {
    throw std::runtime_error("command line override '" + key + "=" + overrides.at(key) +
                             "': " + what);
  }

  // The file's value for key, or a none node.
  cv::FileNode fileValue(const std::string& key) const {
    return section_found ? map[key] : cv::FileNode();
  }

  const std::string* overrideValue(const std::string& key) const {
    const auto it = overrides.find(key);
    return it == overrides.end() ? nullptr : &it->second;
  }

  void record(const std::string& key, std::string text) {
    asked.insert(key);
    for (auto& [k, v] : in_force) {
      if (k == key) {
        v = std::move(text);
        return;
      }
    }
    in_force.emplace_back(key, std::move(text));
  }
};

ParamReader::ParamReader(const std::string& yaml_path, const std::string& section)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = yaml_path;
  impl_->section = section;
  if (yaml_path.empty()) return;
  std::ifstream file(yaml_path, std::ios::binary);
  if (!file) throw std::runtime_error("cannot open params file '" + yaml_path + "'");
  std::ostringstream content;
  content << file.rdbuf();
  std::string text = content.str();
  if (!hasYamlDirective(text)) text = "%YAML:1.0\n" + text;
  try {
    impl_->storage.open(
        text, cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_YAML);
  } catch (const cv::Exception& e) {
    // OpenCV puts the parser's message in func and the parser function in err.
    throw std::runtime_error("params file '" + yaml_path + "' is not valid YAML: " + e.func + " (" +
                             e.err + ")");
  }
  if (!impl_->storage.isOpened()) {
    throw std::runtime_error("params file '" + yaml_path + "' is not valid YAML");
  }
  const cv::FileNode root = impl_->storage.root();
  if (root.isNone()) return;  // empty file: defaults
  if (!root.isMap()) {
    throw std::runtime_error("params file '" + yaml_path + "': the top level must be a map");
  }
  cv::FileNode map = root;
  if (!section.empty()) {
    map = root[section];
    if (map.isNone()) return;  // another process's file section: defaults here
    if (!map.isMap()) {
      throw std::runtime_error(impl_->where() + ": the section must be a map of key: value");
    }
  }
  impl_->map = map;
  impl_->section_found = true;
  std::set<std::string> seen;
  for (auto it = map.begin(); it != map.end(); ++it) {
    const std::string name = (*it).name();
    if (!seen.insert(name).second) {
      throw std::runtime_error(impl_->where() + ": key '" + name + "' appears twice");
    }
    impl_->file_keys.push_back(name);
  }
}

ParamReader::~ParamReader() = default;

void ParamReader::addOverride(const std::string& assignment) {
  const size_t eq = assignment.find('=');
  const std::string key = eq == std::string::npos ? "" : trim(assignment.substr(0, eq));
  if (key.empty()) {
    throw std::runtime_error("command line override '" + assignment +
                             "' is not of the form key=value");
  }
  impl_->overrides[key] = trim(assignment.substr(eq + 1));
}

void ParamReader::get(const std::string& key, double* v) {
  const cv::FileNode n = impl_->fileValue(key);
  if (!n.isNone()) {
    if (n.isInt()) {
      *v = static_cast<int>(n);
    } else if (n.isReal()) {
      *v = n.real();
    } else {
      impl_->fileError(key, "expected a number, got " + describe(n));
    }
  }
  if (const std::string* o = impl_->overrideValue(key)) {
    const auto parsed = parseDouble(*o);
    if (!parsed) impl_->overrideError(key, "expected a number");
    *v = *parsed;
  }
  impl_->record(key, formatDouble(*v));
}

void ParamReader::get(const std::string& key, int* v) {
  const cv::FileNode n = impl_->fileValue(key);
  if (!n.isNone()) {
    if (!n.isInt()) impl_->fileError(key, "expected an integer, got " + describe(n));
    *v = static_cast<int>(n);
  }
  if (const std::string* o = impl_->overrideValue(key)) {
    const auto parsed = parseInt(*o);
    if (!parsed) impl_->overrideError(key, "expected an integer");
    *v = *parsed;
  }
  impl_->record(key, std::to_string(*v));
}

void ParamReader::get(const std::string& key, bool* v) {
  const cv::FileNode n = impl_->fileValue(key);
  if (!n.isNone()) {
    std::optional<bool> parsed;
    if (n.isString()) parsed = parseBool(n.string());
    if (n.isInt() && (static_cast<int>(n) == 0 || static_cast<int>(n) == 1)) {
      parsed = static_cast<int>(n) == 1;
    }
    if (!parsed) {
      impl_->fileError(key, "expected true or false, got " + describe(n));
    }
    *v = *parsed;
  }
  if (const std::string* o = impl_->overrideValue(key)) {
    const auto parsed = parseBool(*o);
    if (!parsed) impl_->overrideError(key, "expected true or false");
    *v = *parsed;
  }
  impl_->record(key, *v ? "true" : "false");
}

void ParamReader::get(const std::string& key, std::string* v) {
  const cv::FileNode n = impl_->fileValue(key);
  if (!n.isNone()) {
    if (!n.isString()) {
      impl_->fileError(key, "expected a string, got " + describe(n) + " (quote numbers: \"07\")");
    }
    *v = n.string();
  }
  if (const std::string* o = impl_->overrideValue(key)) *v = *o;
  impl_->record(key, quote(*v));
}

void ParamReader::get(const std::string& key, std::vector<double>* v) {
  const cv::FileNode n = impl_->fileValue(key);
  if (!n.isNone()) {
    if (!n.isSeq()) impl_->fileError(key, "expected a sequence of numbers, got " + describe(n));
    std::vector<double> values;
    for (auto it = n.begin(); it != n.end(); ++it) {
      const cv::FileNode item = *it;
      if (item.isInt()) {
        values.push_back(static_cast<int>(item));
      } else if (item.isReal()) {
        values.push_back(item.real());
      } else {
        impl_->fileError(key, "element " + std::to_string(values.size()) +
                                  " of the sequence: expected a number, got " + describe(item));
      }
    }
    *v = std::move(values);
  }
  if (const std::string* o = impl_->overrideValue(key)) {
    auto parsed = parseList(*o);
    if (!parsed) impl_->overrideError(key, "expected a list of numbers like 1,2,3");
    *v = std::move(*parsed);
  }
  std::string text = "[";
  for (size_t i = 0; i < v->size(); ++i) text += (i ? ", " : "") + formatDouble((*v)[i]);
  impl_->record(key, text + "]");
}

void ParamReader::finish() const {
  std::vector<std::string> unknown_file, unknown_override;
  for (const auto& key : impl_->file_keys) {
    if (!impl_->asked.count(key)) unknown_file.push_back(key);
  }
  for (const auto& [key, value] : impl_->overrides) {
    if (!impl_->asked.count(key)) unknown_override.push_back(key);
  }
  if (unknown_file.empty() && unknown_override.empty()) return;
  std::string known;
  for (const auto& [key, value] : impl_->in_force) known += (known.empty() ? "" : ", ") + key;
  std::string message;
  if (!unknown_file.empty()) {
    message = impl_->where() + ": unknown key" + (unknown_file.size() > 1 ? "s " : " ") +
              joinQuoted(unknown_file);
  }
  if (!unknown_override.empty()) {
    if (!message.empty()) message += "; ";
    message += std::string("command line override") +
               (unknown_override.size() > 1 ? "s for unknown keys " : " for unknown key ") +
               joinQuoted(unknown_override);
  }
  throw std::runtime_error(message + " (known: " + known + ")");
}

std::string ParamReader::dump() const {
  std::string out;
  for (const auto& [key, text] : impl_->in_force) out += key + ": " + text + "\n";
  return out;
}

std::string ParamReader::source() const {
  if (impl_->path.empty()) return "defaults";
  if (impl_->section.empty()) return impl_->path;
  if (!impl_->section_found)
    return impl_->path + " (no section '" + impl_->section + "': defaults)";
  return impl_->path + " (section '" + impl_->section + "')";
}

}  // namespace radslam
