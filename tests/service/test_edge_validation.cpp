// SPDX-License-Identifier: Apache-2.0
// Input checked at the edge: every field of a restored snapshot (finite multipliers and time,
// ticks and ids in range, sizes matching the mesh), stream rates, and the server's flags
// (ports, intervals). Each refusal names the field and the value.
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/server/options.hpp"
#include "pliant/server/registry.hpp"
#include "pliant/server/stream_proto.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <functional>
#include <sys/wait.h>

using namespace pliant;
using server::Code;

namespace {

// A valid snapshot of a lockstep beam1 scene after a few ticks.
v1::Snapshot beam_snapshot(server::SceneRegistry& reg) {
  v1::CreateSceneRequest r;
  r.set_scene_id("src");
  r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_solver()->set_substeps(2);
  r.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  v1::Scene scene;
  EXPECT_TRUE(reg.create(r, &scene).ok());
  v1::StepRequest step;
  step.set_scene_id("src");
  step.set_ticks(3);
  v1::StepResponse stepped;
  EXPECT_TRUE(reg.step(step, std::chrono::steady_clock::now() + std::chrono::seconds(60), &stepped).ok());
  v1::SaveSnapshotRequest save;
  save.set_scene_id("src");
  v1::SaveSnapshotResponse saved;
  EXPECT_TRUE(reg.save_snapshot(save, &saved).ok());
  return saved.snapshot();
}

}  // namespace

TEST(EdgeValidation, RestoreSnapshotChecksEveryField) {
  server::SceneRegistry reg({});
  const v1::Snapshot good = beam_snapshot(reg);
  struct Case {
    std::string name;
    std::function<void(v1::Snapshot&)> edit;
    std::string says;
  };
  const std::vector<Case> cases = {
      {"nan lambda", [](auto& s) { s.set_lambda(7, NAN); }, "snapshot.lambda: tet 1 has a non-finite value"},
      {"inf lambda", [](auto& s) { s.set_lambda(0, INFINITY); }, "snapshot.lambda: tet 0 has a non-finite value"},
      {"nan sim_time", [](auto& s) { s.set_sim_time(NAN); }, "snapshot.sim_time must be a finite value >= 0 s, got nan"},
      {"negative sim_time", [](auto& s) { s.set_sim_time(-1); }, "snapshot.sim_time must be a finite value >= 0 s, got -1"},
      {"huge tick", [](auto& s) { s.set_tick(~uint64_t{0}); }, "snapshot.tick must be at most 9007199254740992"},
      {"nan x", [](auto& s) { s.set_x(4, NAN); }, "snapshot.x/v contain non-finite values"},
      {"short v", [](auto& s) { s.mutable_v()->RemoveLast(); }, "snapshot.x/v have"},
      {"short lambda", [](auto& s) { s.mutable_lambda()->RemoveLast(); }, "snapshot.lambda has"},
      {"bad version", [](auto& s) { s.set_format_version(2); }, "snapshot.format_version 2 is not supported"},
      {"too much work",
       [](auto& s) {
         s.mutable_spec()->mutable_solver()->set_substeps(10000);
         s.mutable_spec()->mutable_solver()->set_iterations(100);
       },
       "snapshot.spec.solver.substeps x snapshot.spec.solver.iterations"},
      {"huge next grab id", [](auto& s) { s.set_next_grab_id(~uint64_t{0}); }, "snapshot.next_grab_id"},
      {"huge grab id",
       [](auto& s) {
         auto* g = s.add_grabs();
         g->set_grab_id(~uint64_t{0});
         g->add_vertices(0);
         g->add_weights(1);
       },
       "snapshot.grabs[0].grab_id"},
      {"fixed vertex out of range", [](auto& s) { s.add_fixed_vertices(1 << 30); }, "fixed"},
  };
  for (const auto& c : cases) {
    v1::RestoreSnapshotRequest req;
    *req.mutable_snapshot() = good;
    req.set_scene_id("restored");
    c.edit(*req.mutable_snapshot());
    v1::Scene out;
    server::Error e = reg.restore_snapshot(req, &out);
    EXPECT_EQ(e.code, Code::InvalidArgument) << c.name << ": " << e.message;
    EXPECT_NE(e.message.find(c.says), std::string::npos) << c.name << ": " << e.message;
  }
  v1::RestoreSnapshotRequest ok;
  *ok.mutable_snapshot() = good;
  ok.set_scene_id("restored");
  v1::Scene out;
  server::Error e = reg.restore_snapshot(ok, &out);
  ASSERT_TRUE(e.ok()) << e.message;
  EXPECT_EQ(out.tick(), 3u);
}

TEST(EdgeValidation, StreamRateIsRangeChecked) {
  server::FrameSelection sel;
  for (double bad : {1e-300, 1e-3, -1.0, 1e9, double(NAN), double(INFINITY)}) {
    v1::StreamFramesRequest r;
    r.set_max_rate_hz(bad);
    server::Error e = server::parse_stream_request(r, &sel);
    EXPECT_EQ(e.code, Code::InvalidArgument) << bad;
    EXPECT_NE(e.message.find("max_rate_hz must be 0 (no limit) or in [0.01, 100000] Hz"), std::string::npos) << e.message;
  }
  for (double good : {0.0, 0.01, 60.0, 100000.0}) {
    v1::StreamFramesRequest r;
    r.set_max_rate_hz(good);
    EXPECT_TRUE(server::parse_stream_request(r, &sel).ok()) << good;
  }
}

TEST(EdgeValidation, ServerFlagsAreRangeChecked) {
  auto parse = [](std::vector<std::string> args) {
    server::ServerOptions o;
    bool help = false;
    return server::parse_server_options(args, [](const std::string&) { return std::nullopt; }, &o, &help);
  };
  struct Case {
    std::vector<std::string> args;
    std::string says;
  };
  const std::vector<Case> bad = {
      {{"--listen", "127.0.0.1:65536"}, "--listen must be HOST:PORT with a port in [0, 65535], got '127.0.0.1:65536'"},
      {{"--listen", "127.0.0.1:99999999999999999999"}, "--listen must be HOST:PORT with a port in [0, 65535]"},
      {{"--listen", "127.0.0.1:-1"}, "--listen must be HOST:PORT with a port in [0, 65535]"},
      {{"--listen", "127.0.0.1:80x"}, "--listen must be HOST:PORT with a port in [0, 65535]"},
      {{"--listen", "localhost"}, "--listen must be HOST:PORT"},
      {{"--checkpoint-ms", "10"}, "--checkpoint-ms must be 0 or at least 100, got '10'"},
      {{"--max-tick-ms", "-5"}, "--max-tick-ms must be an integer in [0, 86400000], got '-5'"},
      {{"--stuck-tick-ms", "1e3"}, "--stuck-tick-ms must be an integer"},
      {{"--listen", std::string(5000, '9')}, "(5000 characters)"},
  };
  for (const auto& c : bad) {
    server::Error e = parse(c.args);
    EXPECT_EQ(e.code, Code::InvalidArgument) << c.args[0];
    EXPECT_NE(e.message.find(c.says), std::string::npos) << e.message.substr(0, 400);
    EXPECT_LT(e.message.size(), 400u);
  }
  for (std::vector<std::string> good : {std::vector<std::string>{"--listen", "0.0.0.0:65535"},
                                        {"--listen", "[::1]:0"},
                                        {"--listen", "unix:/tmp/pliant.sock"},
                                        {"--checkpoint-ms", "0"},
                                        {"--max-tick-ms", "0", "--stuck-tick-ms", "0"}})
    EXPECT_TRUE(parse(good).ok()) << good[1];
}

// The CLI refuses a --tls-ca file it cannot read instead of trusting the system roots.
TEST(EdgeValidation, UnreadableTlsCaIsRefused) {
  const std::string cmd = std::string(PLIANT_CLI_BIN) +
                          " --address 127.0.0.1:1 --tls-ca /nonexistent/ca.pem health 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  ASSERT_NE(p, nullptr);
  std::string out;
  char buf[512];
  for (size_t n; (n = fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
  const int status = pclose(p);
  EXPECT_NE(WEXITSTATUS(status), 0) << out;
  EXPECT_NE(out.find("--tls-ca '/nonexistent/ca.pem' cannot be read as PEM certificates"), std::string::npos) << out;
}
