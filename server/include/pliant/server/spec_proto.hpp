// SPDX-License-Identifier: Apache-2.0
// A scene's description in the API (pliant.v1.SceneSpec and its parts: solver, tick, material,
// mesh source, fixed vertices, colliders) to the server's SceneConfig and back, checked on the
// way in. Errors name the field as the request spells it (`prefix`: "spec.solver",
// "snapshot.spec.solver", "solver") and the value. Create, update and snapshots share it.
#pragma once

#include "pliant/server/error.hpp"
#include "pliant/server/scene.hpp"
#include "pliant/v1/pliant.pb.h"

#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace pliant::server {

// The most solver sweeps (substeps x iterations per substep) one tick may ask for.
constexpr int64_t kMaxSweepsPerTick = 200'000;

Vec3 from_proto(const v1::Vec3& v);
void to_proto(const Vec3& v, v1::Vec3* out);
// A vector that must be finite; the error names `field` and the value.
Error finite_from_proto(const v1::Vec3& v, const std::string& field, Vec3* out);
std::optional<TickMode> tick_mode_from(v1::TickMode m);  // nullopt: UNSPECIFIED or unknown
v1::TickMode tick_mode_to(TickMode m);

// A scene or snapshot name: 1 to 64 of A-Z a-z 0-9 _ . - (not "." or "..").
Error check_name(const std::string& field, const std::string& value);

// Merge the fields a message sets into what is there already.
Error merge_solver(const v1::SolverSettings& p, const std::string& prefix, int max_threads, SolverSettings& s);
Error merge_tick(const v1::TickSettings& p, const std::string& prefix, SolverSettings& s, TickMode& mode);
Error merge_gravity(const v1::Vec3& g, const std::string& field, SolverSettings& s);
Error merge_material(const v1::Material& p, const std::string& prefix, Material& m);
// The solver's own checks of merged settings, named as the request names them.
Error check_solver(const SolverSettings& s, const std::string& prefix);
// A tick's work: substeps x iterations within kMaxSweepsPerTick (the substeps a target wave
// Courant number picks for this body included).
Error check_work(const BodyModel& model, const SolverSettings& s, const std::string& prefix);
// Whether solver settings name a budget in sweeps (then the server does not choose the method).
bool pins_budget(const v1::SolverSettings& p);

// The parts of a SceneSpec that do not need the mesh: material, solver, tick, gravity, fixed
// selection and colliders, merged into *cfg and *material and checked, in that order.
Error config_from_spec(const v1::SceneSpec& spec, const std::string& prefix, int max_threads, SceneConfig* cfg,
                       Material* material);

// An uploaded mesh, at most max_vertices vertices (RESOURCE_EXHAUSTED beyond).
Error mesh_from_data(const v1::MeshData& d, const std::string& prefix, int64_t max_vertices, TetMesh* out);
// The mesh a spec.mesh names: builtin, a name in the model path, or uploaded data; scaled.
// Records in cfg where it came from.
Error mesh_from_source(const v1::MeshSource& src, const std::vector<std::string>& model_path, int64_t max_vertices,
                       SceneConfig& cfg, TetMesh* mesh);
Error fixed_from(const v1::FixedSelection& p, const std::string& prefix, FixedSelection* out);
Error colliders_from(const google::protobuf::RepeatedPtrField<v1::Collider>& p, const std::string& prefix,
                     std::vector<Collider>* out);

// SceneSpec.bodies: each body's fields range-checked (errors name `prefix`[i].kind.field and the
// value), names unique, at most kMaxBodiesPerScene bodies and kMaxParticlesPerScene particles
// (RESOURCE_EXHAUSTED; a cloth read from a file is counted once built). A cloth's model_path is
// resolved in `model_path`.
Error bodies_from_spec(const google::protobuf::RepeatedPtrField<v1::BodySpec>& bodies, const std::string& prefix,
                       const std::vector<std::string>& model_path, std::vector<BodyConfig>* out);
void bodies_to_spec(const std::vector<BodyConfig>& bodies, v1::SceneSpec* spec);

// Builds the body model; the solver's std::invalid_argument becomes INVALID_ARGUMENT naming
// the spec's field.
Error build_body(const TetMesh& mesh, const Material& material, const FixedSelection& fixed,
                 std::shared_ptr<const BodyModel>* out);

// What GetScene and a snapshot say about a scene's configuration.
void spec_to_proto(const SceneConfig& cfg, const BodyModel& model, v1::SceneSpec* spec);
v1::SceneState scene_state_of(TickMode mode, bool running);
// The Scene message: configuration, status and the model's figures.
void scene_to_proto(const Scene& scene, v1::Scene* out);

}  // namespace pliant::server
