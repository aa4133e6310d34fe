// SPDX-License-Identifier: Apache-2.0
// FixedSelection.groups: a Gmsh file's physical group fixed by name or tag, resolved by the
// server when it loads the mesh (tests/mesh/data/beam_groups_v41.msh: surface "clamp" is the
// face x = 0); unknown groups and meshes without groups are refused with the field named; the
// pliant CLI's --fix-group sends the same.
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/paths.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <sys/wait.h>

#include <algorithm>
#include <cstdio>

using namespace pliant;
using client::Client;

namespace {

const bool quiet_logs = [] {
  spdlog::set_level(spdlog::level::warn);
  return true;
}();

constexpr int kInvalidArgument = 3;

struct GroupServer {
  std::unique_ptr<server::PliantServer> server;
  std::string address;
  GroupServer() {
    server::ServerOptions o;
    o.listen = "127.0.0.1:0";
    o.model_path = pliant::test::source_path("tests/mesh/data");
    server = std::make_unique<server::PliantServer>(o);
    auto e = server->start();
    EXPECT_TRUE(e.ok()) << e.message;
    address = "127.0.0.1:" + std::to_string(server->port());
  }
  Client client() const {
    client::ConnectOptions c;
    c.address = address;
    c.timeout = std::chrono::seconds(60);
    return Client(c);
  }
};

v1::CreateSceneRequest beam(const std::string& id, const std::string& mesh, std::vector<std::string> groups) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_model_path(mesh);
  for (auto& g : groups) s->mutable_fixed()->add_groups(g);
  s->mutable_material()->set_young_modulus(1e5);
  s->mutable_solver()->set_method(v1::METHOD_XPBD);
  s->mutable_solver()->set_substeps(8);
  s->mutable_solver()->set_iterations(2);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  return r;
}

std::vector<int32_t> fixed_of(Client& c, const std::string& id) {
  auto t = c.topology(id);
  EXPECT_TRUE(t.ok()) << t.status.to_string();
  if (!t.ok()) return {};
  std::vector<int32_t> f(t->fixed_vertices().begin(), t->fixed_vertices().end());
  std::sort(f.begin(), f.end());
  return f;
}

}  // namespace

TEST(FixedGroups, APhysicalSurfaceHoldsTheBeamWhileGravityBendsIt) {
  GroupServer s;
  Client c = s.client();
  auto r = c.create_scene(beam("g", "beam_groups_v41.msh", {"clamp"}));
  ASSERT_TRUE(r.ok()) << r.status.to_string();
  ASSERT_EQ(r->spec().fixed().groups_size(), 1);  // GetScene shows the group as asked
  EXPECT_EQ(r->spec().fixed().groups(0), "clamp");
  EXPECT_EQ(r->spec().fixed().indices_size(), 0);

  auto topo = c.topology("g");
  ASSERT_TRUE(topo.ok());
  const std::vector<int32_t> fixed = fixed_of(c, "g");
  ASSERT_EQ(fixed.size(), 4u);
  for (int32_t v : fixed) EXPECT_EQ(topo->rest_positions(3 * v), 0.0) << v;  // the face x = 0

  ASSERT_TRUE(c.step("g", 30).ok());
  v1::SaveSnapshotRequest save;
  save.set_scene_id("g");
  auto snap = c.save_snapshot(save);
  ASSERT_TRUE(snap.ok()) << snap.status.to_string();
  const auto& x = snap->snapshot().x();
  double tip_drop = 0;
  for (int v = 0; v < static_cast<int>(topo->vertex_count()); ++v) {
    const bool is_fixed = std::binary_search(fixed.begin(), fixed.end(), v);
    const double dy = x[3 * v + 1] - topo->rest_positions(3 * v + 1);
    if (is_fixed) {
      EXPECT_NEAR(dy, 0.0, 1e-7) << "fixed vertex " << v << " moved";  // float32 rest positions
    }
    tip_drop = std::min(tip_drop, dy);
  }
  EXPECT_LT(tip_drop, -1e-5) << "the free end did not sag under gravity";

  // By physical tag, and two groups at once (their union).
  ASSERT_TRUE(c.create_scene(beam("tag", "beam_groups_v22.msh", {"2"})).ok());
  EXPECT_EQ(fixed_of(c, "tag").size(), 4u);
  ASSERT_TRUE(c.create_scene(beam("two", "beam_groups_v41b.msh", {"clamp", "tip"})).ok());
  EXPECT_EQ(fixed_of(c, "two").size(), 5u);
}

TEST(FixedGroups, UnknownGroupsAndMeshesWithoutGroupsAreRefused) {
  GroupServer s;
  Client c = s.client();
  auto r = c.create_scene(beam("bad", "beam_groups_v41.msh", {"clamp", "lid"}));
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status.code, kInvalidArgument);
  for (const char* says : {"spec.fixed.groups[1]", "'lid'", "\"clamp\" (surface, 4 vertices)"})
    EXPECT_NE(r.status.message.find(says), std::string::npos) << says << " in " << r.status.message;

  v1::CreateSceneRequest builtin = beam("b", "x", {"clamp"});
  builtin.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  r = c.create_scene(builtin);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status.code, kInvalidArgument);
  EXPECT_NE(r.status.message.find("has no physical groups"), std::string::npos) << r.status.message;

  r = c.create_scene(beam("empty", "beam_groups_v41.msh", {""}));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status.message.find("spec.fixed.groups[0] is empty"), std::string::npos) << r.status.message;
}

TEST(FixedGroups, TheCliSendsFixGroup) {
  GroupServer s;
  auto run = [&](const std::string& args, std::string* out) {
    const std::string cmd = std::string(PLIANT_CLI_BIN) + " --address " + s.address + " " + args + " 2>&1";
    FILE* p = popen(cmd.c_str(), "r");
    if (!p) return -1;
    char buf[4096];
    out->clear();
    for (size_t n; (n = fread(buf, 1, sizeof buf, p)) > 0;) out->append(buf, n);
    const int st = pclose(p);
    return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  };
  std::string out;
  ASSERT_EQ(run("scenes create cli --mesh beam_groups_v41.msh --fix-group clamp --fix-group 3 --mode lockstep", &out), 0)
      << out;
  Client c = s.client();
  EXPECT_EQ(fixed_of(c, "cli").size(), 5u);
  EXPECT_EQ(run("scenes create nope --mesh beam_groups_v41.msh --fix-group lid", &out), 1) << out;
  EXPECT_NE(out.find("spec.fixed.groups[0] 'lid'"), std::string::npos) << out;
}
