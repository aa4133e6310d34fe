// SPDX-License-Identifier: Apache-2.0
// Two-way contact between a particle body (fluid, cloth, rope) and the tetrahedral body: each
// particle is kept at least `radius` outside the soft body's surface. A touching particle is
// put back outside the surface triangle it entered (or the closest one), with Coulomb friction
// limiting its slip, and the momentum that correction gave it is taken from the triangle's
// vertices as a change of velocity shared by the barycentric weights: the particle pushes the
// body exactly as much as the body pushes it, and the body's own next step spreads that push
// through its elasticity.
#pragma once

#include "pliant/interaction.hpp"
#include "pliant/model.hpp"
#include "pliant/particle_body.hpp"
#include "pliant/state.hpp"

#include <array>
#include <cstdint>
#include <span>

namespace pliant {

struct CouplingSettings {
  double radius = 0.0;    // m, how far outside the surface a particle's centre stays (> 0)
  double friction = 0.0;  // Coulomb coefficient of the contact, >= 0
  // couple_particles_to_body: false leaves the particles themselves alone and keeps only the
  // segments' inside points out (for a body whose particles met the surface in their own step).
  bool particles = true;
};

struct CouplingReport {
  size_t contacts = 0;               // particle-triangle contacts found
  size_t segment_contacts = 0;       // contacts of points inside the first body's segments
  double max_depth = 0.0;            // m, the deepest penetration of radius before correction
  Vec3 force_on_body = Vec3::Zero(); // N, the particles' push on the soft body's free vertices over dt
};

// Finds the particles within `radius` of the body's surface or inside it and pushes them apart
// from the surface: the particle moves, the body's velocities change. A particle whose path over the step (from `particle_start`, or
// when that is empty from x - dt v, to x) entered a surface triangle goes back out through that
// triangle, however deep it got; the others are measured against the closest triangle (so one
// that started inside a thin body may leave through the far side). `dt` is the step the
// positions were reached in (a particle's velocity changes by its correction / dt). Particles
// with inverse mass 0 are left alone; fixed vertices take no momentum. `segments` (a rope's
// links, a cloth's edges) keep the radius along their length too: points inside each segment,
// no farther apart than the radius, are treated as particles whose correction the segment's two
// particles share (by their inverse masses and the point's place), so a link longer than the
// radius does not slide over an edge of the body between its particles. Throws
// std::invalid_argument naming the field when sizes disagree or settings are out of range.
CouplingReport couple_particles_to_body(const BodyModel& model, BodyState& body, ParticleState& particles,
                                        std::span<const double> particle_inv_mass, const CouplingSettings& settings,
                                        double dt, std::span<const Vec3> particle_start = {},
                                        std::span<const std::array<uint32_t, 2>> segments = {});

// The soft body's side of a particle body's contact with its surface inside the particle body's
// step (SurfaceBoundary, whose x and triangles are this body's): each free vertex's velocity
// changes by minus its impulse over its mass (fixed vertices take none), so what the particles
// gained the body loses. Returns the particles' push on the free vertices, N s. Throws
// std::invalid_argument when the impulses are not one per vertex.
Vec3 take_surface_impulse(const BodyModel& model, BodyState& body, const SurfaceBoundary& surface);

// Two-way contact between a particle body (a fluid, a rope, another cloth) and a cloth, after
// both stepped: each particle stays at least `settings.radius` (the two bodies' contact radii
// summed) from the cloth's triangles, on the side of the triangle it started the step on
// (against the triangle where it started). A particle found behind a triangle goes back to its
// side however far it got when one went through the other during the step (its distance to the
// triangle's plane, interpolated linearly, changes sign within the triangle of that moment): a
// thin cloth is not tunnelled by a particle, nor does a cloth springing back pass through one.
// Positions: only the particle moves (a pinned one stays). Velocities: a perfectly inelastic
// contact between the particle and the triangle's point (inverse masses w_p and sum_k b_k^2 w_k,
// b the barycentric weights), an impulse along the normal shared by the corners' weights, and
// Coulomb friction on the tangential speed up to `settings.friction` x that impulse: momentum is
// exact. `force_on_body`: the particles' push on the cloth over dt, N (the pinned corners'
// share included). `*_start`: positions at the start of the step (the side comes from them).
// `segments` (the first body's links or edges) keep the radius along their length too, as in
// couple_particles_to_body: their inside points, no farther apart than the radius, are treated as
// particles moved across their segment, the move and the impulse shared by the segment's two
// particles (counted in segment_contacts); a segment one of whose particles touched, or one
// through the cloth at both the start and the end of the step (threaded), is left to its
// particles. Throws std::invalid_argument naming the field when sizes disagree or settings are
// out of range.
CouplingReport couple_particles_to_cloth(ParticleState& particles, std::span<const double> particle_inv_mass,
                                         std::span<const Vec3> particle_start, ParticleState& cloth,
                                         std::span<const double> cloth_inv_mass,
                                         std::span<const std::array<uint32_t, 3>> triangles,
                                         std::span<const Vec3> cloth_start, const CouplingSettings& settings,
                                         double dt, std::span<const std::array<uint32_t, 2>> segments = {});

// Steps a particle body and a cloth by dt as a scene steps two bodies in contact: in the parts
// shared_step_parts gives for their substeps (or `parts`, which must divide both), with
// couple_particles_to_cloth (the particles' segments included) after each part. Returns the
// contacts summed over the parts, the deepest, and `force_on_body`, the particles' push on the
// cloth averaged over dt. std::invalid_argument when `parts` does not divide a body's substeps.
CouplingReport step_with_cloth_contact(ParticleBody& particles, ParticleBody& cloth, const CouplingSettings& settings,
                                       double dt, std::span<const Collider> colliders, int parts = 0);

// Two-way contact between a particle body (a fluid, a cloth's particles, another rope) and a
// rope, after both stepped: each particle stays at least `settings.radius` (the two bodies'
// contact radii summed) from the rope's segments, the rope being a chain of capsules. A
// particle that passed through a segment during the step (its offset from the segment turned
// around while the two came within the radius, both moving linearly) goes back to the side it
// started on. Positions: only the particle moves (a pinned one stays). Velocities: a perfectly
// inelastic contact between the particle and the segment's point (inverse masses w_p and
// (1-s)^2 w_a + s^2 w_b), with Coulomb friction up to `settings.friction` x the normal impulse,
// shared by the segment's ends: momentum is exact. `force_on_body`: the particles' push on the
// rope over dt (its pinned particles' share included). `*_start`: the positions at the start of
// the step. `segments`: the first body's links or edges, along their length as against a cloth
// (a link crossing the rope between its two particles; one whose particle touched is left to its
// particles). Throws std::invalid_argument naming the
// field when sizes disagree or settings are out of range.
CouplingReport couple_particles_to_rope(ParticleState& particles, std::span<const double> particle_inv_mass,
                                        std::span<const Vec3> particle_start, ParticleState& rope,
                                        std::span<const double> rope_inv_mass, std::span<const Vec3> rope_start,
                                        const CouplingSettings& settings, double dt,
                                        std::span<const std::array<uint32_t, 2>> segments = {});

// A rigid tool (the haptic bridge's sphere or capsule, at its end-of-step pose) against a particle
// body after the body's step: every particle whose centre is inside the tool grown by `radius`
// (the body's contact_radius) is put back on that surface, with Coulomb friction on its motion
// relative to the tool over the step (static: the whole tangential slip taken back while it is
// below static_friction x depth; else shortened by dynamic_friction x depth), and its velocity
// changes by its correction / dt. The tool takes minus the momentum the particles gained, per
// second of the step: added to `reaction` as a force and a torque about the tool's position
// (the per-vertex contact list is the tet body's; particles are not listed). Pinned particles
// (inverse mass 0) are left alone. Returns the particles pushed. `particle_start`: the positions
// at the start of the step (empty: x - dt v). Throws std::invalid_argument naming the field when
// sizes disagree or dt or radius is out of range.
size_t couple_particles_to_tool(ParticleState& particles, std::span<const double> particle_inv_mass,
                                const RigidTool& tool, double radius, double dt, std::span<const Vec3> particle_start,
                                ToolReaction& reaction);

}  // namespace pliant
