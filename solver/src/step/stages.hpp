// SPDX-License-Identifier: Apache-2.0
// Stages of a substep that every solver family shares: the prediction (inertia and loads), the
// static colliders' contacts, and the velocity update with damping at the end.
#pragma once

#include "pliant/colliders.hpp"
#include "pliant/model.hpp"
#include "pliant/settings.hpp"
#include "pliant/state.hpp"
#include "pliant/stepper.hpp"

#include <chrono>
#include <vector>

namespace pliant::detail {

using Clock = std::chrono::steady_clock;
inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Calls an experiment's iteration hook with the time since t0 minus the time spent in earlier
// hooks, then adds this call's own time to hook_ms. One clock reading serves both, so the
// times handed to the hook never decrease (a pause between two readings would otherwise make
// the next time smaller than this one).
inline void call_iteration_hook(const Stepper::IterationHook& hook, int it, const std::vector<Vec3>& x, double r,
                                Clock::time_point t0, double& hook_ms) {
  const auto th = Clock::now();
  hook(it, x, r, std::chrono::duration<double, std::milli>(th - t0).count() - hook_ms);
  hook_ms += ms_since(th);
}

// Saves the positions in x_start, then v += h (g weight/inertia + f/inertia), x += h v for the
// free vertices (fixed vertices get v = 0). The result is the inertial target the solvers
// start from.
void predict(const BodyModel& model, BodyState& state, const SolverSettings& settings,
             const StepInputs& inputs, double h, std::vector<Vec3>& x_start);

// Non-penetration and friction of every free vertex against the static colliders, at position
// level (motion since x_start). Returns the number of vertices in contact.
int resolve_colliders(const BodyModel& model, std::vector<Vec3>& x, const std::vector<Vec3>& x_start,
                      const std::vector<Collider>& colliders);
bool resolve_contact(const Collider& collider, Vec3& x, const Vec3& x_start);

// Adds one substep's report to the step's: counts and times add up, flags accumulate, the
// residual history, contacts and volume corrections are the last substep's. Tool and grab
// reactions are the caller's (each family accumulates them its own way).
void add_substep(StepReport& total, StepReport&& substep);

// The settings of a substep before the step's last: a step reports the residual history of its
// last substep only, so the earlier ones record residuals only where the method (Anderson,
// extrapolation) or a tolerance needs them.
SolverSettings quiet_substep(const SolverSettings& settings);

// v = (x - x_start) / h, then the settings' damping.
void finish_substep(const BodyModel& model, BodyState& state, const std::vector<Vec3>& x_start,
                    const SolverSettings& settings, double h);

}  // namespace pliant::detail
