// SPDX-License-Identifier: Apache-2.0
// End to end: the real pliant-server binary, driven by the real pliant CLI (through a restart;
// grab / move-grab / release) and by pliant-haptic. Paths come from CMake (PLIANT_SERVER_BIN,
// PLIANT_CLI_BIN, PLIANT_HAPTIC_BIN).
#include "pliant/test/wait_until.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <unistd.h>

namespace fs = std::filesystem;

namespace {

struct CommandResult {
  int exit_code = -1;
  std::string out;
};

CommandResult run(const std::string& args) {
  std::string cmd = std::string(PLIANT_CLI_BIN) + " " + args + " 2>&1";
  CommandResult r;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  int status = pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string read_file(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// pliant-server in a child process, its log in a file; the port is read from the log.
class ServerProcess {
 public:
  ServerProcess(const fs::path& data_dir, const fs::path& log) : log_(log) {
    pid_ = fork();
    if (pid_ == 0) {
      FILE* f = std::fopen(log.c_str(), "w");
      dup2(fileno(f), 1);
      dup2(fileno(f), 2);
      execl(PLIANT_SERVER_BIN, PLIANT_SERVER_BIN, "--listen", "127.0.0.1:0", "--data-dir", data_dir.c_str(),
            "--log-level", "info", static_cast<char*>(nullptr));
      _exit(127);
    }
    const std::regex port_re(R"(listening on .*\(port (\d+)\))");
    EXPECT_TRUE(pliant::test::wait_until(
        [&] {
          std::smatch m;
          const std::string text = read_file(log_);
          if (std::regex_search(text, m, port_re)) port_ = std::stoi(m[1]);
          return port_ != 0;
        },
        pliant::test::kPatience, "the server's 'listening on ... (port N)' log line"))
        << read_file(log_);
  }
  ~ServerProcess() {
    if (pid_ > 0) stop();
  }
  int port() const { return port_; }
  // SIGTERM and wait; returns the exit code.
  int stop() {
    kill(pid_, SIGTERM);
    int status = 0;
    waitpid(pid_, &status, 0);
    pid_ = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }
  std::string log() const { return read_file(log_); }

 private:
  fs::path log_;
  pid_t pid_ = -1;
  int port_ = 0;
};

}  // namespace

TEST(EndToEnd, ServerAndCliThroughARestart) {
  fs::path dir = fs::temp_directory_path() / ("pliant_e2e_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::string addr;
  {
    ServerProcess server(dir / "data", dir / "server1.log");
    ASSERT_GT(server.port(), 0) << server.log();
    addr = "--address 127.0.0.1:" + std::to_string(server.port());

    auto h = run(addr + " health");
    EXPECT_EQ(h.exit_code, 0) << h.out;
    EXPECT_NE(h.out.find("SERVING"), std::string::npos);

    auto c = run(addr + " scenes create e2e --mesh beam1 --fix-x-below 0.001 --mode lockstep --substeps 2 --iterations 4");
    EXPECT_EQ(c.exit_code, 0) << c.out;
    auto s = run(addr + " step e2e 10");
    EXPECT_EQ(s.exit_code, 0) << s.out;
    EXPECT_NE(s.out.find("tick 10"), std::string::npos) << s.out;

    auto rt = run(addr + " scenes create live --mesh beam1 --fix-x-below 0.001 --rate 200 --substeps 1 --iterations 2");
    EXPECT_EQ(rt.exit_code, 0) << rt.out;
    auto w = run(addr + " watch live --duration 1 --json");
    EXPECT_EQ(w.exit_code, 0) << w.out;
    for (const char* key : {"\"ticks\":", "\"ticks_per_s\":", "\"late_ticks\":", "\"frames\":",
                            "\"skipped_frames\":", "\"mean_residual\":", "\"p99_residual\":",
                            "\"mean_iterations\":"})
      EXPECT_NE(w.out.find(key), std::string::npos) << key << " in " << w.out;

    auto list = run(addr + " scenes list --json");
    EXPECT_EQ(list.exit_code, 0);
    EXPECT_NE(list.out.find("\"scene_id\":\"e2e\""), std::string::npos) << list.out;

    // Errors a shell user can act on: exit codes and messages.
    auto missing = run(addr + " scenes get nope");
    EXPECT_EQ(missing.exit_code, 4) << missing.out;
    EXPECT_NE(missing.out.find("scene_id 'nope' not found"), std::string::npos) << missing.out;
    auto bad = run(addr + " scenes create bad --poisson 0.5");
    EXPECT_EQ(bad.exit_code, 1) << bad.out;
    EXPECT_NE(bad.out.find("INVALID_ARGUMENT"), std::string::npos) << bad.out;
    auto usage = run(addr + " scenes frobnicate");
    EXPECT_EQ(usage.exit_code, 2) << usage.out;
    auto refused = run(addr + " step live 1");
    EXPECT_EQ(refused.exit_code, 1) << refused.out;
    EXPECT_NE(refused.out.find("FAILED_PRECONDITION"), std::string::npos) << refused.out;

    auto save = run(addr + " snapshot save e2e --out " + (dir / "e2e.snap").string());
    EXPECT_EQ(save.exit_code, 0) << save.out;
    EXPECT_TRUE(fs::exists(dir / "e2e.snap"));

    EXPECT_EQ(server.stop(), 0);
    EXPECT_NE(server.log().find("wrote 2 scene snapshot(s)"), std::string::npos) << server.log();
  }
  // The server is gone: health says so with the "unreachable" exit code.
  auto down = run(addr + " health --timeout 2");
  EXPECT_EQ(down.exit_code, 3) << down.out;
  {
    ServerProcess server(dir / "data", dir / "server2.log");
    ASSERT_GT(server.port(), 0) << server.log();
    addr = "--address 127.0.0.1:" + std::to_string(server.port());
    auto g = run(addr + " scenes get e2e --json");
    EXPECT_EQ(g.exit_code, 0) << g.out;
    EXPECT_NE(g.out.find("\"tick\":\"10\""), std::string::npos) << g.out;  // uint64 in JSON is a string
    auto r = run(addr + " snapshot restore --file " + (dir / "e2e.snap").string() + " --as e2e-copy");
    EXPECT_EQ(r.exit_code, 0) << r.out;
    auto s = run(addr + " step e2e-copy 5 --json");
    EXPECT_EQ(s.exit_code, 0) << s.out;
    EXPECT_NE(s.out.find("\"tick\":\"15\""), std::string::npos) << s.out;
    auto del = run(addr + " scenes delete live");
    EXPECT_EQ(del.exit_code, 0) << del.out;
    EXPECT_EQ(server.stop(), 0);
  }
  fs::remove_all(dir);
}

TEST(EndToEnd, GrabFromTheCliAndTheHapticBridgeAgainstTheServer) {
  fs::path dir = fs::temp_directory_path() / ("pliant_e2e_haptic_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  ServerProcess server(dir / "data", dir / "server.log");
  ASSERT_GT(server.port(), 0) << server.log();
  const std::string addr = "--address 127.0.0.1:" + std::to_string(server.port());

  auto c = run(addr + " scenes create g --mesh beam1 --fix-x-below 0.001 --mode lockstep");
  ASSERT_EQ(c.exit_code, 0) << c.out;
  auto g = run(addr + " grab g --vertex 215 --target 0.115,0.013,0.01");
  EXPECT_EQ(g.exit_code, 0) << g.out;
  EXPECT_NE(g.out.find("grab 1 from tick 1"), std::string::npos) << g.out;
  EXPECT_EQ(run(addr + " step g 10").exit_code, 0);
  auto m = run(addr + " --json move-grab g 1 --target 0.115,0.008,0.01");
  EXPECT_EQ(m.exit_code, 0) << m.out;
  EXPECT_NE(m.out.find("\"first_tick\":\"11\""), std::string::npos) << m.out;
  EXPECT_EQ(run(addr + " release g 1").exit_code, 0);
  auto again = run(addr + " release g 1");
  EXPECT_EQ(again.exit_code, 4) << again.out;
  EXPECT_NE(again.out.find("grab_id 1"), std::string::npos) << again.out;
  auto bad = run(addr + " grab g --vertex 99999");
  EXPECT_EQ(bad.exit_code, 1) << bad.out;
  EXPECT_NE(bad.out.find("vertex = 99999"), std::string::npos) << bad.out;

  // The bridge creates its 1 kHz scene, presses for 3 s and ends with one JSON line on stdout.
  const std::string cmd = std::string(PLIANT_HAPTIC_BIN) + " " + addr + " --duration 3 --json --quiet 2>/dev/null";
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string out;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) out.append(buf, n);
  const int status = pclose(p);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << out;
  for (const char* field : {"\"loop_hz\":", "\"period_p99_us\":", "\"rtt_p50_ms\":", "\"rtt_p99_ms\":",
                            "\"rtt_max_ms\":", "\"max_force_n\":", "\"connected\":true"})
    EXPECT_NE(out.find(field), std::string::npos) << field << " in " << out;
  const auto at = out.find("\"max_force_n\":");
  ASSERT_NE(at, std::string::npos);
  EXPECT_GT(std::stod(out.substr(at + 14)), 0.0) << out;
  EXPECT_EQ(std::count(out.begin(), out.end(), '\n'), 1) << out;
  server.stop();
  fs::remove_all(dir);
}
