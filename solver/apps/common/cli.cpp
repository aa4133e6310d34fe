// SPDX-License-Identifier: Apache-2.0
#include "cli.hpp"

#include <fstream>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <unistd.h>

namespace pliant::cli {

std::string one_line(const std::string& message) {
  std::string s;
  for (char c : message) s += (c == '\n' || c == '\r') ? ' ' : c;
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s;
}

std::optional<int> parse_or_exit(CLI::App& app, int argc, char** argv, const std::string& program) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "%s: %s (see %s --help)\n", program.c_str(), one_line(e.what()).c_str(), program.c_str());
    return 2;
  }
  return std::nullopt;
}

CLI::Validator one_of(const std::vector<std::string>& words) {
  std::string list;
  for (const std::string& w : words) list += (list.empty() ? "" : ", ") + w;
  return CLI::Validator(
      [words, list](std::string& value) -> std::string {
        for (const std::string& w : words)
          if (value == w) return {};
        return "must be one of " + list + ", got '" + value + "'";
      },
      "one of: " + list);
}

const std::vector<std::string>& log_levels() {
  static const std::vector<std::string> levels = {"trace", "debug", "info", "warn", "error", "critical", "off"};
  return levels;
}

std::string json_line(const nlohmann::ordered_json& j) {
  return j.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace);
}

std::optional<std::string> Args::str(const std::string& name) const {
  auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::string Args::str(const std::string& name, const std::string& fallback) const {
  return str(name).value_or(fallback);
}

void add_options(CLI::App& app, const std::set<std::string>& valued, const std::set<std::string>& flags,
                 std::map<std::string, std::string>* into) {
  for (const std::string& name : valued)
    app.add_option_function<std::string>("--" + name, [into, name](const std::string& v) { (*into)[name] = v; })
        ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  for (const std::string& name : flags)
    app.add_flag_callback("--" + name, [into, name] { (*into)[name] = "1"; });
}

void parse_int_pair(const std::string& flag, const std::string& text, int min, int* a, int* b) {
  const size_t comma = text.find(',');
  auto one = [&](const std::string& s, int* out) {
    char* end = nullptr;
    const long v = std::strtol(s.c_str(), &end, 10);
    if (s.empty() || *end != '\0' || v < min || v > 1'000'000) return false;
    *out = static_cast<int>(v);
    return true;
  };
  int x = 0, y = 0;
  if (comma == std::string::npos || !one(text.substr(0, comma), &x) || !one(text.substr(comma + 1), &y))
    throw CLI::ValidationError(flag + " must be two integers A,B, each at least " + std::to_string(min) + ", got '" +
                               text + "'");
  *a = x;
  *b = y;
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

Progress::Progress(std::string program, bool enabled, std::chrono::milliseconds period)
    : program_(std::move(program)), enabled_(enabled), period_(period), start_(std::chrono::steady_clock::now()) {
  if (enabled_) thread_ = std::thread([this] { loop(); });
}

Progress::~Progress() {
  if (!thread_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void Progress::set(std::string text) {
  if (!enabled_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  text_ = std::move(text);
}

bool Progress::stderr_is_terminal() { return ::isatty(STDERR_FILENO) == 1; }

void Progress::loop() {
  std::unique_lock<std::mutex> lock(mutex_);
  auto next = start_ + period_;
  while (!wake_.wait_until(lock, next, [this] { return stop_; })) {
    next += period_;
    if (text_.empty()) continue;
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    std::fprintf(stderr, "%s: [%.0f s] %s\n", program_.c_str(), s, text_.c_str());
    std::fflush(stderr);
  }
}

double load_average() {
  std::ifstream f("/proc/loadavg");
  double v = -1.0;
  if (f) f >> v;
  return v;
}

}  // namespace pliant::cli
