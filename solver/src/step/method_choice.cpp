// SPDX-License-Identifier: Apache-2.0
#include "pliant/method_choice.hpp"

#include "pliant/state.hpp"
#include "pliant/stepper.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

namespace pliant {

namespace {

double distance(const std::vector<Vec3>& a, const std::vector<Vec3>& b) {
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d += (a[i] - b[i]).squaredNorm();
  return std::sqrt(d);
}

// Sweeps per tick no budget reaches (and within the server's work limit): the time budget is
// what stops a candidate.
constexpr int kUncappedSweeps = 100000;

}  // namespace

MethodChoice choose_method(const BodyModel& model, const SolverSettings& base, double budget_ms) {
  if (!(budget_ms > 0)) budget_ms = kAutoBudgetFraction * base.dt * 1e3;
  SolverSettings common = base;
  common.time_budget_ms = budget_ms;
  common.tolerance = 0;
  common.target_wave_courant_number = 0;

  // The converged first step: Newton without a budget to a tight tolerance.
  const BodyState start = rest_state(model);
  SolverSettings exact = common;
  exact.method = Method::Newton;
  exact.substeps = 1;
  exact.iterations = 200;
  exact.time_budget_ms = 0;
  exact.tolerance = 1e-10;
  exact.newton_linear_solver = NewtonLinearSolver::Direct;  // the exact Newton direction
  BodyState converged = start;
  Stepper().step(model, converged, exact);
  const double scale = distance(start.x, converged.x);

  std::vector<SolverSettings> candidates;
  SolverSettings c = common;
  c.method = Method::Newton;
  c.substeps = 1;
  c.iterations = kUncappedSweeps;
  candidates.push_back(c);
  c.method = Method::Vbd;
  candidates.push_back(c);
  c = common;
  if (family_of(base.method) != SolverFamilyKind::ConstraintProjection || base.method == Method::Auto)
    c.method = Method::Xpbd;
  c.iterations = std::max(1, kUncappedSweeps / std::max(1, c.substeps));
  candidates.push_back(c);

  MethodChoice out;
  double best = INFINITY;
  for (const SolverSettings& cand : candidates) {
    MethodTrial t;
    t.settings = cand;
    if (std::string why = validate(cand); !why.empty()) {
      t.failure = why;
    } else {
      // One warm-up step first: what is built once per model (packs, the Hessian's pattern and
      // its symbolic factorisation, threads) is not part of a tick's cost.
      Stepper stepper;
      {
        BodyState warm = start;
        SolverSettings once = cand;
        once.iterations = 1;
        once.time_budget_ms = 0;
        stepper.step(model, warm, once);
      }
      BodyState s = start;
      const StepReport r = stepper.step(model, s, cand);
      t.ms = r.wall_ms;
      t.iterations = r.iterations;
      t.error = r.diverged || !is_finite(s) ? INFINITY : scale > 0 ? distance(s.x, converged.x) / scale : 0.0;
      if (t.error < best) {
        best = t.error;
        out.settings = cand;
      }
    }
    out.trials.push_back(t);
  }
  if (!std::isfinite(best)) {
    // Nothing ran to a finite result: keep the projection family, which degrades gracefully.
    out.settings = candidates.back();
  }
  std::string parts;
  for (const MethodTrial& t : out.trials) {
    if (!parts.empty()) parts += ", ";
    if (!t.failure.empty())
      parts += fmt::format("{} refused ({})", to_string(t.settings.method), t.failure);
    else
      parts += fmt::format("{}{} {}x{} error {:.2e} in {:.2f} ms", to_string(t.settings.method),
                           t.settings.method == Method::Newton && newton_uses_cg(model, t.settings) ? " (cg)" : "",
                           t.settings.substeps,
                           t.iterations / std::max(1, t.settings.substeps), t.error, t.ms);
  }
  out.summary = fmt::format("{} (budget {:.2f} ms; first step from rest: {})", to_string(out.settings.method),
                            budget_ms, parts);
  return out;
}

}  // namespace pliant
