// SPDX-License-Identifier: Apache-2.0
// Choosing a solver by measurement (method auto): each candidate method runs the body's first
// step from rest under the scene's loads within the time budget, and the one whose result is
// nearest the converged implicit step (Newton to a tight tolerance) wins.
#pragma once

#include "pliant/model.hpp"
#include "pliant/settings.hpp"

#include <string>
#include <vector>

namespace pliant {

struct MethodTrial {
  SolverSettings settings;  // the candidate as it ran (time_budget_ms = the budget)
  double error = 0;         // ||x - x*|| / ||x0 - x*|| after one step
  double ms = 0;            // the step's wall time
  int iterations = 0;
  std::string failure;      // why it could not run (empty when it ran)
};

struct MethodChoice {
  SolverSettings settings;          // the winner, budget included
  std::vector<MethodTrial> trials;  // every candidate, in the order tried
  std::string summary;              // one line: the winner and each candidate's error and time
};

// Candidates: newton (its linear solver as base.newton_linear_solver: by default cg above
// kNewtonDirectMaxDofs free dofs, where a factorisation does not fit a tick) and vbd with one substep, and the projection family at base.substeps x 1
// (base.method when it names a projection method, else xpbd), each with iterations capped
// high and time_budget_ms = budget_ms. base supplies dt, gravity, damping, threads, the floor.
// With budget_ms <= 0 the budget is half the tick (base.dt).
MethodChoice choose_method(const BodyModel& model, const SolverSettings& base, double budget_ms);

// The default share of a realtime tick that method auto spends on the solver.
inline constexpr double kAutoBudgetFraction = 0.5;

}  // namespace pliant
