// SPDX-License-Identifier: Apache-2.0
#include "step/stages.hpp"

#include <algorithm>

namespace pliant::detail {

void predict(const BodyModel& m, BodyState& state, const SolverSettings& s, const StepInputs& inputs,
             double h, std::vector<Vec3>& x_start) {
  const size_t nv = m.vertex_count();
  if (state.v.size() != nv) state.v.assign(nv, Vec3::Zero());
  x_start = state.x;
  const bool forces = inputs.external_forces.size() == nv;
  for (size_t i = 0; i < nv; ++i) {
    if (m.inv_mass[i] == 0) {
      state.v[i].setZero();
      continue;
    }
    // Weight is the lumped mass; a floored vertex's inertia is larger (Material::inertia_floor).
    Vec3 a = m.inertia[i] > m.mass[i] ? Vec3(s.gravity * (m.mass[i] / m.inertia[i])) : s.gravity;
    if (forces) a += inputs.external_forces[i] * m.inv_mass[i];
    state.v[i] += h * a;
    state.x[i] += h * state.v[i];
  }
}

// Friction and non-penetration against a static collider for one vertex, at position level
// (Macklin et al. 2019): the normal push-out is exact; the tangential motion since the start of
// the substep is cancelled while it is within the static cone (mu_s * depth), else reduced by
// mu_k * depth.
bool resolve_contact(const Collider& c, Vec3& x, const Vec3& x_start) {
  ContactPoint cp;
  if (!find_contact(c, x, cp)) return false;
  x += cp.depth * cp.normal;
  Vec3 dx = x - x_start;
  Vec3 tangential = dx - dx.dot(cp.normal) * cp.normal;
  const double t = tangential.norm();
  if (t < c.static_friction * cp.depth) x -= tangential;
  else if (t > 0) x -= tangential * std::min(c.dynamic_friction * cp.depth / t, 1.0);
  return true;
}

int resolve_colliders(const BodyModel& m, std::vector<Vec3>& x, const std::vector<Vec3>& x_start,
                      const std::vector<Collider>& colliders) {
  if (colliders.empty()) return 0;
  int n = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    if (m.inv_mass[i] == 0) continue;
    for (const Collider& c : colliders) n += resolve_contact(c, x[i], x_start[i]);
  }
  return n;
}

void add_substep(StepReport& total, StepReport&& r) {
  total.iterations += r.iterations;
  total.accelerations_tried += r.accelerations_tried;
  total.accelerations_accepted += r.accelerations_accepted;
  total.anderson_columns_dropped += r.anderson_columns_dropped;
  total.diverged |= r.diverged;
  total.stopped_by_tolerance |= r.stopped_by_tolerance;
  total.stopped_by_budget |= r.stopped_by_budget;
  total.floor_stopped_by_budget |= r.floor_stopped_by_budget;
  total.cancelled |= r.cancelled;
  total.contacts = r.contacts;
  total.volume_corrections = r.volume_corrections;
  total.linear_iterations += r.linear_iterations;
  total.hessian_reused += r.hessian_reused;
  total.times.projection_ms += r.times.projection_ms;
  total.times.anderson_ms += r.times.anderson_ms;
  total.times.update_ms += r.times.update_ms;
  total.times.residual_ms += r.times.residual_ms;
  total.times.other_ms += r.times.other_ms;
  total.times.floor_ms += r.times.floor_ms;
  total.times.floor_scan_ms += r.times.floor_scan_ms;
  total.floor_passes += r.floor_passes;
  total.floor_scan_passes += r.floor_scan_passes;
  total.floor_settle_clusters += r.floor_settle_clusters;
  total.residuals = std::move(r.residuals);
  total.residual_initial = r.residual_initial;
  total.residual_final = r.residual_final;
}

SolverSettings quiet_substep(const SolverSettings& s) {
  SolverSettings quiet = s;
  quiet.record_residuals = s.record_residuals && (s.tolerance > 0 || s.method == Method::Anderson ||
                                                  s.method == Method::AndersonSor || s.method == Method::Extrapolation);
  return quiet;
}

void finish_substep(const BodyModel& m, BodyState& state, const std::vector<Vec3>& x_start,
                    const SolverSettings& s, double h) {
  for (size_t i = 0; i < m.vertex_count(); ++i) state.v[i] = (state.x[i] - x_start[i]) / h;
  apply_damping(m, state, s, h);
}

}  // namespace pliant::detail
