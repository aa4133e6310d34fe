// SPDX-License-Identifier: Apache-2.0
// One 60 Hz step of the 64 x 64 cloth draped over a sphere (docs/cloth.md):
//   build/bench/bench_cloth --benchmark_counters_tabular=true
// Every timed step starts from the same state: the cloth dropped from 5 cm above the sphere's
// top and stepped kWarmSteps steps (lying on the sphere, its edges still swinging). Arguments:
// substeps, threads, self-collision (0/1). Counters: particles, constraints, self_contacts,
// s_per_particle_substep.
// BM_ClothDrapeStepTool: the same step (16 substeps, 1 thread, self-collision) with a haptic tool
// met inside the substeps (ToolBoundary): argument "tool" 0 none, 1 a 2 cm sphere 5 m away, 2 the
// same sphere pressing into the drape's top while moving along x at 0.3 m/s. Counter:
// tool_contacts (particles it pushed in the last substep).
// BM_ClothOnBodyContact: one contact pass of a cloth hung over beam3 against the tet body
// (couple_particles_to_body, as a scene runs it once per tick), its particles alone or with its
// edges. Arguments: grid resolution, edges (0/1). Counters: particles, segments, contacts.
// BM_ClothOnBodyStep: a whole step of that cloth, its particles meeting the beam inside the
// substeps and its edges after (argument "inside" 1), or the step and then the contact pass of
// its particles and edges (0). Arguments: grid resolution, inside. Counters: particles, contacts.
// BM_ClothOnClothContact: the same for one cloth falling onto another (couple_particles_to_cloth).
// BM_WaterOnArmadilloContact: one contact pass of a block of water (8 x 4 x 8 particles, 5 mm
// apart) against the armadillo (54,990 tets), on its head or 10 cm beside it (argument
// "beside"), as a scene runs it after every part of a fluid's step. Counters: particles,
// contacts.
// BM_WaterOnArmadilloPart: a part of a scene's tick for that water resting on the armadillo's
// head (one 1/120 s substep of 4 iterations, 1 thread): the water meeting the head inside its
// substep (argument "inside" 1), or stepping alone with the contact pass after it (0).
// Counters: particles, contacts.
#include "pliant/builtin_meshes.hpp"
#include "pliant/cloth.hpp"
#include "pliant/coupling.hpp"
#include "pliant/fluid.hpp"
#include "pliant/mesh_io.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

using namespace pliant;

namespace {

constexpr int kWarmSteps = 30;

// The drape's step with `substeps`, `threads`, self-collision `self`; tool 0 none, 1 far away,
// 2 pressing into the drape's top.
void drape_step(benchmark::State& state, int substeps, int threads, bool self, int tool) {
  ClothGridSpec g;  // 64 x 64, 1 m x 1 m
  g.origin = Vec3(-0.5, 0.35, -0.5);
  ConstraintBodySettings s;
  s.substeps = substeps;
  s.threads = threads;
  s.self_collision = self;
  s.stretch_compliance = 1e-9;
  auto cloth = ConstraintBody::cloth_grid(g, s);
  const std::vector<Collider> colliders = {Collider::sphere(Vec3::Zero(), 0.3)};
  for (int k = 0; k < kWarmSteps; ++k) cloth->step(1.0 / 60, colliders);
  const ParticleState warm = cloth->state();
  RigidTool sphere = RigidTool::sphere(tool == 1 ? Vec3(0, 5, 0) : Vec3(0, 0.32, 0), 0.02);
  sphere.velocity = Vec3(0.3, 0, 0);
  const RigidTool tools[] = {sphere};
  ToolBoundary tb;
  tb.tools = tools;
  for (auto _ : state) {
    state.PauseTiming();
    cloth->set_state(warm);
    state.ResumeTiming();
    cloth->advance(1.0 / 60, substeps, colliders, true, nullptr, tool > 0 ? &tb : nullptr);
  }
  if (tool > 0) state.counters["tool_contacts"] = double(tb.pushed);
  state.counters["particles"] = double(cloth->size());
  state.counters["constraints"] = double(cloth->constraint_count());
  state.counters["self_contacts"] = double(cloth->self_contacts());
  state.counters["s_per_particle_substep"] = benchmark::Counter(
      double(cloth->size()) * s.substeps, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_ClothDrapeStep(benchmark::State& state) {
  drape_step(state, int(state.range(0)), int(state.range(1)), state.range(2) != 0, 0);
}
void BM_ClothDrapeStepTool(benchmark::State& state) { drape_step(state, 16, 1, true, int(state.range(0))); }

// A grid x grid cloth (0.12 m square, 2 mm thick) 3.5 mm over beam3's top, beside the beam up to
// 2 cm lower, falling at 0.3 m/s: its edges cross the beam's top edges.
struct ClothOverBeam3 {
  explicit ClothOverBeam3(int grid) : model(build_model(*builtin_mesh("beam3"), Material{1e5, 0.4, 1000})) {
    body = rest_state(*model);
    ClothGridSpec g;
    g.nx = g.ny = grid;
    g.size_x = g.size_y = 0.12;
    g.origin = Vec3(-0.01, 0.0135, -0.055);
    settings.thickness = 0.002;
    cloth = ConstraintBody::cloth_grid(g, settings);
    hung = cloth->state();
    for (Vec3& x : hung.x)
      if (x.z() < 0.0 || x.z() > 0.01) x.y() -= 0.02 * std::min(1.0, std::abs(x.z() - 0.005) / 0.03);
    for (Vec3& v : hung.v) v = Vec3(0, -0.3, 0);
  }
  std::shared_ptr<const BodyModel> model;
  BodyState body;
  ConstraintBodySettings settings;
  std::unique_ptr<ConstraintBody> cloth;
  ParticleState hung;
};

void BM_ClothOnBodyContact(benchmark::State& state) {
  const ClothOverBeam3 scene(int(state.range(0)));
  const auto& [model, body, cs, cloth, hung] = scene;
  const std::vector<Vec3> start = hung.x;
  CouplingSettings contact;
  contact.radius = cs.thickness;
  const bool edges = state.range(1) != 0;
  size_t found = 0;
  for (auto _ : state) {
    state.PauseTiming();
    ParticleState p = hung;
    BodyState b = body;
    state.ResumeTiming();
    const CouplingReport r = couple_particles_to_body(*model, b, p, cloth->inverse_masses(), contact, 1.0 / 60, start,
                                                      edges ? cloth->segments() : std::span<const std::array<uint32_t, 2>>{});
    found = r.contacts + r.segment_contacts;
    benchmark::DoNotOptimize(p.x.data());
  }
  state.counters["particles"] = double(cloth->size());
  state.counters["segments"] = edges ? double(cloth->segments().size()) : 0.0;
  state.counters["contacts"] = double(found);
}

// The cloth of BM_ClothOnBodyContact, 3.5 mm over beam3's top and falling at 0.3 m/s, one whole
// step (16 substeps): its particles meeting the beam's surface inside the substeps and its
// edges after the step (argument "inside" 1), or the step alone followed by the contact pass
// of its particles and edges (0), as a scene runs them.
void BM_ClothOnBodyStep(benchmark::State& state) {
  const ClothOverBeam3 scene(int(state.range(0)));
  const auto& [model, body, cs, cloth, hung] = scene;
  const bool inside = state.range(1) != 0;
  CouplingSettings contact;
  contact.radius = cs.thickness;
  contact.friction = 0.3;
  size_t found = 0;
  for (auto _ : state) {
    state.PauseTiming();
    cloth->set_state(hung);
    BodyState b = body;
    state.ResumeTiming();
    CouplingSettings after = contact;
    if (inside) {
      SurfaceBoundary surface;
      surface.triangles = model->surface;
      surface.x = b.x;
      surface.v = b.v;
      surface.radius = contact.radius;
      surface.friction = contact.friction;
      found = cloth->advance(1.0 / 60, cs.substeps, {}, true, &surface).soft_body_contacts;
      take_surface_impulse(*model, b, surface);
      after.particles = false;
    } else {
      cloth->step(1.0 / 60, {});
      found = 0;
    }
    ParticleState p = cloth->state();
    const CouplingReport r =
        couple_particles_to_body(*model, b, p, cloth->inverse_masses(), after, 1.0 / 60, hung.x, cloth->segments());
    cloth->set_state(p);
    found += r.contacts + r.segment_contacts;
    benchmark::DoNotOptimize(b.v.data());
  }
  state.counters["particles"] = double(cloth->size());
  state.counters["contacts"] = double(found);
}

void BM_WaterOnArmadilloContact(benchmark::State& state) {
  const auto model = build_model(resolve_mesh("armadillo"), Material{1e6, 0.4, 1000});
  const BodyState body = rest_state(*model);
  Vec3 top = body.x[0];
  for (const Vec3& x : body.x)
    if (x.y() > top.y()) top = x;
  // The block's bottom layer 1 mm into the head, falling at 0.3 m/s; or the block 10 cm aside.
  const Vec3 corner = top + Vec3(state.range(0) ? 0.1 : -0.0175, -0.001, -0.0175);
  ParticleState water;
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 4; ++j)
      for (int k = 0; k < 8; ++k) {
        water.x.push_back(corner + 0.005 * Vec3(i, j, k));
        water.v.push_back(Vec3(0, -0.3, 0));
      }
  std::vector<Vec3> start;
  for (const Vec3& x : water.x) start.push_back(x + Vec3(0, 0.005, 0));
  const std::vector<double> w(water.x.size(), 1.0 / 1.25e-4);  // 0.125 g each
  CouplingSettings contact;
  contact.radius = 0.0025;
  size_t found = 0;
  for (auto _ : state) {
    state.PauseTiming();
    ParticleState p = water;
    BodyState b = body;
    state.ResumeTiming();
    found = couple_particles_to_body(*model, b, p, w, contact, 1.0 / 120, start).contacts;
    benchmark::DoNotOptimize(p.x.data());
  }
  state.counters["particles"] = double(water.x.size());
  state.counters["contacts"] = double(found);
}

void BM_WaterOnArmadilloPart(benchmark::State& state) {
  const auto model = build_model(resolve_mesh("armadillo"), Material{1e6, 0.4, 1000});
  const BodyState body = rest_state(*model);
  Vec3 top = body.x[0];
  for (const Vec3& x : body.x)
    if (x.y() > top.y()) top = x;
  FluidSettings fs;
  fs.spacing = 0.005;
  fs.substeps = 1;
  const Vec3 corner = top + Vec3(-0.0175, 0.004, -0.0175);
  FluidBody water(fs, {FluidBlock{corner, corner + Vec3(0.04, 0.02, 0.04)}});
  SurfaceBoundary surface;
  surface.triangles = model->surface;
  surface.x = body.x;
  surface.v = body.v;
  surface.radius = 0.0025;
  surface.friction = 0.3;
  const double h = 1.0 / 120;
  for (int k = 0; k < 60; ++k) water.advance(h, 1, {}, true, &surface);  // resting on the head
  const ParticleState warm = water.state();
  const bool inside = state.range(0) != 0;
  CouplingSettings contact;
  contact.radius = surface.radius;
  contact.friction = surface.friction;
  size_t found = 0;
  for (auto _ : state) {
    state.PauseTiming();
    water.set_state(warm);
    BodyState b = body;
    state.ResumeTiming();
    if (inside) {
      found = water.advance(h, 1, {}, true, &surface).soft_body_contacts;
    } else {
      water.advance(h, 1, {}, true);
      ParticleState p = water.state();
      found = couple_particles_to_body(*model, b, p, water.inverse_masses(), contact, h, warm.x).contacts;
      water.set_state(p);
    }
  }
  state.counters["particles"] = double(water.size());
  state.counters["contacts"] = double(found);
}

// Two 1 m cloths of grid x grid particles (thickness 5 mm each), the upper one 8 mm over the
// lower, shifted half a cell in x and z and falling at 0.3 m/s: one contact pass of the upper
// cloth against the lower's triangles (couple_particles_to_cloth, as a scene runs each pair once
// per tick), its particles alone or with its edges.
void BM_ClothOnClothContact(benchmark::State& state) {
  ClothGridSpec g;
  g.nx = g.ny = int(state.range(0));
  ConstraintBodySettings cs;
  const auto lower = ConstraintBody::cloth_grid(g, cs);
  const double cell = g.size_x / (g.nx - 1);
  g.origin += Vec3(0.5 * cell, 0.008, 0.5 * cell);
  const auto upper = ConstraintBody::cloth_grid(g, cs);
  ParticleState falling = upper->state();
  for (Vec3& v : falling.v) v = Vec3(0, -0.3, 0);
  std::vector<Vec3> start = falling.x;
  for (Vec3& x : falling.x) x.y() -= 0.3 / 60;
  const std::vector<Vec3> lower_start = lower->state().x;
  CouplingSettings contact;
  contact.radius = 2 * cs.thickness;
  const bool edges = state.range(1) != 0;
  size_t found = 0;
  for (auto _ : state) {
    state.PauseTiming();
    ParticleState p = falling, l = lower->state();
    state.ResumeTiming();
    const CouplingReport r = couple_particles_to_cloth(
        p, upper->inverse_masses(), start, l, lower->inverse_masses(), lower->triangles(), lower_start, contact, 1.0 / 60,
        edges ? upper->segments() : std::span<const std::array<uint32_t, 2>>{});
    found = r.contacts + r.segment_contacts;
    benchmark::DoNotOptimize(p.x.data());
  }
  state.counters["particles"] = double(upper->size());
  state.counters["segments"] = edges ? double(upper->segments().size()) : 0.0;
  state.counters["contacts"] = double(found);
}

}  // namespace

BENCHMARK(BM_ClothOnClothContact)
    ->ArgNames({"grid", "edges"})
    ->Args({64, 0})
    ->Args({64, 1})
    ->Unit(benchmark::kMillisecond);

BENCHMARK(BM_ClothOnBodyStep)
    ->ArgNames({"grid", "inside"})
    ->ArgsProduct({{32, 64}, {0, 1}})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WaterOnArmadilloContact)->ArgName("beside")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WaterOnArmadilloPart)->ArgName("inside")->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

BENCHMARK(BM_ClothOnBodyContact)
    ->ArgNames({"grid", "edges"})
    ->Args({64, 0})
    ->Args({64, 1})
    ->Args({128, 0})
    ->Args({128, 1})
    ->Unit(benchmark::kMillisecond);

BENCHMARK(BM_ClothDrapeStep)
    ->ArgNames({"substeps", "threads", "self"})
    ->Args({16, 1, 1})
    ->Args({16, 2, 1})
    ->Args({16, 1, 0})
    ->Args({32, 2, 1})
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ClothDrapeStepTool)->ArgName("tool")->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
