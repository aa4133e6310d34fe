// SPDX-License-Identifier: Apache-2.0
// Bodies made of particles that the position-based loop steps: fluids (SPH density
// constraints), cloth and ropes (distance and bending constraints). A scene holds them beside
// its tetrahedral body; this is what it needs from every kind: the particles and their state,
// one step against the scene's colliders, grabs that report their force, and a state that a
// snapshot can keep and restore.
#pragma once

#include "pliant/colliders.hpp"
#include "pliant/interaction.hpp"
#include "pliant/mesh.hpp"

#include <array>
#include <cstdint>
#include <map>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace pliant {

// How far an emitter has got: the distance its flow moved since its last layer (m) and the
// particles it has created. With it a restored body emits its next layer when the original would.
struct EmitterProgress {
  double travelled = 0.0;
  uint64_t emitted = 0;
};

// The mutable part of a particle body. Kinds keep their multipliers here (one per
// constraint, in the body's constraint order) so a restored snapshot warm-starts like the
// original did.
struct ParticleState {
  std::vector<Vec3> x;          // positions, m
  std::vector<Vec3> v;          // velocities, m/s
  std::vector<double> lambda;   // the last substep's multipliers (kind-defined order)
  double time = 0.0;            // simulated seconds
  uint64_t steps = 0;
  // A kind that keeps the particles in an order of its own (a fluid's cell order) says which:
  // order[k] is the particle (creation index) in its slot k, and substeps counts the substeps
  // run, on which its re-sort schedule depends. With them a restored body continues bit for bit.
  // Empty: the kind has no such order, or (set_state) keep the body's current one.
  std::vector<uint32_t> order;
  uint64_t substeps = 0;
  // A kind that creates particles as it runs (a fluid's emitters): one entry per emitter, and
  // the particle count follows from them. Empty: none, or (set_state) keep the body's current
  // progress, and then its particle count.
  std::vector<EmitterProgress> emitters;
};

// What one step did, for frames and logs.
struct ParticleStepReport {
  int substeps = 0;
  int iterations = 0;             // per substep
  double constraint_error = 0.0;  // kind-defined, dimensionless (fluid: mean relative density
                                  // error; cloth/rope: RMS relative stretch)
  double max_constraint_error = 0.0;
  size_t contacts = 0;            // particle-collider contacts in the last substep
  // Particles the scene's tools pushed in the last substep (ToolBoundary), plus those they pushed
  // after the step (the scene's).
  size_t tool_contacts = 0;
  size_t body_contacts = 0;       // particles and points of segments the scene's cloths and ropes pushed after the step (the scene's)
  // Particles the soft body's surface pushed in the last substep (a kind that meets it inside
  // its step), plus particles and points of segments it pushed after the step (the scene's).
  size_t soft_body_contacts = 0;
  bool self_collision_suspended = false;  // cloth: the step left self-collision out (an edge past twice its length)
  int parts = 1;                  // the parts the scene cut the step into, its contacts after each (the scene's)
  double wall_ms = 0.0;
};

// A soft body's surface that a particle body meets inside its own step, as it meets the
// colliders: each particle kept `radius` outside the triangles (outward, into `x`), held where
// they are over the call, with Coulomb friction (`friction`) on its slip against the surface's
// motion (`v`, the vertices' velocities over the call: a scene passes their mean over the soft
// body's step or part); a fluid also counts it as fluid at rest beyond it in its density
// (FluidSettings::surface_density). What the body does not meet inside its step (the segments
// between a cloth's or a rope's particles) is left to the contact after the step. The momentum the
// particles gained from the surface comes back per vertex in `impulse` (N s, sized to x by the
// call; the soft body takes minus it); the step's report counts the particles it pushed in the
// last substep (soft_body_contacts).
struct SurfaceBoundary {
  std::span<const Triangle> triangles;
  std::span<const Vec3> x;
  std::span<const Vec3> v;
  double radius = 0.0;    // m, > 0
  double friction = 0.0;  // >= 0
  std::vector<Vec3> impulse;
};

// The scene's rigid tools (the haptic bridge's spheres and capsules), met by a particle body inside
// its substeps as it meets the colliders: each tool is where `tools` says at the end of the call
// and moves at its velocity over it (at the end of substep s of n, position - velocity x (dt -
// (s + 1) dt / n)), grown by the body's contact_radius(). A particle inside is put back on its
// surface, with the tool's Coulomb friction on its slip against the tool's motion over the
// substep; so are a cloth's triangles and a rope's links where a tool reaches between their
// particles. What the particles gained comes back per tool, summed over the call: momentum (N s)
// and angular momentum about the tool's centre where it was at each push (N m s), a pinned
// particle's share of a triangle's or a link's push included; the tool takes minus them. A cloth
// or a rope none of whose particles a tool can reach over the call (by their speed and gravity)
// skips the tools for that call.
// `pushed`: the particles a tool pushed in the call's last substep.
struct ToolBoundary {
  std::span<const RigidTool> tools;
  std::vector<Vec3> impulse;          // per tool, sized and zeroed by the call
  std::vector<Vec3> angular_impulse;  // per tool, sized and zeroed by the call
  size_t pushed = 0;
};

// One grab of a particle body: the particle it pulls toward `target` through `compliance` (m/N;
// 0 = hard) and the force it applied to the body over the last step (N). `lambda` is the body's
// multiplier of it: a cloth's or a rope's three rows; a fluid's distance constraint its first
// entry, along `normal`.
struct ParticleGrab {
  size_t particle = 0;
  Vec3 target = Vec3::Zero();
  double compliance = 0.0;
  Vec3 lambda = Vec3::Zero();
  Vec3 normal = Vec3::Zero();
  Vec3 force = Vec3::Zero();
};

// How many parts a step of bodies in contact is cut into, so that their contacts are resolved
// between the parts and not once per step: the largest count that divides every body's substeps
// (each part is whole substeps of every body, so a body alone steps as it would in one piece);
// 1 for no bodies.
int shared_step_parts(std::span<const int> substeps);

// set_state's common check: throws std::invalid_argument naming `kind` and the field when the
// state's positions or velocities are not one per particle.
void check_particle_counts(const ParticleState& state, size_t particles, const std::string& kind);

class ParticleBody {
 public:
  virtual ~ParticleBody() = default;

  // "fluid", "cloth" or "rope".
  virtual std::string kind() const = 0;
  virtual size_t size() const = 0;  // particles
  virtual const ParticleState& state() const = 0;
  // Replaces the state (a snapshot's restore, a rollback): sizes must match the body (a body
  // with emitters: the count its state's emitter progress gives), else std::invalid_argument
  // naming what differs.
  virtual void set_state(const ParticleState& state) = 0;
  // Inverse masses, 1/kg; 0 for a pinned particle.
  virtual std::span<const double> inverse_masses() const = 0;
  // How far from a collider or a tool a particle's centre stays, m (a fluid's particle radius,
  // a cloth's or a rope's thickness).
  virtual double contact_radius() const = 0;
  // Triangles to draw and to collide with (cloth); empty for fluids and ropes.
  virtual std::span<const std::array<uint32_t, 3>> triangles() const { return {}; }
  // Segments that keep the contact radius from a soft body along their length, not only at
  // their particles (a rope's links, a cloth's edges); empty for fluids.
  virtual std::span<const std::array<uint32_t, 2>> segments() const { return {}; }

  // Substeps per step (the body's settings).
  virtual int substeps() const = 0;
  // Advances by dt seconds in `substeps` substeps of dt / substeps against the colliders (and the
  // soft body's surface and the scene's tools, when given): a whole step, or a
  // part of one when a scene cuts the step to resolve the contacts between its bodies in between
  // (`ends_step`: the last part, which counts the step in state().steps).
  virtual ParticleStepReport advance(double dt, int substeps, std::span<const Collider> colliders, bool ends_step,
                                     SurfaceBoundary* surface, ToolBoundary* tools) = 0;
  ParticleStepReport advance(double dt, int substeps, std::span<const Collider> colliders, bool ends_step,
                             SurfaceBoundary* surface) {
    return advance(dt, substeps, colliders, ends_step, surface, nullptr);
  }
  ParticleStepReport advance(double dt, int substeps, std::span<const Collider> colliders, bool ends_step) {
    return advance(dt, substeps, colliders, ends_step, nullptr, nullptr);
  }
  // Advances by dt seconds against the colliders: one step of substeps() substeps.
  ParticleStepReport step(double dt, std::span<const Collider> colliders) {
    return advance(dt, substeps(), colliders, true);
  }
  // Gravity from the next step on (m/s^2; a scene's UpdateScene changes it for all its bodies).
  // std::invalid_argument when not finite.
  virtual void set_gravity(const Vec3& gravity) = 0;

  // Grabs: particle `particle` pulled toward `target` through a constraint of compliance
  // `compliance` (m/N; 0 = hard). The force the grab applies to the body (N) comes from its
  // multiplier, as the soft body's grabs do. grab throws std::invalid_argument naming the bad
  // argument (a particle out of range, a target not finite, a compliance not finite or < 0), as
  // move_grab does for its target; move_grab and release return false for an unknown id.
  void grab(uint64_t id, size_t particle, const Vec3& target, double compliance);
  bool move_grab(uint64_t id, const Vec3& target);
  bool release(uint64_t id);
  Vec3 grab_force(uint64_t id) const;

  // How the body's log lines name it (a scene sets "scene 'S' body 'B'"); kind() when unset.
  void set_log_name(std::string name) { log_name_ = std::move(name); }
  std::string log_name() const { return log_name_.empty() ? kind() : log_name_; }

 protected:
  std::map<uint64_t, ParticleGrab> grabs_;  // by id; each kind solves them in its step

 private:
  std::string log_name_;
};

}  // namespace pliant
