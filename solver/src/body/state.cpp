// SPDX-License-Identifier: Apache-2.0
#include "pliant/state.hpp"

#include "pliant/strain_constraint.hpp"

#include <algorithm>
#include <cmath>

namespace pliant {

BodyState rest_state(const BodyModel& model) {
  BodyState s;
  s.x = model.rest_positions;
  s.v.assign(model.vertex_count(), Vec3::Zero());
  s.lambda.assign(model.slot_count(), Vec6::Zero());
  return s;
}

bool is_finite(const BodyState& s) {
  for (const Vec3& p : s.x)
    if (!p.allFinite()) return false;
  for (const Vec3& p : s.v)
    if (!p.allFinite()) return false;
  return true;
}

size_t count_inverted(const BodyModel& model, const std::vector<Vec3>& x) {
  size_t n = 0;
  for (const TetRest& t : model.tets)
    if (volume_ratio(t, gather(x, t.v)) <= 0) ++n;
  return n;
}

double max_speed(const BodyState& state) {
  double v = 0;
  for (const Vec3& vi : state.v) v = std::max(v, vi.norm());
  return v;
}

double kinetic_energy(const BodyModel& model, const BodyState& state) {
  double e = 0;
  for (size_t i = 0; i < state.v.size() && i < model.mass.size(); ++i)
    if (model.inv_mass[i] > 0) e += 0.5 * model.mass[i] * state.v[i].squaredNorm();
  return e;
}

double rms_speed(const BodyModel& model, const BodyState& state) {
  double m = 0;
  for (size_t i = 0; i < model.mass.size(); ++i)
    if (model.inv_mass[i] > 0) m += model.mass[i];
  return m > 0 ? std::sqrt(2 * kinetic_energy(model, state) / m) : 0.0;
}

}  // namespace pliant
