// SPDX-License-Identifier: Apache-2.0
// The strain constraint's projection, written once for a lane type T: double (one tet: the
// sequential and Jacobi sweeps, the tests' scalar calls) or v4d (a pack of four tets of one
// colour: the Gauss-Seidel sweep; GCC vector extensions, one AVX2 instruction per operation
// with -march supporting it, two SSE2 halves otherwise). Algebraically equal to the readable
// forms in strain_constraint.cpp (tests compare them), written on the deformation gradient's
// columns: with S = F^T F and Q = sum_k w_k b_k b_k^T the 6x6 system matrix is
// V0 (bilinear terms in S and Q) + alpha~, and the position update is dx_k = w_k sqrt(V0) F P b_k
// with P the symmetric 3x3 of the increment. Symmetric 3x3 matrices are stored in the strain
// vector's Voigt order: 00 11 22 12 02 01.
//
// The four tets of a pack share no vertex (a colour, or a block's colours, is cut into packs),
// and their rest data is stored lane by lane (structure of arrays); padding lanes of a short
// pack repeat a real tet and are never written back. The multipliers (lambda, dlambda) the kernels read and write
// are in SLOT order: pack i owns slots 4i..4i+3, one per lane, so a sweep walks them
// contiguously; BodyState keeps them so and the model maps them per tet for I/O (tet_slot).
#pragma once

#include "pliant/model.hpp"

#include <cstdint>
#include <vector>

// v4d as a template argument: GCC warns that it drops the vector type's attributes there, but
// the type (4 doubles, 32-byte aligned by its size) is what the templates see.
// Put before a small loop of fixed length in the kernels: unrolled whole, its arrays stay in
// registers (GCC kept the 6x6 solve's nested loops as loops over the stack otherwise).
#define PLIANT_UNROLL _Pragma("GCC unroll 8")

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wignored-attributes"

namespace pliant::detail {

typedef double v4d __attribute__((vector_size(32)));  // 32-byte aligned by its size

// Lanes of a lane type, and per-lane access.
template <class T>
inline constexpr int kLanes = 1;
template <>
inline constexpr int kLanes<v4d> = 4;

inline double get_lane(double a, int) { return a; }
inline double get_lane(const v4d& a, int l) { return a[l]; }
inline void set_lane(double& a, int, double value) { a = value; }
inline void set_lane(v4d& a, int l, double value) { a[l] = value; }
template <class T>
inline T splat(double a) {
  if constexpr (kLanes<T> == 1) return a;
  else return T{a, a, a, a};
}

// Rest data of kLanes<T> tets, lane by lane.
template <class T>
struct alignas(sizeof(T)) TetLanes {
  T B[9];  // D_m^-1, row major: B[3 * k + i] = B(k, i)
  T volume;  // V0
  T sqrt_volume;
  T Q[6];  // sum_k w_k b_k b_k^T (Voigt order)
  T w[4];  // inverse masses of the corners
  int32_t tet[kLanes<T>];
  int32_t v[4][kLanes<T>];  // v[corner][lane]
  int lanes;  // real lanes (1..kLanes)
  int32_t slot;  // multiplier slot of lane 0; lane l has slot + l
};
using TetPack = TetLanes<v4d>;
using TetOne = TetLanes<double>;

// Lane l of a pack as one tet.
TetOne lane_of(const TetPack& pack, int lane);

// One tet's rest data with the given corner inverse masses; slot 0.
TetOne tet_lanes(const TetRest& tet, const double w[4]);

// A step of the sweep's schedule: its groups share no vertex and run in parallel, each group's
// packs in order on one thread; a split phase is one colour, whose packs may be cut anywhere.
struct SolvePhase {
  std::vector<size_t> group_begin;  // packs of group g: [group_begin[g], group_begin[g + 1])
  bool split = false;
};

// What the inversion floor reads of a pack (288 of its 768 bytes): det F is det D_s det B, so its
// corners, their inverse masses and det B are all the floor needs, and a bound on how far that
// product can be from the exact det F lets its pre-check skip packs far above the floor; padding
// lanes repeat a real one.
struct alignas(32) FloorCheck {
  v4d det_b;    // det B, B = D_m^-1
  v4d b_norm3;  // ||B||^3, max row sum of |B|
  v4d w[4];     // inverse masses of the corners
  int32_t v[4][4];  // v[corner][lane], as the pack's
  int lanes = 4;    // real lanes, as the pack's
};

// The model's packs, compiled with it (compile_solve_order). Running the phases in order gives
// the same result as projecting every pack in storage order on one thread.
struct PackedModel {
  std::vector<TetPack> packs;  // the four lanes of a pack share no vertex
  std::vector<FloorCheck> floor_checks;  // one per pack
  std::vector<SolvePhase> phases;
  int blocks = 1;  // slabs of the block order (1: colour by colour)
  // BodyModel::vertex_tet_entry addressed by slot (4 x slot + corner): the Jacobi gather.
  std::vector<int32_t> vertex_slot_entry;
  // The Gauss-Seidel sweep's own numbering of the vertices: in the order the packs, in storage
  // order, first reach them, so that each block's vertices lie together in memory. (A mesh's
  // own numbering may scatter them: two threads then write positions that share cache lines.)
  // The sweep projects sweep_packs, the packs with their corners so numbered, on the positions
  // copied into that order; the same arithmetic on the same values as on packs.
  std::vector<int32_t> sweep_vertex;  // per mesh vertex, its sweep index
  std::vector<int32_t> mesh_vertex;   // per sweep index, its mesh vertex
  std::vector<TetPack> sweep_packs;
  // The floor's passes in the same numbering: floor_checks renumbered, and per sweep index its
  // entries of vertex_slot_entry ([sweep_slot_start[s], sweep_slot_start[s + 1])).
  std::vector<FloorCheck> sweep_floor_checks;
  std::vector<int32_t> sweep_slot_start, sweep_slot_entry;
  size_t slot_count() const { return 4 * packs.size(); }  // padding lanes' slots stay zero
};

// Compiles the solve order of a model whose tets, colours, adjacency and inverse masses are
// set: BodyModel::tet_slot and packed (build_model and its variants call this).
// Small meshes go colour by colour (one split phase per colour, as many thread hand-offs per
// sweep as colours). Meshes long enough for several slabs go by blocks: the vertices are cut
// into K slabs of equal count along the rest shape's longest axis; the tets inside a slab form
// one block per slab (phase 1), the tets across the cut between slabs j - 1 and j form cut
// blocks, odd cuts (phase 2) then even cuts (phase 3), and the few tets across more than one
// cut go colour by colour at the end. Each block is coloured on its own into packs. Three
// hand-offs per sweep, and each thread works on its own part of the mesh. K is even (two
// threads take as many slabs each), at most 8, with slabs at least 6 mean edges thick and 512
// tets on average; otherwise 1.
int solve_order_blocks(const BodyModel& model);
void compile_solve_order(BodyModel& model);

// The model's packs (compiled with it).
inline const PackedModel& packed(const BodyModel& model) { return *model.packed; }

// alpha~ (the compliance over h^2) as the kernels take it: the 6x6, and whether its only nonzero
// entries are the normal block (rows and columns 0-2) and the shear rows' diagonal, as an
// isotropic material's are. The kernels then leave out the products with the zeros, which add
// exactly nothing (same results, fewer operations).
struct KernelCompliance {
  Mat6 m = Mat6::Zero();
  bool normal_and_shear = true;
  KernelCompliance() = default;
  KernelCompliance(const Mat6& alpha_tilde);  // NOLINT(google-explicit-constructor): a Mat6 converts
  double operator()(int r, int c) const { return m(r, c); }
};

// One projection's result per lane, before it is applied: the multiplier increment and the
// corner moves (line-search step and lambda_scale included), det F before the projection, and
// the lanes whose 6x6 system was positive definite (bit l; the others must be skipped).
template <class T>
struct StrainStep {
  T dlambda[6];
  T dx[4][3];
  T det;
  int ok = 0;
};

// The kernel's 6x6 solve: A y = rhs lane-wise by LDL^T with reciprocal pivots (6 divisions, no
// square roots; the lower triangle of A), y scaled by lambda_scale; D gets the pivots (a lane with
// a non-positive pivot is not positive definite). The factor is formed with W = L D (Golub and
// Van Loan's form): an entry of column j is A_ij - sum_k W_ik L_jk and a pivot A_jj - sum_k
// W_jk^2 / D_k, whose last term waits on the division before it by one multiply-add. The
// divisions are a chain, the kernel's largest stalls; this form shortens each link and has fewer
// operations (docs/solver.md, "The 6x6 solve's chain of divisions"). Inverting 3x3 or 2x2 blocks
// by their adjugates needs fewer divisions, but its errors grow with the square of A's condition
// number (test StrainConstraint.TheSixBySixSolveIsAccurateToItsConditionNumber). Always inlined:
// in the kernel its arrays stay in registers (here for the tests, GCC would otherwise call it).
template <class T>
[[gnu::always_inline]] inline void ldlt_solve(const T A[6][6], const T rhs[6], double lambda_scale, T D[6], T y[6]) {
  T W[6][6], L[6][6], invD[6];  // W[i][j] = L[i][j] D[j], i > j
  PLIANT_UNROLL
  for (int j = 0; j < 6; ++j) {
    T d = A[j][j];
    PLIANT_UNROLL
    for (int k = 0; k < j; ++k) d -= (W[j][k] * W[j][k]) * invD[k];
    D[j] = d;
    invD[j] = 1.0 / d;
    PLIANT_UNROLL
    for (int i = j + 1; i < 6; ++i) {
      T s = A[i][j];
      PLIANT_UNROLL
      for (int k = 0; k < j; ++k) s -= W[i][k] * L[j][k];
      W[i][j] = s;
      L[i][j] = s * invD[j];
    }
  }
  T z[6];
  PLIANT_UNROLL
  for (int i = 0; i < 6; ++i) {
    T s = rhs[i];
    PLIANT_UNROLL
    for (int k = 0; k < i; ++k) s -= L[i][k] * z[k];
    z[i] = s;
  }
  PLIANT_UNROLL
  for (int i = 5; i >= 0; --i) {
    T s = z[i] * invD[i];
    PLIANT_UNROLL
    for (int k = i + 1; k < 6; ++k) s -= L[k][i] * y[k];
    y[i] = lambda_scale * s;
  }
}

// The projection of the lanes' tets at x: solves [grad C W grad C^T + alpha~] dl =
// -C - alpha~ lambda (LDL^T), dx = W grad C^T dl; with line_search each lane's step is shortened
// until its own residual does not grow (projection.hpp). lambda_t: the lanes' multipliers.
template <class T>
void strain_step(const TetLanes<T>& p, const std::vector<Vec3>& x, const T lambda_t[6], ElasticModel model,
                 const KernelCompliance& alpha_tilde, double lambda_scale, bool line_search, StrainStep<T>& out);

// Gauss-Seidel projection of the real lanes: x, lambda and dlambda (slot order) updated; a lane
// whose system is not positive definite is skipped (dlambda zero). dlambda may be null when no
// one reads the increments (only the multiplier accelerators do): a sweep then does not write
// them. Then the inversion floor for the lanes whose det F was below it before the projection;
// returns how many it corrected. With lambda_zero the multipliers are taken as zero whatever the
// slots hold, and the pack's slots are all written (a substep's first sweep: no zeroing pass).
template <class T>
int project_lanes(const TetLanes<T>& p, std::vector<Vec3>& x, std::vector<Vec6>& lambda,
                  std::vector<Vec6>* dlambda, const BodyModel& model, const KernelCompliance& alpha_tilde,
                  double lambda_scale, double inversion_floor, bool line_search, bool lambda_zero = false);

// x += M^-1 grad C(x)^T dl for the real lanes (the accelerators' position update; dl in slots).
template <class T>
void apply_increment_lanes(const TetLanes<T>& p, std::vector<Vec3>& x, const std::vector<Vec6>& dl,
                           ElasticModel model);

// The inversion floor on a pack's real lanes (tets of one colour) from its FloorCheck: each lane
// with det F = det D_s det B below `trigger` (the floor, or a hair under it) takes the linearised
// correction of enforce_volume_floor (projection.hpp) along grad det F = det B grad det D_s,
// towards `target` (the floor) and scaled by `relax` (1; over-relaxed in a tangled body), all
// lanes at once. Returns the corrected lanes as a bit mask.
int volume_floor_pack(const FloorCheck& c, std::vector<Vec3>& x, double trigger, double target, double relax);

// det F of each lane at x, as volume_floor_pack takes it (det D_s det B).
v4d floor_volume_ratio(const FloorCheck& c, const std::vector<Vec3>& x);

// False only when no lane of the pack can be below `trigger` at x: then volume_floor_pack with
// that trigger would act on none (the same det F with a margin for rounding; tested), so a pass
// may skip the pack after reading its corners alone.
bool floor_may_act(const FloorCheck& c, const std::vector<Vec3>& x, double trigger);

// Sum over the real lanes of ||C + alpha~ lambda||^2 (lambda in slots).
template <class T>
double residual_squared_lanes(const TetLanes<T>& p, const std::vector<Vec3>& x, const std::vector<Vec6>& lambda,
                              const KernelCompliance& alpha_tilde, ElasticModel model);

// Arithmetic operations (+, -, *, /) of one projection (strain_step of one tet), averaged over
// the model's tets at x with multipliers lambda (slots): the kernel's own code run on a number
// type that counts them. The rotation's per-lane scaling and SVD fallback (corotated) and the
// line search's bookkeeping are scalar code outside the count.
double mean_projection_flops(const BodyModel& model, const std::vector<Vec3>& x, const std::vector<Vec6>& lambda,
                             const KernelCompliance& alpha_tilde, bool line_search);

// Ask for a pack's data ahead of its turn: a sweep streams the packs (and the multipliers in
// their slots) from memory and reads the corners' positions scattered.
template <int Write>
inline void prefetch_bytes(const void* p, size_t n) {  // every 64-byte line of [p, p + n)
  const char* a = static_cast<const char*>(p);
  const char* last = a + n - 1;
  for (; a < last; a += 64) __builtin_prefetch(a, Write);
  __builtin_prefetch(last, Write);
}
inline void prefetch_pack(const TetPack& p) { prefetch_bytes<0>(&p, sizeof p); }
// The corners of a pack (a TetPack, or its FloorCheck).
template <class Pack>
inline void prefetch_corners(const Pack& p, const std::vector<Vec3>& x) {
  for (int k = 0; k < 4; ++k)
    for (int l = 0; l < 4; ++l) __builtin_prefetch(x[size_t(p.v[k][l])].data());
}
inline void prefetch_slots(const TetPack& p, const std::vector<Vec6>& slots) {
  prefetch_bytes<1>(slots[size_t(p.slot)].data(), 4 * sizeof(Vec6));
}
// In a loop over packs i < e: the rest data four packs ahead, the corners and the slots of the
// given multiplier vectors two ahead.
template <class... Slots>
inline void prefetch_ahead(const std::vector<TetPack>& packs, size_t i, size_t e, const std::vector<Vec3>& x,
                           const Slots&... slots) {
  if (i + 4 < e) prefetch_pack(packs[i + 4]);
  if (i + 2 < e) {
    prefetch_corners(packs[i + 2], x);
    (prefetch_slots(packs[i + 2], slots), ...);
  }
}

// The pack-of-four names the sweeps use.
inline int project_pack(const TetPack& p, std::vector<Vec3>& x, std::vector<Vec6>& lambda,
                        std::vector<Vec6>* dlambda, const BodyModel& model, const KernelCompliance& alpha_tilde,
                        double lambda_scale, double inversion_floor, bool line_search, bool lambda_zero = false) {
  return project_lanes(p, x, lambda, dlambda, model, alpha_tilde, lambda_scale, inversion_floor, line_search,
                       lambda_zero);
}

}  // namespace pliant::detail

#pragma GCC diagnostic pop
