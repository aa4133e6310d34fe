// SPDX-License-Identifier: Apache-2.0
// The immutable part of a soft body: rest shape, per-tet rest data, lumped masses, material
// and the constraint colouring. Built once from a mesh, shared read-only (shared_ptr<const>)
// by the solver, snapshots and any number of readers. Mutable quantities live in BodyState.
#pragma once

#include "pliant/material.hpp"
#include "pliant/mesh.hpp"

#include <Eigen/Core>

#include <memory>
#include <string>
#include <vector>

namespace pliant {

using Mat3 = Eigen::Matrix3d;

namespace detail {
struct PackedModel;  // the sweeps' packs (solver-internal, kernels/strain_kernel.hpp)
}

// Rest data of one strain constraint, laid out flat for the projection loop.
struct TetRest {
  Tet v;               // vertex indices
  Mat3 dm_inv;         // inverse of D_m = [X0-X3, X1-X3, X2-X3]
  double volume;       // rest volume V0 (> 0)
  double sqrt_volume;  // sqrt(V0): C = sqrt(V0) * strain
};

// Which vertices are held in place (inverse mass 0).
struct FixedSelection {
  std::vector<int32_t> indices;            // explicit vertex indices
  struct Box { Vec3 min, max; };
  std::vector<Box> boxes;                  // every vertex inside any box
  struct HalfSpace { Vec3 point, normal; };
  std::vector<HalfSpace> half_spaces;      // every vertex with (x - point).normal <= 0
};

// Compiled once with the model (build_model, with_material, with_fixed): everything the solver
// families read besides the rest data, so that no step rebuilds or remaps anything.
struct BodyModel {
  uint64_t id = 0;  // unique per built model
  std::string name;
  std::vector<Vec3> rest_positions;
  std::vector<TetRest> tets;
  std::vector<double> mass;       // lumped: each tet gives rho*V0/4 to each vertex (its weight)
  std::vector<double> inertia;    // max(mass, material.inertia_floor x mean vertex mass,
                                  //     material.support_inertia x supported_mass)
  std::vector<double> inv_mass;   // 1 / inertia; 0 for fixed vertices
  std::vector<uint8_t> fixed;     // 1 for fixed vertices
  std::vector<Triangle> surface;  // boundary triangles, outward
  std::vector<int32_t> vertex_tet_count;  // constraints touching each vertex (Jacobi averaging)
  double mean_edge = 0;           // mean rest length of the tets' edges (6 per tet)
  Material material;
  Lame lame{};
  Mat6 stiffness = Mat6::Zero();  // K (alpha = K^-1)
  Mat6 compliance = Mat6::Zero(); // alpha = K^-1
  // Tets grouped so that no two tets of a colour share a vertex: a colour can be projected
  // in parallel with the same result as sequentially (Gauss-Seidel stays deterministic).
  std::vector<std::vector<int32_t>> colours;
  // Vertex -> (tet, corner) adjacency, compressed rows: the tets at vertex i are the entries
  // vertex_tet_entry[vertex_tet_start[i] .. vertex_tet_start[i + 1]), each 4 x tet + corner.
  std::vector<int32_t> vertex_tet_start, vertex_tet_entry;
  // Vertices grouped so that no two vertices of a colour share a tet: vertex block descent
  // updates a colour in parallel with the same result as sequentially.
  std::vector<std::vector<int32_t>> vertex_colours;
  // Solve order: colours (small meshes) or blocks of a mesh cut into slabs, each coloured, cut
  // into packs of 4 tets (padding lanes in a short pack; compile_solve_order), one
  // multiplier slot per lane. BodyState::lambda is kept in this order; tet t's multipliers are
  // at slot tet_slot[t] (multipliers_per_tet maps them for snapshots and other I/O).
  std::vector<int32_t> tet_slot;
  std::shared_ptr<const detail::PackedModel> packed;

  size_t vertex_count() const { return rest_positions.size(); }
  size_t tet_count() const { return tets.size(); }
  size_t slot_count() const;  // multiplier slots (4 x packs >= tet_count)
  double total_mass() const;
  // Inertia the floor adds to free vertices, as a fraction of the total mass, and how many
  // free vertices it raises.
  double added_inertia() const;
  size_t floored_vertices() const;
};

// Builds the model; throws std::invalid_argument with a message naming field and value on a
// bad material, an empty mesh, an out-of-range index, or a tet with non-positive volume.
std::shared_ptr<const BodyModel> build_model(const TetMesh& mesh, const Material& material,
                                             const FixedSelection& fixed = {});

// Same geometry, new material (live material edits): recomputes masses and compliance only.
std::shared_ptr<const BodyModel> with_material(const BodyModel& model, const Material& material);

// Same geometry and material, a new set of fixed vertices.
std::shared_ptr<const BodyModel> with_fixed(const BodyModel& model, const FixedSelection& fixed);

// Multipliers in solve order (slot_count() entries) -> one per tet, in the mesh's order.
std::vector<Vec6> multipliers_per_tet(const BodyModel& model, const std::vector<Vec6>& slots);

// One per tet -> solve order (padding slots zero). Throws std::invalid_argument unless
// per_tet has tet_count() entries.
std::vector<Vec6> multipliers_in_slots(const BodyModel& model, const std::vector<Vec6>& per_tet);

// Speed of pressure waves in the body's material: sqrt((lambda + 2 mu) / rho).
double pressure_wave_speed(const BodyModel& model);

// How many elements a pressure wave crosses in one substep of length h: c_p h / mean edge.
// With one Gauss-Seidel iteration per substep, a body is as stiff as its material only when
// this is well below 1; above, the solve is far from converged and the body is too soft
// (docs/solver.md, "Accuracy of a real-time budget").
double wave_courant_number(const BodyModel& model, double substep);

// The mass each vertex carries to the fixed vertices, kg: vertices are grouped by their
// distance from the fixed ones in tet edges (breadth-first); a vertex at distance d gets the
// mass of every vertex at distance >= d divided by the number of vertices at distance d. A
// hanging chain of equal masses gets, at each mass, the mass of the chain from it down.
// 0 for fixed vertices and for those no path of edges connects to a fixed vertex.
std::vector<double> supported_mass(const BodyModel& model);

// Indices of vertices selected by the selection (sorted, unique).
std::vector<int32_t> select_vertices(const std::vector<Vec3>& positions, const FixedSelection& sel);

// Greedy colouring of tets by shared vertices.
std::vector<std::vector<int32_t>> colour_tets(const std::vector<TetRest>& tets, size_t vertex_count);

// Vertex -> (tet, corner) adjacency in compressed rows (BodyModel::vertex_tet_start/entry).
void vertex_tet_adjacency(const std::vector<TetRest>& tets, size_t vertex_count,
                          std::vector<int32_t>& start, std::vector<int32_t>& entry);

// Greedy colouring of vertices by shared tets (each vertex takes the lowest colour none of its
// tet neighbours has), from the adjacency above. Every vertex gets a colour (one in no tet: 0).
std::vector<std::vector<int32_t>> colour_vertices(const std::vector<TetRest>& tets,
                                                  const std::vector<int32_t>& start,
                                                  const std::vector<int32_t>& entry);

}  // namespace pliant
