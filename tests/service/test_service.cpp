// SPDX-License-Identifier: Apache-2.0
// Integration tests: an in-process pliant server on 127.0.0.1 port 0, driven through the client
// library. Scenes are beam1 with few iterations so the suite stays fast; nothing here asserts
// on timing (the benchmark measures that).
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/experiments.hpp"
#include "pliant/model.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/wait_until.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <thread>

namespace fs = std::filesystem;
using namespace pliant;
using client::Client;

namespace {

using namespace test::grpc_codes;

using TestServer = test::InProcessServer;

fs::path temp_dir(const std::string& name) {
  fs::path p = fs::temp_directory_path() /
               ("pliant_test_" + name + "_" + std::to_string(::getpid()) + "_" +
                std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()));
  fs::create_directories(p);
  return p;
}

// A small, cheap scene: beam1 clamped at x = 0, few iterations.
v1::CreateSceneRequest beam_request(const std::string& id, v1::TickMode mode = v1::TICK_MODE_LOCKSTEP) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*s, 1e-3);
  s->mutable_solver()->set_substeps(2);
  s->mutable_solver()->set_iterations(4);
  s->mutable_tick()->set_mode(mode);
  s->mutable_tick()->set_dt(1.0 / 60);
  return r;
}

std::vector<double> positions_of(Client& c, const std::string& id) {
  v1::SaveSnapshotRequest r;
  r.set_scene_id(id);
  auto s = c.save_snapshot(r);
  EXPECT_TRUE(s.ok()) << s.status.to_string();
  return {s->snapshot().x().begin(), s->snapshot().x().end()};
}

bool bit_equal(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0;
}

}  // namespace

TEST(Service, HealthIsServingAndNotServingAfterShutdown) {
  TestServer ts;
  Client c = ts.client();
  auto h = c.health();
  ASSERT_TRUE(h.ok()) << h.status.to_string();
  EXPECT_EQ(*h, client::Health::Serving);
  auto hs = c.health("pliant.v1.SceneService");
  ASSERT_TRUE(hs.ok());
  EXPECT_EQ(*hs, client::Health::Serving);
  ts.server->shutdown();
  EXPECT_FALSE(c.health().ok());  // the port is closed
}

TEST(Service, SceneLifecycle) {
  TestServer ts;
  Client c = ts.client();
  auto created = c.create_scene(beam_request("a"));
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  EXPECT_EQ(created->scene_id(), "a");
  EXPECT_EQ(created->state(), v1::SCENE_STATE_LOCKSTEP);
  EXPECT_GT(created->vertex_count(), 0u);
  EXPECT_EQ(created->tet_count(), 460u);
  EXPECT_EQ(created->spec().solver().iterations(), 4);
  EXPECT_NEAR(created->spec().material().poisson_ratio(), 0.4, 1e-12);  // default filled in
  EXPECT_EQ(created->spec().material().inertia_floor(), kDefaultInertiaFloor);  // default filled in
  EXPECT_TRUE(created->spec().material().has_support_inertia());                 // default filled in
  EXPECT_EQ(created->spec().material().support_inertia(), 0.0);
  EXPECT_EQ(created->spec().material().model(), v1::ELASTIC_MODEL_STVK);  // default filled in

  // The server picks an id when none is given.
  v1::CreateSceneRequest anon = beam_request("");
  auto b = c.create_scene(anon);
  ASSERT_TRUE(b.ok()) << b.status.to_string();
  EXPECT_EQ(b->scene_id().rfind("scene-", 0), 0u);

  auto list = c.list_scenes();
  ASSERT_TRUE(list.ok());
  ASSERT_EQ(list->size(), 2u);
  EXPECT_EQ((*list)[0].scene_id(), "a");

  auto step = c.step("a", 7);
  ASSERT_TRUE(step.ok()) << step.status.to_string();
  EXPECT_EQ(step->tick(), 7u);
  EXPECT_NEAR(step->sim_time(), 7.0 / 60, 1e-9);
  auto got = c.get_scene("a");
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->tick(), 7u);

  v1::UpdateSceneRequest up;
  up.set_scene_id("a");
  up.mutable_solver()->set_method(v1::METHOD_ANDERSON_SOR);
  up.mutable_solver()->set_omega(2.0);
  up.mutable_material()->set_young_modulus(2e6);
  auto updated = c.update_scene(up);
  ASSERT_TRUE(updated.ok()) << updated.status.to_string();
  EXPECT_EQ(updated->spec().solver().method(), v1::METHOD_ANDERSON_SOR);
  EXPECT_EQ(updated->spec().solver().omega(), 2.0);
  EXPECT_EQ(updated->spec().solver().iterations(), 4);  // unset fields are kept
  EXPECT_EQ(updated->spec().material().young_modulus(), 2e6);
  EXPECT_EQ(updated->spec().material().inertia_floor(), kDefaultInertiaFloor);  // kept
  v1::UpdateSceneRequest floor;
  floor.set_scene_id("a");
  floor.mutable_material()->set_inertia_floor(0.5);
  updated = c.update_scene(floor);
  ASSERT_TRUE(updated.ok()) << updated.status.to_string();
  EXPECT_EQ(updated->spec().material().inertia_floor(), 0.5);
  EXPECT_EQ(updated->spec().material().young_modulus(), 2e6);
  {
    // The scene reports what the floor does to its mesh: the same as the library's model.
    Material m{2e6, 0.4, 1000};
    m.inertia_floor = 0.5;
    const TetMesh beam = *builtin_mesh("beam1");
    auto local = build_model(beam, m, clamp_below_x(1e-3));
    ASSERT_GT(local->floored_vertices(), 4u);
    EXPECT_EQ(updated->floored_vertices(), local->floored_vertices());
    EXPECT_DOUBLE_EQ(updated->added_inertia(), local->added_inertia());
    EXPECT_EQ(created->floored_vertices(), 0u);  // beam1 clamped at x = 0: its light corners are fixed
  }
  floor.mutable_material()->set_inertia_floor(-0.5);
  updated = c.update_scene(floor);
  EXPECT_EQ(updated.status.code, kInvalidArgument);
  EXPECT_NE(updated.status.message.find("material.inertia_floor"), std::string::npos) << updated.status.message;
  {
    // Support inertia: set live, the rest of the material kept, reported like the floor (the
    // library's model with both), and bad values named.
    v1::UpdateSceneRequest support;
    support.set_scene_id("a");
    support.mutable_material()->set_support_inertia(1.0);
    updated = c.update_scene(support);
    ASSERT_TRUE(updated.ok()) << updated.status.to_string();
    EXPECT_EQ(updated->spec().material().support_inertia(), 1.0);
    EXPECT_EQ(updated->spec().material().inertia_floor(), 0.5);
    Material m{2e6, 0.4, 1000};
    m.inertia_floor = 0.5;
    m.support_inertia = 1.0;
    auto local = build_model(*builtin_mesh("beam1"), m, clamp_below_x(1e-3));
    EXPECT_GT(local->added_inertia(), 1.0);  // beam1 clamped at one end: about 10x its mass
    EXPECT_EQ(updated->floored_vertices(), local->floored_vertices());
    EXPECT_DOUBLE_EQ(updated->added_inertia(), local->added_inertia());
    support.mutable_material()->set_support_inertia(1.5);
    auto bad = c.update_scene(support);
    EXPECT_EQ(bad.status.code, kInvalidArgument);
    EXPECT_NE(bad.status.message.find("material.support_inertia must be in [0, 1]"), std::string::npos)
        << bad.status.message;
    EXPECT_NE(bad.status.message.find("got 1.5"), std::string::npos) << bad.status.message;
    support.mutable_material()->set_support_inertia(0.0);
    updated = c.update_scene(support);
    ASSERT_TRUE(updated.ok()) << updated.status.to_string();
    EXPECT_EQ(updated->spec().material().support_inertia(), 0.0);
  }
  {
    // The strain model: switched live, the rest of the material kept, and it is what the scene
    // steps with (the same steps from the same state end elsewhere).
    ASSERT_TRUE(c.reset_scene("a").ok());
    ASSERT_TRUE(c.step("a", 20).ok());
    const auto stvk = positions_of(c, "a");
    v1::UpdateSceneRequest corot;
    corot.set_scene_id("a");
    corot.mutable_material()->set_model(v1::ELASTIC_MODEL_COROTATED);
    updated = c.update_scene(corot);
    ASSERT_TRUE(updated.ok()) << updated.status.to_string();
    EXPECT_EQ(updated->spec().material().model(), v1::ELASTIC_MODEL_COROTATED);
    EXPECT_EQ(updated->spec().material().young_modulus(), 2e6);
    EXPECT_EQ(updated->spec().material().inertia_floor(), 0.5);
    ASSERT_TRUE(c.reset_scene("a").ok());
    ASSERT_TRUE(c.step("a", 20).ok());
    const auto corotated = positions_of(c, "a");
    ASSERT_EQ(corotated.size(), stvk.size());
    double moved = 0;
    for (size_t i = 0; i < stvk.size(); ++i) moved = std::max(moved, std::abs(corotated[i] - stvk[i]));
    EXPECT_GT(moved, 1e-6);  // 2 x 4 budget at 2 MPa: far from converged, so the models part by mm
    corot.mutable_material()->set_model(static_cast<v1::ElasticModel>(7));
    updated = c.update_scene(corot);
    EXPECT_EQ(updated.status.code, kInvalidArgument);
    EXPECT_NE(updated.status.message.find("material.model must be ELASTIC_MODEL_STVK or ELASTIC_MODEL_COROTATED, got 7"),
              std::string::npos) << updated.status.message;
  }

  auto reset = c.reset_scene("a");
  ASSERT_TRUE(reset.ok());
  EXPECT_EQ(reset->tick(), 0u);
  EXPECT_EQ(reset->sim_time(), 0.0);

  ASSERT_TRUE(c.delete_scene("a").ok());
  EXPECT_EQ(c.get_scene("a").status.code, kNotFound);
  EXPECT_EQ(c.list_scenes()->size(), 1u);

  // A mesh file on the model path (the source tree's meshes/ by default).
  v1::CreateSceneRequest from_file = beam_request("file");
  from_file.mutable_spec()->mutable_mesh()->set_model_path("beams/beam1.vtk");
  auto f = c.create_scene(from_file);
  ASSERT_TRUE(f.ok()) << f.status.to_string();
  EXPECT_EQ(f->tet_count(), 460u);
  EXPECT_EQ(f->spec().mesh().model_path(), "beams/beam1.vtk");
}

TEST(Service, PauseResumeAndStepWhilePaused) {
  TestServer ts;
  Client c = ts.client();
  auto req = beam_request("rt", v1::TICK_MODE_AS_FAST_AS_POSSIBLE);
  req.mutable_spec()->set_start_paused(true);
  auto s = c.create_scene(req);
  ASSERT_TRUE(s.ok()) << s.status.to_string();
  EXPECT_EQ(s->state(), v1::SCENE_STATE_PAUSED);
  auto st = c.step("rt", 3);  // stepping a paused scene is allowed
  ASSERT_TRUE(st.ok()) << st.status.to_string();
  EXPECT_EQ(st->tick(), 3u);
  auto r = c.resume_scene("rt");
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->state(), v1::SCENE_STATE_RUNNING);
  EXPECT_EQ(c.step("rt", 1).status.code, kFailedPrecondition);
  // It advances on its own now: wait for a frame past tick 3.
  auto stream = c.stream_frames([] {
    v1::StreamFramesRequest q;
    q.set_scene_id("rt");
    return q;
  }());
  v1::Frame f;
  while (stream->next(&f) && f.tick() <= 3) {
  }
  EXPECT_GT(f.tick(), 3u);
  stream->cancel();
  auto p = c.pause_scene("rt");
  ASSERT_TRUE(p.ok());
  EXPECT_EQ(p->state(), v1::SCENE_STATE_PAUSED);
  const uint64_t t1 = c.get_scene("rt")->tick();
  // Paused means no ticks: while a running scene on the same server ticks 20 times (each
  // scene has its own thread), the paused one stays where it is.
  ASSERT_TRUE(c.create_scene(beam_request("witness", v1::TICK_MODE_AS_FAST_AS_POSSIBLE)).ok());
  ASSERT_TRUE(test::wait_until([&] { return c.get_scene("witness")->tick() >= 20; }, test::kPatience,
                               "20 ticks of a running scene"));
  EXPECT_EQ(c.get_scene("rt")->tick(), t1);
}

// A realtime scene whose period is far shorter than a step: every tick overruns, and the
// scheduler counts late ticks and skipped deadlines instead of stretching its schedule.
TEST(Service, OverrunsAreCountedNotStretched) {
  TestServer ts;
  Client c = ts.client();
  auto req = beam_request("fast", v1::TICK_MODE_REALTIME);
  req.mutable_spec()->mutable_tick()->set_dt(1e-6);  // 1 MHz: no step fits
  ASSERT_TRUE(c.create_scene(req).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("fast");
  q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  auto s = c.stream_frames(q);
  v1::Frame f;
  while (s->next(&f) && f.tick() < 20) {
  }
  s->cancel();
  EXPECT_GE(f.tick(), 20u);
  EXPECT_GT(f.late_ticks(), 0u);
  EXPECT_GT(f.skipped_ticks(), 0u);
  auto scene = c.get_scene("fast");
  ASSERT_TRUE(scene.ok());
  EXPECT_GE(scene->late_ticks(), f.late_ticks());
}

TEST(Service, TopologyAndFrameFields) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("t")).ok());
  auto topo = c.topology("t");
  ASSERT_TRUE(topo.ok()) << topo.status.to_string();
  const int nv = static_cast<int>(topo->vertex_count());
  EXPECT_EQ(topo->rest_positions_size(), 3 * nv);
  EXPECT_EQ(topo->tets_size(), 4 * 460);
  EXPECT_GT(topo->surface_triangles_size(), 0);
  EXPECT_GT(topo->surface_vertices_size(), 0);
  EXPECT_LE(topo->surface_vertices_size(), nv);
  EXPECT_GT(topo->fixed_vertices_size(), 0);
  ASSERT_TRUE(c.step("t", 1).ok());

  auto first_frame = [&](v1::StreamFramesRequest q) {
    q.set_scene_id("t");
    auto s = c.stream_frames(q);
    v1::Frame f;
    EXPECT_TRUE(s->next(&f));
    s->cancel();
    return f;
  };
  v1::Frame all = first_frame({});
  EXPECT_EQ(all.tick(), 1u);
  EXPECT_EQ(all.positions_size(), 3 * nv);
  EXPECT_GT(all.residuals_size(), 0);  // the last substep's history
  EXPECT_LE(all.residuals_size(), 5);
  EXPECT_EQ(all.solver().iterations(), 8);
  EXPECT_EQ(all.state(), v1::SCENE_STATE_LOCKSTEP);
  // Fixed vertices stay at rest; free ones fall under gravity.
  for (int v : topo->fixed_vertices())
    for (int k = 0; k < 3; ++k) EXPECT_EQ(all.positions(3 * v + k), topo->rest_positions(3 * v + k));

  v1::StreamFramesRequest surface;
  surface.set_surface_only(true);
  v1::Frame s = first_frame(surface);
  EXPECT_TRUE(s.surface_only());
  EXPECT_EQ(s.positions_size(), 3 * topo->surface_vertices_size());
  const int sv = topo->surface_vertices(topo->surface_vertices_size() - 1);
  EXPECT_EQ(s.positions(s.positions_size() - 1), all.positions(3 * sv + 2));

  v1::StreamFramesRequest only_residuals;
  only_residuals.add_fields(v1::FRAME_FIELD_RESIDUALS);
  v1::Frame r = first_frame(only_residuals);
  EXPECT_EQ(r.positions_size(), 0);
  EXPECT_EQ(r.residuals_size(), all.residuals_size());
  EXPECT_EQ(r.solver().iterations(), 8);  // always present
}

TEST(Service, DecimationSendsEveryNthFrame) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("d")).ok());
  ASSERT_TRUE(c.step("d", 1).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("d");
  q.set_every_nth_tick(5);
  q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  auto s = c.stream_frames(q);
  v1::Frame f;
  ASSERT_TRUE(s->next(&f));
  EXPECT_EQ(f.tick(), 1u);
  std::vector<uint64_t> ticks;
  uint64_t skipped = 0;
  for (int i = 0; i < 4; ++i) {
    ASSERT_TRUE(c.step("d", 5).ok());
  }
  while (ticks.empty() || ticks.back() < 21) {
    ASSERT_TRUE(s->next(&f));
    ticks.push_back(f.tick());
    skipped += f.skipped_frames();
  }
  s->cancel();
  // Every 5th tick after the first frame (6, 11, 16, 21); a reader that fell behind gets the
  // latest frame instead, which can be off phase (7), and the next one is back on phase (11):
  // at most one frame per 5-tick window, and it is told what it missed.
  EXPECT_EQ(ticks.back(), 21u);
  EXPECT_EQ(ticks.size() + skipped, 4u);
  uint64_t previous = 1;
  for (uint64_t t : ticks) {
    EXPECT_GT((t - 1) / 5, (previous - 1) / 5) << "ticks " << previous << " and " << t << " share a window";
    previous = t;
  }
}

TEST(Service, NewtonLinearSolverIsKeptThroughUpdatesAndSnapshots) {
  TestServer ts;
  Client c = ts.client();
  auto req = beam_request("lin");
  req.mutable_spec()->mutable_solver()->set_method(v1::METHOD_NEWTON);
  req.mutable_spec()->mutable_solver()->set_substeps(1);
  req.mutable_spec()->mutable_solver()->set_iterations(2);
  auto created = c.create_scene(req);
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  EXPECT_EQ(created->spec().solver().newton_linear_solver(), v1::NEWTON_LINEAR_SOLVER_AUTO);  // the default
  v1::UpdateSceneRequest u;
  u.set_scene_id("lin");
  u.mutable_solver()->set_newton_linear_solver(v1::NEWTON_LINEAR_SOLVER_CG_FACTOR);
  auto updated = c.update_scene(u);
  ASSERT_TRUE(updated.ok()) << updated.status.to_string();
  EXPECT_EQ(updated->spec().solver().newton_linear_solver(), v1::NEWTON_LINEAR_SOLVER_CG_FACTOR);
  ASSERT_TRUE(c.step("lin", 5).ok());
  v1::SaveSnapshotRequest save;
  save.set_scene_id("lin");
  auto snap = c.save_snapshot(save);
  ASSERT_TRUE(snap.ok()) << snap.status.to_string();
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = snap->snapshot();
  restore.set_scene_id("lin-copy");
  auto copy = c.restore_snapshot(restore);
  ASSERT_TRUE(copy.ok()) << copy.status.to_string();
  EXPECT_EQ(copy->spec().solver().newton_linear_solver(), v1::NEWTON_LINEAR_SOLVER_CG_FACTOR);
}

TEST(Service, SceneReportsHowWellItsBudgetResolvesTheMaterial) {
  // wave_courant_number = c_p (dt / substeps) / mean edge, computed by the solver library on the
  // same mesh and material, and kept current through updates of the substeps and of E.
  TestServer ts;
  Client c = ts.client();
  auto created = c.create_scene(beam_request("w"));
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  const double young = created->spec().material().young_modulus();
  auto model = build_model(*builtin_mesh("beam1"),
                           Material{young, created->spec().material().poisson_ratio(),
                                    created->spec().material().density()});
  const double expected = wave_courant_number(*model, (1.0 / 60) / 2);
  ASSERT_GT(expected, 0);
  EXPECT_NEAR(created->wave_courant_number(), expected, 1e-12 * expected);

  v1::UpdateSceneRequest more_substeps;
  more_substeps.set_scene_id("w");
  more_substeps.mutable_solver()->set_substeps(8);
  auto u = c.update_scene(more_substeps);
  ASSERT_TRUE(u.ok()) << u.status.to_string();
  EXPECT_NEAR(u->wave_courant_number(), expected / 4, 1e-12 * expected);

  v1::UpdateSceneRequest stiffer;
  stiffer.set_scene_id("w");
  stiffer.mutable_material()->set_young_modulus(4 * young);
  u = c.update_scene(stiffer);
  ASSERT_TRUE(u.ok()) << u.status.to_string();
  EXPECT_NEAR(u->wave_courant_number(), expected / 2, 1e-9 * expected);
  auto got = c.get_scene("w");
  ASSERT_TRUE(got.ok());
  EXPECT_NEAR(got->wave_courant_number(), expected / 2, 1e-9 * expected);

  // Substeps chosen by the server: the fewest that keep the number at or below the target,
  // reported as the substeps in use, and recomputed when E changes (4x E: 2x the substeps).
  v1::UpdateSceneRequest target;
  target.set_scene_id("w");
  target.mutable_solver()->set_target_wave_courant_number(0.3);
  u = c.update_scene(target);
  ASSERT_TRUE(u.ok()) << u.status.to_string();
  const int n = u->spec().solver().substeps();
  EXPECT_DOUBLE_EQ(u->spec().solver().target_wave_courant_number(), 0.3);
  EXPECT_LE(u->wave_courant_number(), 0.3 * (1 + 1e-9));
  auto stiff_model = with_material(*model, Material{4 * young, model->material.poisson, model->material.density});
  EXPECT_GT(wave_courant_number(*stiff_model, (1.0 / 60) / (n - 1)), 0.3) << n << " substeps are not the fewest";
  v1::UpdateSceneRequest back;
  back.set_scene_id("w");
  back.mutable_material()->set_young_modulus(young);
  u = c.update_scene(back);
  ASSERT_TRUE(u.ok()) << u.status.to_string();
  EXPECT_NEAR(u->spec().solver().substeps(), n / 2.0, 1.0);
  EXPECT_LE(u->wave_courant_number(), 0.3 * (1 + 1e-9));
  // A tick runs them: the frame's solver stats say how many.
  ASSERT_TRUE(c.step("w", 1).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("w");
  q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  auto stream = c.stream_frames(q);
  v1::Frame f;
  ASSERT_TRUE(stream->next(&f));
  EXPECT_EQ(f.tick(), 1u);
  EXPECT_EQ(f.solver().substeps(), u->spec().solver().substeps());
  stream->cancel();
}

TEST(Service, ApplyForcePushesVertices) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("free")).ok());
  ASSERT_TRUE(c.create_scene(beam_request("pushed")).ok());
  auto topo = c.topology("free");
  const int tip = static_cast<int>(topo->vertex_count()) - 1;  // far end of the beam
  v1::ApplyForceRequest f;
  f.set_scene_id("pushed");
  f.add_vertices(tip);
  f.mutable_force()->set_y(50.0);
  f.set_ticks(10);
  auto r = c.apply_force(f);
  ASSERT_TRUE(r.ok()) << r.status.to_string();
  EXPECT_EQ(r->first_tick(), 1u);
  ASSERT_TRUE(c.step("free", 10).ok());
  ASSERT_TRUE(c.step("pushed", 10).ok());
  auto a = positions_of(c, "free"), b = positions_of(c, "pushed");
  EXPECT_GT(b[3 * tip + 1], a[3 * tip + 1]);  // pushed up relative to the free fall
}

TEST(Service, LockstepIsDeterministicBitForBit) {
  TestServer ts;
  Client c = ts.client();
  auto run = [&](const std::string& id) {
    auto req = beam_request(id);
    req.mutable_spec()->mutable_solver()->set_method(v1::METHOD_ANDERSON_SOR);
    req.mutable_spec()->mutable_solver()->set_omega(1.5);
    EXPECT_TRUE(c.create_scene(req).ok());
    v1::ApplyForceRequest f;
    f.set_scene_id(id);
    f.add_vertices(100);
    f.mutable_force()->set_z(5.0);
    f.set_ticks(5);
    EXPECT_TRUE(c.apply_force(f).ok());
    for (int i = 0; i < 4; ++i) EXPECT_TRUE(c.step(id, 5).ok());
    return positions_of(c, id);
  };
  auto a = run("one"), b = run("two");
  ASSERT_FALSE(a.empty());
  EXPECT_TRUE(bit_equal(a, b));
  // And again after a reset: same inputs, same positions.
  ASSERT_TRUE(c.reset_scene("one").ok());
  v1::ApplyForceRequest f;
  f.set_scene_id("one");
  f.add_vertices(100);
  f.mutable_force()->set_z(5.0);
  f.set_ticks(5);
  ASSERT_TRUE(c.apply_force(f).ok());
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(c.step("one", 5).ok());
  EXPECT_TRUE(bit_equal(positions_of(c, "one"), a));
}

TEST(Service, BlowUpIsRolledBackAndReported) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("boom")).ok());
  ASSERT_TRUE(c.step("boom", 2).ok());
  auto before = positions_of(c, "boom");
  v1::ApplyForceRequest f;
  f.set_scene_id("boom");
  f.add_vertices(150);
  f.mutable_force()->set_y(1e308);  // finite, but the step overflows
  f.set_ticks(1);
  ASSERT_TRUE(c.apply_force(f).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("boom");
  auto stream = c.stream_frames(q);
  v1::Frame fr;
  ASSERT_TRUE(stream->next(&fr));  // the latest frame (tick 2)
  auto st = c.step("boom", 1);
  ASSERT_TRUE(st.ok()) << st.status.to_string();
  EXPECT_EQ(st->rollbacks(), 1u);
  EXPECT_TRUE(bit_equal(positions_of(c, "boom"), before));  // back to the last good state
  ASSERT_TRUE(stream->next(&fr));
  EXPECT_TRUE(fr.rolled_back());
  EXPECT_EQ(fr.rollbacks(), 1u);
  EXPECT_FALSE(fr.rollback_reason().empty());
  stream->cancel();
  // It keeps serving: the next ticks are fine.
  auto next = c.step("boom", 3);
  ASSERT_TRUE(next.ok());
  EXPECT_EQ(next->rollbacks(), 0u);
  EXPECT_EQ(c.get_scene("boom")->rollbacks(), 1u);
}

TEST(Service, SlowSubscriberSkipsFramesAndDoesNotSlowTheTick) {
  TestServer ts;
  Client c = ts.client();
  auto req = beam_request("slow");
  req.mutable_spec()->mutable_mesh()->set_builtin("beam3");  // bigger frames fill the buffers
  req.mutable_spec()->mutable_solver()->set_substeps(1);
  req.mutable_spec()->mutable_solver()->set_iterations(1);
  ASSERT_TRUE(c.create_scene(req).ok());
  ASSERT_TRUE(c.step("slow", 1).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("slow");
  auto stream = c.stream_frames(q);
  v1::Frame f;
  ASSERT_TRUE(stream->next(&f));
  // The subscriber stops reading while the scene ticks 1500 times: the step completes (the
  // tick never waits for readers) ...
  constexpr uint64_t kTicks = 1500;
  auto st = c.step("slow", kTicks);
  ASSERT_TRUE(st.ok()) << st.status.to_string();
  EXPECT_EQ(st->tick(), 1 + kTicks);
  // ... and the subscriber, reading again, gets to the latest frame having skipped most.
  uint64_t received = 0, skipped = 0;
  while (f.tick() < 1 + kTicks) {
    ASSERT_TRUE(stream->next(&f));
    ++received;
    skipped += f.skipped_frames();
  }
  stream->cancel();
  EXPECT_EQ(received + skipped, kTicks);  // every frame is either received or counted
  EXPECT_GT(skipped, 0u);
}

TEST(Service, ThirtyTwoConcurrentSubscribers) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("many")).ok());
  ASSERT_TRUE(c.step("many", 1).ok());
  constexpr int kSubscribers = 32;
  constexpr uint64_t kLast = 41;
  std::atomic<int> ready{0};
  std::vector<uint64_t> received(kSubscribers), skipped(kSubscribers), last(kSubscribers);
  std::vector<int> monotonic(kSubscribers, 1);
  std::vector<std::thread> threads;
  for (int i = 0; i < kSubscribers; ++i) {
    threads.emplace_back([&, i] {
      Client own = ts.client();
      v1::StreamFramesRequest q;
      q.set_scene_id("many");
      q.set_surface_only(true);
      auto s = own.stream_frames(q);
      v1::Frame f;
      if (!s->next(&f)) return;
      ready++;
      uint64_t prev = f.tick();
      while (f.tick() < kLast && s->next(&f)) {
        ++received[i];
        skipped[i] += f.skipped_frames();
        if (f.tick() <= prev) monotonic[i] = 0;
        prev = f.tick();
      }
      last[i] = f.tick();
      s->cancel();
    });
  }
  ASSERT_TRUE(test::wait_until([&] { return ready == kSubscribers; }, test::kPatience,
                               "every subscriber's first frame"));
  for (int k = 0; k < 4; ++k) ASSERT_TRUE(c.step("many", 10).ok());
  for (auto& t : threads) t.join();
  for (int i = 0; i < kSubscribers; ++i) {
    EXPECT_EQ(last[i], kLast) << "subscriber " << i;
    EXPECT_EQ(received[i] + skipped[i], kLast - 1) << "subscriber " << i;
    EXPECT_TRUE(monotonic[i]) << "subscriber " << i;
  }
}

TEST(Service, DeleteEndsStreamsWithNotFoundAndShutdownWithUnavailable) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("gone")).ok());
  ASSERT_TRUE(c.create_scene(beam_request("stays")).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("gone");
  auto s1 = c.stream_frames(q);
  q.set_scene_id("stays");
  auto s2 = c.stream_frames(q);
  // Both streams are open once each has delivered a frame (the first tick's, or the latest
  // when the server saw the subscription after the step).
  ASSERT_TRUE(c.step("gone", 1).ok());
  ASSERT_TRUE(c.step("stays", 1).ok());
  v1::Frame f;
  ASSERT_TRUE(s1->next(&f));
  ASSERT_TRUE(s2->next(&f));
  ASSERT_TRUE(c.delete_scene("gone").ok());
  EXPECT_EQ(s1->finish().code, kNotFound);
  ts.server->shutdown();
  EXPECT_EQ(s2->finish().code, kUnavailable);
}

TEST(Service, SnapshotBytesRoundTrip) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("orig")).ok());
  ASSERT_TRUE(c.step("orig", 6).ok());
  v1::SaveSnapshotRequest save;
  save.set_scene_id("orig");
  auto snap = c.save_snapshot(save);
  ASSERT_TRUE(snap.ok()) << snap.status.to_string();
  EXPECT_EQ(snap->snapshot().tick(), 6u);
  EXPECT_TRUE(snap->path().empty());  // no name: nothing written on the server
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = snap->snapshot();
  restore.set_scene_id("copy");
  auto copy = c.restore_snapshot(restore);
  ASSERT_TRUE(copy.ok()) << copy.status.to_string();
  EXPECT_EQ(copy->tick(), 6u);
  EXPECT_EQ(c.restore_snapshot(restore).status.code, kAlreadyExists);
  restore.set_replace(true);
  EXPECT_TRUE(c.restore_snapshot(restore).ok());
  ASSERT_TRUE(c.step("orig", 5).ok());
  ASSERT_TRUE(c.step("copy", 5).ok());
  EXPECT_TRUE(bit_equal(positions_of(c, "orig"), positions_of(c, "copy")));
}

TEST(Service, RestartKeepsScenes) {
  fs::path dir = temp_dir("restart");
  server::ServerOptions o;
  o.data_dir = dir.string();
  std::vector<double> x;
  {
    TestServer a(o);
    Client c = a.client();
    ASSERT_TRUE(c.create_scene(beam_request("keep")).ok());
    ASSERT_TRUE(c.step("keep", 12).ok());
    // A scene whose substeps the server chooses keeps that choice across the restart.
    auto resolved = beam_request("resolved");
    resolved.mutable_spec()->mutable_solver()->set_target_wave_courant_number(0.5);
    resolved.mutable_spec()->mutable_material()->set_inertia_floor(0);  // plain lumped masses, kept too
    resolved.mutable_spec()->mutable_material()->set_support_inertia(0.25);  // kept too
    resolved.mutable_spec()->mutable_material()->set_model(v1::ELASTIC_MODEL_COROTATED);  // kept too
    ASSERT_TRUE(c.create_scene(resolved).ok());
    auto deleted = beam_request("deleted");
    ASSERT_TRUE(c.create_scene(deleted).ok());
    ASSERT_TRUE(c.delete_scene("deleted").ok());
    x = positions_of(c, "keep");
    v1::SaveSnapshotRequest named;
    named.set_scene_id("keep");
    named.set_name("checkpoint");
    named.set_omit_snapshot(true);
    auto saved = c.save_snapshot(named);
    ASSERT_TRUE(saved.ok()) << saved.status.to_string();
    EXPECT_TRUE(fs::exists(saved->path()));
    EXPECT_EQ(a.server->shutdown(), 2);
  }
  EXPECT_TRUE(fs::exists(dir / "scenes" / "keep.snapshot"));
  {
    TestServer b(o);
    Client c = b.client();
    auto got = c.get_scene("keep");
    ASSERT_TRUE(got.ok()) << got.status.to_string();
    EXPECT_EQ(got->tick(), 12u);
    EXPECT_EQ(got->state(), v1::SCENE_STATE_LOCKSTEP);
    EXPECT_EQ(got->spec().solver().iterations(), 4);
    EXPECT_TRUE(bit_equal(positions_of(c, "keep"), x));
    auto r2 = c.get_scene("resolved");
    ASSERT_TRUE(r2.ok()) << r2.status.to_string();
    EXPECT_DOUBLE_EQ(r2->spec().solver().target_wave_courant_number(), 0.5);
    EXPECT_EQ(r2->spec().material().inertia_floor(), 0.0);
    EXPECT_EQ(r2->spec().material().support_inertia(), 0.25);
    EXPECT_EQ(r2->spec().material().model(), v1::ELASTIC_MODEL_COROTATED);
    EXPECT_LE(r2->wave_courant_number(), 0.5 * (1 + 1e-9));
    EXPECT_GT(r2->spec().solver().substeps(), 2);  // chosen, not the request's 2
    EXPECT_EQ(c.get_scene("deleted").status.code, kNotFound);
    auto names = c.list_snapshots();
    ASSERT_TRUE(names.ok());
    ASSERT_EQ(names->size(), 1u);
    EXPECT_EQ((*names)[0], "checkpoint");
    v1::RestoreSnapshotRequest r;
    r.set_name("checkpoint");
    r.set_scene_id("from-name");
    auto restored = c.restore_snapshot(r);
    ASSERT_TRUE(restored.ok()) << restored.status.to_string();
    EXPECT_EQ(restored->tick(), 12u);
  }
  {
    server::ServerOptions no_restore = o;
    no_restore.restore = false;
    TestServer d(no_restore);
    Client c = d.client();
    EXPECT_EQ(c.list_scenes()->size(), 0u);
    d.server->shutdown();
  }
  fs::remove_all(dir);
}

TEST(Service, TokenIsRequiredWhenSet) {
  server::ServerOptions o;
  o.token = "s3cret";
  TestServer ts(o);
  Client none = ts.client();
  Client wrong = ts.client("nope");
  Client right = ts.client("s3cret");
  EXPECT_EQ(none.list_scenes().status.code, kUnauthenticated);
  EXPECT_EQ(wrong.create_scene(beam_request("x")).status.code, kUnauthenticated);
  EXPECT_TRUE(right.list_scenes().ok());
  EXPECT_TRUE(none.health().ok());  // health stays open for probes
}

// Every RPC's bad inputs: the right code, a message naming the field and value, and no effect
// on a scene that is running beside them.
TEST(Service, BadInputsGetTheRightStatus) {
  fs::path models = temp_dir("models");
  fs::path data = temp_dir("data");
  server::ServerOptions o;
  o.max_scenes = 3;
  o.max_vertices = 500;
  o.model_path = models.string();
  o.data_dir = data.string();
  TestServer ts(o);
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("ok")).ok());
  ASSERT_TRUE(c.create_scene(beam_request("rt", v1::TICK_MODE_REALTIME)).ok());

  struct Case {
    std::string name;
    std::function<void(v1::CreateSceneRequest&)> edit;
    int code;
    std::string says;
  };
  auto tet = [](v1::MeshData* d, std::vector<double> p, std::vector<int> t) {
    for (double v : p) d->add_positions(v);
    for (int v : t) d->add_tets(v);
  };
  std::vector<Case> cases = {
      {"poisson 0.5", [](auto& r) { r.mutable_spec()->mutable_material()->set_poisson_ratio(0.5); },
       kInvalidArgument, "spec.material.poisson_ratio must be in (-1, 0.5), got 0.5"},
      {"negative E", [](auto& r) { r.mutable_spec()->mutable_material()->set_young_modulus(-1); },
       kInvalidArgument, "spec.material.young_modulus"},
      {"zero density", [](auto& r) { r.mutable_spec()->mutable_material()->set_density(0); },
       kInvalidArgument, "spec.material.density"},
      {"inertia floor 2", [](auto& r) { r.mutable_spec()->mutable_material()->set_inertia_floor(2); },
       kInvalidArgument, "spec.material.inertia_floor must be in [0, 1] (a fraction of the mean vertex mass), got 2"},
      {"support inertia -1", [](auto& r) { r.mutable_spec()->mutable_material()->set_support_inertia(-1); },
       kInvalidArgument,
       "spec.material.support_inertia must be in [0, 1] (a fraction of the mass a vertex carries to the fixed "
       "vertices), got -1"},
      {"inertia floor nan", [](auto& r) { r.mutable_spec()->mutable_material()->set_inertia_floor(NAN); },
       kInvalidArgument, "spec.material.inertia_floor"},
      {"unknown strain model", [](auto& r) { r.mutable_spec()->mutable_material()->set_model(static_cast<v1::ElasticModel>(9)); },
       kInvalidArgument, "spec.material.model must be ELASTIC_MODEL_STVK or ELASTIC_MODEL_COROTATED, got 9"},
      {"unknown builtin", [](auto& r) { r.mutable_spec()->mutable_mesh()->set_builtin("beam9"); },
       kInvalidArgument, "spec.mesh.builtin 'beam9'"},
      {"no mesh", [](auto& r) { r.mutable_spec()->clear_mesh(); }, kInvalidArgument, "spec.mesh"},
      {"escaping path", [](auto& r) { r.mutable_spec()->mutable_mesh()->set_model_path("../etc/passwd"); },
       kInvalidArgument, "spec.mesh.model_path '../etc/passwd'"},
      {"missing file", [](auto& r) { r.mutable_spec()->mutable_mesh()->set_model_path("nothing.node"); },
       kNotFound, "spec.mesh.model_path 'nothing.node'"},
      {"positions not xyz", [&](auto& r) { tet(r.mutable_spec()->mutable_mesh()->mutable_data(), {0, 0}, {0, 1, 2, 3}); },
       kInvalidArgument, "spec.mesh.data.positions has 2 values"},
      {"index out of range",
       [&](auto& r) { tet(r.mutable_spec()->mutable_mesh()->mutable_data(), {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1}, {0, 1, 2, 7}); },
       kInvalidArgument, "spec.mesh.data.tets[0]: vertex index 7"},
      {"inverted tet",
       [&](auto& r) { tet(r.mutable_spec()->mutable_mesh()->mutable_data(), {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1}, {0, 2, 1, 3}); },
       kInvalidArgument, "not positive"},
      {"too many vertices", [](auto& r) { r.mutable_spec()->mutable_mesh()->set_builtin("beam3"); },
       kResourceExhausted, "--max-vertices 500"},
      {"dt 0", [](auto& r) { r.mutable_spec()->mutable_tick()->set_dt(0); }, kInvalidArgument,
       "spec.tick.dt must be in (0, 1] s, got 0"},
      {"dt nan", [](auto& r) { r.mutable_spec()->mutable_tick()->set_dt(NAN); }, kInvalidArgument, "spec.tick.dt"},
      {"unknown mode", [](auto& r) { r.mutable_spec()->mutable_tick()->set_mode(static_cast<v1::TickMode>(42)); },
       kInvalidArgument, "spec.tick.mode has unknown value 42"},
      {"unknown method", [](auto& r) { r.mutable_spec()->mutable_solver()->set_method(static_cast<v1::Method>(99)); },
       kInvalidArgument, "spec.solver.method has unknown value 99"},
      {"unknown newton linear solver",
       [](auto& r) { r.mutable_spec()->mutable_solver()->set_newton_linear_solver(static_cast<v1::NewtonLinearSolver>(77)); },
       kInvalidArgument, "spec.solver.newton_linear_solver has unknown value 77"},
      {"omega 0", [](auto& r) { r.mutable_spec()->mutable_solver()->set_omega(0); }, kInvalidArgument,
       "spec.solver.omega"},
      {"negative iterations", [](auto& r) { r.mutable_spec()->mutable_solver()->set_iterations(-1); },
       kInvalidArgument, "spec.solver.iterations"},
      {"window 0", [](auto& r) { r.mutable_spec()->mutable_solver()->set_window(0); }, kInvalidArgument,
       "spec.solver.window"},
      {"inversion floor 1.5", [](auto& r) { r.mutable_spec()->mutable_solver()->set_inversion_floor(1.5); },
       kInvalidArgument, "spec.solver.inversion_floor must be in [0, 1), got 1.5"},
      {"negative wave courant", [](auto& r) { r.mutable_spec()->mutable_solver()->set_target_wave_courant_number(-1); },
       kInvalidArgument, "spec.solver.target_wave_courant_number must be in [0, 1000] (0: use substeps), got -1"},
      {"wave courant nan", [](auto& r) { r.mutable_spec()->mutable_solver()->set_target_wave_courant_number(NAN); },
       kInvalidArgument, "spec.solver.target_wave_courant_number"},
      {"gravity inf", [](auto& r) { r.mutable_spec()->mutable_gravity()->set_y(INFINITY); }, kInvalidArgument,
       "spec.gravity"},
      {"fixed index", [](auto& r) { r.mutable_spec()->mutable_fixed()->add_indices(100000); }, kInvalidArgument,
       "fixed.indices"},
      {"inverted box",
       [](auto& r) {
         auto* b = r.mutable_spec()->mutable_fixed()->add_boxes();
         b->mutable_min()->set_x(1);
       },
       kInvalidArgument, "spec.fixed.boxes[1]"},
      {"bad id", [](auto& r) { r.set_scene_id("a/b"); }, kInvalidArgument, "scene_id 'a/b'"},
      {"duplicate id", [](auto& r) { r.set_scene_id("ok"); }, kAlreadyExists, "scene_id 'ok' already exists"},
  };
  for (auto& k : cases) {
    auto req = beam_request("new");
    k.edit(req);
    auto r = c.create_scene(req);
    EXPECT_EQ(r.status.code, k.code) << k.name << ": " << r.status.to_string();
    EXPECT_NE(r.status.message.find(k.says), std::string::npos) << k.name << ": " << r.status.message;
  }
  ASSERT_TRUE(c.create_scene(beam_request("third")).ok());
  auto full = c.create_scene(beam_request("fourth"));
  EXPECT_EQ(full.status.code, kResourceExhausted);
  EXPECT_NE(full.status.message.find("--max-scenes 3"), std::string::npos);

  // Unknown and empty scene ids, for every RPC that takes one.
  v1::StreamFramesRequest sq;
  sq.set_scene_id("nope");
  v1::SaveSnapshotRequest sv;
  sv.set_scene_id("nope");
  v1::ApplyForceRequest af;
  af.set_scene_id("nope");
  af.add_vertices(0);
  v1::UpdateSceneRequest upd;
  upd.set_scene_id("nope");
  std::vector<std::pair<std::string, int>> unknown = {
      {"get", c.get_scene("nope").status.code},
      {"delete", c.delete_scene("nope").code},
      {"reset", c.reset_scene("nope").status.code},
      {"pause", c.pause_scene("nope").status.code},
      {"resume", c.resume_scene("nope").status.code},
      {"step", c.step("nope").status.code},
      {"force", c.apply_force(af).status.code},
      {"update", c.update_scene(upd).status.code},
      {"topology", c.topology("nope").status.code},
      {"stream", c.stream_frames(sq)->finish().code},
      {"save", c.save_snapshot(sv).status.code},
  };
  for (auto& [rpc, code] : unknown) EXPECT_EQ(code, kNotFound) << rpc;
  EXPECT_EQ(c.get_scene("").status.code, kInvalidArgument);
  EXPECT_EQ(c.step("").status.code, kInvalidArgument);

  // Scene-specific preconditions and values.
  auto stepping_realtime = c.step("rt", 1);
  EXPECT_EQ(stepping_realtime.status.code, kFailedPrecondition);
  EXPECT_NE(stepping_realtime.status.message.find("realtime"), std::string::npos);
  EXPECT_EQ(c.pause_scene("ok").status.code, kFailedPrecondition);  // lockstep
  EXPECT_EQ(c.step("ok", 100001).status.code, kInvalidArgument);
  v1::ApplyForceRequest bad_force;
  bad_force.set_scene_id("ok");
  EXPECT_EQ(c.apply_force(bad_force).status.code, kInvalidArgument);  // no vertices
  bad_force.add_vertices(5000);
  auto oor = c.apply_force(bad_force);
  EXPECT_EQ(oor.status.code, kInvalidArgument);
  EXPECT_NE(oor.status.message.find("vertices[0] = 5000"), std::string::npos) << oor.status.message;
  v1::UpdateSceneRequest bad_update;
  bad_update.set_scene_id("ok");
  bad_update.mutable_solver()->set_omega(-2);
  auto bu = c.update_scene(bad_update);
  EXPECT_EQ(bu.status.code, kInvalidArgument);
  EXPECT_NE(bu.status.message.find("solver.omega"), std::string::npos) << bu.status.message;
  EXPECT_EQ(c.get_scene("ok")->spec().solver().omega(), 1.0);  // unchanged
  bad_update.clear_solver();
  bad_update.mutable_material()->set_poisson_ratio(0.7);
  EXPECT_EQ(c.update_scene(bad_update).status.code, kInvalidArgument);
  v1::StreamFramesRequest bad_rate;
  bad_rate.set_scene_id("ok");
  bad_rate.set_max_rate_hz(-1);
  EXPECT_EQ(c.stream_frames(bad_rate)->finish().code, kInvalidArgument);
  v1::SaveSnapshotRequest bad_name;
  bad_name.set_scene_id("ok");
  bad_name.set_name("../x");
  EXPECT_EQ(c.save_snapshot(bad_name).status.code, kInvalidArgument);
  v1::RestoreSnapshotRequest missing;
  missing.set_name("never-saved");
  EXPECT_EQ(c.restore_snapshot(missing).status.code, kNotFound);
  v1::RestoreSnapshotRequest garbage;
  garbage.mutable_snapshot()->set_format_version(7);
  auto g = c.restore_snapshot(garbage);
  EXPECT_EQ(g.status.code, kInvalidArgument);
  EXPECT_NE(g.status.message.find("format_version 7"), std::string::npos);
  v1::RestoreSnapshotRequest empty;
  EXPECT_EQ(c.restore_snapshot(empty).status.code, kInvalidArgument);

  // The scene beside all of this is untouched and still steps.
  auto st = c.step("ok", 2);
  ASSERT_TRUE(st.ok()) << st.status.to_string();
  EXPECT_EQ(st->tick(), 2u);
  ts.server->shutdown();  // the server writes checkpoints into data until it stops
  fs::remove_all(models);
  fs::remove_all(data);
}

TEST(Service, SaveByNameNeedsADataDir) {
  TestServer ts;
  Client c = ts.client();
  ASSERT_TRUE(c.create_scene(beam_request("s")).ok());
  v1::SaveSnapshotRequest r;
  r.set_scene_id("s");
  r.set_name("x");
  auto s = c.save_snapshot(r);
  EXPECT_EQ(s.status.code, kFailedPrecondition);
  EXPECT_NE(s.status.message.find("--data-dir"), std::string::npos);
}

TEST(ServerOptions, FlagsWinOverEnvironmentOverConfigFile) {
  fs::path dir = temp_dir("config");
  fs::path cfg = dir / "pliant.conf";
  std::ofstream(cfg) << "# comment\nlisten = 1.2.3.4:1\nmax-scenes = 5\nthreads = 3\n";
  std::map<std::string, std::string> env = {{"PLIANT_MAX_SCENES", "7"}, {"PLIANT_TOKEN", "t"},
                                            {"PLIANT_DATA_DIR", "/d"}};
  auto lookup = [&](const std::string& n) -> std::optional<std::string> {
    auto it = env.find(n);
    if (it == env.end()) return std::nullopt;
    return it->second;
  };
  server::ServerOptions o;
  bool help = false;
  auto e = server::parse_server_options({"--config", cfg.string(), "--threads=2", "--no-restore"}, lookup, &o, &help);
  ASSERT_TRUE(e.ok()) << e.message;
  EXPECT_EQ(o.listen, "1.2.3.4:1");  // config file
  EXPECT_EQ(o.max_scenes, 7);        // environment over config
  EXPECT_EQ(o.threads, 2);           // flag over config
  EXPECT_EQ(o.token, "t");
  EXPECT_EQ(o.data_dir, "/d");
  EXPECT_FALSE(o.restore);

  e = server::parse_server_options({"--max-scenes", "0"}, lookup, &o, &help);
  EXPECT_EQ(e.code, server::Code::InvalidArgument);
  EXPECT_NE(e.message.find("--max-scenes"), std::string::npos);
  e = server::parse_server_options({"--bogus", "1"}, lookup, &o, &help);
  EXPECT_NE(e.message.find("unknown flag --bogus"), std::string::npos);
  env["PLIANT_LOG_LEVEL"] = "loud";
  e = server::parse_server_options({}, lookup, &o, &help);
  EXPECT_NE(e.message.find("PLIANT_LOG_LEVEL"), std::string::npos);
  fs::remove_all(dir);
}

TEST(Service, OversizeUploadIsResourceExhausted) {
  server::ServerOptions o;
  o.max_message_mb = 1;
  TestServer ts(o);
  Client c = ts.client();
  auto req = beam_request("huge");
  auto* d = req.mutable_spec()->mutable_mesh()->mutable_data();
  for (int i = 0; i < 200000; ++i) d->add_positions(i * 1e-3);  // 1.6 MB of doubles
  for (int i = 0; i < 4; ++i) d->add_tets(i);
  auto r = c.create_scene(req);
  EXPECT_EQ(r.status.code, kResourceExhausted) << r.status.to_string();
  EXPECT_TRUE(c.list_scenes().ok());  // and the server carries on
}

TEST(Service, TlsWithAPrivateCa) {
  fs::path dir = temp_dir("tls");
  const std::string key = (dir / "key.pem").string(), cert = (dir / "cert.pem").string();
  const std::string cmd = "openssl req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=localhost "
                          "-addext subjectAltName=IP:127.0.0.1 -keyout " + key + " -out " + cert +
                          " >/dev/null 2>&1";
  if (std::system(cmd.c_str()) != 0) GTEST_SKIP() << "openssl is not available";
  server::ServerOptions o;
  o.tls_cert = cert;
  o.tls_key = key;
  TestServer ts(o);
  client::ConnectOptions secure;
  secure.address = ts.address;
  secure.tls_ca_file = cert;
  secure.timeout = std::chrono::seconds(10);
  Client c(secure);
  auto h = c.health();
  ASSERT_TRUE(h.ok()) << h.status.to_string();
  EXPECT_EQ(*h, client::Health::Serving);
  EXPECT_TRUE(c.create_scene(beam_request("secure")).ok());
  client::ConnectOptions plain;
  plain.address = ts.address;
  plain.timeout = std::chrono::seconds(5);
  EXPECT_FALSE(Client(plain).list_scenes().ok());  // plaintext is refused
  ts.server->shutdown();
  fs::remove_all(dir);
}

TEST(Service, AStepPastItsDeadlineDropsTheRemainingTicks) {
  TestServer ts;
  client::ConnectOptions o;
  o.address = ts.address;
  o.step_timeout = std::chrono::milliseconds(200);
  Client c(o);
  ASSERT_TRUE(c.create_scene(beam_request("long")).ok());
  auto st = c.step("long", 100000);  // far more than 200 ms of work
  EXPECT_EQ(st.status.code, kDeadlineExceeded) << st.status.to_string();
  // The scene is not stuck running the rest: it answers and steps again right away.
  const uint64_t before = c.get_scene("long")->tick();
  EXPECT_LT(before, 100000u);
  auto next = c.step("long", 1);
  ASSERT_TRUE(next.ok()) << next.status.to_string();
  EXPECT_LT(next->tick(), 100000u);
  EXPECT_GT(next->tick(), 0u);
}

TEST(MethodAuto, RealtimeScenesWithoutAMethodRunTheMeasuredChoice) {
  TestServer ts;
  Client c = ts.client();
  v1::CreateSceneRequest r = beam_request("auto", v1::TICK_MODE_REALTIME);
  r.mutable_spec()->mutable_solver()->clear_substeps();  // no budget in sweeps
  r.mutable_spec()->mutable_solver()->clear_iterations();
  r.mutable_spec()->set_start_paused(true);
  auto created = c.create_scene(r);
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  const std::string& choice = created->method_choice();
  ASSERT_FALSE(choice.empty());
  const v1::Method chosen = created->spec().solver().method();
  EXPECT_NE(chosen, v1::METHOD_AUTO);
  EXPECT_NE(chosen, v1::METHOD_UNSPECIFIED);
  EXPECT_NE(choice.find("newton"), std::string::npos) << choice;
  EXPECT_NE(choice.find("xpbd"), std::string::npos) << choice;
  EXPECT_GT(created->spec().solver().time_budget_ms(), 0);  // half the tick by default

  // Lockstep scenes, scenes that name a method and scenes that name a budget in sweeps keep
  // what they asked for.
  v1::CreateSceneRequest budget = beam_request("budget", v1::TICK_MODE_REALTIME);
  budget.mutable_spec()->set_start_paused(true);
  auto b = c.create_scene(budget);
  ASSERT_TRUE(b.ok());
  EXPECT_TRUE(b->method_choice().empty());
  EXPECT_EQ(b->spec().solver().method(), v1::METHOD_XPBD);
  EXPECT_EQ(b->spec().solver().substeps(), 2);
  EXPECT_EQ(b->spec().solver().iterations(), 4);
  auto lockstep = c.create_scene(beam_request("lockstep"));
  ASSERT_TRUE(lockstep.ok());
  EXPECT_TRUE(lockstep->method_choice().empty());
  EXPECT_EQ(lockstep->spec().solver().method(), v1::METHOD_XPBD);
  v1::CreateSceneRequest pinned = beam_request("pinned", v1::TICK_MODE_REALTIME);
  pinned.mutable_spec()->set_start_paused(true);
  pinned.mutable_spec()->mutable_solver()->set_method(v1::METHOD_ANDERSON_SOR);
  auto p = c.create_scene(pinned);
  ASSERT_TRUE(p.ok());
  EXPECT_TRUE(p->method_choice().empty());
  EXPECT_EQ(p->spec().solver().method(), v1::METHOD_ANDERSON_SOR);

  // A new material is measured again; pinning a method ends auto, asking for it starts it.
  v1::UpdateSceneRequest up;
  up.set_scene_id("auto");
  up.mutable_material()->set_young_modulus(1e7);
  auto u = c.update_scene(up);
  ASSERT_TRUE(u.ok()) << u.status.to_string();
  EXPECT_FALSE(u->method_choice().empty());
  // A new budget in sweeps pins the method in use with it.
  up.Clear();
  up.set_scene_id("auto");
  up.mutable_solver()->set_iterations(3);
  u = c.update_scene(up);
  ASSERT_TRUE(u.ok());
  EXPECT_TRUE(u->method_choice().empty());
  EXPECT_EQ(u->spec().solver().iterations(), 3);
  up.Clear();
  up.set_scene_id("auto");
  up.mutable_solver()->set_method(v1::METHOD_XPBD);
  u = c.update_scene(up);
  ASSERT_TRUE(u.ok());
  EXPECT_TRUE(u->method_choice().empty());
  EXPECT_EQ(u->spec().solver().method(), v1::METHOD_XPBD);
  up.mutable_solver()->set_method(v1::METHOD_AUTO);
  u = c.update_scene(up);
  ASSERT_TRUE(u.ok());
  EXPECT_FALSE(u->method_choice().empty());
  EXPECT_NE(u->spec().solver().method(), v1::METHOD_AUTO);
}
