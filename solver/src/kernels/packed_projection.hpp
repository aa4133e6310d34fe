// SPDX-License-Identifier: Apache-2.0
// The strain projection four tets at a time. Tets of one colour share no vertex, so a colour
// is cut into packs of 4 whose rest data is stored lane by lane (structure of arrays); the
// kernel is the same algebra as projection.cpp written on 4-wide vectors (GCC vector
// extensions: AVX with -march supporting it, two SSE2 halves otherwise). Padding lanes of the
// last pack of a colour repeat a real tet and are never written back.
//
// The multipliers (lambda, dlambda) the packed kernels read and write are in SLOT order: pack
// i owns slots 4i..4i+3, one per lane, so a sweep walks them contiguously. Indexed by tet (the
// mesh's order, scattered within a colour) they would cost a cache miss per tet on large
// meshes; BodyState keeps them in slots and the model maps them per tet for I/O (tet_slot).
#pragma once

#include "pliant/model.hpp"

#include <cstdint>
#include <vector>

namespace pliant::detail {

typedef double v4d __attribute__((vector_size(32), aligned(32)));

struct alignas(32) TetPack {
  v4d B[9];      // D_m^-1, row major: B[3 * k + i] = B(k, i)
  v4d volume;    // V0
  v4d sqrt_volume;
  v4d Q[6];      // sum_k w_k b_k b_k^T: 00 11 22 01 02 12
  v4d w[4];      // inverse masses of the corners
  int32_t tet[4];
  int32_t v[4][4];  // v[corner][lane]
  int lanes;        // real lanes (1..4)
  int32_t slot;     // multiplier slot of lane 0 (4 x the pack's index); lane l has slot + l
};

struct PackedModel {
  std::vector<TetPack> packs;
  std::vector<size_t> colour_begin;  // packs of colour c: [colour_begin[c], colour_begin[c+1])
  // BodyModel::vertex_tet_entry addressed by slot (4 x slot + corner): the Jacobi gather.
  std::vector<int32_t> vertex_slot_entry;
  size_t slot_count() const { return 4 * packs.size(); }  // padding lanes' slots stay zero
};

// Compiles the solve order of a model whose tets, colours, adjacency and inverse masses are
// set: BodyModel::tet_slot, tet_colour and packed (build_model and its variants call this).
void compile_solve_order(BodyModel& model);

// The model's packs (compiled with it).
inline const PackedModel& packed(const BodyModel& model) { return *model.packed; }

// Gauss-Seidel projection of one pack: x, lambda and dlambda (slot order) updated for the real
// lanes.
// Returns the number of lanes below the inversion floor (handled here, scalar). With
// line_search, each tet's step is shortened until its own residual does not grow.
int project_pack(const TetPack& p, std::vector<Vec3>& x, std::vector<Vec6>& lambda,
                 std::vector<Vec6>& dlambda, const BodyModel& model, const Mat6& alpha_tilde,
                 double lambda_scale, double inversion_floor, bool line_search);

// x += M^-1 grad C(x)^T dl for the real lanes (the accelerators' position update; dl in slots).
void pack_apply_increment(const TetPack& p, std::vector<Vec3>& x, const std::vector<Vec6>& dl,
                          ElasticModel model);

// Enforces the inversion floor on the real lanes whose det(F) is below it; returns how many.
// The tets it corrected are appended to hit when given.
int pack_volume_floor(const TetPack& p, std::vector<Vec3>& x, const BodyModel& model, double floor,
                      std::vector<int32_t>* hit = nullptr);

// Sum over the real lanes of ||C + alpha~ lambda||^2 (lambda in slots).
double pack_residual_squared(const TetPack& p, const std::vector<Vec3>& x,
                             const std::vector<Vec6>& lambda, const Mat6& alpha_tilde, ElasticModel model);

}  // namespace pliant::detail
