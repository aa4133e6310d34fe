// SPDX-License-Identifier: Apache-2.0
#include "cli.hpp"

#include <cmath>
#include <cstdlib>

namespace pliant::cli {

Args::Args(int argc, char** argv, int first, const std::set<std::string>& valued,
           const std::set<std::string>& flags) {
  for (int i = first; i < argc; ++i) {
    std::string a = argv[i];
    if (a.rfind("--", 0) != 0) {
      positional_.push_back(a);
      continue;
    }
    std::string name = a.substr(2), value;
    if (auto eq = name.find('='); eq != std::string::npos) {
      value = name.substr(eq + 1);
      name = name.substr(0, eq);
      if (!valued.count(name)) throw UsageError("unknown or valueless option --" + name);
      values_[name] = value;
      continue;
    }
    if (flags.count(name)) {
      values_.insert_or_assign(name, std::string("1"));  // not operator=(const char*): GCC 12 -Wrestrict false positive
    } else if (valued.count(name)) {
      if (i + 1 >= argc) throw UsageError("option --" + name + " needs a value");
      values_[name] = argv[++i];
    } else {
      throw UsageError("unknown option --" + name);
    }
  }
}

std::optional<std::string> Args::str(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::string Args::str(const std::string& name, const std::string& fallback) const {
  return str(name).value_or(fallback);
}

double parse_number(const std::string& name, const std::string& text) {
  auto parse = [&](const std::string& s) {
    char* end = nullptr;
    double v = std::strtod(s.c_str(), &end);
    if (s.empty() || end != s.c_str() + s.size() || !std::isfinite(v))
      throw UsageError("--" + name + ": '" + text + "' is not a number");
    return v;
  };
  if (auto slash = text.find('/'); slash != std::string::npos) {
    double d = parse(text.substr(slash + 1));
    if (d == 0) throw UsageError("--" + name + ": '" + text + "' divides by zero");
    return parse(text.substr(0, slash)) / d;
  }
  return parse(text);
}

std::optional<double> Args::number(const std::string& name) const {
  auto s = str(name);
  if (!s) return std::nullopt;
  return parse_number(name, *s);
}

double Args::number(const std::string& name, double fallback) const {
  return number(name).value_or(fallback);
}

long Args::integer(const std::string& name, long fallback, long min, long max) const {
  auto s = str(name);
  if (!s) return fallback;
  char* end = nullptr;
  long v = std::strtol(s->c_str(), &end, 10);
  if (s->empty() || end != s->c_str() + s->size())
    throw UsageError("--" + name + ": '" + *s + "' is not an integer");
  if (v < min || v > max)
    throw UsageError("--" + name + ": " + *s + " is out of range [" + std::to_string(min) + ", " +
                     std::to_string(max) + "]");
  return v;
}

}  // namespace pliant::cli
