// SPDX-License-Identifier: Apache-2.0
// The seam between the step and its solver families. Stepper::step hands a step to the family
// of settings.method: constraint projection (XPBD with its sweeps and accelerators, in
// stepper.cpp), vertex block descent (vbd/) or the global Newton step (newton/). Every family
// advances the same model and state, honours the same inputs (fixed vertices, external forces,
// colliders, attachments, tools, cancellation) and fills the same report, using the shared
// stages in stages.hpp for what is not its own (prediction, velocities, damping, colliders).
#pragma once

#include "pliant/stepper.hpp"

#include <memory>

namespace pliant::detail {

class SolverFamily {
 public:
  virtual ~SolverFamily() = default;
  // Advances `state` by settings.dt in effective_substeps(model, settings) substeps, running
  // up to settings.iterations iterations per substep (fewer under settings.tolerance,
  // settings.time_budget_ms or inputs.cancel). The report's residuals are the family's own
  // convergence measure per iteration of the last substep (for VBD and Newton: the norm of the
  // incremental potential's gradient over the free vertices, N). `hook`, when set, is called
  // after every iteration of every substep with the current positions (the experiments' true
  // error), its time excluded from the report.
  virtual StepReport step(const BodyModel& model, BodyState& state, const SolverSettings& settings,
                          const StepInputs& inputs, const Stepper::IterationHook& hook) = 0;
};

std::unique_ptr<SolverFamily> make_vbd_family();
std::unique_ptr<SolverFamily> make_newton_family();

}  // namespace pliant::detail
