// SPDX-License-Identifier: Apache-2.0
// pliant-sim: offline experiments with the solver, no server.
//   converge  the thesis's one-step convergence experiment (residual and true error per iteration)
//   static    step a clamped body under gravity to rest and report the tip displacement
//   run       simulate N steps and write VTK frames for ParaView
//   accuracy  true error of one step against wall-clock ms for a list of solver budgets
#include "pliant/accuracy.hpp"
#include "pliant/builtin_meshes.hpp"
#include "cli.hpp"
#include "pliant/experiments.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/stepper.hpp"
#include "pliant/strain_constraint.hpp"
#include "pliant/version.hpp"
#include "pliant/vtu_recording.hpp"
#include "sim_cloth.hpp"
#include "sim_fluid.hpp"

#include <Eigen/SVD>
#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <optional>

#include <unistd.h>

using namespace pliant;
namespace cli = pliant::cli;

namespace {

const char* kUsage = R"(usage: pliant-sim COMMAND [options]

commands:
  converge  One step of length --dt from a bent cantilever at rest (tip 10 mm down along -y,
            the linear tip-load shape; velocity zero; gravity off; no substeps). Records ||r||
            every iteration (--csv) and the true error ||x - x*|| / ||x0 - x*|| against the
            reference Newton solution x* of the same step. Last line: one JSON object.
  static    Clamp the vertices with x <= --fix-x-max, apply gravity -y, step with damping until
            at rest. Without solver flags it uses settings that converge to the model's
            equilibrium; with them, what that real-time budget gives. Last line: JSON.
  reference Static equilibrium of the same set-up by Newton's method (independent check).
  run       Simulate --steps steps under gravity and write VTK frames to --out DIR.
  cloth     A cloth grid (or a triangle surface file) dropped on a sphere or a floor: ms per
            step, stretch, penetrations. Last line: JSON (options below).
  rope      A rope hung between two pins at equal height against the catenary. Last line: JSON.
  fluid     A position-based fluid: dam break or column at rest (pliant-sim fluid --help).
  accuracy  The true error ||x - x*|| / ||x0 - x*|| of one implicit-Euler step of length --dt
            against wall-clock ms, x* the Newton solution of the step, for every solver budget in
            --methods (see below). Last line: JSON with, per method, ms_to_error for 1e-1, 1e-2
            and 1e-3 (null when not reached) and error_final.

common options:
  --mesh M            beam1 | beam2 | beam3 | a model name (armadillo, hippo, ...) | a mesh file
  --fix-group G       fix the vertices of the Gmsh file's physical group G (a name or a physical
                      tag) instead of the default clamp (with --fix-x-max: both)
  --young E           Young's modulus, Pa (default 1e6)
  --poisson NU        Poisson's ratio (default 0.4)
  --density RHO       kg/m^3 (default 1000)
  --inertia-floor F   a free vertex's inertia is at least F x the mean vertex mass, its weight
                      stays its mass (default 0.1; 0: plain lumped masses)
  --support-inertia K a free vertex's inertia is at least K x the mass it carries to the
                      clamp, its weight stays its mass (default 0: off; 1 lets one iteration
                      per substep hold a stiff body up, slowing motion near the clamp)
  --model M           strain of the tet constraint: stvk (Green strain, the thesis's; default)
                      | corotated (S - I of F = R S: resists compression down to zero volume)
  --method X          xpbd | sor | lambda-sor | chebyshev | anderson | anderson-sor | extrapolation
                      (constraint projection) | vbd (vertex block descent) | newton (global
                      Newton step on the implicit-Euler potential; iterations = Newton iterations)
  --newton-linear-solver L   newton's linear solver: direct (sparse LDL^T) | cg (inexact
                      Newton: CG preconditioned by an earlier factorisation up to 20000 free
                      dofs, by cg-twolevel above) | cg-jacobi (vertex blocks only) |
                      cg-factor (the factorisation whatever the size) | cg-twolevel (vertex
                      blocks plus a coarse solve on rigid motions of vertex aggregates; what cg
                      uses above 20000 free dofs) | auto (default: cg above 5000 free dofs)
  --newton-forcing F  newton with CG: the loosest relative residual CG is asked for per
                      iteration (default 0: 0.5, or 0.01 with the two-level preconditioner)
  --sweep S           gauss-seidel (coloured, parallel) | jacobi | sequential (one tet at a time
                      in mesh order, one thread: the thesis's sweep; needs --threads 1)
  --tet-order O       renumber the tets before building the body: mesh (as given; the beams:
                      x fastest) | x-slabs (by a tet's smallest corner x, mesh order within:
                      a beam's cubes slab by slab) | x-sorted (by centroid x) | reversed |
                      random (--seed S)
  --anderson-form F   thesis | type2 (default thesis)
  --iterations N      iterations (per substep)
  --substeps N        substeps per step
  --wave-courant C    instead of --substeps: the fewest substeps that keep a pressure wave
                      within C elements per substep (static, run; 0.3 resolves the material)
  --dt H              step length, s (fractions like 1/60 accepted)
  --omega W           over-relaxation factor of sor / lambda-sor / anderson-sor / extrapolation
  --window M          Anderson window (default 5)
  --rho R --gamma G --delay D   Chebyshev parameters
  --tolerance T       stop a substep when ||r||/||r0|| < T
  --time-budget-ms MS stop a step's iterations once it has used MS of wall time (a realtime
                      budget: static and run then show what that budget gives on this machine)
  --threads N         worker threads (default 1)
  --inversion-floor F volume floor det F >= F (default 0.2; 0: the thesis's behaviour)
  --no-line-search    take each tet's full projection step, as the thesis (default: halve it
                      until that tet's residual does not grow)
  --damping K         velocity damping v *= exp(-K h), 1/s (default 0.5; static: 50)
  --log-level L       trace | debug | info | warn | error | critical | off (default warn)
  --quiet             no progress lines (by default converge, static, reference, run and
                      accuracy print one to stderr every 2 s while they run, on a terminal only;
                      stdout carries only the data)
  --version           print the version and exit

converge:  --csv FILE  --match xpbd  --bend-mm D (default 10)
accuracy:  --methods LIST  --budget-ms T (default 100)  --start bend|sag (default bend)
           --csv-dir DIR  --png FILE  --dynamic  --substep-floor  --max-steps K (default 600)
           --bend-mm D
           bend: the bent cantilever at rest as converge, gravity off; sag: the clamped body
           at rest in its rest shape, gravity on (the first step of a sag).
           LIST: comma-separated specs METHOD:SUBSTEPSxITERATIONS[:KEY=VALUE...], N in one of
           the two places meaning "grows with the budget", e.g.
             xpbd:64x1,xpbd:16x4,xpbd:1xN,xpbd:Nx1,anderson-sor:1xN:omega=2,chebyshev:1xN:rho=0.99
           keys: omega window sweep form rho gamma delay relaxation cond floor line-search
           linear (newton: direct | cg | cg-jacobi | cg-factor | cg-twolevel | auto).
           1xN records every iteration of one step (hook time excluded); other N specs run
           the whole step for N = 1, 2, 3, 4, 6, 8, 11, 16, ... until a run takes T ms; a fixed
           spec is one point. Every time is the fastest of up to 3 runs (per iteration for
           1xN: a loaded machine's noise only adds). A method the build refuses (validate)
           is reported with "refused" and the others still run. --csv-dir writes one CSV per
           spec (ms, iterations, substeps, error, residual) and DIR/true_error_vs_ms.png
           (log-log, gnuplot) unless --png names it. --dynamic adds, per fixed spec, the rest
           shape under gravity (damping 5/s, as static --damping 5) as rest_tip_ratio = |tip| /
           |Newton static tip|, and first_turn_s and first_turn_ratio: the tip's first swing
           turn (damping --damping) over that of a converged run (wave Courant 0.3 x 1).
           --substep-floor adds, for specs with a fixed substep count S in 2..256,
           substep_floor: the error of S converged substeps (S Newton solves) against the
           one-step x*, which no iteration count of that spec can go below.
static:    --fix-x-max X  --max-steps K  --speed-tol V (m/s)
converge, static, reference, run: the JSON has "model" (the strain model); converge also
           "tet_order".
static, run: the JSON also has inertia_floor, support_inertia, added_inertia (what the two
           add, as a fraction of the total mass) and floored_vertices, rms_speed (mass-weighted, m/s), kinetic_energy (J) and
           wave_courant_number (c_p h / mean edge: the elements a pressure wave crosses per
           substep; with 1 iteration per substep the body is too soft above ~0.3)
run:       --steps N  --out DIR  --every K  --tip-csv FILE (last line: JSON with ms_per_step,
           inverted_tets at the end, max_inverted_tets and steps_with_inverted over all steps,
           max_speed at the end and peak_speed over all steps, m/s, and tip_first_turn_s: when
           the tip's y first turns back, s, the first half swing of a body let go from rest, or
           null; --tip-csv writes step, t, tip dx/dy/dz, max speed, kinetic energy per step)
)";

const std::set<std::string> kValued = {
    "mesh", "young", "poisson", "density", "method", "sweep", "anderson-form", "iterations",
    "substeps", "wave-courant", "dt", "omega", "window", "rho", "gamma", "delay", "tolerance", "time-budget-ms", "threads",
    "log-level", "csv", "newton-linear-solver", "newton-forcing", "match", "bend-mm", "fix-x-max", "max-steps", "speed-tol", "damping",
    "steps", "out", "every", "tip-csv", "inversion-floor", "inertia-floor", "support-inertia", "model",
    "methods", "budget-ms", "start", "csv-dir", "png", "tet-order", "seed", "fix-group"};
const std::set<std::string> kFlags = {"progress", "quiet", "no-line-search", "dynamic", "substep-floor"};

const std::vector<std::string> kCommands = {"converge", "static", "reference", "run", "accuracy"};
const std::vector<std::string> kParticleCommands = {"cloth", "rope"};

// Progress on stderr while a command runs (cli::Progress: a line every 2 s on a terminal).
std::unique_ptr<cli::Progress> g_progress;
template <class... T>
void progress(fmt::format_string<T...> f, T&&... args) {
  if (g_progress && g_progress->enabled()) g_progress->set(fmt::format(f, std::forward<T>(args)...));
}

// A JSON object written field by field (nlohmann-json, field order kept): strings escaped,
// numbers round-trip, NaN and infinities as null.
class JsonLine {
 public:
  template <class T>
  JsonLine& add(const std::string& k, const T& v) {
    j_[k] = v;
    return *this;
  }
  JsonLine& add(const std::string& k, const Vec3& v) {
    j_[k] = nlohmann::ordered_json::array({v.x(), v.y(), v.z()});
    return *this;
  }
  JsonLine& add(const std::string& k, std::optional<double> v) { return v ? add(k, *v) : null(k); }
  JsonLine& null(const std::string& k) {
    j_[k] = nullptr;
    return *this;
  }
  const nlohmann::ordered_json& json() const { return j_; }
  std::string str() const { return cli::json_line(j_); }

 private:
  nlohmann::ordered_json j_ = nlohmann::ordered_json::object();
};

Material material_from(const cli::Args& a) {
  Material m;
  m.young = a.number("young", 1e6);
  m.poisson = a.number("poisson", 0.4);
  m.density = a.number("density", 1000);
  m.inertia_floor = a.number("inertia-floor", kDefaultInertiaFloor);
  m.support_inertia = a.number("support-inertia", 0.0);
  if (auto v = a.str("model")) {
    auto e = parse_elastic_model(*v);
    if (!e) throw cli::UsageError("--model: unknown model '" + *v + "' (stvk, corotated)");
    m.model = *e;
  }
  if (std::string err = validate(m); !err.empty()) throw cli::UsageError(err);
  return m;
}

// Solver settings from flags on top of `s`.
SolverSettings settings_from(const cli::Args& a, SolverSettings s) {
  if (auto v = a.str("method")) {
    auto m = parse_method(*v);
    if (!m || *m == Method::Auto)
      throw cli::UsageError("--method: unknown method '" + *v + "' (" + std::string(method_names()) +
                            " but auto, which the server resolves per scene)");
    s.method = *m;
  }
  if (auto v = a.str("sweep")) {
    auto w = parse_sweep(*v);
    if (!w) throw cli::UsageError("--sweep: unknown sweep '" + *v + "' (" + std::string(sweep_names()) + ")");
    s.sweep = *w;
  }
  if (auto v = a.str("newton-linear-solver")) {
    auto l = parse_newton_linear_solver(*v);
    if (!l) throw cli::UsageError("--newton-linear-solver: unknown linear solver '" + *v + "' (auto, direct, cg, cg-jacobi, cg-factor, cg-twolevel)");
    s.newton_linear_solver = *l;
  }
  if (auto v = a.str("anderson-form")) {
    auto f = parse_anderson_form(*v);
    if (!f) throw cli::UsageError("--anderson-form: unknown form '" + *v + "' (thesis, type2)");
    s.anderson_form = *f;
  }
  s.iterations = int(a.integer("iterations", s.iterations, 0, 1000000));
  s.substeps = int(a.integer("substeps", s.substeps, 1, 100000));
  s.target_wave_courant_number = a.number("wave-courant", s.target_wave_courant_number);
  s.dt = a.number("dt", s.dt);
  s.omega = a.number("omega", s.omega);
  s.window = int(a.integer("window", s.window, 1, 50));
  s.chebyshev.rho = a.number("rho", s.chebyshev.rho);
  s.chebyshev.gamma = a.number("gamma", s.chebyshev.gamma);
  s.chebyshev.delay = int(a.integer("delay", s.chebyshev.delay, 0, 1000000));
  s.tolerance = a.number("tolerance", s.tolerance);
  s.time_budget_ms = a.number("time-budget-ms", s.time_budget_ms);
  s.newton_forcing = a.number("newton-forcing", s.newton_forcing);
  if (!(s.newton_forcing >= 0 && s.newton_forcing < 1))
    throw cli::UsageError("--newton-forcing: a relative residual in [0, 1), not " + std::to_string(s.newton_forcing));
  s.threads = int(a.integer("threads", s.threads, 1, 256));
  s.inversion_floor = a.number("inversion-floor", s.inversion_floor);
  if (a.has("no-line-search")) s.line_search = false;
  s.damping_coefficient = a.number("damping", s.damping_coefficient);

  if (std::string err = validate(s); !err.empty()) throw cli::UsageError(err);
  return s;
}

std::shared_ptr<const BodyModel> load_model(const cli::Args& a, const Material& mat, std::optional<double> fix_x) {
  const std::string spec = a.str("mesh", "");
  if (spec.empty()) throw cli::UsageError("--mesh is required (beam1, beam2, beam3, a model name or a mesh file)");
  TetMesh mesh;
  try {
    mesh = resolve_mesh(spec);
  } catch (const std::exception& e) {
    throw cli::UsageError(std::string("--mesh: ") + e.what());
  }
  if (auto order = a.str("tet-order")) {
    try {
      reorder_tets(mesh, *order, unsigned(a.integer("seed", 1, 0, 1L << 31)));
    } catch (const std::invalid_argument& e) {
      throw cli::UsageError(e.what());
    }
  }
  const auto group = a.str("fix-group");
  FixedSelection fixed;
  if (fix_x || !group) fixed = clamp_below_x(fix_x ? *fix_x : default_clamp_x(mesh.vertices));
  if (group) {
    try {
      for (int32_t v : group_vertices(mesh, *group)) fixed.indices.push_back(v);
    } catch (const std::exception& e) {
      throw cli::UsageError(std::string("--fix-group: ") + e.what());
    }
  }
  return build_model(mesh, mat, fixed);
}

int cmd_converge(const cli::Args& a) {
  const Material mat = material_from(a);
  auto model = load_model(a, mat, std::nullopt);
  SolverSettings s;
  s.iterations = 600;
  s.gravity.setZero();
  s = settings_from(a, s);
  if (!a.has("omega")) s.omega = recommended_omega(s.method);
  s.substeps = 1;
  const double h = s.dt;
  const double bend = a.number("bend-mm", 10.0) * 1e-3;
  const auto x0 = cantilever_bend(*model, default_clamp_x(model->rest_positions), bend);

  spdlog::info("reference solution of the step (Newton, sparse LDLT)...");
  progress("converge: reference solution of the step (Newton) on {} ({} tets)", model->name, model->tet_count());
  NewtonOptions nopt;
  nopt.tolerance = 1e-10;
  const NewtonResult ref = solve_implicit_step(*model, x0, x0, h, nopt);
  if (!ref.converged) spdlog::warn("reference solver did not converge (|g| = {:.3e})", ref.gradient_norm);

  progress("converge: {} iterations of {} on {}", s.iterations, to_string(s.method), model->name);
  const ConvergenceRun run = run_convergence(*model, x0, ref.x, h, s);
  const double r0 = run.residual0;
  auto iters_to = [&](double rel) -> long {
    for (size_t i = 0; i < run.residual.size(); ++i)
      if (run.residual[i] < rel * r0) return long(i + 1);
    return -1;
  };
  auto ms_at = [&](long iters) { return iters > 0 ? run.elapsed_ms[iters - 1] : std::nan(""); };

  if (auto csv = a.str("csv")) {
    std::ofstream f(*csv);
    if (!f) throw cli::UsageError("--csv: cannot write '" + *csv + "'");
    f << "iteration,residual,relative_residual,error,time_ms\n";
    f << 0 << ',' << r0 << ',' << 1.0 << ',' << 1.0 << ',' << 0.0 << '\n';
    for (size_t i = 0; i < run.residual.size(); ++i)
      f << i + 1 << ',' << run.residual[i] << ',' << run.residual[i] / r0 << ','
        << (i < run.error.size() ? run.error[i] : std::nan("")) << ',' << run.elapsed_ms[i] << '\n';
  }

  JsonLine j;
  j.add("method", std::string(to_string(s.method)))
      .add("sweep", std::string(to_string(s.sweep)))
      .add("mesh", model->name)
      .add("tet_order", a.str("tet-order", "mesh"))
      .add("tets", long(model->tet_count()))
      .add("young", mat.young)
      .add("model", std::string(to_string(mat.model)))
      .add("dt", h)
      .add("omega", s.omega)
      .add("window", s.window)
      .add("iterations", run.report.iterations)
      .add("residual0", r0)
      .add("residual_final", run.report.residual_final);
  for (auto [key, rel] : {std::pair{"iters_to_1e-2", 1e-2}, std::pair{"iters_to_1e-3", 1e-3}}) {
    long it = iters_to(rel);
    if (it > 0) j.add(key, it); else j.null(key);
  }
  j.add("error_final", run.error.empty() ? std::nan("") : run.error.back())
      .add("wall_ms", run.report.wall_ms);
  if (long it = iters_to(1e-3); it > 0) j.add("ms_to_1e-3", ms_at(it)); else j.null("ms_to_1e-3");
  j.add("accelerations_accepted", run.report.accelerations_accepted)
      .add("accelerations_tried", run.report.accelerations_tried)
      .add("anderson_columns_dropped", run.report.anderson_columns_dropped)
      .add("diverged", run.report.diverged)
      .add("projection_ms", run.report.times.projection_ms)
      .add("anderson_ms", run.report.times.anderson_ms)
      .add("update_ms", run.report.times.update_ms)
      .add("residual_ms", run.report.times.residual_ms)
      .add("reference_newton_iterations", ref.iterations);

  if (auto match = a.str("match")) {
    auto mm = parse_method(*match);
    if (!mm) throw cli::UsageError("--match: unknown method '" + *match + "'");
    SolverSettings base = s;
    base.method = *mm;
    base.omega = recommended_omega(*mm);
    progress("converge: {} iterations of {} to match", base.iterations, *match);
    const ConvergenceRun b = run_convergence(*model, x0, ref.x, h, base);
    const double target = b.report.residual_final;
    long it_match = -1;
    for (size_t i = 0; i < run.residual.size(); ++i)
      if (run.residual[i] <= target) { it_match = long(i + 1); break; }
    j.add("match_method", *match).add("match_iterations", b.report.iterations).add("match_residual", target)
        .add("match_wall_ms", b.report.wall_ms)
        .add("match_error_final", b.error.empty() ? std::nan("") : b.error.back());
    if (it_match > 0) j.add("iters_to_match", it_match).add("ms_to_match", ms_at(it_match));
    else j.null("iters_to_match").null("ms_to_match");
  }
  std::cout << j.str() << std::endl;
  return run.report.diverged ? 3 : 0;
}

int cmd_static(const cli::Args& a) {
  const Material mat = material_from(a);
  auto model = load_model(a, mat, a.number("fix-x-max"));
  const bool solver_flags = a.has("method") || a.has("substeps") || a.has("wave-courant") || a.has("iterations") || a.has("dt") ||
                            a.has("sweep") || a.has("tolerance") || a.has("time-budget-ms");
  SolverSettings s;
  if (!solver_flags) {
    // Converge to the model's equilibrium. A converged implicit-Euler step has the static
    // equilibrium as its fixed point, and Gauss-Seidel on the strain multipliers converges in a
    // few tens of sweeps only when alpha/h^2 dominates J M^-1 J^T, i.e. when a substep is no
    // longer than a couple of times the time a pressure wave needs to cross one element
    // (measured in docs/solver.md). So: substeps of h = 2 l / c_p (a wave Courant number of 2),
    // 30 iterations each.
    s.dt = 1.0 / 60.0;
    s.target_wave_courant_number = 2.0;
    s.iterations = 30;
  }
  s.damping = Damping::Simple;
  s.damping_coefficient = 50.0;
  s = settings_from(a, s);
  if (!a.has("omega")) s.omega = recommended_omega(s.method);
  const int substeps = effective_substeps(*model, s);
  spdlog::info("static: {} substeps of {:.3g} s (c_p {:.3g} m/s), {} iterations", substeps, s.dt / substeps,
               pressure_wave_speed(*model), s.iterations);
  const int max_steps = int(a.integer("max-steps", 2000, 1, 10000000));
  const double speed_tol = a.number("speed-tol", 1e-4);
  const bool progress = a.has("progress");
  const RestResult r = run_to_rest(*model, s, max_steps, speed_tol, 5, [&](int k, double v) {
    if (progress && k % 10 == 0) spdlog::info("step {}: max speed {:.3e} m/s", k, v);
    ::progress("static: step {} of at most {}, max speed {:.3e} m/s (at rest below {:.3g})", k, max_steps, v, speed_tol);
  });
  JsonLine j;
  j.add("mesh", model->name).add("young", mat.young).add("poisson", mat.poisson).add("density", mat.density)
      .add("model", std::string(to_string(mat.model)))
      .add("method", std::string(to_string(s.method))).add("substeps", substeps).add("iterations", s.iterations)
      .add("dt", s.dt).add("tip_displacement", tip_displacement(*model, r.state.x)).add("steps", r.steps)
      .add("wave_courant_number", wave_courant_number(*model, s.dt / substeps))
      .add("inertia_floor", mat.inertia_floor).add("support_inertia", mat.support_inertia)
      .add("added_inertia", model->added_inertia())
      .add("floored_vertices", long(model->floored_vertices()))
      .add("max_speed", r.max_speed).add("rms_speed", rms_speed(*model, r.state))
      .add("kinetic_energy", kinetic_energy(*model, r.state)).add("at_rest", r.at_rest).add("diverged", r.diverged)
      .add("inverted_tets", long(count_inverted(*model, r.state.x)))
      .add("last_step_iterations", r.last_report.iterations)
      .add("last_step_wall_ms", r.last_report.wall_ms)
      .add("last_step_phase_ms", nlohmann::ordered_json{{"projection", r.last_report.times.projection_ms},
                                                        {"accelerator", r.last_report.times.anderson_ms},
                                                        {"update", r.last_report.times.update_ms},
                                                        {"residual", r.last_report.times.residual_ms},
                                                        {"other", r.last_report.times.other_ms},
                                                        {"floor", r.last_report.times.floor_ms}});
  if (s.method == Method::Newton)
    j.add("newton_linear_solver",
          std::string(to_string(newton_uses_cg(*model, s) ? NewtonLinearSolver::Cg : NewtonLinearSolver::Direct)))
        .add("last_step_cg_iterations", r.last_report.linear_iterations)
        .add("last_step_hessian_reused", r.last_report.hessian_reused);
  std::cout << j.str() << std::endl;
  return r.diverged ? 3 : (r.at_rest ? 0 : 4);
}

int cmd_reference(const cli::Args& a) {
  const Material mat = material_from(a);
  auto model = load_model(a, mat, a.number("fix-x-max"));
  NewtonOptions opt;
  opt.load_steps = int(a.integer("steps", 10, 1, 10000));
  opt.max_iterations = 200;
  const auto t0 = std::chrono::steady_clock::now();
  progress("reference: Newton static solve of {} ({} tets, {} load steps)", model->name, model->tet_count(), opt.load_steps);
  const NewtonResult r = solve_static(*model, model->rest_positions, Vec3(0, -9.81, 0), {}, opt);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  JsonLine j;
  j.add("mesh", model->name).add("young", mat.young).add("poisson", mat.poisson).add("density", mat.density)
      .add("model", std::string(to_string(mat.model)))
      .add("tip_displacement", tip_displacement(*model, r.x)).add("newton_iterations", r.iterations)
      .add("converged", r.converged).add("gradient_norm", r.gradient_norm).add("wall_ms", ms)
      .add("inverted_tets", long(count_inverted(*model, r.x)));
  std::cout << j.str() << std::endl;
  return r.converged ? 0 : 4;
}

int cmd_run(const cli::Args& a) {
  const Material mat = material_from(a);
  auto model = load_model(a, mat, a.number("fix-x-max"));
  SolverSettings s = settings_from(a, SolverSettings{});
  if (!a.has("omega")) s.omega = recommended_omega(s.method);
  const int substeps = effective_substeps(*model, s);
  const int steps = int(a.integer("steps", 60, 1, 10000000));
  const int every = int(a.integer("every", 1, 1, 10000000));
  const std::string out = a.str("out", "");
  if (out.empty()) throw cli::UsageError("--out DIR is required");
  std::error_code ec;
  std::filesystem::create_directories(out, ec);
  if (ec) throw cli::UsageError("--out: cannot create '" + out + "': " + ec.message());
  BodyState state = rest_state(*model);
  Stepper stepper;
  // Binary .vtu frames and frames.pvd (simulation time per frame) for ParaView.
  RecordingTopology topology;
  topology.rest_positions = model->rest_positions;
  for (const TetRest& t : model->tets) topology.tets.push_back(t.v);
  topology.fixed = model->fixed;
  VtuRecorder recorder(out, std::move(topology));
  double last_residual = 0;
  int written = 0, diverged = 0;
  double wall = 0;
  // Health over the run, checked after every step: the most tets found inverted at a step's
  // end and the fastest vertex seen (a blow-up shows in both long before positions go wild).
  size_t worst_inverted = 0;
  int steps_with_inverted = 0;
  double speed = 0, peak_speed = 0;
  auto write = [&](int k) {
    RecordingFrame frame;
    frame.time = state.time;
    frame.positions = state.x;
    frame.velocity = state.v;
    frame.residual = last_residual;
    recorder.write(frame, k);
    ++written;
  };
  std::ofstream tip_csv;
  if (const std::string path = a.str("tip-csv", ""); !path.empty()) {
    tip_csv.open(path);
    if (!tip_csv) throw cli::UsageError("--tip-csv: cannot write '" + path + "'");
    tip_csv << "step,t_s,tip_dx_m,tip_dy_m,tip_dz_m,max_speed_m_s,kinetic_energy_j\n";
  }
  write(0);
  // The tip's first turning point in y (a parabola through the three samples around it).
  FirstTurnDetector turn(s.dt);
  for (int k = 1; k <= steps; ++k) {
    const StepReport r = stepper.step(*model, state, s);
    const Vec3 tip = tip_displacement(*model, state.x);
    turn.add(k, tip.y());
    wall += r.wall_ms;
    diverged += r.diverged;
    last_residual = r.residual_final;
    const size_t inverted = count_inverted(*model, state.x);
    worst_inverted = std::max(worst_inverted, inverted);
    steps_with_inverted += inverted > 0;
    speed = max_speed(state);
    peak_speed = std::max(peak_speed, speed);
    if (k % every == 0) write(k);
    if (tip_csv.is_open()) {
      char line[256];
      std::snprintf(line, sizeof line, "%d,%.10g,%.10g,%.10g,%.10g,%.6g,%.6g\n", k, k * s.dt, tip.x(), tip.y(),
                    tip.z(), speed, kinetic_energy(*model, state));
      tip_csv << line;
    }
    if (spdlog::should_log(spdlog::level::debug)) {
      // Where the speed is: a few light vertices jittering, or the body moving.
      size_t fast = 0, fastest = 0;
      const double kinetic = kinetic_energy(*model, state);
      for (size_t i = 0; i < state.v.size(); ++i) {
        const double vi = state.v[i].norm();
        fast += vi > 1.0;
        if (vi == speed) fastest = i;
      }
      spdlog::debug("step {}: {} inverted, max speed {:.3g} m/s (vertex {}, mass {:.3g} kg, inertia {:.3g} kg), "
                    "{} vertices above 1 m/s, kinetic energy {:.3g} J", k, inverted, speed, fastest,
                    model->mass[fastest], model->inertia[fastest], fast, kinetic);
    }
    progress("run: step {}/{}, {:.2f} ms/step", k, steps, wall / k);
    if (k % 60 == 0) spdlog::info("step {}/{}: {:.2f} ms/step, {} inverted, max speed {:.3g} m/s", k, steps, wall / k, inverted, speed);
  }
  if (spdlog::should_log(spdlog::level::debug)) {
    double mean_volume = 0;
    for (const TetRest& t : model->tets) mean_volume += t.volume / double(model->tets.size());
    for (size_t t = 0; t < model->tets.size(); ++t) {
      const double j = volume_ratio(model->tets[t], gather(state.x, model->tets[t].v));
      if (j <= 0) spdlog::debug("inverted at the end: tet {} det F {:.3g}, rest volume {:.2g} of the mean", t, j,
                                model->tets[t].volume / mean_volume);
    }
    // Principal stretches at the end: how strained the body is, and around the fastest vertices
    // (an under-resolved budget can hang a stiff body at strains where StVK is no longer stable).
    std::vector<double> smin(model->tets.size()), smax(model->tets.size());
    int count[6] = {0, 0, 0, 0, 0, 0};  // min stretch < 0.5, < 0.7, < 0.9; max stretch > 1.1, > 1.5, > 2
    for (size_t t = 0; t < model->tets.size(); ++t) {
      const auto p = gather(state.x, model->tets[t].v);
      Mat3 ds;
      for (int c = 0; c < 3; ++c) ds.col(c) = p[c] - p[3];
      const Vec3 sv = Eigen::JacobiSVD<Mat3>(ds * model->tets[t].dm_inv).singularValues();
      smin[t] = sv.minCoeff();
      smax[t] = sv.maxCoeff();
      count[0] += smin[t] < 0.5, count[1] += smin[t] < 0.7, count[2] += smin[t] < 0.9;
      count[3] += smax[t] > 1.1, count[4] += smax[t] > 1.5, count[5] += smax[t] > 2;
    }
    spdlog::debug("principal stretches at the end: {} / {} / {} tets with one under 0.5 / 0.7 / 0.9, "
                  "{} / {} / {} with one over 1.1 / 1.5 / 2 (of {})", count[0], count[1], count[2], count[3],
                  count[4], count[5], model->tets.size());
    std::vector<int32_t> order(model->vertex_count());
    for (size_t i = 0; i < order.size(); ++i) order[i] = int32_t(i);
    const size_t shown = std::min<size_t>(8, order.size());
    std::partial_sort(order.begin(), order.begin() + shown, order.end(),
                      [&](int32_t a, int32_t b) { return state.v[a].norm() > state.v[b].norm(); });
    std::vector<double> vmin(model->vertex_count(), 1e300), vmax(model->vertex_count(), 0);
    for (size_t t = 0; t < model->tets.size(); ++t)
      for (int32_t v : model->tets[t].v) vmin[v] = std::min(vmin[v], smin[t]), vmax[v] = std::max(vmax[v], smax[t]);
    for (size_t k = 0; k < shown; ++k) {
      const int32_t v = order[k];
      int fixed_neighbours = 0;
      for (const TetRest& t : model->tets)
        if (std::find(t.v.begin(), t.v.end(), v) != t.v.end())
          for (int32_t u : t.v) fixed_neighbours += model->fixed[u];
      spdlog::debug("fast vertex {}: {:.3g} m/s, rest x {:.4g} m, mass {:.3g} kg, stretches of its tets {:.3g}..{:.3g}, "
                    "{} fixed corners among its tets", v, state.v[v].norm(), model->rest_positions[v].x(),
                    model->mass[v], vmin[v], vmax[v], fixed_neighbours);
    }
  }
  JsonLine j;
  j.add("mesh", model->name).add("young", mat.young).add("model", std::string(to_string(mat.model)))
      .add("steps", steps).add("frames", written).add("out", out)
      .add("ms_per_step", wall / steps).add("diverged_steps", diverged)
      .add("substeps", substeps)
      .add("wave_courant_number", wave_courant_number(*model, s.dt / substeps))
      .add("inertia_floor", mat.inertia_floor).add("support_inertia", mat.support_inertia)
      .add("added_inertia", model->added_inertia())
      .add("floored_vertices", long(model->floored_vertices()))
      .add("tip_displacement", tip_displacement(*model, state.x))
      .add("inverted_tets", long(count_inverted(*model, state.x)))
      .add("max_inverted_tets", long(worst_inverted)).add("steps_with_inverted", steps_with_inverted)
      .add("max_speed", speed).add("peak_speed", peak_speed).add("rms_speed", rms_speed(*model, state))
      .add("kinetic_energy", kinetic_energy(*model, state)).add("tip_first_turn_s", turn.time());
  std::cout << j.str() << std::endl;
  return 0;
}

// A file name for a method spec: letters, digits, '.', '-' and 'x' kept, the rest '_'.
std::string spec_file_name(const std::string& spec) {
  std::string out;
  for (char c : spec) out += (std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '-') ? c : '_';
  return out + ".csv";
}

void write_accuracy_csv(const std::filesystem::path& path, const AccuracyCurve& c) {
  std::ofstream f(path);
  if (!f) throw cli::UsageError("--csv-dir: cannot write '" + path.string() + "'");
  f << "ms,iterations,substeps,error,residual\n";
  char line[160];
  for (const AccuracyPoint& p : c.points) {
    std::snprintf(line, sizeof line, "%.6g,%d,%d,%.10g,%.10g\n", p.ms, p.iterations, p.substeps, p.error, p.residual);
    f << line;
  }
}

// One log-log plot of the true error against ms, a curve per measured spec: colour, dash and
// point type all vary (so curves stay apart in print too), markers thinned to about 20 per
// curve. Returns false when gnuplot failed.
struct PlottedCurve {
  std::string title, csv;
  size_t points = 0;
  double max_error = 0;
};
bool plot_accuracy(const std::string& png, const std::string& title, const std::vector<PlottedCurve>& curves) {
  static const char* kColours[] = {"#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02",
                                   "#a6761d", "#1f78b4", "#e31a1c", "#000000", "#6a3d9a", "#b15928"};
  const std::filesystem::path script = std::filesystem::path(png).replace_extension(".gp");
  double top = 1.0;
  for (const PlottedCurve& c : curves)
    if (std::isfinite(c.max_error)) top = std::max(top, c.max_error);
  {
    std::ofstream g(script);
    if (!g) return false;
    g << "set datafile separator ','\nset terminal pngcairo size 1000,620 font ',10'\n"
      << "set output '" << png << "'\nset logscale xy\nset grid\nset key outside right\n"
      << "set yrange [*:" << 1.3 * top << "]\n"
      << "set title \"" << title << "\"\nset xlabel 'wall time of the step (ms)'\n"
      << "set ylabel '||x - x*|| / ||x0 - x*||  (x*: Newton step)'\nplot ";
    for (size_t i = 0; i < curves.size(); ++i) {
      const size_t every = std::max<size_t>(1, curves[i].points / 20);
      g << (i ? ", \\\n     " : "") << "'" << curves[i].csv << "' using 1:($4 > 0 ? $4 : 1/0) with linespoints lw 2 lc rgb '"
        << kColours[i % 12] << "' dt " << i % 5 + 1 << " pt " << i % 13 + 1 << " ps 1.3 pi " << every << " title '"
        << curves[i].title << "'";
    }
    g << "\n";
  }
  const std::string cmd = "gnuplot '" + script.string() + "' 1>&2";
  const int rc = std::system(cmd.c_str());
  std::filesystem::remove(script);
  return rc == 0;
}

int cmd_accuracy(const cli::Args& a) {
  const Material mat = material_from(a);
  auto model = load_model(a, mat, a.number("fix-x-max"));
  SolverSettings base = settings_from(a, SolverSettings{});
  const std::string start_name = a.str("start", "bend");
  const double budget = a.number("budget-ms", 100.0);
  if (!(budget > 0) || !std::isfinite(budget)) throw cli::UsageError("--budget-ms must be > 0, got " + a.str("budget-ms", ""));
  const std::string list = a.str("methods", "");
  if (list.empty()) throw cli::UsageError("--methods is required (e.g. xpbd:64x1,xpbd:1xN,anderson-sor:1xN:omega=2)");
  std::vector<MethodSpec> specs;
  AccuracyStart start;
  try {
    specs = parse_method_specs(list, base);
    start = accuracy_start(*model, start_name, base.dt, a.number("bend-mm", 10.0) * 1e-3);
  } catch (const std::invalid_argument& e) {
    throw cli::UsageError(e.what());
  }

  spdlog::info("accuracy: reference step (Newton, sparse LDLT)...");
  progress("accuracy: reference step (Newton) on {} ({} tets)", model->name, model->tet_count());
  NewtonOptions nopt;
  nopt.tolerance = 1e-10;
  const NewtonResult ref = solve_implicit_step(*model, start.state.x, start.predicted, base.dt, nopt);
  if (!ref.converged) spdlog::warn("reference solver did not converge (|g| = {:.3e})", ref.gradient_norm);
  double e0 = 0;
  for (size_t i = 0; i < ref.x.size(); ++i) e0 += (start.state.x[i] - ref.x[i]).squaredNorm();

  const bool dynamic = a.has("dynamic");
  std::optional<Vec3> static_tip;
  std::optional<double> reference_turn;
  const int rest_steps = int(a.integer("max-steps", 600, 1, 100000));
  const int swing_steps = std::max(3, int(std::ceil(2.0 / base.dt)));
  if (dynamic) {
    spdlog::info("accuracy: static equilibrium (Newton) and the converged swing (wave Courant 0.3 x 1)...");
    progress("accuracy: static equilibrium (Newton) and the converged swing");
    NewtonOptions sopt;
    sopt.load_steps = 10;
    sopt.max_iterations = 200;
    static_tip = tip_displacement(*model, solve_static(*model, model->rest_positions, Vec3(0, -9.81, 0), {}, sopt).x);
    SolverSettings conv = base;
    conv.method = Method::Xpbd;
    conv.iterations = 1;
    conv.target_wave_courant_number = 0.3;
    reference_turn = measure_dynamics(*model, conv, swing_steps, 0).first_turn_s;
  }

  std::filesystem::path csv_dir;
  if (auto d = a.str("csv-dir")) {
    csv_dir = *d;
    std::error_code ec;
    std::filesystem::create_directories(csv_dir, ec);
    if (ec) throw cli::UsageError("--csv-dir: cannot create '" + *d + "': " + ec.message());
  }
  std::string png = a.str("png", "");
  if (png.empty() && !csv_dir.empty()) png = (csv_dir / "true_error_vs_ms.png").string();
  std::filesystem::path plot_dir = csv_dir;
  if (!png.empty() && plot_dir.empty())
    plot_dir = std::filesystem::temp_directory_path() / ("pliant-accuracy-" + std::to_string(::getpid()));
  if (!plot_dir.empty()) std::filesystem::create_directories(plot_dir);

  std::vector<PlottedCurve> plotted;
  std::map<int, std::vector<Vec3>> floors;  // converged substeps by count
  constexpr int kMaxFloorSubsteps = 256;    // Newton solves per floor: bounded
  nlohmann::ordered_json methods_json = nlohmann::ordered_json::array();
  for (size_t i = 0; i < specs.size(); ++i) {
    const MethodSpec& spec = specs[i];
    spdlog::info("accuracy: {} ...", spec.text);
    progress("accuracy: spec {}/{}: {} (budget {} ms per point)", i + 1, specs.size(), spec.text, budget);
    AccuracyCurve c;
    try {
      c = measure_accuracy(*model, start, ref.x, spec, budget);
    } catch (const std::exception& e) {
      c.spec = spec;
      c.refused = e.what();
    }
    if (!c.refused.empty()) spdlog::warn("accuracy: {} refused: {}", spec.text, c.refused);
    JsonLine m;
    const SolverSettings& s = c.spec.settings;
    m.add("spec", spec.text).add("method", std::string(to_string(s.method))).add("sweep", std::string(to_string(s.sweep)));
    if (spec.substeps_grow) m.add("substeps", "N"); else m.add("substeps", s.substeps);
    if (spec.iterations_grow) m.add("iterations", "N"); else m.add("iterations", s.iterations);
    m.add("omega", s.omega);
    if (c.refused.empty()) m.null("refused"); else m.add("refused", c.refused);
    m.add("diverged", c.diverged).add("points", long(c.points.size()));
    const AccuracyPoint last = c.points.empty() ? AccuracyPoint{std::nan(""), 0, 0, std::nan(""), std::nan("")} : c.points.back();
    m.add("error_final", last.error).add("ms_final", last.ms).add("residual_final", last.residual);
    JsonLine to;
    to.add("1e-1", ms_to_error(c, 1e-1)).add("1e-2", ms_to_error(c, 1e-2)).add("1e-3", ms_to_error(c, 1e-3));
    m.add("ms_to_error", to.json());
    if (!plot_dir.empty() && !c.points.empty()) {
      const auto path = plot_dir / spec_file_name(spec.text);
      write_accuracy_csv(path, c);
      double worst = 0;
      for (const AccuracyPoint& p : c.points) worst = std::max(worst, p.error);
      plotted.push_back({spec.text, path.string(), c.points.size(), worst});
      if (!csv_dir.empty()) m.add("csv", path.string());
    }
    // The floor of a fixed substep count: its converged substeps against the one-step x*.
    if (a.has("substep-floor") && c.refused.empty() && !spec.substeps_grow && s.substeps > 1 &&
        s.substeps <= kMaxFloorSubsteps) {
      auto& floor = floors[s.substeps];
      if (floor.empty()) floor = converged_substeps(*model, start, s, s.substeps);
      m.add("substep_floor", relative_error(floor, start.state.x, ref.x));
    }
    if (dynamic && !spec.grows() && c.refused.empty()) {
      spdlog::info("accuracy: {} dynamic run...", spec.text);
      progress("accuracy: spec {}/{}: {}, dynamic run", i + 1, specs.size(), spec.text);
      SolverSettings ds = s;
      ds.gravity = Vec3(0, -9.81, 0);
      const DynamicMeasures d = measure_dynamics(*model, ds, swing_steps, rest_steps);
      const double tip_ratio = static_tip->norm() > 0 ? d.rest_tip.norm() / static_tip->norm() : std::nan("");
      m.add("rest_tip", d.rest_tip).add("rest_tip_ratio", tip_ratio).add("at_rest", d.at_rest)
          .add("rest_steps", d.rest_steps).add("rest_inverted_tets", long(d.inverted_tets))
          .add("ms_per_step", d.ms_per_step).add("first_turn_s", d.first_turn_s)
          .add("first_turn_ratio", d.first_turn_s && reference_turn ? std::optional<double>(*d.first_turn_s / *reference_turn)
                                                                     : std::nullopt)
          .add("dynamic_diverged", d.diverged);
    }
    methods_json.push_back(m.json());
  }

  if (!png.empty() && !plotted.empty()) {
    char title[256];
    std::snprintf(title, sizeof title, "%s, E = %.3g Pa, h = %.4g s, %s start: true error of one step", model->name.c_str(),
                  mat.young, base.dt, start.name.c_str());
    if (!plot_accuracy(png, title, plotted)) spdlog::warn("accuracy: gnuplot failed or is missing: no plot written to {}", png);
  }
  if (csv_dir.empty() && !plot_dir.empty()) std::filesystem::remove_all(plot_dir);

  JsonLine j;
  j.add("command", "accuracy").add("mesh", model->name).add("tets", long(model->tet_count())).add("young", mat.young)
      .add("poisson", mat.poisson).add("model", std::string(to_string(mat.model))).add("dt", base.dt)
      .add("start", start.name).add("budget_ms", budget).add("threads", base.threads)
      .add("reference_newton_iterations", ref.iterations).add("reference_converged", ref.converged)
      .add("initial_error_m", std::sqrt(e0));
  if (dynamic) {
    j.add("static_tip", *static_tip).add("reference_first_turn_s", reference_turn)
        .add("reference_swing", "xpbd, wave Courant 0.3 x 1 iteration");
  }
  if (!png.empty() && !plotted.empty()) j.add("png", png);
  j.add("methods", methods_json);
  std::cout << j.str() << std::endl;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cout << kUsage;
    return 2;
  }
  if (const std::string first = argv[1]; first != "--help" && first != "-h" && first != "--version" &&
                                         first != "fluid" &&
                                         std::find(kCommands.begin(), kCommands.end(), first) == kCommands.end() &&
                                         std::find(kParticleCommands.begin(), kParticleCommands.end(), first) ==
                                             kParticleCommands.end()) {
    std::cerr << "pliant-sim: unknown command '" << first << "' (converge, static, reference, run, accuracy, fluid, cloth, rope)\n";
    return 2;
  }
  CLI::App app{"pliant-sim"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.formatter_fn([](const CLI::App*, std::string, CLI::AppFormatMode) {
    return std::string(kUsage) + pliant::sim::kClothUsage;
  });
  app.require_subcommand(1, 1);
  std::map<std::string, std::string> values;
  for (const std::string& c : kCommands) {
    CLI::App* sub = app.add_subcommand(c);
    sub->set_version_flag("--version", std::string(pliant::kVersion));
    cli::add_options(*sub, kValued, kFlags, &values);
    sub->get_option("--log-level")->check(cli::one_of(cli::log_levels()));
  }
  std::map<std::string, std::string> fluid_values;
  {
    CLI::App* sub = app.add_subcommand("fluid");
    sub->formatter_fn([](const CLI::App*, std::string, CLI::AppFormatMode) { return std::string(sim::kFluidUsage); });
    cli::add_options(*sub, sim::kFluidValued, sim::kFluidFlags, &fluid_values);
    sub->get_option("--log-level")->check(cli::one_of(cli::log_levels()));
  }
  for (const std::string& c : kParticleCommands) {
    CLI::App* sub = app.add_subcommand(c);
    sub->set_version_flag("--version", std::string(pliant::kVersion));
    cli::add_options(*sub, pliant::sim::kClothValued, pliant::sim::kClothFlags, &values);
    sub->get_option("--log-level")->check(cli::one_of(cli::log_levels()));
  }
  if (auto rc = cli::parse_or_exit(app, argc, argv, "pliant-sim")) return *rc;
  const std::string cmd = app.get_subcommands().at(0)->get_name();
  try {
    if (cmd == "fluid") {
      const cli::Args fa(fluid_values);
      spdlog::set_level(spdlog::level::from_str(fa.str("log-level", "warn")));
      return sim::cmd_fluid(fa);
    }
    const cli::Args a(values);
    spdlog::set_level(spdlog::level::from_str(a.str("log-level", "warn")));
    g_progress = std::make_unique<cli::Progress>("pliant-sim", !a.has("quiet") && cli::Progress::stderr_is_terminal());
    if (cmd == "converge") return cmd_converge(a);
    if (cmd == "static") return cmd_static(a);
    if (cmd == "reference") return cmd_reference(a);
    if (cmd == "run") return cmd_run(a);
    if (cmd == "cloth") return pliant::sim::cmd_cloth(a, *g_progress);
    if (cmd == "rope") return pliant::sim::cmd_rope(a, *g_progress);
    return cmd_accuracy(a);
  } catch (const cli::UsageError& e) {
    g_progress.reset();
    std::cerr << "pliant-sim: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    g_progress.reset();
    std::cerr << "pliant-sim: " << e.what() << "\n";
    return 1;
  }
}
