// SPDX-License-Identifier: Apache-2.0
// Particle bodies in a scene (fluids, cloth, ropes): how each was asked for, in the solver's own
// option structs, and how it is built. The scene keeps the configs so that reset, snapshots and
// GetScene can rebuild or echo them. No protobuf in here (body_proto.cpp converts).
#pragma once

#include "pliant/cloth.hpp"
#include "pliant/fluid.hpp"
#include "pliant/particle_body.hpp"

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace pliant::server {

// Limits per scene (docs/service.md).
constexpr size_t kMaxBodiesPerScene = 16;
constexpr size_t kMaxParticlesPerScene = 200'000;
constexpr size_t kMaxEmittersPerFluid = 16;
constexpr size_t kDefaultEmitterParticles = 10'000;  // an emitter's max_particles when unset

struct BodyConfig {
  std::string name;
  std::string kind;  // "fluid" | "cloth" | "rope"
  // fluid
  FluidSettings fluid;
  std::vector<FluidBlock> blocks;
  std::vector<FluidEmitter> emitters;
  // cloth and rope
  ConstraintBodySettings constraint;
  double mass_per_area = 0.2;      // cloth, kg/m^2
  ClothGridSpec grid;              // cloth without a mesh file
  std::string mesh_name;           // cloth from a model-path file: the name the request gave
  std::string mesh_file;           // ... and the file it resolved to
  double mesh_scale = 1.0;
  std::vector<Vec3> rope_points;   // rope polyline, m
  int segments = 0;
  double linear_density = 0.1;     // rope, kg/m
  bool soft_body_contact = true;   // two-way contact with the scene's tet body
  double soft_body_friction = 0.3;
  bool body_contact = true;        // two-way contact with the scene's cloths (and, for a cloth, of
                                   // the other bodies with it)
  double body_friction = 0.3;
  std::vector<uint32_t> pin_indices;
  std::vector<std::pair<Vec3, Vec3>> pin_boxes;  // (min, max)
};

// How far outside the soft body's surface the body's particles stay (fluid: particle_radius x
// spacing; cloth and rope: thickness), m.
double contact_radius(const BodyConfig& config);

// Builds the body with the scene's gravity and pins it. Throws std::invalid_argument naming
// what is wrong (the solver's checks, a pin index out of range).
std::unique_ptr<ParticleBody> make_particle_body(const BodyConfig& config, const Vec3& gravity);

// The most particles a body built from the config can have: its particles at creation plus what
// its emitters may add (`at_creation`: the built body's count).
size_t particle_capacity(const BodyConfig& config, size_t at_creation);

// What readers outside the tick thread know of a body (fixed once the scene is built).
struct BodyInfo {
  std::string name;
  std::string kind;
  size_t particles = 0;  // at creation
  size_t capacity = 0;   // the most it can have (a fluid with emitters grows up to it)
  std::vector<std::array<uint32_t, 3>> triangles;
  std::vector<uint32_t> pinned;  // ascending
  std::vector<Vec3> rest;        // positions at creation
};

}  // namespace pliant::server
