// SPDX-License-Identifier: Apache-2.0
// One time step of the XPBD solver: substeps, the projection sweep (Gauss-Seidel or Jacobi),
// the chosen accelerator, contacts, damping, and a report of what the step did (iterations,
// residual history, accelerations accepted/rejected, time split as in thesis figure 3.10).
// A Stepper owns scratch buffers only; the model is shared and the state is the caller's.
#pragma once

#include "pliant/colliders.hpp"
#include "pliant/interaction.hpp"
#include "pliant/model.hpp"
#include "pliant/settings.hpp"
#include "pliant/state.hpp"

#include <atomic>
#include <functional>
#include <memory>
#include <vector>

namespace pliant {

// Wall time spent in each phase of the iterations, ms (thesis figure 3.10).
struct PhaseTimes {
  double projection_ms = 0;  // constraint projection sweeps
  double anderson_ms = 0;    // the accelerator's own work (least squares, extrapolation)
  double update_ms = 0;      // position updates from accelerated multipliers / relaxation
  double residual_ms = 0;    // residual evaluation
  double other_ms = 0;       // prediction, contacts, velocity update, damping, the inversion floor
  double floor_ms = 0;       // of other_ms: the inversion floor's passes after the iterations
  double floor_scan_ms = 0;  // of floor_ms: its later passes that checked every tet (a tangled body)
};

struct StepReport {
  int substeps = 0;
  int iterations = 0;                  // iterations run over all substeps
  std::vector<double> residuals;       // ||r|| after each iteration of the LAST substep
  double residual_initial = 0;         // ||r|| at lambda = 0 of the last substep
  double residual_final = 0;           // last entry of residuals (or initial)
  int accelerations_tried = 0;
  int accelerations_accepted = 0;
  int anderson_columns_dropped = 0;    // condition-number safeguard
  bool diverged = false;               // residual exploded or state went non-finite
  bool stopped_by_tolerance = false;
  bool stopped_by_budget = false;
  // The inversion floor's later passes were cut short by the time budget in some substep (the
  // first pass always runs; the next step's floor goes on).
  bool floor_stopped_by_budget = false;
  bool cancelled = false;              // StepInputs::cancel was set: the step stopped between sweeps
  int contacts = 0;                    // active contacts at the end of the step
  int volume_corrections = 0;          // inversion-floor projections in the last iteration
  // The inversion floor's passes after the iterations, over all substeps (the first of each
  // substep included), and of them the later ones that checked every tet instead of those around
  // the last corrections (the constraint-projection methods' tangled-body passes; 0 for vbd and
  // newton, whose passes follow the moved vertices only).
  int floor_passes = 0;
  int floor_scan_passes = 0;
  // Clusters of slivers the floor's settling passes ran on separate threads (sharing no moving
  // corner), over all substeps: 0 with one thread or one cluster at a time.
  int floor_settle_clusters = 0;
  int linear_iterations = 0;           // method newton with cg: CG iterations over all substeps
  int hessian_reused = 0;              // method newton with cg: iterations that kept an earlier Hessian
  // One per StepInputs::tools, same order: force/torque on the tool averaged over the substeps
  // of the step (= impulse during the step / dt), and the vertices that touched it.
  std::vector<ToolReaction> tools;
  // One per StepInputs::attachments: the force the attachment puts ON THE BODY (lambda / h^2,
  // averaged over the substeps); the force on whatever holds the target is minus this.
  std::vector<Vec3> attachment_forces;
  // One per StepInputs::obstacles (every method): per corner, the impulse the body put on it
  // during the step, N s (the body took minus their sum).
  std::vector<std::vector<Vec3>> obstacle_impulses;
  PhaseTimes times;
  double wall_ms = 0;
};

// Per-step inputs that are not part of the body: external forces (N, per vertex; empty for none),
// static colliders, attachments (grabs) and rigid tools (posed by the caller, fixed during the
// step). Attachments and tools are projected inside every iteration, after the strain sweep,
// like the colliders. Check them with validate_interaction before stepping.
struct StepInputs {
  std::vector<Vec3> external_forces;
  std::vector<Collider> colliders;
  std::vector<Attachment> attachments;
  std::vector<RigidTool> tools;
  std::vector<TriangleObstacle> obstacles;
  // When set, checked between sweeps (iterations) and substeps: once it reads true the step
  // stops where it is (positions stay valid, velocities are those of the work done) and the
  // report says cancelled. Lets a scene's delete, update, reset or shutdown take effect within
  // one sweep whatever the budget.
  const std::atomic<bool>* cancel = nullptr;
};

// The degrees of freedom a global solve works on: 3 per vertex of non-zero inverse mass.
inline int free_dofs(const BodyModel& model) {
  int n = 0;
  for (double w : model.inv_mass) n += w > 0 ? 3 : 0;
  return n;
}

// Whether method newton solves this body's linear systems with cg (settings' choice, auto by size).
inline bool newton_uses_cg(const BodyModel& model, const SolverSettings& settings) {
  return newton_uses_cg(settings.newton_linear_solver, free_dofs(model));
}

class Stepper {
 public:
  Stepper();
  ~Stepper();
  Stepper(Stepper&&) noexcept;
  Stepper& operator=(Stepper&&) noexcept;

  // Advances `state` by settings.dt. The state must belong to `model`.
  StepReport step(const BodyModel& model, BodyState& state, const SolverSettings& settings,
                  const StepInputs& inputs = {});

  // The step cut into `parts` steps of settings.dt / parts, of effective_substeps / parts
  // substeps each (parts must divide them; throws std::invalid_argument naming both), with
  // after_part(part, part_report, inputs) after each part: a scene steps its other bodies
  // alongside, and their contacts may change the state's velocities and move the obstacles the
  // next part sees. A moving tool is posed where it is at each part's end; the time budget is
  // shared over the parts as over the substeps. The report is the step's: substeps and
  // iterations summed, tool and grab forces averaged over all its substeps, the last part's
  // residuals, obstacle_impulses summed over the parts (after_part gets the part's own report). A part
  // that diverges or is cancelled ends the step without its after_part. With nothing changed
  // between the parts the state is step()'s to rounding: to the last bit when parts is a power of
  // two and no tool moves.
  using AfterPart = std::function<void(int part, const StepReport& part_report, StepInputs& inputs)>;
  StepReport step_in_parts(const BodyModel& model, BodyState& state, const SolverSettings& settings,
                           StepInputs inputs, int parts, const AfterPart& after_part);

  // One substep of length h from a given predicted start, exposed for the convergence
  // experiment: x = x_pred on entry, runs up to settings.iterations; the report holds the full
  // residual history. `x_prev` is the position at the start of the substep. lambda is in the
  // model's solve order (model.slot_count() entries; empty: starts at zero).
  StepReport solve_substep(const BodyModel& model, const std::vector<Vec3>& x_prev,
                           std::vector<Vec3>& x, std::vector<Vec6>& lambda, double h,
                           const SolverSettings& settings, const StepInputs& inputs = {});

  // Optional per-iteration hook for experiments (called after every iteration with the
  // current positions); used by the convergence tool to track the true error.
  // elapsed_ms: solver time since the substep started, hook time excluded.
  using IterationHook = std::function<void(int iteration, const std::vector<Vec3>& x,
                                           double residual, double elapsed_ms)>;
  void set_iteration_hook(IterationHook hook);

 private:
  // The substep solve (multipliers in solve order) under a time budget (0: none); with
  // lambda_zero the multipliers start at zero whatever lambda holds.
  StepReport solve_in_slots(const BodyModel& model, const std::vector<Vec3>& x_prev, std::vector<Vec3>& x,
                            std::vector<Vec6>& lambda, double h, const SolverSettings& settings,
                            const StepInputs& inputs, double budget_ms, bool lambda_zero);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Substeps a step runs: settings.substeps, or with settings.target_wave_courant_number > 0 the
// fewest n in [1, 10000] with wave_courant_number(model, dt / n) <= that target.
int effective_substeps(const BodyModel& model, const SolverSettings& settings);

// Velocity damping of one substep of length h (settings.damping).
void apply_damping(const BodyModel& model, BodyState& state, const SolverSettings& settings, double h);

// ||r|| with r = C(x) + alpha~ lambda stacked over all tets (thesis eq. 2.18), alpha~ = alpha/h^2;
// lambda in the model's solve order (BodyState::lambda).
double residual_norm(const BodyModel& model, const std::vector<Vec3>& x,
                     const std::vector<Vec6>& lambda, double h);

}  // namespace pliant
