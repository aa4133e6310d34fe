// SPDX-License-Identifier: Apache-2.0
// Every program's command-line conventions: --version prints pliant::kVersion, --help the
// usage (both exit 0 on stdout), an unknown flag or a bad value exits non-zero with ONE line
// on stderr naming the flag and the value, nothing on stdout. And their JSON lines are strict
// JSON for any input: a mesh path with quotes, backslashes and non-ASCII, NaN as null.
#include "cli.hpp"
#include "pliant/test/scratch_dir.hpp"
#include "pliant/test/paths.hpp"
#include "pliant/version.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace fs = std::filesystem;

namespace {

struct ProgramRun {
  int status = -1;
  std::string out, err;
};

// Runs `program args` through the shell (stdin closed), stdout and stderr apart.
ProgramRun run(const std::string& program, const std::string& args, const fs::path& dir) {
  const fs::path err_file = dir / "stderr.txt";
  const std::string cmd = "'" + program + "' " + args + " </dev/null 2>'" + err_file.string() + "'";
  ProgramRun r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) r.out.append(buf, n);
  const int st = ::pclose(p);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  std::ifstream in(err_file);
  r.err.assign(std::istreambuf_iterator<char>(in), {});
  return r;
}

struct Program {
  std::string path;
  std::string bad_value_args;            // arguments with one bad value
  std::vector<std::string> names;        // what its one-line error must name
};

std::vector<Program> programs() {
  std::vector<Program> p = {
      {PLIANT_SERVER_BIN, "--max-scenes -3", {"--max-scenes", "-3"}},
      {PLIANT_SERVER_BIN, "--metrics-listen 127.0.0.1:70000", {"--metrics-listen", "127.0.0.1:70000"}},
      {PLIANT_SIM_BIN, "static --mesh beam1 --log-level verbose", {"--log-level", "verbose", "trace, debug, info"}},
      {PLIANT_SIM_BIN, "static --mesh beam1 --max-steps -3", {"--max-steps", "-3"}},
      {PLIANT_SIM_BIN, "frobnicate --mesh beam1", {"unknown command", "frobnicate"}},
      {PLIANT_MESH_BIN, "info --unit furlong beam1", {"--unit", "furlong"}},
      {PLIANT_HAPTIC_BIN, "--rate 5", {"--rate", "5"}},
      {PLIANT_HAPTIC_BIN, "--script wobble", {"--script", "wobble"}},
      {PLIANT_CLI_BIN, "--timeout -3 list", {"--timeout", "-3"}},
  };
#ifdef PLIANT_WEB_BIN
  p.push_back({PLIANT_WEB_BIN, "--threads 1", {"--threads", "1"}});
  p.push_back({PLIANT_WEB_BIN, "--log-level loud", {"--log-level", "loud"}});
#endif
  return p;
}

size_t lines(const std::string& s) { return static_cast<size_t>(std::count(s.begin(), s.end(), '\n')); }

}  // namespace

TEST(Programs, VersionHelpUnknownFlagAndBadValue) {
  pliant::test::ScratchDir dir;
  for (const Program& p : programs()) {
    SCOPED_TRACE(p.path);
    ProgramRun r = run(p.path, "--version", dir.path());
    EXPECT_EQ(r.status, 0) << r.err;
    EXPECT_EQ(r.out, std::string(pliant::kVersion) + "\n");
    r = run(p.path, "--help", dir.path());
    EXPECT_EQ(r.status, 0) << r.err;
    EXPECT_NE(r.out.find("usage"), std::string::npos) << r.out;
    r = run(p.path, "--no-such-flag 1", dir.path());
    EXPECT_NE(r.status, 0);
    EXPECT_NE(r.err.find("--no-such-flag"), std::string::npos) << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
    SCOPED_TRACE(p.bad_value_args);
    r = run(p.path, p.bad_value_args, dir.path());
    EXPECT_NE(r.status, 0);
    for (const std::string& n : p.names) EXPECT_NE(r.err.find(n), std::string::npos) << n << " in: " << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
  }
}

TEST(Programs, SimJsonIsStrictForAnyMeshPath) {
  pliant::test::ScratchDir dir;
  // A mesh whose file name holds quotes, a backslash and non-ASCII letters.
  const std::string stem = "cube \"q\" back\\slash \xc3\xbc\xc3\x9f";
  const fs::path data = pliant::test::source_path("tests/mesh/data");
  fs::copy_file(data / "cube.node", dir.path() / (stem + ".node"));
  fs::copy_file(data / "cube.ele", dir.path() / (stem + ".ele"));
  const std::string mesh = (dir.path() / (stem + ".node")).string();
  for (const char* cmd : {"reference", "static --max-steps 2"}) {
    SCOPED_TRACE(cmd);
    ProgramRun r = run(PLIANT_SIM_BIN, std::string(cmd) + " --quiet --mesh '" + mesh + "'", dir.path());
    ASSERT_TRUE(r.status == 0 || r.status == 4) << r.err;  // 4: not at rest after 2 steps
    nlohmann::json j;
    ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
    ASSERT_TRUE(j.is_object());
    EXPECT_NE(j["mesh"].get<std::string>().find("\"q\" back\\slash \xc3\xbc"), std::string::npos) << r.out;
    EXPECT_TRUE(r.err.empty()) << r.err;  // --quiet, and stderr is not a terminal anyway
  }
  // NaN and infinities become null; invalid UTF-8 is replaced, never written raw.
  nlohmann::ordered_json j;
  j["nan"] = std::nan("");
  j["inf"] = INFINITY;
  j["bytes"] = std::string("a\xff" "b");
  const std::string line = pliant::cli::json_line(j);
  EXPECT_EQ(line, "{\"nan\":null,\"inf\":null,\"bytes\":\"a\xef\xbf\xbd" "b\"}");
  nlohmann::json back;
  ASSERT_NO_THROW(back = nlohmann::json::parse(line)) << line;
  EXPECT_TRUE(back["nan"].is_null());
  EXPECT_TRUE(back["inf"].is_null());
  EXPECT_EQ(back["bytes"].get<std::string>(), "a\xef\xbf\xbd" "b");
}
