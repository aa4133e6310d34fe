// SPDX-License-Identifier: Apache-2.0
#include "kernels/strain_kernel.hpp"

#include "kernels/lane_geometry.hpp"
#include "kernels/projection.hpp"

#include "pliant/strain_constraint.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <string>

namespace pliant::detail {

TetOne lane_of(const TetPack& p, int l) {
  TetOne t;
  for (int i = 0; i < 9; ++i) t.B[i] = p.B[i][l];
  t.volume = p.volume[l];
  t.sqrt_volume = p.sqrt_volume[l];
  for (int i = 0; i < 6; ++i) t.Q[i] = p.Q[i][l];
  for (int k = 0; k < 4; ++k) {
    t.w[k] = p.w[k][l];
    t.v[k][0] = p.v[k][l];
  }
  t.tet[0] = p.tet[l];
  t.lanes = 1;
  t.slot = p.slot + l;
  return t;
}

namespace {

// Rest data of one tet into lane l of p.
template <class T>
void fill_lane(TetLanes<T>& p, int l, int32_t t, const TetRest& tr, const double w[4]) {
  p.tet[l] = t;
  for (int k = 0; k < 4; ++k) {
    p.v[k][l] = tr.v[k];
    set_lane(p.w[k], l, w[k]);
  }
  for (int k = 0; k < 3; ++k)
    for (int i = 0; i < 3; ++i) set_lane(p.B[3 * k + i], l, tr.dm_inv(k, i));
  set_lane(p.volume, l, tr.volume);
  set_lane(p.sqrt_volume, l, tr.sqrt_volume);
  Vec3 b[4];
  for (int k = 0; k < 3; ++k) b[k] = tr.dm_inv.row(k).transpose();
  b[3] = -(b[0] + b[1] + b[2]);
  double Q[3][3] = {};
  for (int k = 0; k < 4; ++k)
    for (int i = 0; i < 3; ++i)
      for (int j = i; j < 3; ++j) Q[i][j] += w[k] * b[k][i] * b[k][j];
  set_lane(p.Q[0], l, Q[0][0]);
  set_lane(p.Q[1], l, Q[1][1]);
  set_lane(p.Q[2], l, Q[2][2]);
  set_lane(p.Q[3], l, Q[1][2]);
  set_lane(p.Q[4], l, Q[0][2]);
  set_lane(p.Q[5], l, Q[0][1]);
}

}  // namespace

TetOne tet_lanes(const TetRest& tet, const double w[4]) {
  TetOne t{};
  fill_lane(t, 0, 0, tet, w);
  t.lanes = 1;
  t.slot = 0;
  return t;
}

namespace {

// Greedy colouring of a subset of the tets (each takes the lowest colour none of its vertices has
// used in this subset), then each colour sorted by lowest vertex index so that neighbouring packs
// touch nearby memory (the thesis armadillo's numbering is otherwise scattered).
std::vector<std::vector<int32_t>> colour_subset(const BodyModel& m, const std::vector<int32_t>& subset,
                                                std::vector<std::vector<uint64_t>>& used) {
  std::vector<std::vector<int32_t>> colours;
  for (int32_t t : subset) {
    const Tet& v = m.tets[t].v;
    int c = 0;
    for (;; ++c) {
      const size_t w = size_t(c) / 64;
      const uint64_t bit = uint64_t(1) << (c % 64);
      bool taken = false;
      for (int k = 0; k < 4 && !taken; ++k) taken = w < used[v[k]].size() && (used[v[k]][w] & bit);
      if (!taken) break;
    }
    const size_t w = size_t(c) / 64;
    const uint64_t bit = uint64_t(1) << (c % 64);
    for (int k = 0; k < 4; ++k) {
      if (used[v[k]].size() <= w) used[v[k]].resize(w + 1, 0);
      used[v[k]][w] |= bit;
    }
    if (colours.size() <= size_t(c)) colours.resize(c + 1);
    colours[c].push_back(t);
  }
  for (int32_t t : subset)
    for (int k = 0; k < 4; ++k) used[m.tets[t].v[k]].clear();  // ready for the next subset
  auto lowest = [&](int32_t t) { return *std::min_element(m.tets[t].v.begin(), m.tets[t].v.end()); };
  for (auto& colour : colours)
    std::sort(colour.begin(), colour.end(), [&](int32_t a, int32_t b) { return lowest(a) < lowest(b); });
  return colours;
}

// Appends one pack of n (1..4) tets that share no vertex; a short pack repeats its last tet in
// the padding lanes, which are never written back.
void append_pack(BodyModel& m, PackedModel& pm, const int32_t* tets, int n) {
  TetPack p{};
  p.lanes = n;
  p.slot = int32_t(4 * pm.packs.size());
  for (int l = 0; l < 4; ++l) {
    const int32_t t = tets[std::min(l, n - 1)];
    const TetRest& tr = m.tets[t];
    if (l < n) m.tet_slot[t] = p.slot + l;
    const double w[4] = {m.inv_mass[tr.v[0]], m.inv_mass[tr.v[1]], m.inv_mass[tr.v[2]], m.inv_mass[tr.v[3]]};
    fill_lane(p, l, t, tr, w);
  }
  pm.packs.push_back(p);
  FloorCheck c{};
  for (int l = 0; l < 4; ++l) {
    double b[3][3], row_max = 0;
    for (int k = 0; k < 3; ++k) {
      double row = 0;
      for (int i = 0; i < 3; ++i) {
        b[k][i] = p.B[3 * k + i][l];
        row += std::abs(b[k][i]);
      }
      row_max = std::max(row_max, row);
    }
    c.det_b[l] = det3(b);
    c.b_norm3[l] = row_max * row_max * row_max;
    for (int k = 0; k < 4; ++k) {
      c.v[k][l] = p.v[k][l];
      c.w[k][l] = p.w[k][l];
    }
  }
  c.lanes = p.lanes;
  pm.floor_checks.push_back(c);
}

// One colour as packs of 4 (the last one short).
void append_colour(BodyModel& m, PackedModel& pm, const std::vector<int32_t>& colour) {
  for (size_t start = 0; start < colour.size(); start += 4)
    append_pack(m, pm, &colour[start], int(std::min<size_t>(4, colour.size() - start)));
}

// A block's colours as packs run in order on one thread. A colour's last few tets need not wait
// for padding: they share a pack with tets of the next colour that touch none of their vertices
// (looked for among that colour's first kFillWindow tets), so a block has about one short pack
// instead of one per colour.
constexpr size_t kFillWindow = 64;
void append_block(BodyModel& m, PackedModel& pm, std::vector<std::vector<int32_t>> colours) {
  auto shares_vertex = [&](int32_t a, int32_t b) {
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
        if (m.tets[a].v[i] == m.tets[b].v[j]) return true;
    return false;
  };
  std::vector<int32_t> carry;  // the previous colour's remainder (0..3 tets)
  for (auto& colour : colours) {
    if (!carry.empty()) {
      for (size_t i = 0; i < colour.size() && i < kFillWindow && carry.size() < 4;) {
        bool free = true;
        for (int32_t c : carry) free = free && !shares_vertex(c, colour[i]);
        if (free) {
          carry.push_back(colour[i]);
          colour.erase(colour.begin() + std::ptrdiff_t(i));
        } else {
          ++i;
        }
      }
      append_pack(m, pm, carry.data(), int(carry.size()));
      carry.clear();
    }
    const size_t full = colour.size() / 4 * 4;
    for (size_t start = 0; start < full; start += 4) append_pack(m, pm, &colour[start], 4);
    carry.assign(colour.begin() + std::ptrdiff_t(full), colour.end());
  }
  if (!carry.empty()) append_pack(m, pm, carry.data(), int(carry.size()));
}

// The rest shape's extent along its longest axis (axis: which one).
double longest_extent(const BodyModel& m, int& axis) {
  Vec3 low = m.rest_positions[0], high = low;
  for (const Vec3& p : m.rest_positions) {
    low = low.cwiseMin(p);
    high = high.cwiseMax(p);
  }
  return (high - low).maxCoeff(&axis);
}

// PackedModel's sweep numbering: vertices in the order the packs first reach them, those of no
// tet after.
void number_sweep_vertices(const BodyModel& m, PackedModel& pm) {
  const size_t nv = m.vertex_count();
  pm.sweep_vertex.assign(nv, -1);
  pm.mesh_vertex.clear();
  pm.mesh_vertex.reserve(nv);
  auto number = [&](int32_t v) {
    if (pm.sweep_vertex[size_t(v)] >= 0) return;
    pm.sweep_vertex[size_t(v)] = int32_t(pm.mesh_vertex.size());
    pm.mesh_vertex.push_back(v);
  };
  for (const TetPack& p : pm.packs)
    for (int l = 0; l < p.lanes; ++l)
      for (int k = 0; k < 4; ++k) number(p.v[k][l]);
  for (size_t v = 0; v < nv; ++v) number(int32_t(v));
  pm.sweep_packs = pm.packs;
  for (TetPack& p : pm.sweep_packs)
    for (auto& corner : p.v)
      for (int32_t& v : corner) v = pm.sweep_vertex[size_t(v)];  // padding lanes repeat a real one
  pm.sweep_floor_checks = pm.floor_checks;
  for (FloorCheck& c : pm.sweep_floor_checks)
    for (auto& corner : c.v)
      for (int32_t& v : corner) v = pm.sweep_vertex[size_t(v)];
  pm.sweep_slot_start.assign(1, 0);
  pm.sweep_slot_entry.clear();
  pm.sweep_slot_entry.reserve(pm.vertex_slot_entry.size());
  for (size_t s = 0; s < nv; ++s) {
    const size_t v = size_t(pm.mesh_vertex[s]);
    pm.sweep_slot_entry.insert(pm.sweep_slot_entry.end(), pm.vertex_slot_entry.begin() + m.vertex_tet_start[v],
                               pm.vertex_slot_entry.begin() + m.vertex_tet_start[v + 1]);
    pm.sweep_slot_start.push_back(int32_t(pm.sweep_slot_entry.size()));
  }
}

constexpr int kMaxBlocks = 8;
constexpr double kMinSlabLayers = 6;   // a slab at least this many mean edges thick
constexpr size_t kMinBlockTets = 512;  // and holding this many tets on average

}  // namespace

int solve_order_blocks(const BodyModel& m) {
  if (m.tets.empty() || !(m.mean_edge > 0)) return 1;
  int axis = 0;
  const double layers = longest_extent(m, axis) / m.mean_edge;
  const int k = int(std::min<double>({double(kMaxBlocks), std::floor(layers / kMinSlabLayers),
                                      std::floor(double(m.tets.size()) / double(kMinBlockTets))}));
  return k >= 2 ? k / 2 * 2 : 1;  // even: two threads take as many slabs each
}

void compile_solve_order(BodyModel& m) {
  auto pm = std::make_shared<PackedModel>();
  m.tet_slot.assign(m.tets.size(), 0);
  const int K = solve_order_blocks(m);
  pm->blocks = K;
  std::vector<std::vector<uint64_t>> used(m.vertex_count());
  // A colour of the whole mesh or of the leftover tets: one split phase each.
  auto colour_phases = [&](const std::vector<int32_t>& tets) {
    for (const auto& colour : colour_subset(m, tets, used)) {
      SolvePhase phase;
      phase.split = true;
      phase.group_begin = {pm->packs.size()};
      append_colour(m, *pm, colour);
      phase.group_begin.push_back(pm->packs.size());
      pm->phases.push_back(std::move(phase));
    }
  };
  if (K == 1) {
    // Colour by colour: the mesh's own colouring (the same greedy in tet order).
    std::vector<int32_t> all(m.tets.size());
    for (size_t t = 0; t < all.size(); ++t) all[t] = int32_t(t);
    colour_phases(all);
  } else {
    // Slabs of equal vertex count along the longest axis (ties by index: grid planes split
    // the same way every time).
    const size_t nv = m.vertex_count();
    int axis = 0;
    longest_extent(m, axis);
    std::vector<int32_t> order(nv);
    for (size_t i = 0; i < nv; ++i) order[i] = int32_t(i);
    std::sort(order.begin(), order.end(), [&](int32_t a, int32_t b) {
      const double ca = m.rest_positions[a][axis], cb = m.rest_positions[b][axis];
      return ca < cb || (ca == cb && a < b);
    });
    std::vector<int> slab(nv);
    for (size_t r = 0; r < nv; ++r) slab[order[r]] = int(r * size_t(K) / nv);
    // Block of each tet: inside slab s (block s), across cut j between slabs j - 1 and j
    // (block K - 1 + j), or across more than one cut (leftover).
    std::vector<std::vector<int32_t>> block(2 * size_t(K) - 1);
    std::vector<int32_t> leftover;
    for (size_t t = 0; t < m.tets.size(); ++t) {
      int a = K, b = -1;
      for (int k = 0; k < 4; ++k) {
        a = std::min(a, slab[m.tets[t].v[k]]);
        b = std::max(b, slab[m.tets[t].v[k]]);
      }
      if (a == b) block[size_t(a)].push_back(int32_t(t));
      else if (b == a + 1) block[size_t(K - 1 + b)].push_back(int32_t(t));
      else leftover.push_back(int32_t(t));
    }
    // Slabs share no vertex; nor do cuts j and j + 2 (slabs j - 1, j against j + 1, j + 2).
    auto block_phase = [&](const std::vector<size_t>& blocks) {
      SolvePhase phase;
      phase.group_begin = {pm->packs.size()};
      for (size_t bi : blocks) {
        append_block(m, *pm, colour_subset(m, block[bi], used));
        phase.group_begin.push_back(pm->packs.size());
      }
      pm->phases.push_back(std::move(phase));
    };
    std::vector<size_t> slabs, odd, even;
    for (int s = 0; s < K; ++s) slabs.push_back(size_t(s));
    for (int j = 1; j < K; ++j) (j % 2 ? odd : even).push_back(size_t(K - 1 + j));
    block_phase(slabs);
    block_phase(odd);
    if (!even.empty()) block_phase(even);
    colour_phases(leftover);
  }
  if (spdlog::should_log(spdlog::level::debug)) {
    std::string sizes;
    for (const SolvePhase& ph : pm->phases)
      if (!ph.split) {
        sizes += " [";
        for (size_t g = 0; g + 1 < ph.group_begin.size(); ++g)
          sizes += fmt::format("{}{}", g ? " " : "", ph.group_begin[g + 1] - ph.group_begin[g]);
        sizes += "]";
      }
    spdlog::debug("solve order: {} tets in {} packs ({} lanes of padding), {} blocks, {} phases, packs per block{}",
                  m.tets.size(), pm->packs.size(), 4 * pm->packs.size() - m.tets.size(), K, pm->phases.size(), sizes);
  }
  pm->vertex_slot_entry.resize(m.vertex_tet_entry.size());
  for (size_t a = 0; a < m.vertex_tet_entry.size(); ++a)
    pm->vertex_slot_entry[a] = 4 * m.tet_slot[m.vertex_tet_entry[a] / 4] + m.vertex_tet_entry[a] % 4;
  number_sweep_vertices(m, *pm);
  m.packed = std::move(pm);
}

namespace {

// The rows d_k = x_k - x_3 (k < 3; D_s's columns) of the lanes' corners v[corner][lane] at x.
template <class T>
inline void edge_rows(const int32_t (&v)[4][kLanes<T>], const std::vector<Vec3>& x, T d[3][3]) {
  T px[4][3];
  PLIANT_UNROLL
  for (int k = 0; k < 4; ++k)
    for (int l = 0; l < kLanes<T>; ++l) {
      const Vec3& q = x[size_t(v[k][l])];
      set_lane(px[k][0], l, q[0]);
      set_lane(px[k][1], l, q[1]);
      set_lane(px[k][2], l, q[2]);
    }
  PLIANT_UNROLL
  for (int k = 0; k < 3; ++k)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) d[k][c] = px[k][c] - px[3][c];
}

// F's columns of the lanes' tets at x.
template <class T>
inline void deformation(const TetLanes<T>& p, const std::vector<Vec3>& x, T f[3][3]) {
  T d[3][3];
  edge_rows(p.v, x, d);
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) f[i][c] = d[0][c] * p.B[i] + d[1][c] * p.B[3 + i] + d[2][c] * p.B[6 + i];
}

template <class T>
inline void geometry(const TetLanes<T>& p, const std::vector<Vec3>& x, Geometry<T>& g, ElasticModel model) {
  deformation(p, x, g.f);
  strain(g, model);
}

template <class T>
inline void constraint(const TetLanes<T>& p, const Geometry<T>& g, T C[6]) {
  PLIANT_UNROLL
  for (int r = 0; r < 6; ++r) C[r] = p.sqrt_volume * g.c[r];
}

// A pack's four slots hold 24 doubles, lane after lane (l0r0..l0r5, l1r0, ...); the kernels work
// on six rows of four lanes. The two layouts, one into the other, in registers.
inline v4d load4(const double* p) {
  v4d v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store4(double* p, const v4d& v) { std::memcpy(p, &v, sizeof v); }

inline void rows_of_slots(const double* s, v4d r[6]) {
  const v4d m0 = load4(s), m1 = load4(s + 4), m2 = load4(s + 8), m3 = load4(s + 12), m4 = load4(s + 16),
            m5 = load4(s + 20);
  const v4d t1 = __builtin_shufflevector(m1, m2, 2, 3, 4, 5), t3 = __builtin_shufflevector(m4, m5, 2, 3, 4, 5);
  const v4d u0 = __builtin_shufflevector(m1, m2, 0, 1, 6, 7), u1 = __builtin_shufflevector(m4, m5, 0, 1, 6, 7);
  const v4d a = __builtin_shufflevector(m0, t1, 0, 4, 2, 6), b = __builtin_shufflevector(m0, t1, 1, 5, 3, 7);
  const v4d c = __builtin_shufflevector(m3, t3, 0, 4, 2, 6), d = __builtin_shufflevector(m3, t3, 1, 5, 3, 7);
  r[0] = __builtin_shufflevector(a, c, 0, 1, 4, 5);
  r[1] = __builtin_shufflevector(b, d, 0, 1, 4, 5);
  r[2] = __builtin_shufflevector(a, c, 2, 3, 6, 7);
  r[3] = __builtin_shufflevector(b, d, 2, 3, 6, 7);
  r[4] = __builtin_shufflevector(u0, u1, 0, 2, 4, 6);
  r[5] = __builtin_shufflevector(u0, u1, 1, 3, 5, 7);
}

inline void slots_of_rows(const v4d r[6], double* s) {
  const v4d a = __builtin_shufflevector(r[0], r[1], 0, 4, 2, 6), b = __builtin_shufflevector(r[0], r[1], 1, 5, 3, 7);
  const v4d c = __builtin_shufflevector(r[2], r[3], 0, 4, 2, 6), d = __builtin_shufflevector(r[2], r[3], 1, 5, 3, 7);
  const v4d t0 = __builtin_shufflevector(a, c, 0, 1, 4, 5), t2 = __builtin_shufflevector(a, c, 2, 3, 6, 7);
  const v4d t1 = __builtin_shufflevector(b, d, 0, 1, 4, 5), t3 = __builtin_shufflevector(b, d, 2, 3, 6, 7);
  const v4d u0 = __builtin_shufflevector(r[4], r[5], 0, 4, 1, 5), u1 = __builtin_shufflevector(r[4], r[5], 2, 6, 3, 7);
  store4(s, t0);
  store4(s + 4, __builtin_shufflevector(u0, t1, 0, 1, 4, 5));
  store4(s + 8, __builtin_shufflevector(t1, u0, 2, 3, 6, 7));
  store4(s + 12, t2);
  store4(s + 16, __builtin_shufflevector(u1, t3, 0, 1, 4, 5));
  store4(s + 20, __builtin_shufflevector(t3, u1, 2, 3, 6, 7));
}

template <class T>
inline void gather_slots(const TetLanes<T>& p, const std::vector<Vec6>& lambda, T lam[6]) {
  if constexpr (kLanes<T> == 4) {
    rows_of_slots(lambda[size_t(p.slot)].data(), lam);  // a pack's slots all exist, padding's too
  } else {
    for (int l = 0; l < kLanes<T>; ++l) {
      const Vec6& a = lambda[p.slot + l];
      PLIANT_UNROLL
      for (int r = 0; r < 6; ++r) set_lane(lam[r], l, a[r]);
    }
  }
}

// dx_k = w_k sqrt(V0) (G P) b_k for a 3x3 P (P[m][i]) and G's columns.
template <class T>
inline void move_corners(const TetLanes<T>& p, const T G[3][3], const T P[3][3], T dx[4][3]) {
  T M[3][3];  // M[i][c]: component c of column i of G P
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) M[i][c] = G[0][c] * P[0][i] + G[1][c] * P[1][i] + G[2][c] * P[2][i];
  T b[4][3];
  PLIANT_UNROLL
  for (int k = 0; k < 3; ++k)
    PLIANT_UNROLL
    for (int i = 0; i < 3; ++i) b[k][i] = p.B[3 * k + i];
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i) b[3][i] = -(b[0][i] + b[1][i] + b[2][i]);
  PLIANT_UNROLL
  for (int k = 0; k < 4; ++k) {
    const T s = p.w[k] * p.sqrt_volume;
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) dx[k][c] = s * (M[0][c] * b[k][0] + M[1][c] * b[k][1] + M[2][c] * b[k][2]);
  }
}

// The symmetric 3x3 of a Voigt 6-vector with engineering shears y (y_3 on 12, ...).
template <class T>
inline void symmetric_of(const T y[6], T P[3][3]) {
  P[0][0] = y[0], P[0][1] = y[5], P[0][2] = y[4];
  P[1][0] = y[5], P[1][1] = y[1], P[1][2] = y[3];
  P[2][0] = y[4], P[2][1] = y[3], P[2][2] = y[2];
}

// StVK: dx_k = w_k sqrt(V0) (F P) b_k, P the symmetric 3x3 of the increment y.
template <class T>
inline void stvk_corrections(const TetLanes<T>& p, const Geometry<T>& g, const T y[6], T dx[4][3]) {
  T P[3][3];
  symmetric_of(y, P);
  move_corners(p, g.f, P, dx);
}

// Whether alpha~(r, c) may be nonzero: every entry, or with Blocks (KernelCompliance::
// normal_and_shear) the normal block and the shear diagonal only.
template <bool Blocks>
constexpr bool couples(int r, int c) {
  return !Blocks || (r < 3 && c < 3) || r == c;
}

// ||C + alpha~ lambda||^2 per lane.
template <bool Blocks, class T>
inline T lane_residual_squared(const T C[6], const T lam[6], const KernelCompliance& at) {
  T sum = splat<T>(0.0);
  PLIANT_UNROLL
  for (int r = 0; r < 6; ++r) {
    T s = C[r];
    PLIANT_UNROLL
    for (int c = 0; c < 6; ++c)
      if (couples<Blocks>(r, c)) s += at(r, c) * lam[c];
    sum += s * s;
  }
  return sum;
}

// Step length along the projection's increment (y for lambda, dx for the corners), per lane:
// see kMaxHalvings in projection.hpp.
template <bool Blocks, class T>
T residual_decreasing_step(ElasticModel model, const TetLanes<T>& p, const Geometry<T>& g, const T C[6], const T lam[6],
                           const T y[6], const T dx[4][3], const KernelCompliance& at) {
  // dF[i][c]: change of column i, component c of F for the full step.
  T dd[3][3];
  PLIANT_UNROLL
  for (int k = 0; k < 3; ++k)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) dd[k][c] = dx[k][c] - dx[3][c];
  T dF[3][3];
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) dF[i][c] = dd[0][c] * p.B[i] + dd[1][c] * p.B[3 + i] + dd[2][c] * p.B[6 + i];
  T step = splat<T>(1.0);
  T trial = splat<T>(1.0);
  // Lanes whose full step changes F by less than kSmallStep keep it.
  T n2 = splat<T>(0.0);
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) n2 += dF[i][c] * dF[i][c];
  int pending = 0;
  for (int l = 0; l < p.lanes; ++l)
    if (get_lane(n2, l) > kSmallStep * kSmallStep) pending |= 1 << l;
  if (!pending) return step;
  const T before = lane_residual_squared<Blocks>(C, lam, at);
  for (int h = 0; h <= kMaxHalvings && pending; ++h) {
    Geometry<T> n;
    PLIANT_UNROLL
    for (int i = 0; i < 3; ++i)
      PLIANT_UNROLL
      for (int c = 0; c < 3; ++c) n.f[i][c] = g.f[i][c] + trial * dF[i][c];
    strain(n, model);
    T Cn[6], ln[6];
    constraint(p, n, Cn);
    PLIANT_UNROLL
    for (int r = 0; r < 6; ++r) ln[r] = lam[r] + trial * y[r];
    const T after = lane_residual_squared<Blocks>(Cn, ln, at);
    for (int l = 0; l < p.lanes; ++l) {
      if (!(pending & (1 << l))) continue;
      set_lane(step, l, get_lane(trial, l));
      if (get_lane(after, l) <= get_lane(before, l)) pending &= ~(1 << l);
    }
    trial *= 0.5;
  }
  return step;
}

// a + alpha~(r, c), or a where that entry is zero (Blocks).
template <bool Blocks, int r, int c, class T>
inline T with_alpha(const T& a, const KernelCompliance& at) {
  if constexpr (couples<Blocks>(r, c)) return a + at(r, c);
  else return a;
}

// The StVK 6x6 system, lower triangle: A = V0 (bilinear terms in S = F^T F and Q) + alpha~.
template <bool Blocks, class T>
inline void stvk_system(const T S[6], const T Q[6], const T& V, const KernelCompliance& at, T A[6][6]) {
  const T &S00 = S[0], &S11 = S[1], &S22 = S[2], &S12 = S[3], &S02 = S[4], &S01 = S[5];
  const T &Q00 = Q[0], &Q11 = Q[1], &Q22 = Q[2], &Q12 = Q[3], &Q02 = Q[4], &Q01 = Q[5];
  A[0][0] = with_alpha<Blocks, 0, 0>(V * (S00 * Q00), at);
  A[1][0] = with_alpha<Blocks, 1, 0>(V * (S01 * Q01), at);
  A[1][1] = with_alpha<Blocks, 1, 1>(V * (S11 * Q11), at);
  A[2][0] = with_alpha<Blocks, 2, 0>(V * (S02 * Q02), at);
  A[2][1] = with_alpha<Blocks, 2, 1>(V * (S12 * Q12), at);
  A[2][2] = with_alpha<Blocks, 2, 2>(V * (S22 * Q22), at);
  A[3][0] = with_alpha<Blocks, 3, 0>(V * (S02 * Q01 + S01 * Q02), at);
  A[3][1] = with_alpha<Blocks, 3, 1>(V * (S12 * Q11 + S11 * Q12), at);
  A[3][2] = with_alpha<Blocks, 3, 2>(V * (S22 * Q12 + S12 * Q22), at);
  A[3][3] = with_alpha<Blocks, 3, 3>(V * (S22 * Q11 + S12 * Q12 + S12 * Q12 + S11 * Q22), at);
  A[4][0] = with_alpha<Blocks, 4, 0>(V * (S02 * Q00 + S00 * Q02), at);
  A[4][1] = with_alpha<Blocks, 4, 1>(V * (S12 * Q01 + S01 * Q12), at);
  A[4][2] = with_alpha<Blocks, 4, 2>(V * (S22 * Q02 + S02 * Q22), at);
  A[4][3] = with_alpha<Blocks, 4, 3>(V * (S22 * Q01 + S12 * Q02 + S02 * Q12 + S01 * Q22), at);
  A[4][4] = with_alpha<Blocks, 4, 4>(V * (S22 * Q00 + S02 * Q02 + S02 * Q02 + S00 * Q22), at);
  A[5][0] = with_alpha<Blocks, 5, 0>(V * (S01 * Q00 + S00 * Q01), at);
  A[5][1] = with_alpha<Blocks, 5, 1>(V * (S11 * Q01 + S01 * Q11), at);
  A[5][2] = with_alpha<Blocks, 5, 2>(V * (S12 * Q02 + S02 * Q12), at);
  A[5][3] = with_alpha<Blocks, 5, 3>(V * (S12 * Q01 + S11 * Q02 + S02 * Q11 + S01 * Q12), at);
  A[5][4] = with_alpha<Blocks, 5, 4>(V * (S12 * Q00 + S01 * Q02 + S02 * Q01 + S00 * Q12), at);
  A[5][5] = with_alpha<Blocks, 5, 5>(V * (S11 * Q00 + S01 * Q01 + S01 * Q01 + S00 * Q11), at);
}

// The corotated constraint (corotated_rows in projection.hpp gives the rows
// Y_ik = E_i b_k - 2 u_i x b_k): from the stretch S = sym(R^T F) in g, Ginv per lane, the
// rotation axes u_i, and the lower triangle of A = V0 sum_k w_k Y_ik . Y_jk + alpha~ summed over
// the corners in closed form with Q = sum_k w_k b_k b_k^T:
//   sum_k w_k Y_ik . Y_jk = tr(E_i E_j Q) - 2 (u_j . v_i + u_i . v_j) + 4 ((u_i . u_j) tr Q - u_i^T Q u_j),
// v_i = sum_k w_k b_k x (E_i b_k) = 2 axial(skew(E_i Q)).
template <class T>
inline void corotated_axes_of(const Geometry<T>& g, T u[6][3]) {
  const T* S = g.stretch;
  // Ginv = (tr(S) I - S)^-1 by cofactors, zero in the lanes where corotated_rotation_inverse
  // gives zero (same test).
  const T G00 = S[1] + S[2], G11 = S[0] + S[2], G22 = S[0] + S[1], G12 = -S[3], G02 = -S[4], G01 = -S[5];
  T Ginv[6] = {G11 * G22 - G12 * G12, G00 * G22 - G02 * G02, G00 * G11 - G01 * G01,
               G02 * G01 - G00 * G12, G01 * G12 - G11 * G02, G02 * G12 - G22 * G01};
  const T det = G00 * Ginv[0] + G01 * Ginv[5] + G02 * Ginv[4];
  const T third = (G00 + G11 + G22) * (1.0 / 3.0);
  for (int l = 0; l < kLanes<T>; ++l) {
    const double t3 = get_lane(third, l), d = get_lane(det, l);
    const bool ok = d > kRotationConditionLimit * t3 * t3 * t3;
    const double inv = ok ? 1.0 / d : 0.0;
    PLIANT_UNROLL
    for (int i = 0; i < 6; ++i) set_lane(Ginv[i], l, get_lane(Ginv[i], l) * inv);
  }
  corotated_axes(S, Ginv, u);
}

template <class T>
inline void corotated_system(const TetLanes<T>& p, const Geometry<T>& g, const KernelCompliance& at, T A[6][6],
                             T u[6][3]) {
  corotated_axes_of(g, u);
  const T &Q00 = p.Q[0], &Q11 = p.Q[1], &Q22 = p.Q[2], &Q12 = p.Q[3], &Q02 = p.Q[4], &Q01 = p.Q[5];
  T v[6][3];
  corotated_axials(p.Q, v);  // half of v_i
  const T trQ = Q00 + Q11 + Q22;
  T Qu[6][3];
  PLIANT_UNROLL
  for (int i = 0; i < 6; ++i) {
    Qu[i][0] = Q00 * u[i][0] + Q01 * u[i][1] + Q02 * u[i][2];
    Qu[i][1] = Q01 * u[i][0] + Q11 * u[i][1] + Q12 * u[i][2];
    Qu[i][2] = Q02 * u[i][0] + Q12 * u[i][1] + Q22 * u[i][2];
  }
  // tr(E_i E_j Q): the StVK system's Q terms with F^T F = I.
  const T zero = splat<T>(0.0);
  const T A0[6][6] = {
      {Q00, zero, zero, zero, zero, zero},
      {zero, Q11, zero, zero, zero, zero},
      {zero, zero, Q22, zero, zero, zero},
      {zero, Q12, Q12, Q11 + Q22, zero, zero},
      {Q02, zero, Q02, Q01, Q00 + Q22, zero},
      {Q01, Q01, zero, Q02, Q12, Q00 + Q11}};
  PLIANT_UNROLL
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j <= i; ++j) {
      // v holds half of v_i: -2 (u_j . v_i + u_i . v_j) = -4 (u_j . v~_i + u_i . v~_j).
      const T cross_terms = column_dot(u[j], v[i]) + column_dot(u[i], v[j]);
      const T rot = column_dot(u[i], u[j]) * trQ - column_dot(u[i], Qu[j]);
      A[i][j] = p.volume * (A0[i][j] - 4.0 * cross_terms + 4.0 * rot) + at(i, j);
    }
}

// dx_k = w_k sqrt(V0) R (P - 2 [U]x) b_k, P the symmetric 3x3 of the increment y, U = sum_i y_i u_i
// (= w_k sqrt(V0) R sum_i y_i Y_ik).
template <class T>
inline void corotated_corrections(const TetLanes<T>& p, const Geometry<T>& g, const T u[6][3], const T y[6],
                                  T dx[4][3]) {
  T U[3];
  PLIANT_UNROLL
  for (int c = 0; c < 3; ++c) {
    U[c] = y[0] * u[0][c];
    PLIANT_UNROLL
    for (int i = 1; i < 6; ++i) U[c] += y[i] * u[i][c];
  }
  const T two = splat<T>(2.0);
  const T P[3][3] = {{y[0], y[5] + two * U[2], y[4] - two * U[1]},
                     {y[5] - two * U[2], y[1], y[3] + two * U[0]},
                     {y[4] + two * U[1], y[3] - two * U[0], y[2]}};
  move_corners(p, g.r, P, dx);
}

template <bool Blocks, class T>
void strain_step_with(const TetLanes<T>& p, const std::vector<Vec3>& x, const T lam[6], ElasticModel elastic,
                      const KernelCompliance& at, double lambda_scale, bool line_search, StrainStep<T>& out) {
  Geometry<T> g;
  geometry(p, x, g, elastic);
  T C[6];
  constraint(p, g, C);
  T A[6][6];
  T u[6][3];  // corotated only: the rotation axes of the rows
  if (elastic == ElasticModel::Corotated) corotated_system(p, g, at, A, u);
  else stvk_system<Blocks>(g.S, p.Q, p.volume, at, A);
  T rhs[6];  // -C - alpha~ lambda
  PLIANT_UNROLL
  for (int r = 0; r < 6; ++r) {
    T s = -C[r];
    PLIANT_UNROLL
    for (int c = 0; c < 6; ++c)
      if (couples<Blocks>(r, c)) s -= at(r, c) * lam[c];
    rhs[r] = s;
  }
  T D[6], y[6];
  ldlt_solve(A, rhs, lambda_scale, D, y);
  T dx[4][3];
  if (elastic == ElasticModel::Corotated) corotated_corrections(p, g, u, y, dx);
  else stvk_corrections(p, g, y, dx);
  // A lane's increment shortened by the line search (a step of 1 multiplies by nothing).
  bool shortened = false;
  T step = splat<T>(1.0);
  if (line_search) {
    step = residual_decreasing_step<Blocks>(elastic, p, g, C, lam, y, dx, at);
    for (int l = 0; l < kLanes<T>; ++l) shortened |= get_lane(step, l) != 1.0;
  }
  out.det = det3(g.f);
  out.ok = 0;
  if constexpr (kLanes<T> == 4) {
    // y - y == 0 exactly when y is finite; all six rows at once, lane by lane.
    auto good = (y[0] - y[0] == 0) & (D[0] > 0);
    PLIANT_UNROLL
    for (int r = 1; r < 6; ++r) good &= (y[r] - y[r] == 0) & (D[r] > 0);
    for (int l = 0; l < p.lanes; ++l)
      if (good[l]) out.ok |= 1 << l;
  } else {
    for (int l = 0; l < p.lanes; ++l) {
      bool ok = true;
      PLIANT_UNROLL
      for (int r = 0; r < 6; ++r) ok &= std::isfinite(get_lane(y[r], l)) && get_lane(D[r], l) > 0;
      if (ok) out.ok |= 1 << l;
    }
  }
  PLIANT_UNROLL
  for (int r = 0; r < 6; ++r) out.dlambda[r] = shortened ? step * y[r] : y[r];
  PLIANT_UNROLL
  for (int k = 0; k < 4; ++k)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) out.dx[k][c] = shortened ? step * dx[k][c] : dx[k][c];
}

}  // namespace

KernelCompliance::KernelCompliance(const Mat6& alpha_tilde) : m(alpha_tilde) {
  for (int r = 0; r < 6; ++r)
    for (int c = 0; c < 6; ++c)
      if (!couples<true>(r, c) && m(r, c) != 0.0) normal_and_shear = false;
}

template <class T>
void strain_step(const TetLanes<T>& p, const std::vector<Vec3>& x, const T lam[6], ElasticModel elastic,
                 const KernelCompliance& at, double lambda_scale, bool line_search, StrainStep<T>& out) {
  if (at.normal_and_shear) strain_step_with<true>(p, x, lam, elastic, at, lambda_scale, line_search, out);
  else strain_step_with<false>(p, x, lam, elastic, at, lambda_scale, line_search, out);
}

namespace {

// det D_s of every lane (D_s's columns d_k = x_k - x_3) and its gradient's pieces, the rows
// c_k = d det D_s / d x_k (k < 3: d_1 x d_2, d_2 x d_0, d_0 x d_1; x_3's is minus their sum).
template <class T>
struct FloorGeometry {
  T d[3][3];
  T c[3][3];
  T det_d;
};

template <class T>
inline void floor_geometry(const int32_t (&v)[4][kLanes<T>], const std::vector<Vec3>& x, FloorGeometry<T>& g) {
  edge_rows(v, x, g.d);
  cross(g.d[1], g.d[2], g.c[0]);
  cross(g.d[2], g.d[0], g.c[1]);
  cross(g.d[0], g.d[1], g.c[2]);
  g.det_d = g.d[0][0] * g.c[0][0] + g.d[0][1] * g.c[0][1] + g.d[0][2] * g.c[0][2];
}

// The floor on the lanes of `lanes` (bit l) whose det F = det D_s det B is below trigger: each
// takes the linearised correction towards `target` along grad det F = det B grad det D_s, times
// `relax`, moving corner k by w_k. Returns the corrected lanes (bit l).
template <class T>
int floor_lanes(const T& det_b, const int32_t (&v)[4][kLanes<T>], const T (&w)[4], int lanes, std::vector<Vec3>& x,
                double trigger, double target, double relax) {
  FloorGeometry<T> g;
  floor_geometry(v, x, g);
  const T J = g.det_d * det_b;
  int below = 0;
  for (int l = 0; l < kLanes<T>; ++l)
    if ((lanes >> l & 1) && get_lane(J, l) < trigger) below |= 1 << l;
  if (!below) return 0;
  T grad[4][3];
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i) {
    PLIANT_UNROLL
    for (int k = 0; k < 3; ++k) grad[k][i] = det_b * g.c[k][i];
    grad[3][i] = -(grad[0][i] + grad[1][i] + grad[2][i]);
  }
  T denom = splat<T>(0.0);
  PLIANT_UNROLL
  for (int k = 0; k < 4; ++k)
    denom += w[k] * (grad[k][0] * grad[k][0] + grad[k][1] * grad[k][1] + grad[k][2] * grad[k][2]);
  const T dl = relax * (splat<T>(target) - J) / denom;
  int corrected = 0;
  for (int l = 0; l < kLanes<T>; ++l) {
    if (!(below & (1 << l)) || !(get_lane(denom, l) > 1e-300)) continue;
    corrected |= 1 << l;
    PLIANT_UNROLL
    for (int k = 0; k < 4; ++k) {
      const double s = get_lane(w[k], l) * get_lane(dl, l);
      Vec3& q = x[size_t(v[k][l])];
      q[0] += s * get_lane(grad[k][0], l);
      q[1] += s * get_lane(grad[k][1], l);
      q[2] += s * get_lane(grad[k][2], l);
    }
  }
  return corrected;
}

// det B of every lane.
template <class T>
T det_b_lanes(const TetLanes<T>& p) {
  T b[3][3];
  for (int k = 0; k < 3; ++k)
    for (int i = 0; i < 3; ++i) b[k][i] = p.B[3 * k + i];
  return det3(b);
}

}  // namespace

template <class T>
int project_lanes(const TetLanes<T>& p, std::vector<Vec3>& x, std::vector<Vec6>& lambda, std::vector<Vec6>* dlambda,
                  const BodyModel& model, const KernelCompliance& at, double lambda_scale, double inversion_floor, bool line_search,
                  bool lambda_zero) {
  T lam[6];
  if (lambda_zero) {
    PLIANT_UNROLL
    for (int r = 0; r < 6; ++r) lam[r] = splat<T>(0.0);
  } else {
    gather_slots(p, lambda, lam);
  }
  StrainStep<T> st;
  strain_step(p, x, lam, model.material.model, at, lambda_scale, line_search, st);
  // A full pack whose every lane is positive definite writes its slots from the rows at once.
  bool slots_written = false;
  if constexpr (kLanes<T> == 4) {
    if (st.ok == 0xF) {
      T sum[6];
      for (int r = 0; r < 6; ++r) sum[r] = lam[r] + st.dlambda[r];
      if (dlambda) slots_of_rows(st.dlambda, (*dlambda)[size_t(p.slot)].data());
      slots_of_rows(sum, lambda[size_t(p.slot)].data());
      slots_written = true;
    }
  }
  // Taken as zero, the slots are written whole: those of lanes skipped or padding get zero.
  if (lambda_zero && !slots_written)
    for (int l = 0; l < kLanes<T>; ++l) lambda[size_t(p.slot) + size_t(l)].setZero();
  int floor_lanes_mask = 0;  // lanes below the floor before the projection: checked again after it
  for (int l = 0; l < p.lanes; ++l) {
    if (!slots_written) {
      if (!(st.ok & (1 << l))) {  // not positive definite (cannot happen with alpha~ > 0): skip the tet
        if (dlambda) (*dlambda)[p.slot + l].setZero();
        continue;
      }
      Vec6 dl;
      for (int r = 0; r < 6; ++r) dl[r] = get_lane(st.dlambda[r], l);
      if (dlambda) (*dlambda)[p.slot + l] = dl;
      lambda[p.slot + l] += dl;
    }
    for (int k = 0; k < 4; ++k) {
      Vec3& q = x[p.v[k][l]];
      q[0] += get_lane(st.dx[k][0], l);
      q[1] += get_lane(st.dx[k][1], l);
      q[2] += get_lane(st.dx[k][2], l);
    }
    if (inversion_floor > 0 && get_lane(st.det, l) < inversion_floor) floor_lanes_mask |= 1 << l;
  }
  // The floor from the pack's own rest data (in cache), all its lanes at once; the lanes share no
  // corner, so flooring them after every lane's move is flooring each after its own.
  if (!floor_lanes_mask) return 0;
  return std::popcount(unsigned(floor_lanes(det_b_lanes(p), p.v, p.w, floor_lanes_mask, x, inversion_floor, inversion_floor, 1.0)));
}

template <class T>
void apply_increment_lanes(const TetLanes<T>& p, std::vector<Vec3>& x, const std::vector<Vec6>& dl, ElasticModel model) {
  Geometry<T> g;
  geometry(p, x, g, model);
  T y[6];
  gather_slots(p, dl, y);
  T dx[4][3];
  if (model == ElasticModel::Corotated) {
    T u[6][3];
    corotated_axes_of(g, u);
    corotated_corrections(p, g, u, y, dx);
  } else {
    stvk_corrections(p, g, y, dx);
  }
  for (int l = 0; l < p.lanes; ++l)
    PLIANT_UNROLL
    for (int k = 0; k < 4; ++k) {
      Vec3& q = x[p.v[k][l]];
      q[0] += get_lane(dx[k][0], l);
      q[1] += get_lane(dx[k][1], l);
      q[2] += get_lane(dx[k][2], l);
    }
}

int volume_floor_pack(const FloorCheck& c, std::vector<Vec3>& x, double trigger, double target, double relax) {
  return floor_lanes(c.det_b, c.v, c.w, (1 << c.lanes) - 1, x, trigger, target, relax);
}

v4d floor_volume_ratio(const FloorCheck& c, const std::vector<Vec3>& x) {
  FloorGeometry<v4d> g;
  floor_geometry(c.v, x, g);
  return g.det_d * c.det_b;
}

bool floor_may_act(const FloorCheck& c, const std::vector<Vec3>& x, double trigger) {
  FloorGeometry<v4d> g;
  floor_geometry(c.v, x, g);
  // ||D_s|| as max row sum of |D_s| (columns d[k]).
  v4d norm_d = splat<v4d>(0.0);
  for (int i = 0; i < 3; ++i) {
    v4d row = splat<v4d>(0.0);
    for (int k = 0; k < 3; ++k) row += g.d[k][i] < 0 ? -g.d[k][i] : g.d[k][i];
    norm_d = norm_d > row ? norm_d : row;
  }
  // The product is within a few tens of ulps of ||D_s||^3 ||B||^3 of the exact det F (every term
  // is a product of three entries bounded so), whatever multiply-adds the compiler fuses; 1e-12
  // is thousands of ulps.
  const v4d bound = 1e-12 * norm_d * norm_d * norm_d * c.b_norm3;
  const v4d gap = g.det_d * c.det_b - (trigger + bound);
  for (int l = 0; l < 4; ++l)
    if (!(gap[l] >= 0)) return true;  // below, or not finite
  return false;
}

template <class T>
double residual_squared_lanes(const TetLanes<T>& p, const std::vector<Vec3>& x, const std::vector<Vec6>& lambda,
                              const KernelCompliance& at, ElasticModel model) {
  Geometry<T> g;
  geometry(p, x, g, model);
  T C[6], lam[6];
  constraint(p, g, C);
  gather_slots(p, lambda, lam);
  const T sum = at.normal_and_shear ? lane_residual_squared<true>(C, lam, at) : lane_residual_squared<false>(C, lam, at);
  double total = 0;
  for (int l = 0; l < p.lanes; ++l) total += get_lane(sum, l);
  return total;
}

#define PLIANT_STRAIN_KERNEL(T)                                                                                    \
  template void strain_step(const TetLanes<T>&, const std::vector<Vec3>&, const T[6], ElasticModel,               \
                            const KernelCompliance&,                                                         \
                            double, bool, StrainStep<T>&);                                                         \
  template int project_lanes(const TetLanes<T>&, std::vector<Vec3>&, std::vector<Vec6>&, std::vector<Vec6>*,       \
                             const BodyModel&, const KernelCompliance&, double, double, bool, bool);                           \
  template void apply_increment_lanes(const TetLanes<T>&, std::vector<Vec3>&, const std::vector<Vec6>&,            \
                                      ElasticModel);                                                               \
  template double residual_squared_lanes(const TetLanes<T>&, const std::vector<Vec3>&, const std::vector<Vec6>&,   \
                                         const KernelCompliance&, ElasticModel);
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wignored-attributes"  // see strain_kernel.hpp
PLIANT_STRAIN_KERNEL(double)
PLIANT_STRAIN_KERNEL(v4d)
#pragma GCC diagnostic pop
#undef PLIANT_STRAIN_KERNEL

namespace {

// A number that counts the arithmetic done on it (+, -, *, /: one flop each; negation is free),
// so that the kernel's flop count comes from the kernel's own code.
struct Counted {
  double v = 0;
  Counted() = default;
  Counted(double a) : v(a) {}  // NOLINT: constants mix in as in the kernel's arithmetic
  static inline thread_local int64_t flops = 0;
};
inline Counted operator+(Counted a, Counted b) { ++Counted::flops; return a.v + b.v; }
inline Counted operator-(Counted a, Counted b) { ++Counted::flops; return a.v - b.v; }
inline Counted operator*(Counted a, Counted b) { ++Counted::flops; return a.v * b.v; }
inline Counted operator/(Counted a, Counted b) { ++Counted::flops; return a.v / b.v; }
inline Counted operator-(Counted a) { return -a.v; }
inline Counted& operator+=(Counted& a, Counted b) { return a = a + b; }
inline Counted& operator-=(Counted& a, Counted b) { return a = a - b; }
inline Counted& operator*=(Counted& a, Counted b) { return a = a * b; }
inline double get_lane(const Counted& a, int) { return a.v; }  // found by argument lookup
inline void set_lane(Counted& a, int, double value) { a.v = value; }

}  // namespace

double mean_projection_flops(const BodyModel& m, const std::vector<Vec3>& x, const std::vector<Vec6>& lambda,
                             const KernelCompliance& alpha_tilde, bool line_search) {
  if (m.tets.empty()) return 0;
  const int64_t before = Counted::flops;
  for (size_t t = 0; t < m.tets.size(); ++t) {
    const TetRest& tr = m.tets[t];
    const double w[4] = {m.inv_mass[tr.v[0]], m.inv_mass[tr.v[1]], m.inv_mass[tr.v[2]], m.inv_mass[tr.v[3]]};
    TetLanes<Counted> p{};
    fill_lane(p, 0, int32_t(t), tr, w);
    p.lanes = 1;
    p.slot = m.tet_slot[t];
    Counted lam[6];
    for (int r = 0; r < 6; ++r) lam[r] = lambda[p.slot][r];
    StrainStep<Counted> st;
    strain_step(p, x, lam, m.material.model, alpha_tilde, 1.0, line_search, st);
  }
  return double(Counted::flops - before) / double(m.tets.size());
}

}  // namespace pliant::detail
