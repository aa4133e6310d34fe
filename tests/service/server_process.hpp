// SPDX-License-Identifier: Apache-2.0
// pliant-server (the real binary, PLIANT_SERVER_BIN) in a child process for the service tests
// that restart or kill it: its log goes to a file, its port is read from the log. With the
// small scene those tests load it with.
#pragma once

#include "pliant/client/client.hpp"

#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>
#include <vector>

namespace pliant::test {

namespace fs = std::filesystem;

inline std::string read_text(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// beam1 clamped at x = 0, 2 substeps x 2 iterations: cheap enough for many scenes at once.
inline v1::CreateSceneRequest beam1_request(const std::string& id, v1::TickMode mode) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_solver()->set_substeps(2);
  r.mutable_spec()->mutable_solver()->set_iterations(2);
  r.mutable_spec()->mutable_tick()->set_mode(mode);
  return r;
}

class ServerProcess {
 public:
  ServerProcess(const fs::path& data, const fs::path& log, std::vector<std::string> extra = {}) : log_(log) {
    std::vector<std::string> args = {PLIANT_SERVER_BIN, "--listen", "127.0.0.1:0", "--data-dir", data.string(),
                                     "--log-level", "info"};
    args.insert(args.end(), extra.begin(), extra.end());
    pid_ = fork();
    if (pid_ == 0) {
      FILE* f = std::fopen(log.c_str(), "w");
      dup2(fileno(f), 1);
      dup2(fileno(f), 2);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(PLIANT_SERVER_BIN, argv.data());
      _exit(127);
    }
    const std::regex port_re(R"(listening on .*\(port (\d+)\))");
    for (int i = 0; i < 3000 && port_ == 0; ++i) {
      std::smatch m;
      const std::string text = read_text(log_);
      if (std::regex_search(text, m, port_re)) port_ = std::stoi(m[1]);
      else std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  ~ServerProcess() {
    if (pid_ > 0) kill_now();
  }
  int port() const { return port_; }
  pid_t pid() const { return pid_; }
  client::Client client() const {
    client::ConnectOptions c;
    c.address = "127.0.0.1:" + std::to_string(port_);
    c.timeout = std::chrono::seconds(20);
    c.step_timeout = std::chrono::seconds(20);
    return client::Client(c);
  }
  void kill_now() {
    ::kill(pid_, SIGKILL);
    int status = 0;
    waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  // SIGTERM, then waits up to `limit` for the exit. The exit code, or -1 if it did not exit
  // (then it is killed).
  int terminate(std::chrono::seconds limit) {
    ::kill(pid_, SIGTERM);
    const auto end = std::chrono::steady_clock::now() + limit;
    int status = 0;
    while (std::chrono::steady_clock::now() < end) {
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    kill_now();
    return -1;
  }
  std::string log() const { return read_text(log_); }

 private:
  fs::path log_;
  pid_t pid_ = -1;
  int port_ = 0;
};

}  // namespace pliant::test
