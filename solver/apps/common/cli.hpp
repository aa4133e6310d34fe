// SPDX-License-Identifier: Apache-2.0
// Minimal command-line parsing shared by Pliant's offline tools: "--name value" and
// "--flag" options after a subcommand, with typed getters that fail with a one-line message
// naming the argument. (The gRPC tools have their own richer front end.)
#pragma once

#include <map>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace pliant::cli {

class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class Args {
 public:
  // `flags` take no value; every other "--x" takes exactly one. Unknown names are errors.
  Args(int argc, char** argv, int first, const std::set<std::string>& valued,
       const std::set<std::string>& flags);

  bool has(const std::string& name) const { return values_.count(name) > 0; }
  std::optional<std::string> str(const std::string& name) const;
  std::string str(const std::string& name, const std::string& fallback) const;
  double number(const std::string& name, double fallback) const;
  std::optional<double> number(const std::string& name) const;
  long integer(const std::string& name, long fallback, long min, long max) const;
  const std::vector<std::string>& positional() const { return positional_; }

 private:
  std::map<std::string, std::string> values_;
  std::vector<std::string> positional_;
};

// Parses a number that may be a fraction like "1/60".
double parse_number(const std::string& name, const std::string& text);

}  // namespace pliant::cli
