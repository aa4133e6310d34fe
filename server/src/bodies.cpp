// SPDX-License-Identifier: Apache-2.0
// Builds a scene's particle bodies from their configs.
#include "pliant/server/bodies.hpp"

#include <stdexcept>

namespace pliant::server {

std::unique_ptr<ParticleBody> make_particle_body(const BodyConfig& c, const Vec3& gravity) {
  if (c.kind == "fluid") {
    FluidSettings s = c.fluid;
    s.gravity = gravity;
    s.max_particles = kMaxParticlesPerScene;
    return std::make_unique<FluidBody>(s, c.blocks, c.emitters);
  }
  ConstraintBodySettings s = c.constraint;
  s.gravity = gravity;
  std::unique_ptr<ConstraintBody> body;
  if (c.kind == "cloth") {
    if (!c.mesh_file.empty()) body = ConstraintBody::cloth_from_file(c.mesh_file, c.mesh_scale, c.mass_per_area, s);
    else body = ConstraintBody::cloth_grid(c.grid, s);
  } else if (c.kind == "rope") {
    body = ConstraintBody::rope(c.rope_points, c.segments, c.linear_density, s);
  } else {
    throw std::invalid_argument("kind '" + c.kind + "' is not a particle body kind (fluid, cloth, rope)");
  }
  const size_t n = body->size();
  for (size_t k = 0; k < c.pin_indices.size(); ++k) {
    if (c.pin_indices[k] >= n)
      throw std::invalid_argument("pins.indices[" + std::to_string(k) + "] = " + std::to_string(c.pin_indices[k]) +
                                  " is out of range (the body has " + std::to_string(n) + " particles)");
    body->pin(c.pin_indices[k]);
  }
  if (!c.pin_boxes.empty()) {
    const auto& x = body->state().x;
    for (size_t i = 0; i < n; ++i)
      for (const auto& [lo, hi] : c.pin_boxes)
        if ((x[i].array() >= lo.array()).all() && (x[i].array() <= hi.array()).all()) {
          body->pin(i);
          break;
        }
  }
  return body;
}

size_t particle_capacity(const BodyConfig& c, size_t at_creation) {
  size_t n = at_creation;
  for (const FluidEmitter& e : c.emitters) n += e.max_particles;
  return n;
}

double contact_radius(const BodyConfig& c) {
  return c.kind == "fluid" ? c.fluid.particle_radius * c.fluid.spacing : c.constraint.thickness;
}

}  // namespace pliant::server
