// SPDX-License-Identifier: Apache-2.0
// Google Benchmark: position-based fluids on 10,000 particles (a 17 x 34 x 17 lattice block
// of spacing 2 cm in a box, after half a second of dam break so the particles are disordered).
//   build/bench/bench_fluid --benchmark_counters_tabular=true
// neighbour_search: the grid and every particle's neighbour list (arg: threads);
// ns_per_particle the wall time / particles.
// step_1it / step_4it: one substep of 1/120 s with 1 or 4 density iterations (prediction,
// neighbour search, iterations, friction, velocities, XSPH); the difference over 3 is what one
// iteration costs: ns_per_particle_iter = wall time / (particles x iterations) of the whole step.
// step_60hz: one 1/60 s step of 4 substeps x 4 iterations (the real-time target) from the same
// state, with the split of its wall time by phase in ms per step (FluidBody::phase_times):
// sort, predict, neighbours, density, correction, grabs, velocity, xsph.
// step_60hz_tool: the same with a 5 cm haptic sphere in the water moving at 0.5 m/s along x, met
// inside the substeps (ToolBoundary); tool_contacts: the particles it pushed in the last substep.
#include "fluid/neighbour_grid.hpp"
#include "pliant/fluid.hpp"
#include "step/thread_pool.hpp"

#include <benchmark/benchmark.h>

#include <memory>

using namespace pliant;

namespace {

FluidSettings dam_settings(int threads, int iterations) {
  FluidSettings s;
  s.spacing = 0.02;
  s.threads = threads;
  s.substeps = 1;
  s.iterations = iterations;
  s.container = Collider::box(Vec3(0.68, 0.68, 0.17), Vec3(0.68, 0.68, 0.17));
  return s;
}

// The dam break after 0.5 s (30 steps of 2 substeps x 4 iterations), as a state.
const ParticleState& disordered_state() {
  static const ParticleState st = [] {
    FluidSettings s = dam_settings(2, 4);
    s.substeps = 2;
    FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.34, 0.68, 0.34)}});
    for (int i = 0; i < 30; ++i) f.step(1.0 / 60.0, {});
    return f.state();
  }();
  return st;
}

void BM_FluidNeighbourSearch(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  const ParticleState& st = disordered_state();
  std::unique_ptr<ThreadPool> pool = threads > 1 ? std::make_unique<ThreadPool>(threads) : nullptr;
  fluid::NeighbourGrid grid;
  for (auto _ : state) {
    grid.build(st.x, 0.04, pool.get());
    benchmark::DoNotOptimize(grid.pairs());
  }
  state.counters["particles"] = static_cast<double>(st.x.size());
  state.counters["pairs_per_particle"] = static_cast<double>(grid.pairs()) / static_cast<double>(st.x.size());
  state.counters["ns_per_particle"] = benchmark::Counter(
      static_cast<double>(st.x.size()) * 1e-9, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_FluidStep(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  const int iterations = static_cast<int>(state.range(1));
  FluidBody f(dam_settings(threads, iterations), {FluidBlock{Vec3(0, 0, 0), Vec3(0.34, 0.68, 0.34)}});
  const ParticleState& st = disordered_state();
  for (auto _ : state) {
    state.PauseTiming();
    f.set_state(st);
    state.ResumeTiming();
    benchmark::DoNotOptimize(f.step(1.0 / 120.0, {}));
  }
  const double n = static_cast<double>(f.size());
  state.counters["particles"] = n;
  state.counters["ns_per_particle_iter"] = benchmark::Counter(
      n * iterations * 1e-9, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void step_60hz(benchmark::State& state, bool with_tool) {
  const int threads = static_cast<int>(state.range(0));
  FluidSettings s = dam_settings(threads, 4);
  s.substeps = 4;
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.34, 0.68, 0.34)}});
  const ParticleState& st = disordered_state();
  RigidTool tool = RigidTool::sphere(Vec3(0.3, 0.1, 0.17), 0.05);
  tool.velocity = Vec3(0.5, 0, 0);
  const RigidTool tools[] = {tool};
  ToolBoundary tb;
  tb.tools = tools;
  f.reset_phase_times();
  for (auto _ : state) {
    state.PauseTiming();
    f.set_state(st);
    state.ResumeTiming();
    benchmark::DoNotOptimize(f.advance(1.0 / 60.0, s.substeps, {}, true, nullptr, with_tool ? &tb : nullptr));
  }
  if (with_tool) state.counters["tool_contacts"] = static_cast<double>(tb.pushed);
  const FluidPhaseTimes& t = f.phase_times();
  const double steps = static_cast<double>(state.iterations());
  state.counters["particles"] = static_cast<double>(f.size());
  state.counters["sort"] = t.sort_ms / steps;
  state.counters["predict"] = t.predict_ms / steps;
  state.counters["neighbours"] = t.neighbours_ms / steps;
  state.counters["density"] = t.density_ms / steps;
  state.counters["correction"] = t.correction_ms / steps;
  state.counters["grabs"] = t.grabs_ms / steps;
  state.counters["velocity"] = t.velocity_ms / steps;
  state.counters["xsph"] = t.xsph_ms / steps;
}

void BM_FluidStep60Hz(benchmark::State& state) { step_60hz(state, false); }
void BM_FluidStep60HzTool(benchmark::State& state) { step_60hz(state, true); }

}  // namespace

BENCHMARK(BM_FluidNeighbourSearch)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_FluidStep)->ArgNames({"threads", "iterations"})->Args({1, 1})->Args({1, 4})->Args({2, 1})->Args({2, 4})
    ->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_FluidStep60Hz)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_FluidStep60HzTool)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();
