// SPDX-License-Identifier: Apache-2.0
// The mutable part of a soft body: positions, velocities and the Lagrange multipliers of the
// last step. Plain vectors, cheap to copy for snapshots and rollback.
#pragma once

#include "pliant/material.hpp"
#include "pliant/model.hpp"

#include <cstdint>
#include <vector>

namespace pliant {

struct BodyState {
  std::vector<Vec3> x;       // positions, m
  std::vector<Vec3> v;       // velocities, m/s
  std::vector<Vec6> lambda;  // strain multipliers of the last substep, in the model's solve order
                             // (model.slot_count() 6-vectors; multipliers_per_tet maps them)
  double lambda_h = 0;       // the substep length lambda belongs to (lambda scales with h^2)
  double time = 0.0;         // simulated seconds
  uint64_t steps = 0;        // steps taken
};

// Rest positions, zero velocity, zero multipliers.
BodyState rest_state(const BodyModel& model);

// True when every position and velocity is finite.
bool is_finite(const BodyState& state);

// Number of tets with det(F) <= 0.
size_t count_inverted(const BodyModel& model, const std::vector<Vec3>& x);

// The largest vertex speed, m/s.
double max_speed(const BodyState& state);

// Kinetic energy of the free vertices, J, and their mass-weighted RMS speed sqrt(2 E / M), m/s:
// whether the body moves, where max_speed can be one light vertex.
double kinetic_energy(const BodyModel& model, const BodyState& state);
double rms_speed(const BodyModel& model, const BodyState& state);

}  // namespace pliant
