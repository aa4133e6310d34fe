// SPDX-License-Identifier: Apache-2.0
// The figure of merit of a solver budget: the true error of one implicit-Euler step,
// ||x - x*|| / ||x0 - x*|| against the converged step x* (Newton, reference_solver.hpp), as a
// function of wall-clock milliseconds, for method specs such as "xpbd:64x1" or
// "anderson-sor:1xN:omega=2"; and, for a fixed budget, the dynamic measures the docs use (the
// rest shape against Newton's static solution, the first swing against a converged run).
// Used by `pliant-sim accuracy` and its tests.
#pragma once

#include "pliant/mesh.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/model.hpp"
#include "pliant/settings.hpp"
#include "pliant/state.hpp"

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace pliant {

// One entry of --methods: METHOD:SUBSTEPSxITERATIONS[:KEY=VALUE...], e.g. xpbd:64x1,
// xpbd:1xN, anderson-sor:1xN:omega=2, chebyshev:4xN:rho=0.99, xpbd:Nx1:sweep=sequential.
// N (in one of the two places) grows with the time budget. Keys: omega, window, sweep,
// form (thesis | type2), rho, gamma, delay, relaxation (Jacobi), cond (Anderson condition
// limit), floor (inversion floor), line-search (0 | 1).
struct MethodSpec {
  std::string text;  // as given
  SolverSettings settings;  // base settings with the spec applied (substeps, iterations: fixed part)
  bool substeps_grow = false;
  bool iterations_grow = false;
  bool grows() const { return substeps_grow || iterations_grow; }
};

// Parses one spec on top of `base` (dt, threads, gravity, damping). Without an omega key the
// method's recommended omega is used. Throws std::invalid_argument naming the bad part. Does
// not validate() the settings: the caller reports a refusal per spec.
MethodSpec parse_method_spec(std::string_view text, const SolverSettings& base);
// A comma-separated list of specs.
std::vector<MethodSpec> parse_method_specs(std::string_view list, const SolverSettings& base);

// The omega a relaxed method gets when none is given (1 for the plain methods): sor and
// lambda-sor 1.5, anderson-sor and extrapolation 2 (docs/solver.md has the sweep that chose them).
double recommended_omega(Method method);

// The start of the measured step: positions x0 at rest (v = 0), the gravity of the step and
// the prediction x~ the stepper makes from them (x0 + h^2 g, weight over inertia).
struct AccuracyStart {
  std::string name;  // "bend" | "sag"
  BodyState state;
  Eigen::Vector3d gravity = Eigen::Vector3d::Zero();
  std::vector<Vec3> predicted;
};
// bend: the cantilever bent by bend_m at its tip (as `converge`), gravity off;
// sag: the rest shape with gravity on (the first step of a sag).
AccuracyStart accuracy_start(const BodyModel& model, std::string_view start, double dt, double bend_m = 0.01);

struct AccuracyPoint {
  double ms = 0;        // wall time of the step up to this point
  int iterations = 0;   // per substep
  int substeps = 0;
  double error = 0;     // ||x - x*|| / ||x0 - x*||
  double residual = 0;  // the method's own measure after the last iteration (||r|| or gradient norm)
};

struct AccuracyCurve {
  MethodSpec spec;
  std::vector<AccuracyPoint> points;  // in order of increasing work
  std::string refused;                // validate()'s message when the settings were refused
  bool diverged = false;
};

// Runs one spec from `start` against x_star until budget_ms: a single-substep spec whose
// iterations grow runs with the iteration hook (a point per iteration, hook time excluded);
// other growing specs run the whole step for N = 1, 2, 3, 4, 6, 8, 11, 16, ... (about x sqrt 2)
// until a run takes budget_ms or more; a fixed spec is one point. Times are the fastest of up
// to 3 runs (repeats of the whole-step runs only while they fit in the budget; for the hook
// runs, the fastest of each iteration's durations, summed, and as many iterations as fill the
// budget that way).
AccuracyCurve measure_accuracy(const BodyModel& model, const AccuracyStart& start,
                               const std::vector<Vec3>& x_star, const MethodSpec& spec, double budget_ms);

// What S substeps give when each is converged: S implicit-Euler steps of dt / S from the start
// (Newton, the stepper's prediction and its simple damping between substeps). Its error against
// the one-step x* is the floor a spec with S substeps cannot go below, however many iterations.
std::vector<Vec3> converged_substeps(const BodyModel& model, const AccuracyStart& start, const SolverSettings& settings,
                                     int substeps);

// The least ms at which the curve's error is at or below `target` (nullopt if never).
std::optional<double> ms_to_error(const AccuracyCurve& curve, double target);

// ||x - x*|| / ||x0 - x*|| (0 when x0 = x*).
double relative_error(const std::vector<Vec3>& x, const std::vector<Vec3>& x0, const std::vector<Vec3>& x_star);

// The tip's first turning point in y while a body swings, from the tip's y after each step
// (a parabola through the three samples around the turn), s; what `pliant-sim run` reports as
// tip_first_turn_s.
class FirstTurnDetector {
 public:
  explicit FirstTurnDetector(double dt) : dt_(dt) {}
  void add(int step, double tip_y);  // step k >= 1: the state after k steps
  std::optional<double> time() const { return turn_; }

 private:
  double dt_;
  double y_before_ = 0, y_last_ = 0;
  std::optional<double> turn_;
};

// The dynamic measures of one fixed budget: from the rest shape under gravity, the first swing
// turn (damping as given, up to swing_steps steps) and the rest shape (damping 5/s, speed below
// 1e-3 m/s for 5 steps, up to rest_steps steps), as `pliant-sim static --damping 5`.
struct DynamicMeasures {
  std::optional<double> first_turn_s;
  Vec3 rest_tip = Vec3::Zero();
  bool at_rest = false;
  bool diverged = false;
  int rest_steps = 0;
  size_t inverted_tets = 0;  // at rest
  double ms_per_step = 0;    // mean over the rest run
};
DynamicMeasures measure_dynamics(const BodyModel& model, const SolverSettings& settings, int swing_steps,
                                 int rest_steps);

// Tet orders for the sweep-order experiments: "mesh" (as given), "x-slabs" (by the smallest x
// of a tet's corners, mesh order kept within: a beam's cubes slab by slab along its axis, each
// cube's tets together), "x-sorted" (by centroid x), "reversed", "random" (seeded shuffle).
// Vertices are untouched, so x* is the same; only the order the sweeps visit the tets changes.
void reorder_tets(TetMesh& mesh, std::string_view order, unsigned seed = 1);
std::string_view tet_order_names();  // "mesh, x-slabs, x-sorted, reversed, random"

}  // namespace pliant
