// SPDX-License-Identifier: Apache-2.0
// The solve order compiled with the body (compile_solve_order): every tet in exactly one lane,
// no two lanes of a pack sharing a vertex, and within a phase no two groups sharing a vertex
// (nor two packs of a split phase), so that running a phase's groups in parallel gives the
// result of running the packs in storage order. Small meshes go colour by colour; longer ones
// by slabs (ThreadCount in test_threads.cpp checks the step's bits for 1, 2 and 4 threads).
#include "kernels/strain_kernel.hpp"
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/model.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <climits>
#include <cstring>
#include <set>
#include <string>
#include <vector>

using namespace pliant;

namespace {

// The vertices of the real lanes of packs [b, e).
std::set<int32_t> vertices_of(const detail::PackedModel& pm, size_t b, size_t e) {
  std::set<int32_t> out;
  for (size_t i = b; i < e; ++i)
    for (int l = 0; l < pm.packs[i].lanes; ++l)
      for (int k = 0; k < 4; ++k) out.insert(pm.packs[i].v[k][l]);
  return out;
}

bool disjoint(const std::set<int32_t>& a, const std::set<int32_t>& b) {
  for (int32_t v : a)
    if (b.count(v)) return false;
  return true;
}

// The sweep's own vertex numbering: a permutation that numbers the vertices in the order the
// packs (storage order) first reach them, the sweep's packs the packs with their corners so
// renumbered (nothing else changed), the floor's checks (which carry the packs' corners, inverse
// masses and real lanes) and its vertex adjacency carried along. So the groups of the
// first phase (slabs, which share no vertex), each on its own thread, write disjoint ranges of
// positions in order.
void check_sweep_numbering(const BodyModel& m) {
  const detail::PackedModel& pm = detail::packed(m);
  const size_t nv = m.vertex_count();
  ASSERT_EQ(pm.sweep_vertex.size(), nv);
  ASSERT_EQ(pm.mesh_vertex.size(), nv);
  for (size_t v = 0; v < nv; ++v) {
    ASSERT_GE(pm.sweep_vertex[v], 0);
    ASSERT_EQ(size_t(pm.mesh_vertex[size_t(pm.sweep_vertex[v])]), v);
  }
  int32_t reached = 0;
  for (const detail::TetPack& p : pm.packs)
    for (int l = 0; l < p.lanes; ++l)
      for (int k = 0; k < 4; ++k) {
        const int32_t s = pm.sweep_vertex[size_t(p.v[k][l])];
        ASSERT_LE(s, reached) << "vertex " << p.v[k][l] << " numbered before the packs reach it";
        if (s == reached) ++reached;
      }
  ASSERT_EQ(pm.sweep_packs.size(), pm.packs.size());
  for (size_t i = 0; i < pm.packs.size(); ++i) {
    detail::TetPack renumbered = pm.packs[i];
    for (auto& corner : renumbered.v)
      for (int32_t& v : corner) v = pm.sweep_vertex[size_t(v)];
    ASSERT_EQ(0, std::memcmp(&renumbered, &pm.sweep_packs[i], sizeof renumbered)) << "pack " << i;
    detail::FloorCheck check = pm.floor_checks[i];
    // The floor's record carries the pack's corners, inverse masses and real lanes.
    ASSERT_EQ(check.lanes, pm.packs[i].lanes) << "floor check " << i;
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l) {
        ASSERT_EQ(check.v[k][l], pm.packs[i].v[k][l]) << "floor check " << i;
        ASSERT_EQ(check.w[k][l], pm.packs[i].w[k][l]) << "floor check " << i;
      }
    for (auto& corner : check.v)
      for (int32_t& v : corner) v = pm.sweep_vertex[size_t(v)];
    ASSERT_EQ(0, std::memcmp(&check, &pm.sweep_floor_checks[i], sizeof check)) << "floor check " << i;
  }
  // The floor's adjacency: sweep index s has mesh vertex mesh_vertex[s]'s entries, in order.
  ASSERT_EQ(pm.sweep_slot_start.size(), nv + 1);
  for (size_t sv = 0; sv < nv; ++sv) {
    const size_t v = size_t(pm.mesh_vertex[sv]);
    const std::vector<int32_t> mesh_row(pm.vertex_slot_entry.begin() + m.vertex_tet_start[v],
                                        pm.vertex_slot_entry.begin() + m.vertex_tet_start[v + 1]);
    const std::vector<int32_t> sweep_row(pm.sweep_slot_entry.begin() + pm.sweep_slot_start[sv],
                                         pm.sweep_slot_entry.begin() + pm.sweep_slot_start[sv + 1]);
    ASSERT_EQ(sweep_row, mesh_row) << "sweep vertex " << sv;
  }
  if (pm.phases.empty() || pm.phases[0].split) return;
  const auto& g = pm.phases[0].group_begin;
  int32_t end = 0;
  for (size_t a = 0; a + 1 < g.size(); ++a) {
    int32_t lo = INT32_MAX, hi = -1;
    for (int32_t v : vertices_of(pm, g[a], g[a + 1])) {
      lo = std::min(lo, pm.sweep_vertex[size_t(v)]);
      hi = std::max(hi, pm.sweep_vertex[size_t(v)]);
    }
    EXPECT_EQ(lo, end) << "group " << a;
    end = hi + 1;
  }
}

void check_order(const BodyModel& m, const std::string& name) {
  SCOPED_TRACE(name);
  const detail::PackedModel& pm = detail::packed(m);
  // Every tet in one real lane, at the slot the model maps it to.
  std::vector<int> seen(m.tet_count(), 0);
  for (size_t i = 0; i < pm.packs.size(); ++i) {
    const detail::TetPack& p = pm.packs[i];
    ASSERT_EQ(p.slot, int32_t(4 * i));
    ASSERT_GE(p.lanes, 1);
    ASSERT_LE(p.lanes, 4);
    std::set<int32_t> lanes;
    for (int l = 0; l < p.lanes; ++l) {
      const int32_t t = p.tet[l];
      ASSERT_GE(t, 0);
      ASSERT_LT(size_t(t), m.tet_count());
      seen[size_t(t)]++;
      EXPECT_EQ(m.tet_slot[size_t(t)], p.slot + l);
      for (int k = 0; k < 4; ++k) {
        EXPECT_EQ(p.v[k][l], m.tets[size_t(t)].v[k]);
        EXPECT_TRUE(lanes.insert(p.v[k][l]).second) << "pack " << i << " shares vertex " << p.v[k][l];
      }
    }
  }
  for (size_t t = 0; t < seen.size(); ++t) ASSERT_EQ(seen[t], 1) << "tet " << t;
  // Phases cover the packs in order; their groups (or a split phase's packs) share no vertex.
  size_t next = 0;
  for (size_t ph = 0; ph < pm.phases.size(); ++ph) {
    const auto& g = pm.phases[ph].group_begin;
    ASSERT_GE(g.size(), 2u);
    ASSERT_EQ(g.front(), next) << "phase " << ph;
    next = g.back();
    if (pm.phases[ph].split) {
      ASSERT_EQ(g.size(), 2u);
      std::set<int32_t> all;
      for (size_t i = g[0]; i < g[1]; ++i)
        for (int32_t v : vertices_of(pm, i, i + 1))
          ASSERT_TRUE(all.insert(v).second) << "split phase " << ph << ", pack " << i << ", vertex " << v;
    } else {
      for (size_t a = 0; a + 1 < g.size(); ++a) {
        ASSERT_LE(g[a], g[a + 1]);
        for (size_t b = a + 1; b + 1 < g.size(); ++b)
          EXPECT_TRUE(disjoint(vertices_of(pm, g[a], g[a + 1]), vertices_of(pm, g[b], g[b + 1])))
              << "phase " << ph << ", groups " << a << " and " << b;
      }
    }
  }
  EXPECT_EQ(next, pm.packs.size());
  check_sweep_numbering(m);
}

std::shared_ptr<const BodyModel> builtin(const std::string& name) {
  return build_model(*builtin_mesh(name), Material{1e6, 0.45, 1000});
}

}  // namespace

TEST(SolveOrder, SmallMeshesGoColourByColour) {
  // beam1: 460 tets, fewer than two slabs of 512.
  auto m = builtin("beam1");
  const detail::PackedModel& pm = detail::packed(*m);
  EXPECT_EQ(pm.blocks, 1);
  ASSERT_EQ(pm.phases.size(), m->colours.size());
  for (size_t c = 0; c < pm.phases.size(); ++c) {
    EXPECT_TRUE(pm.phases[c].split);
    const auto& g = pm.phases[c].group_begin;
    EXPECT_EQ(g.back() - g.front(), (m->colours[c].size() + 3) / 4) << "colour " << c;
  }
  check_order(*m, "beam1");
}

TEST(SolveOrder, LongerMeshesGoBySlabsAndStayIndependent) {
  // beam3 (40 x 5 x 5 cells): 4 slabs, one group each, then the 3 cuts (odd, even).
  auto beam3 = builtin("beam3");
  const detail::PackedModel& pm = detail::packed(*beam3);
  EXPECT_EQ(pm.blocks, 4);
  ASSERT_GE(pm.phases.size(), 3u);
  EXPECT_FALSE(pm.phases[0].split);
  EXPECT_EQ(pm.phases[0].group_begin.size(), 5u);  // 4 slabs
  EXPECT_EQ(pm.phases[1].group_begin.size(), 3u);  // cuts 1 and 3
  EXPECT_EQ(pm.phases[2].group_begin.size(), 2u);  // cut 2
  // The slabs hold equal vertex counts: no slab has more than 1.5x the packs of another.
  size_t lo = SIZE_MAX, hi = 0;
  for (size_t g = 0; g + 1 < pm.phases[0].group_begin.size(); ++g) {
    const size_t n = pm.phases[0].group_begin[g + 1] - pm.phases[0].group_begin[g];
    lo = std::min(lo, n);
    hi = std::max(hi, n);
  }
  EXPECT_LE(double(hi), 1.5 * double(lo));
  // Padding: a block fills a colour's last pack with the next colour's tets. Packed colour by
  // colour within each block, beam3 wasted 428 lanes (12% of its tets; about 20 colours per
  // slab, each with a short last pack); now under 5%.
  EXPECT_LT(double(4 * pm.packs.size() - beam3->tet_count()), 0.05 * double(beam3->tet_count()));
  check_order(*beam3, "beam3");
  check_order(*builtin("beam2"), "beam2");
  // The thesis hippo: an irregular mesh with slivers.
  check_order(*build_model(resolve_mesh("hippo"), Material{1e6, 0.45, 1000}), "hippo");
}

TEST(SolveOrder, TetsAcrossSeveralCutsGoColourByColourAtTheEnd) {
  // beam3 with one more tet from the clamped end to the free end: it crosses every cut, so it
  // belongs to no slab and no cut; it goes last, in a split phase of its own colour.
  TetMesh mesh = *builtin_mesh("beam3");
  Vec3 low = mesh.vertices[0], high = low;
  for (const Vec3& p : mesh.vertices) {
    low = low.cwiseMin(p);
    high = high.cwiseMax(p);
  }
  auto nearest = [&](const Vec3& q) {
    int32_t best = 0;
    for (size_t i = 0; i < mesh.vertices.size(); ++i)
      if ((mesh.vertices[i] - q).norm() < (mesh.vertices[best] - q).norm()) best = int32_t(i);
    return best;
  };
  Tet long_tet = {nearest(low), nearest(Vec3(low.x(), high.y(), low.z())), nearest(Vec3(high.x(), low.y(), low.z())),
                  nearest(high)};
  const auto& v = mesh.vertices;
  if ((v[long_tet[1]] - v[long_tet[0]]).cross(v[long_tet[2]] - v[long_tet[0]]).dot(v[long_tet[3]] - v[long_tet[0]]) < 0)
    std::swap(long_tet[2], long_tet[3]);
  mesh.tets.push_back(long_tet);
  auto m = build_model(mesh, Material{1e6, 0.45, 1000});
  const detail::PackedModel& pm = detail::packed(*m);
  ASSERT_EQ(pm.blocks, 4);
  ASSERT_EQ(pm.phases.size(), 4u);
  const detail::SolvePhase& last = pm.phases.back();
  EXPECT_TRUE(last.split);
  ASSERT_EQ(last.group_begin.back() - last.group_begin.front(), 1u);
  EXPECT_EQ(pm.packs.back().lanes, 1);
  EXPECT_EQ(pm.packs.back().tet[0], int32_t(mesh.tets.size() - 1));
  check_order(*m, "beam3 and a long tet");
}
