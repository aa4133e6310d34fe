// SPDX-License-Identifier: Apache-2.0
// Bounded work per tick: the sweeps a tick may ask for are limited; update, reset, pause,
// delete and shutdown stop a tick in progress at its next sweep; --max-tick-ms stops a tick
// that runs too long and pauses its scene; a tick stuck past --stuck-tick-ms turns health
// NOT_SERVING. The "slow" scene's tick would take minutes: every call below is bounded by a
// client deadline far shorter than that, so a tick that cannot be interrupted fails the test.
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/server/registry.hpp"
#include "pliant/server/server.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <future>
#include <thread>

namespace fs = std::filesystem;
using namespace pliant;
using client::Client;

namespace {

using namespace test::grpc_codes;

// A 2,875-tet beam at the sweep limit (2000 substeps x 100 iterations): minutes per tick.
v1::CreateSceneRequest slow_request(const std::string& id, v1::TickMode mode) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  const TetMesh beam = make_beam(24, 6, 6, 0.01);
  auto* d = s->mutable_mesh()->mutable_data();
  d->set_name("slow-beam");
  for (const Vec3& p : beam.vertices)
    for (int k = 0; k < 3; ++k) d->add_positions(p[k]);
  for (const auto& t : beam.tets)
    for (int k = 0; k < 4; ++k) d->add_tets(t[k]);
  client::clamp_below_x(*s, 1e-3);
  s->mutable_solver()->set_substeps(2000);
  s->mutable_solver()->set_iterations(100);
  s->mutable_tick()->set_mode(mode);
  return r;
}

v1::CreateSceneRequest small_request(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  return r;
}

struct Server : test::InProcessServer {
  explicit Server(server::ServerOptions o)
      : InProcessServer(std::move(o), {std::chrono::seconds(20), std::chrono::seconds(20)}) {}
  // Waits (at most 20 s) until the scene's tick thread is inside a tick.
  bool wait_ticking(const std::string& id) {
    std::shared_ptr<server::Scene> scene;
    if (!registry().find(id, &scene).ok()) return false;
    for (int i = 0; i < 2000; ++i) {
      if (scene->tick_running_for() > std::chrono::steady_clock::duration::zero()) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  }
};

server::ServerOptions no_tick_limits() {
  server::ServerOptions o;
  o.max_tick_ms = 0;
  o.stuck_tick_ms = 0;
  return o;
}

}  // namespace

TEST(BoundedWork, SweepsPerTickAreLimited) {
  server::SceneRegistry reg({});
  auto req = small_request("heavy");
  req.mutable_spec()->mutable_solver()->set_substeps(10000);
  req.mutable_spec()->mutable_solver()->set_iterations(100000);
  v1::Scene out;
  server::Error e = reg.create(req, &out);
  EXPECT_EQ(e.code, server::Code::InvalidArgument);
  EXPECT_EQ(e.message, "spec.solver.substeps x spec.solver.iterations = 10000 x 100000 = 1000000000 sweeps per tick, "
                       "more than this server's limit of 200000 (lower either, or use time_budget_ms)");
  req.mutable_spec()->mutable_solver()->set_iterations(21);
  EXPECT_EQ(reg.create(req, &out).code, server::Code::InvalidArgument);
  req.mutable_spec()->mutable_solver()->set_iterations(20);  // 200,000: at the limit
  ASSERT_TRUE(reg.create(req, &out).ok());

  v1::UpdateSceneRequest up;
  up.set_scene_id("heavy");
  up.mutable_solver()->set_iterations(40);
  e = reg.update(up, &out);
  EXPECT_EQ(e.code, server::Code::InvalidArgument);
  EXPECT_NE(e.message.find("solver.substeps x solver.iterations = 10000 x 40"), std::string::npos) << e.message;
  EXPECT_TRUE(reg.remove("heavy").ok());
}

TEST(BoundedWork, CommandsInterruptALongTick) {
  Server s(no_tick_limits());
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(slow_request("slow", v1::TICK_MODE_REALTIME)).ok());

  // Update: the tick in progress is dropped, the new settings take effect.
  ASSERT_TRUE(s.wait_ticking("slow"));
  v1::UpdateSceneRequest fast;
  fast.set_scene_id("slow");
  fast.mutable_solver()->set_substeps(1);
  fast.mutable_solver()->set_iterations(1);
  auto updated = c.update_scene(fast);
  ASSERT_TRUE(updated.ok()) << updated.status.to_string();
  EXPECT_EQ(updated->spec().solver().substeps(), 1);
  EXPECT_EQ(updated->spec().solver().iterations(), 1);
  uint64_t tick = 0;
  for (int i = 0; i < 2000 && tick < 3; ++i) {
    auto g = c.get_scene("slow");
    ASSERT_TRUE(g.ok());
    tick = g->tick();
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_GE(tick, 3u);

  // Back to the slow settings: reset, pause and delete each act on the tick in progress.
  v1::UpdateSceneRequest slow;
  slow.set_scene_id("slow");
  slow.mutable_solver()->set_substeps(2000);
  slow.mutable_solver()->set_iterations(100);
  ASSERT_TRUE(c.update_scene(slow).ok());
  ASSERT_TRUE(s.wait_ticking("slow"));
  auto reset = c.reset_scene("slow");
  ASSERT_TRUE(reset.ok()) << reset.status.to_string();
  EXPECT_EQ(reset->tick(), 0u);
  ASSERT_TRUE(s.wait_ticking("slow"));
  auto paused = c.pause_scene("slow");
  ASSERT_TRUE(paused.ok()) << paused.status.to_string();
  EXPECT_EQ(paused->state(), v1::SCENE_STATE_PAUSED);
  ASSERT_TRUE(c.resume_scene("slow").ok());
  ASSERT_TRUE(s.wait_ticking("slow"));
  auto deleted = c.delete_scene("slow");
  EXPECT_TRUE(deleted.ok()) << deleted.to_string();
  EXPECT_EQ(c.get_scene("slow").status.code, 5);
}

TEST(BoundedWork, ShutdownInterruptsALongTickAndSavesTheStateBeforeIt) {
  const fs::path data = fs::temp_directory_path() / ("pliant_bounded_" + std::to_string(::getpid()));
  fs::remove_all(data);
  server::ServerOptions o = no_tick_limits();
  o.data_dir = data.string();
  Server s(o);
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(slow_request("slow", v1::TICK_MODE_REALTIME)).ok());
  ASSERT_TRUE(s.wait_ticking("slow"));
  auto done = std::async(std::launch::async, [&] { return s.server->shutdown(); });
  ASSERT_EQ(done.wait_for(std::chrono::seconds(30)), std::future_status::ready);
  EXPECT_EQ(done.get(), 1);
  EXPECT_FALSE(s.server->save_failed());
  v1::Snapshot snap;
  std::ifstream f(data / "scenes" / "slow.snapshot", std::ios::binary);
  ASSERT_TRUE(snap.ParseFromIstream(&f));
  EXPECT_EQ(snap.tick(), 0u);
  EXPECT_EQ(snap.sim_time(), 0.0);
  fs::remove_all(data);
}

TEST(BoundedWork, MaxTickStopsTheTickAndPausesTheScene) {
  server::ServerOptions o = no_tick_limits();
  o.max_tick_ms = 200;
  Server s(o);
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(slow_request("rt", v1::TICK_MODE_REALTIME)).ok());
  v1::Scene scene;
  for (int i = 0; i < 3000 && scene.pause_reason().empty(); ++i) {
    auto g = c.get_scene("rt");
    ASSERT_TRUE(g.ok());
    scene = *g;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(scene.state(), v1::SCENE_STATE_PAUSED);
  EXPECT_EQ(scene.tick(), 0u);
  EXPECT_NE(scene.pause_reason().find("a tick ran longer than this server's --max-tick-ms 200"), std::string::npos)
      << scene.pause_reason();

  // Lockstep: the Step fails with the reason; the scene stays at its last tick.
  ASSERT_TRUE(c.create_scene(slow_request("ls", v1::TICK_MODE_LOCKSTEP)).ok());
  auto step = c.step("ls", 1);
  EXPECT_EQ(step.status.code, kResourceExhausted) << step.status.to_string();
  EXPECT_NE(step.status.message.find("--max-tick-ms 200"), std::string::npos) << step.status.message;
  auto ls = c.get_scene("ls");
  ASSERT_TRUE(ls.ok());
  EXPECT_EQ(ls->tick(), 0u);
  EXPECT_EQ(ls->state(), v1::SCENE_STATE_LOCKSTEP);
}

TEST(BoundedWork, HealthIsNotServingWhileATickIsStuck) {
  server::ServerOptions o = no_tick_limits();
  o.stuck_tick_ms = 200;
  Server s(o);
  Client c = s.client();
  ASSERT_EQ(*c.health("pliant.v1.SceneService"), client::Health::Serving);
  ASSERT_TRUE(c.create_scene(slow_request("stuck", v1::TICK_MODE_REALTIME)).ok());
  auto wait_for = [&](client::Health want) {
    for (int i = 0; i < 3000; ++i) {
      auto h = c.health("pliant.v1.SceneService");
      if (h.ok() && *h == want) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  };
  EXPECT_TRUE(wait_for(client::Health::NotServing));
  EXPECT_EQ(*c.health(""), client::Health::NotServing);
  ASSERT_TRUE(c.delete_scene("stuck").ok());
  EXPECT_TRUE(wait_for(client::Health::Serving));
}

TEST(BoundedWork, TooMuchWorkOverGrpcIsInvalidArgument) {
  Server s(no_tick_limits());
  Client c = s.client();
  auto req = small_request("x");
  req.mutable_spec()->mutable_solver()->set_substeps(10000);
  req.mutable_spec()->mutable_solver()->set_iterations(100000);
  auto r = c.create_scene(req);
  EXPECT_EQ(r.status.code, kInvalidArgument);
  EXPECT_NE(r.status.message.find("sweeps per tick"), std::string::npos) << r.status.message;
}
