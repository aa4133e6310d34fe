// SPDX-License-Identifier: Apache-2.0
// A fresh directory under the system temp dir for one test, removed when it goes out of scope.
#pragma once

#include <filesystem>
#include <string>

namespace pliant::test {

class ScratchDir {
 public:
  // Named after `prefix`, the running test and the process, so that parallel runs do not meet.
  explicit ScratchDir(const std::string& prefix = "pliant-test");
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::filesystem::path& path() const { return path_; }
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  // Writes `content` (bytes as given) to `name` in the directory; returns its path.
  std::string write(const std::string& name, const std::string& content) const;

 private:
  std::filesystem::path path_;
};

}  // namespace pliant::test
