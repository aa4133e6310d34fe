// SPDX-License-Identifier: Apache-2.0
// Server scenes with particle bodies beside the soft body, shared by the service tests
// (test_bodies.cpp) and the ensembles that run a scene over a grid of nearby configurations
// (test_body_ensembles.cpp): the scene builders, the in-process server they run on, and the runs
// of the two chaotic scenes whose outcome one configuration does not tell.
#pragma once

#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace pliant::test {

struct BodiesServer : InProcessServer {
  explicit BodiesServer(server::ServerOptions o = {}) : InProcessServer(std::move(o), {std::chrono::seconds(60)}) {}
};

inline void set(v1::Vec3* v, double x, double y, double z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}

// beam1 clamped at x <= 0.01, lockstep at 60 Hz: the scene the body tests add their bodies to.
inline v1::CreateSceneRequest beam_scene(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*s, 0.01);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  s->mutable_tick()->set_dt(1.0 / 60);
  return r;
}

// A box container at `center` with half sizes `half`, m.
inline void set_container(v1::FluidSpec* f, double cx, double cy, double cz, double hx, double hy, double hz) {
  auto* box = f->mutable_container()->mutable_box();
  set(box->mutable_center(), cx, cy, cz);
  set(box->mutable_half_extent(), hx, hy, hz);
}

inline v1::Frame latest_frame(client::Client& c, const std::string& id) {
  v1::StreamFramesRequest q;
  q.set_scene_id(id);
  auto s = c.stream_frames(q);
  v1::Frame f;
  EXPECT_TRUE(s->next(&f));
  s->cancel();
  return f;
}

// The browser test's scene: beam1 fixed at x <= 1 mm (XPBD 4 x 2), a rope of twenty 1 cm links
// pinned at one end beside its tip (at z = rope_z), a 12 x 12 cloth of 15 cm hung from two
// corners at height cloth_y above it (too few substeps for it: it stretches, the log says so),
// falling onto the rope and wrapping it, and a box of water with a tap.
inline v1::CreateSceneRequest rope_under_cloth_request(const std::string& id, double cloth_y = 0.06,
                                                       double rope_z = 0.0075) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  s->mutable_fixed()->Clear();
  auto* box = s->mutable_fixed()->add_boxes();
  set(box->mutable_min(), -1, -1, -1);
  set(box->mutable_max(), 0.001, 1, 1);
  s->mutable_solver()->set_method(v1::METHOD_XPBD);
  s->mutable_solver()->set_substeps(4);
  s->mutable_solver()->set_iterations(2);
  auto* rope = s->add_bodies();
  rope->set_name("rope");
  auto* rs = rope->mutable_rope();
  set(rs->add_points(), 0.13, 0.0075, rope_z);
  set(rs->add_points(), 0.33, 0.0075, rope_z);
  rs->set_segments(20);
  rs->set_damping(0.5);
  rs->mutable_pins()->add_indices(0);
  auto* sheet = s->add_bodies();
  sheet->set_name("sheet");
  auto* cs = sheet->mutable_cloth();
  auto* g = cs->mutable_grid();
  g->set_resolution_x(12);
  g->set_resolution_y(12);
  g->set_size_x(0.15);
  g->set_size_y(0.15);
  set(g->mutable_origin(), 0, cloth_y, -0.075);
  set(g->mutable_u(), 1, 0, 0);
  set(g->mutable_v(), 0, 0, 1);
  cs->mutable_pins()->add_indices(0);
  cs->mutable_pins()->add_indices(11);
  auto* water = s->add_bodies();
  water->set_name("water");
  auto* fl = water->mutable_fluid();
  fl->set_spacing(0.02);
  auto* blk = fl->add_blocks();
  set(blk->mutable_min(), -0.2, -0.2, -0.06);
  set(blk->mutable_max(), -0.1, -0.08, 0.06);
  set_container(fl, -0.15, -0.15, 0, 0.08, 0.08, 0.08);
  auto* tap = fl->add_emitters();
  set(tap->mutable_center(), -0.15, -0.085, 0);
  tap->set_speed(0.5);
  tap->set_radius(0.01);
  tap->set_max_particles(40);
  return r;
}

// Steps scene `id` one tick at a time, `ticks` times, handing each tick's frame (which must
// carry `bodies` particle bodies) to on_frame, until it returns false. Returns the ticks run; a
// failed step or a frame of another body count fails the test and ends the run.
template <class OnFrame>
int step_frames(client::Client& c, const std::string& id, int ticks, int bodies, OnFrame&& on_frame) {
  int run = 0;
  while (run < ticks) {
    if (!c.step(id, 1).ok()) {
      ADD_FAILURE() << id << ": step " << run << " failed";
      break;
    }
    const v1::Frame f = latest_frame(c, id);
    if (f.bodies_size() != bodies || f.solver().bodies_size() != bodies) {
      ADD_FAILURE() << id << ": frame " << run << " has " << f.bodies_size() << " bodies";
      break;
    }
    ++run;
    if (!on_frame(f)) break;
  }
  return run;
}

// The rope's RMS stretch over a run of that scene: the mean over the ticks and the largest, and
// the contacts the rope and the cloth made. `stop_above`: a run whose stretch passes it stops
// there (an explosion; the mean is then over the ticks run).
struct RopeRun {
  double mean = 0, worst = 0;
  uint64_t contacts = 0;
  int ticks = 0;
};
inline RopeRun run_rope_under_cloth(client::Client& c, double cloth_y, double rope_z, int ticks,
                                    double stop_above = INFINITY) {
  RopeRun run;
  EXPECT_TRUE(c.create_scene(rope_under_cloth_request("wrap", cloth_y, rope_z)).ok());
  double sum = 0;
  run.ticks = step_frames(c, "wrap", ticks, 3, [&](const v1::Frame& f) {
    const double stretch = f.solver().bodies(0).constraint_error();
    run.worst = std::max(run.worst, stretch);
    sum += stretch;
    run.contacts += f.solver().bodies(0).body_contacts() + f.solver().bodies(1).body_contacts();
    return !(stretch > stop_above);
  });
  run.mean = run.ticks > 0 ? sum / run.ticks : 0.0;
  return run;
}

// beam1 (clamped, E `young`) sagging onto a 32 x 32 cloth of 12 cm held at its four corners at
// height `cloth_z` (5 mm under it at -0.055), 64 cloth substeps, no self-collision.
inline v1::CreateSceneRequest sagging_beam_on_cloth_request(const std::string& id, double young, double cloth_z) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  s->mutable_material()->set_young_modulus(young);
  auto* body = s->add_bodies();
  body->set_name("sheet");
  auto* cl = body->mutable_cloth();
  auto* g = cl->mutable_grid();
  g->set_resolution_x(32);
  g->set_resolution_y(32);
  g->set_size_x(0.12);
  g->set_size_y(0.12);
  set(g->mutable_origin(), 0.005, -0.005, cloth_z);
  for (uint32_t i : {0u, 31u, 32u * 31u, 32u * 32u - 1u}) cl->mutable_pins()->add_indices(i);
  cl->set_substeps(64);  // a fine cloth stretches by its weight at fewer (docs/cloth.md)
  cl->set_self_collision(false);
  return r;
}

// The cloth's fastest particle over `ticks` ticks of that scene (from its positions in
// consecutive frames) and the particles the beam touched; a run stops once the fastest passes
// `stop_above` (blown up). `through`: at the end of a run that was not stopped, the beam is
// through the cloth: more than a quarter of its vertices past x = 2 cm (away from the clamp)
// have a cloth particle within 2 mm across (x and z) and more than 2 mm above them (a cloth that
// holds the beam hangs below it).
struct SagRun {
  double fastest = 0;
  uint64_t touched = 0;
  bool through = false;
};
inline SagRun run_sagging_beam_on_cloth(client::Client& c, double young, double cloth_z, int ticks,
                                        double stop_above = INFINITY) {
  SagRun run;
  EXPECT_TRUE(c.create_scene(sagging_beam_on_cloth_request("press", young, cloth_z)).ok());
  std::vector<float> before;
  step_frames(c, "press", ticks, 1, [&](const v1::Frame& f) {
    const auto& x = f.bodies(0).positions();
    if (!before.empty())
      for (int i = 0; i + 2 < x.size(); i += 3)
        run.fastest = std::max<double>(
            run.fastest, std::hypot(x[i] - before[i], x[i + 1] - before[i + 1], x[i + 2] - before[i + 2]) * 60);
    before.assign(x.begin(), x.end());
    run.touched += f.solver().bodies(0).soft_body_contacts();
    return !(run.fastest > stop_above);
  });
  if (run.fastest > stop_above) return run;
  v1::SaveSnapshotRequest q;
  q.set_scene_id("press");
  const auto snap = c.save_snapshot(q);
  EXPECT_TRUE(snap.ok());
  const auto& b = snap->snapshot().x();
  int covered = 0, away = 0;
  for (int i = 0; i + 2 < b.size(); i += 3) {
    if (b[i] < 0.02) continue;
    ++away;
    for (size_t j = 0; j + 2 < before.size(); j += 3)
      if (std::abs(before[j] - b[i]) < 0.002 && std::abs(before[j + 2] - b[i + 2]) < 0.002 &&
          before[j + 1] > b[i + 1] + 0.002) {
        ++covered;
        break;
      }
  }
  run.through = 4 * covered > away;
  return run;
}

}  // namespace pliant::test
