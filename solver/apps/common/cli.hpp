// SPDX-License-Identifier: Apache-2.0
// Command-line plumbing shared by Pliant's programs: CLI11 errors as one line, a validator for
// a fixed set of words, JSON lines through nlohmann-json (strict JSON for any input: escaped
// strings, invalid UTF-8 replaced, NaN and infinities as null), a progress reporter for long
// runs on a terminal, and the typed option getters of the offline tools (pliant-sim).
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace pliant::cli {

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Parses argv with `app`; on --help or --version prints them to stdout and returns 0, on a bad
// flag or value prints "PROGRAM: MESSAGE" (one line) to stderr and returns 2. Returns nullopt
// when the program should go on.
std::optional<int> parse_or_exit(CLI::App& app, int argc, char** argv, const std::string& program);

// The one-line form of a CLI11 error (CLI11's own messages, newlines folded).
std::string one_line(const std::string& message);

// Accepts exactly one of `words`; the error names the accepted ones.
CLI::Validator one_of(const std::vector<std::string>& words);

// spdlog's levels as the --log-level flags accept them.
const std::vector<std::string>& log_levels();

// A JSON value as one line of strict JSON (field order kept with ordered_json).
std::string json_line(const nlohmann::ordered_json& j);

// The 1-minute load average (/proc/loadavg), -1 where it cannot be read: measuring programs
// print it beside their timings.
double load_average();

// The options a tool's subcommand was given, by name without "--", with typed getters that
// fail with a one-line message naming the option.
class Args {
 public:
  Args() = default;
  explicit Args(std::map<std::string, std::string> values) : values_(std::move(values)) {}

  bool has(const std::string& name) const { return values_.count(name) > 0; }
  std::optional<std::string> str(const std::string& name) const;
  std::string str(const std::string& name, const std::string& fallback) const;
  double number(const std::string& name, double fallback) const;
  std::optional<double> number(const std::string& name) const;
  long integer(const std::string& name, long fallback, long min, long max) const;

 private:
  std::map<std::string, std::string> values_;
};

// Registers `valued` names as "--name VALUE" and `flags` as "--name" on `app`; what the user
// gives lands in *into (the last of repeated options wins; a flag's value is "1").
void add_options(CLI::App& app, const std::set<std::string>& valued, const std::set<std::string>& flags,
                 std::map<std::string, std::string>* into);

// Parses "A,B" (two integers, each at least `min`) for a flag such as --big SUBSTEPS,ITERATIONS;
// throws CLI::ValidationError naming the flag and the value.
void parse_int_pair(const std::string& flag, const std::string& text, int min, int* a, int* b);

// Parses a number that may be a fraction like "1/60".
double parse_number(const std::string& name, const std::string& text);

// Progress of a long run on stderr: every `period` a line "PROGRAM: [12 s] TEXT" with the
// latest text set by the run. Silent when disabled (--quiet, or stderr not a terminal) and for
// runs shorter than one period. Never writes to stdout.
class Progress {
 public:
  Progress(std::string program, bool enabled, std::chrono::milliseconds period = std::chrono::seconds(2));
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;

  void set(std::string text);
  bool enabled() const { return enabled_; }

  // Whether progress should show by default: stderr is a terminal.
  static bool stderr_is_terminal();

 private:
  void loop();
  std::string program_;
  bool enabled_;
  std::chrono::milliseconds period_;
  std::chrono::steady_clock::time_point start_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::string text_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace pliant::cli
