// SPDX-License-Identifier: Apache-2.0
// Google Benchmark: cost of the solver's iterations in ns per tet-iteration, on the thesis
// beam3 and armadillo, per sweep, accelerator, strain model (StVK / corotated) and thread count.
//   build/bench/bench_solver --benchmark_counters_tabular=true
//   PLIANT_BENCH_MESHES=a.node:b.node build/bench/bench_solver ...   (more meshes)
// The counter s_per_tet_iter is wall time / (iterations x tets) of one substep solve.
// step_* (the whole step: prediction, sweeps, floor contacts, inversion floor, velocities) is
// the armadillo standing on its feet (vertices with y <= -0.040 fixed, as the service's
// armadillo scene), E 1 MPa, under gravity, above a floor plane, one tick of 1/60 s in S
// substeps x N iterations (step_xpbd_SxN: 1 x N the tangled scene, 64 x 1 the default budget),
// after kWarmTicks ticks from rest; every timed step starts from that same state. s_per_tet_iter
// is wall time / (tets x substeps x iterations); floor_corrections the last step's
// inversion-floor corrections; projection_ms / residual_ms / other_ms the last step's split
// (other: prediction, contacts, the floor, velocities; floor_ms its inversion floor);
// floor_passes / floor_scans its floor's passes over all substeps and, of them, the later ones
// that checked every pack. Public API only (and the flop count where the library has it), so that the
// same file builds against an older library for before/after runs.
// flops_per_tet / flop_per_s (gs_*, jacobi_*): the projection's arithmetic, counted by the
// kernel itself (detail::mean_projection_flops), and the rate the solve achieved with it.
// step_newton_1x1/hippo: the server's realtime tick of the thesis hippo hanging at 1 MPa (the
// vertices with x <= -0.07159 fixed, gravity, 1 substep of 1/60 s, one Newton iteration, the
// default linear solver: CG preconditioned by an earlier factorisation, residuals recorded as a
// scene does), timed from the state kNewtonRestTicks ticks from rest (about at rest), the same
// stepper throughout so its factorisation is kept as in a running scene; cg_iterations the last
// step's CG iterations.
// vbd_* (vertex block descent): s_per_vertex_iter is wall time / (iterations x vertices) of one
// step of one substep from the bent beam at rest, and residual_ratio the gradient norm after
// the 20 iterations over the initial one (lower converges better), per Hessian choice
// (vbd: Gauss-Newton blocks, the default; _projected: each tet's exact block, eigenvalues
// clamped at 0; corotated: Gauss-Newton there means the rotation held fixed).
#include "pliant/experiments.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/stepper.hpp"
#include "vbd/vbd.hpp"
#if __has_include("kernels/strain_kernel.hpp")  // the flop count (absent from older libraries)
#include "kernels/strain_kernel.hpp"
#define PLIANT_BENCH_FLOPS 1
#endif

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdlib>
#include <map>
#include <memory>

using namespace pliant;

namespace {

struct Setup {
  std::shared_ptr<const BodyModel> model;
  std::vector<Vec3> x0;
};

const Setup& setup(const std::string& mesh, ElasticModel elastic) {
  static std::map<std::pair<std::string, ElasticModel>, Setup> cache;
  auto it = cache.find({mesh, elastic});
  if (it != cache.end()) return it->second;
  const TetMesh m = resolve_mesh(mesh);
  Setup s;
  const double clamp = default_clamp_x(m.vertices);
  Material material{1e6, 0.4, 1000};
  material.model = elastic;
  s.model = build_model(m, material, clamp_below_x(clamp));
  s.x0 = cantilever_bend(*s.model, clamp, 0.1 * bounding_box(m.vertices).extent().x());
  return cache.emplace(std::make_pair(mesh, elastic), std::move(s)).first->second;
}

void run(benchmark::State& state, const std::string& mesh, Method method, Sweep sweep, bool residuals,
         bool line_search, ElasticModel elastic) {
  const Setup& su = setup(mesh, elastic);
  SolverSettings s;
  s.method = method;
  s.sweep = sweep;
  s.omega = method == Method::AndersonSor ? 2.0 : (method == Method::Sor ? 1.5 : 1.0);
  s.iterations = 20;
  s.line_search = line_search;
  s.threads = int(state.range(0));
  s.record_residuals = residuals || method == Method::AndersonSor || method == Method::Anderson;
  Stepper stepper;
  std::vector<Vec3> x;
  std::vector<Vec6> lambda;  // empty: every solve starts from zero multipliers
  long iterations = 0;
  StepReport last;
  for (auto _ : state) {
    state.PauseTiming();
    x = su.x0;
    lambda.clear();
    state.ResumeTiming();
    last = stepper.solve_substep(*su.model, su.x0, x, lambda, 1.0 / 60, s);
    iterations += last.iterations;
    benchmark::DoNotOptimize(x.data());
  }
  state.counters["tets"] = double(su.model->tet_count());
#ifdef PLIANT_BENCH_FLOPS
  // Arithmetic of one projection counted by running the kernel on a counting number type, mean
  // over the tets at the start of the solve; flop_per_s: what the solve achieved with it (the
  // roofline's numerator; docs/solver.md gives this machine's peak).
  const double flops = detail::mean_projection_flops(*su.model, su.x0, std::vector<Vec6>(su.model->slot_count(), Vec6::Zero()),
                                                     Mat6(su.model->compliance * 3600.0), line_search);
  state.counters["flops_per_tet"] = flops;
  state.counters["flop_per_s"] =
      benchmark::Counter(flops * double(iterations) * double(su.model->tet_count()), benchmark::Counter::kIsRate);
#endif
  // Seconds per tet-iteration (printed with an SI prefix: "57n" is 57 ns).
  state.counters["s_per_tet_iter"] = benchmark::Counter(
      double(iterations) * double(su.model->tet_count()), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  const double total = last.times.projection_ms + last.times.anderson_ms + last.times.update_ms + last.times.residual_ms;
  if (total > 0) {
    state.counters["share_projection"] = last.times.projection_ms / total;
    state.counters["share_anderson"] = last.times.anderson_ms / total;
    state.counters["share_update"] = last.times.update_ms / total;
    state.counters["share_residual"] = last.times.residual_ms / total;
  }
}

// Ticks the whole-step benchmarks run from rest before timing (the body swinging, tangled
// where the budget under-resolves it: what a running scene steps).
constexpr int kWarmTicks = 30;

struct StepSetup {
  std::shared_ptr<const BodyModel> model;
  BodyState start;
  StepInputs inputs;
};

SolverSettings scene_settings(int substeps, int iterations, int threads) {
  SolverSettings s;
  s.substeps = substeps;
  s.iterations = iterations;
  s.threads = threads;
  s.record_residuals = false;
  return s;
}

const StepSetup& step_setup(const std::string& mesh, int substeps, int iterations) {
  static std::map<std::tuple<std::string, int, int>, StepSetup> cache;
  auto it = cache.find({mesh, substeps, iterations});
  if (it != cache.end()) return it->second;
  const TetMesh m = resolve_mesh(mesh);
  StepSetup su;
  const auto box = bounding_box(m.vertices);
  FixedSelection fixed;
  fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(1, -0.040, 1)});  // the service scene's --fix-box
  su.model = build_model(m, Material{1e6, 0.4, 1000}, fixed);
  su.inputs.colliders.push_back(Collider::plane(Vec3(0, box.min.y(), 0), Vec3(0, 1, 0)));
  su.start = rest_state(*su.model);
  Stepper stepper;
  const SolverSettings s = scene_settings(substeps, iterations, 1);
  for (int t = 0; t < kWarmTicks; ++t) stepper.step(*su.model, su.start, s, su.inputs);
  return cache.emplace(std::make_tuple(mesh, substeps, iterations), std::move(su)).first->second;
}

void run_step(benchmark::State& state, const std::string& mesh, int substeps, int iterations) {
  const StepSetup& su = step_setup(mesh, substeps, iterations);
  const SolverSettings s = scene_settings(substeps, iterations, int(state.range(0)));
  Stepper stepper;
  BodyState body = su.start;
  long tet_iterations = 0;
  StepReport last;
  for (auto _ : state) {
    state.PauseTiming();
    body = su.start;
    state.ResumeTiming();
    last = stepper.step(*su.model, body, s, su.inputs);
    tet_iterations += long(last.iterations) * long(su.model->tet_count());
    benchmark::DoNotOptimize(body.x.data());
  }
  state.counters["tets"] = double(su.model->tet_count());
  state.counters["s_per_tet_iter"] =
      benchmark::Counter(double(tet_iterations), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["floor_corrections"] = double(last.volume_corrections);
  // The last step's split (PhaseTimes): the sweeps against everything else in it.
  state.counters["projection_ms"] = last.times.projection_ms;
  state.counters["residual_ms"] = last.times.residual_ms;
  state.counters["other_ms"] = last.times.other_ms;
  state.counters["floor_ms"] = last.times.floor_ms;  // of other_ms
  state.counters["floor_passes"] = double(last.floor_passes);  // all substeps
  state.counters["floor_scans"] = double(last.floor_scan_passes);
  state.counters["inverted"] = double(count_inverted(*su.model, body.x));
}

constexpr int kNewtonRestTicks = 200;

void run_newton_at_rest(benchmark::State& state, const std::string& mesh, double fix_x_max) {
  static std::map<std::string, std::pair<std::shared_ptr<const BodyModel>, BodyState>> cache;
  SolverSettings s;
  s.method = Method::Newton;
  s.substeps = 1;
  s.iterations = 1;
  s.threads = int(state.range(0));
  auto it = cache.find(mesh);
  if (it == cache.end()) {
    FixedSelection fixed;
    fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(fix_x_max, 1, 1)});
    auto model = build_model(resolve_mesh(mesh), Material{1e6, 0.4, 1000}, fixed);
    BodyState body = rest_state(*model);
    Stepper warm;
    for (int t = 0; t < kNewtonRestTicks; ++t) warm.step(*model, body, s, {});
    it = cache.emplace(mesh, std::make_pair(model, body)).first;
  }
  const BodyModel& model = *it->second.first;
  Stepper stepper;
  BodyState body = it->second.second;
  StepReport last = stepper.step(model, body, s, {});  // the preconditioner's factorisation, untimed
  for (auto _ : state) {
    state.PauseTiming();
    body = it->second.second;
    state.ResumeTiming();
    last = stepper.step(model, body, s, {});
    benchmark::DoNotOptimize(body.x.data());
  }
  state.counters["tets"] = double(model.tet_count());
  state.counters["cg_iterations"] = double(last.linear_iterations);
}

void run_vbd(benchmark::State& state, const std::string& mesh, ElasticModel elastic, detail::VbdHessian hessian,
             bool line_search, bool chebyshev) {
  const Setup& su = setup(mesh, elastic);
  SolverSettings s;
  s.method = Method::Vbd;
  s.substeps = 1;
  s.iterations = 20;
  s.line_search = line_search;
  s.chebyshev.delay = chebyshev ? 2 : s.iterations;
  s.threads = int(state.range(0));
  s.record_residuals = false;  // the last step's residuals are taken once, outside the timing
  detail::VbdOptions opt;
  opt.hessian = hessian;
  auto family = detail::make_vbd_family(opt);
  BodyState body = rest_state(*su.model);
  long iterations = 0;
  for (auto _ : state) {
    state.PauseTiming();
    body = rest_state(*su.model);
    body.x = su.x0;
    state.ResumeTiming();
    iterations += family->step(*su.model, body, s, {}, {}).iterations;
    benchmark::DoNotOptimize(body.x.data());
  }
  body = rest_state(*su.model);
  body.x = su.x0;
  s.record_residuals = true;
  const StepReport last = family->step(*su.model, body, s, {}, {});
  state.counters["vertices"] = double(su.model->vertex_count());
  state.counters["s_per_vertex_iter"] = benchmark::Counter(
      double(iterations) * double(su.model->vertex_count()), benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["residual_ratio"] = last.residual_initial > 0 ? last.residual_final / last.residual_initial : 0.0;
}

void register_all() {
  std::vector<std::string> meshes = {"beam3", "armadillo"};
  // More meshes (a builtin name or a mesh path each, ':'-separated) to compare layouts.
  if (const char* extra = std::getenv("PLIANT_BENCH_MESHES")) {
    std::string list = extra;
    for (size_t at = 0; at <= list.size();) {
      const size_t end = std::min(list.find(':', at), list.size());
      if (end > at) meshes.push_back(list.substr(at, end - at));
      at = end + 1;
    }
  }
  // 1 x N: the tangled scene; 64 x 1: the default budget, which keeps the armadillo untangled.
  for (const auto& [substeps, iterations] : {std::pair{1, 1}, std::pair{1, 4}, std::pair{64, 1}})
    benchmark::RegisterBenchmark(
        ("step_xpbd_" + std::to_string(substeps) + "x" + std::to_string(iterations) + "/armadillo").c_str(),
        [=](benchmark::State& st) { run_step(st, "armadillo", substeps, iterations); })
        ->Arg(1)->Arg(2)->ArgName("threads")->Unit(benchmark::kMillisecond)->UseRealTime();
  benchmark::RegisterBenchmark("step_newton_1x1/hippo", [](benchmark::State& st) { run_newton_at_rest(st, "hippo", -0.07159); })
      ->Arg(1)->Arg(2)->ArgName("threads")->Unit(benchmark::kMillisecond)->UseRealTime();
  for (const std::string& mesh : meshes) {
    struct Variant {
      const char* name;
      Method method;
      Sweep sweep;
      bool residuals;
      bool line_search = true;
      ElasticModel elastic = ElasticModel::StVK;
    };
    for (const Variant& v : {Variant{"gs_xpbd", Method::Xpbd, Sweep::GaussSeidel, false},
                             Variant{"gs_xpbd_no_line_search", Method::Xpbd, Sweep::GaussSeidel, false, false},
                             Variant{"gs_xpbd_residual", Method::Xpbd, Sweep::GaussSeidel, true},
                             Variant{"gs_xpbd_corotated", Method::Xpbd, Sweep::GaussSeidel, false, true,
                                     ElasticModel::Corotated},
                             Variant{"jacobi_xpbd", Method::Xpbd, Sweep::Jacobi, false},
                             Variant{"gs_chebyshev", Method::Chebyshev, Sweep::GaussSeidel, false},
                             Variant{"gs_anderson_sor", Method::AndersonSor, Sweep::GaussSeidel, true}}) {
      benchmark::RegisterBenchmark((std::string(v.name) + "/" + mesh).c_str(),
                                   [=](benchmark::State& st) { run(st, mesh, v.method, v.sweep, v.residuals, v.line_search, v.elastic); })
          ->Arg(1)->Arg(2)->ArgName("threads")->Unit(benchmark::kMillisecond)->UseRealTime();
    }
    struct VbdVariant {
      const char* name;
      ElasticModel elastic;
      detail::VbdHessian hessian;
      bool line_search = true;
      bool chebyshev = false;
    };
    using detail::VbdHessian;
    for (const VbdVariant& v : {VbdVariant{"vbd", ElasticModel::StVK, VbdHessian::GaussNewton},
                                VbdVariant{"vbd_projected", ElasticModel::StVK, VbdHessian::Projected},
                                VbdVariant{"vbd_no_line_search", ElasticModel::StVK, VbdHessian::GaussNewton, false},
                                VbdVariant{"vbd_chebyshev", ElasticModel::StVK, VbdHessian::GaussNewton, true, true},
                                VbdVariant{"vbd_corotated", ElasticModel::Corotated, VbdHessian::GaussNewton},
                                VbdVariant{"vbd_corotated_projected", ElasticModel::Corotated, VbdHessian::Projected}}) {
      benchmark::RegisterBenchmark((std::string(v.name) + "/" + mesh).c_str(),
                                   [=](benchmark::State& st) { run_vbd(st, mesh, v.elastic, v.hessian, v.line_search, v.chebyshev); })
          ->Arg(1)->Arg(2)->ArgName("threads")->Unit(benchmark::kMillisecond)->UseRealTime();
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  register_all();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
