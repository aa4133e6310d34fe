// SPDX-License-Identifier: Apache-2.0
// One 60 Hz step of the 64 x 64 cloth draped over a sphere (docs/cloth.md):
//   build/bench/bench_cloth --benchmark_counters_tabular=true
// Every timed step starts from the same state: the cloth dropped from 5 cm above the sphere's
// top and stepped kWarmSteps steps (lying on the sphere, its edges still swinging). Arguments:
// substeps, threads, self-collision (0/1). Counters: particles, constraints, self_contacts,
// s_per_particle_substep.
#include "pliant/cloth.hpp"

#include <benchmark/benchmark.h>

#include <vector>

using namespace pliant;

namespace {

constexpr int kWarmSteps = 30;

void BM_ClothDrapeStep(benchmark::State& state) {
  ClothGridSpec g;  // 64 x 64, 1 m x 1 m
  g.origin = Vec3(-0.5, 0.35, -0.5);
  ConstraintBodySettings s;
  s.substeps = int(state.range(0));
  s.threads = int(state.range(1));
  s.self_collision = state.range(2) != 0;
  s.stretch_compliance = 1e-9;
  auto cloth = ConstraintBody::cloth_grid(g, s);
  const std::vector<Collider> colliders = {Collider::sphere(Vec3::Zero(), 0.3)};
  for (int k = 0; k < kWarmSteps; ++k) cloth->step(1.0 / 60, colliders);
  const ParticleState warm = cloth->state();
  for (auto _ : state) {
    state.PauseTiming();
    cloth->set_state(warm);
    state.ResumeTiming();
    cloth->step(1.0 / 60, colliders);
  }
  state.counters["particles"] = double(cloth->size());
  state.counters["constraints"] = double(cloth->constraint_count());
  state.counters["self_contacts"] = double(cloth->self_contacts());
  state.counters["s_per_particle_substep"] = benchmark::Counter(
      double(cloth->size()) * s.substeps, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

}  // namespace

BENCHMARK(BM_ClothDrapeStep)
    ->ArgNames({"substeps", "threads", "self"})
    ->Args({16, 1, 1})
    ->Args({16, 2, 1})
    ->Args({16, 1, 0})
    ->Args({32, 2, 1})
    ->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();
