// SPDX-License-Identifier: Apache-2.0
// Two-way contact between a particle body (fluid, cloth, rope) and the tetrahedral body: each
// particle is kept at least `radius` outside the soft body's surface. A touching particle and
// the surface triangle under it share one unilateral constraint C = (p - q).n - radius >= 0,
// q = sum b_i x_i the closest point of the triangle (barycentric b), projected with both sides'
// inverse masses (position-based dynamics), so the corrections carry equal and opposite
// momentum: the particle pushes the body as much as the body pushes it. Coulomb friction
// limits the tangential slip of the contact in the same way. Velocities change by the
// corrections over dt, as a position-based step's do.
#pragma once

#include "pliant/model.hpp"
#include "pliant/particle_body.hpp"
#include "pliant/state.hpp"

#include <span>

namespace pliant {

struct CouplingSettings {
  double radius = 0.0;    // m, how far outside the surface a particle's centre stays (> 0)
  double friction = 0.0;  // Coulomb coefficient of the contact, >= 0
  int iterations = 2;     // Gauss-Seidel passes over the contacts found
};

struct CouplingReport {
  size_t contacts = 0;               // particle-triangle contacts found
  double max_depth = 0.0;            // m, the deepest penetration of radius before correction
  Vec3 force_on_body = Vec3::Zero(); // N, the particles' push on the soft body over dt
};

// Finds the particles within `radius` of the body's surface or inside it (up to about one
// surface-triangle size deep) and pushes them apart from the surface, moving both. `dt` is the
// step the positions were reached in (velocities change by the corrections / dt). Particles with
// inverse mass 0 and fixed vertices do not move. Throws std::invalid_argument naming the field
// when sizes disagree or settings are out of range.
CouplingReport couple_particles_to_body(const BodyModel& model, BodyState& body, ParticleState& particles,
                                        std::span<const double> particle_inv_mass, const CouplingSettings& settings,
                                        double dt);

}  // namespace pliant
