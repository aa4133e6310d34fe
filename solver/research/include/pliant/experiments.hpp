// SPDX-License-Identifier: Apache-2.0
// The thesis experiments as library calls, shared by pliant-sim, the tests and the benchmarks:
// the cantilever set-up (clamp, bent start), the one-step convergence run with its true error
// against the reference solver, and stepping a body to rest.
#pragma once

#include "pliant/model.hpp"
#include "pliant/settings.hpp"
#include "pliant/stepper.hpp"

#include <vector>

namespace pliant {

// Selects every vertex with x <= x_max (the clamped end of a cantilever).
FixedSelection clamp_below_x(double x_max);
// Default clamp: the minimum x of the rest shape plus a relative tolerance of the extent.
double default_clamp_x(const std::vector<Vec3>& rest);

// The static shape of a cantilever loaded at its tip (linear beam theory) with the tip moved by
// `tip` along -y: v(s) = -tip s^2 (3L - s) / (2 L^3) for s = x - x_clamp, cross-sections rotated
// with the slope (plane sections stay normal to the axis). Clamped vertices stay put.
std::vector<Vec3> cantilever_bend(const BodyModel& model, double x_clamp, double tip);

struct ConvergenceRun {
  std::vector<double> residual;    // ||r|| after each iteration
  std::vector<double> error;       // ||x - x*|| / ||x0 - x*|| after each iteration (if x* given)
  std::vector<double> elapsed_ms;  // solver time up to each iteration
  double residual0 = 0;
  StepReport report;
};

// One step of length h (no substeps) from positions x0 at rest (v = 0, gravity off): the
// prediction is x0 itself; runs settings.iterations and records residual and true error.
ConvergenceRun run_convergence(const BodyModel& model, const std::vector<Vec3>& x0,
                               const std::vector<Vec3>& x_star, double h,
                               const SolverSettings& settings);

struct RestResult {
  BodyState state;
  int steps = 0;
  double max_speed = 0;
  bool at_rest = false;
  bool diverged = false;
  StepReport last_report;
};

// Steps from the rest shape under settings.gravity until every vertex is slower than
// speed_tolerance (m/s) for `calm_steps` consecutive steps, or max_steps. `progress` is called
// every step (may be empty).
RestResult run_to_rest(const BodyModel& model, const SolverSettings& settings, int max_steps,
                       double speed_tolerance, int calm_steps = 5,
                       const std::function<void(int, double)>& progress = {});

// Mean displacement of the vertices at maximum x (the tip of a beam).
Vec3 tip_displacement(const BodyModel& model, const std::vector<Vec3>& x);

}  // namespace pliant
