// SPDX-License-Identifier: Apache-2.0
// A step cut into parts (Stepper::step_in_parts): every part is a step of its own of whole
// substeps, so the solver families need nothing for it; what is per step (the time, the count of
// steps, the damping that is given per step, the budget, the tools' poses, the report) is shared
// out here and put together again.
#include "pliant/stepper.hpp"
#include "step/stages.hpp"

#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace pliant {

namespace {

// The sums of the parts' tool and grab forces, weighted by their substeps, and the contacts by
// vertex; divided by the step's substeps at the end.
struct PartForces {
  std::vector<ToolReaction> tools;
  std::vector<std::unordered_map<int32_t, size_t>> contact_of;  // per tool: vertex -> its contact
  std::vector<Vec3> attachments;

  void add(const StepReport& part) {
    const double n = part.substeps;
    if (tools.size() < part.tools.size()) {
      tools.resize(part.tools.size());
      contact_of.resize(part.tools.size());
    }
    for (size_t t = 0; t < part.tools.size(); ++t) {
      tools[t].force += n * part.tools[t].force;
      tools[t].torque += n * part.tools[t].torque;
      for (const ToolContact& c : part.tools[t].contacts) {
        auto [it, added] = contact_of[t].try_emplace(c.vertex, tools[t].contacts.size());
        if (added) tools[t].contacts.push_back(ToolContact{c.vertex, c.point, c.normal, Vec3::Zero()});
        ToolContact& merged = tools[t].contacts[it->second];
        merged.normal = c.normal;  // the last part in contact
        merged.force += n * c.force;
      }
    }
    if (attachments.size() < part.attachment_forces.size()) attachments.resize(part.attachment_forces.size(), Vec3::Zero());
    for (size_t j = 0; j < part.attachment_forces.size(); ++j) attachments[j] += n * part.attachment_forces[j];
  }

  void finish(StepReport& total, const std::vector<Vec3>& x) {
    const double n = std::max(total.substeps, 1);
    for (ToolReaction& r : tools) {
      r.force /= n;
      r.torque /= n;
      for (ToolContact& c : r.contacts) {
        c.force /= n;
        c.point = x[size_t(c.vertex)];  // as a whole step reports it: the vertex at the step's end
      }
    }
    for (Vec3& f : attachments) f /= n;
    total.tools = std::move(tools);
    total.attachment_forces = std::move(attachments);
  }
};

// A part's report into the step's: as a substep's (add_substep), with its substeps, obstacle
// impulses and wall time added.
void add_part(StepReport& total, StepReport&& part) {
  total.substeps += part.substeps;
  total.wall_ms += part.wall_ms;
  if (total.obstacle_impulses.size() < part.obstacle_impulses.size())
    total.obstacle_impulses.resize(part.obstacle_impulses.size());
  for (size_t o = 0; o < part.obstacle_impulses.size(); ++o) {
    auto& sum = total.obstacle_impulses[o];
    const auto& add = part.obstacle_impulses[o];
    if (sum.size() < add.size()) sum.resize(add.size(), Vec3::Zero());
    for (size_t k = 0; k < add.size(); ++k) sum[k] += add[k];
  }
  detail::add_substep(total, std::move(part));
}

}  // namespace

StepReport Stepper::step_in_parts(const BodyModel& m, BodyState& state, const SolverSettings& s, StepInputs inputs,
                                  int parts, const AfterPart& after_part) {
  const int n = effective_substeps(m, s);
  if (parts < 1 || n % parts != 0)
    throw std::invalid_argument("a step in parts needs parts that divide its substeps: parts " + std::to_string(parts) +
                                ", substeps " + std::to_string(n));
  SolverSettings part = s;
  part.dt = s.dt / parts;
  part.substeps = n / parts;
  part.target_wave_courant_number = 0;  // the substeps are the whole step's
  // Given per step: (1 - k_part)^parts = 1 - k keeps every substep's damping.
  if (s.damping == Damping::RigidPreserving)
    part.damping_coefficient = 1.0 - std::pow(1.0 - s.damping_coefficient, 1.0 / parts);
  // A step records the residuals of its last substep only; so do the parts together.
  SolverSettings early = detail::quiet_substep(part);
  const std::vector<RigidTool> tools = inputs.tools;  // posed at the step's end
  const double time = state.time;
  const uint64_t steps = state.steps;
  StepReport total;
  PartForces forces;
  for (int p = 0; p < parts; ++p) {
    const bool last = p + 1 == parts;
    SolverSettings& ps = last ? part : early;
    if (s.time_budget_ms > 0) ps.time_budget_ms = std::max(1e-6, (s.time_budget_ms - total.wall_ms) / (parts - p));
    for (size_t t = 0; t < tools.size() && t < inputs.tools.size(); ++t)
      inputs.tools[t] = tools[t].at(-(parts - 1 - p) * part.dt);
    StepReport r = step(m, state, ps, inputs);
    forces.add(r);
    const bool stop = r.cancelled || r.diverged;
    if (!stop && after_part) after_part(p, r, inputs);
    add_part(total, std::move(r));
    if (stop) break;
  }
  forces.finish(total, state.x);
  if (!total.cancelled) state.time = time + s.dt;  // one step of dt, as step() counts it
  state.steps = steps + 1;
  return total;
}

}  // namespace pliant
