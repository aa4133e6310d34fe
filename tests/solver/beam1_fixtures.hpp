// SPDX-License-Identifier: Apache-2.0
// beam1 as the interaction tests use it: clamped at x = 0 (it spans [0, 0.115] x [0, 0.01] x
// [0, 0.01] m), and the vertex or top-face triangle nearest to a point.
#pragma once

#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/model.hpp"

#include <cmath>
#include <memory>

namespace pliant::test {

inline std::shared_ptr<const BodyModel> clamped_beam(double young) {
  TetMesh mesh = *builtin_mesh("beam1");
  return build_model(mesh, Material{young, 0.4, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
}

inline int32_t nearest_vertex(const BodyModel& m, const Vec3& p) {
  int32_t best = 0;
  for (size_t i = 0; i < m.vertex_count(); ++i)
    if ((m.rest_positions[i] - p).squaredNorm() < (m.rest_positions[best] - p).squaredNorm()) best = int32_t(i);
  return best;
}

// The top-face triangle of the beam (y = 0.01, outward +y) whose centroid is nearest to p.
inline Triangle top_triangle_near(const BodyModel& m, const Vec3& p, Vec3* centroid) {
  Triangle best{};
  *centroid = Vec3::Zero();  // set on every path (no triangle at y = 0.01: none found)
  double bd = 1e300;
  for (const Triangle& t : m.surface) {
    const Vec3 a = m.rest_positions[t[0]], b = m.rest_positions[t[1]], c = m.rest_positions[t[2]];
    if (std::abs(a.y() - 0.01) > 1e-9 || std::abs(b.y() - 0.01) > 1e-9 || std::abs(c.y() - 0.01) > 1e-9) continue;
    const Vec3 g = (a + b + c) / 3;
    if ((g - p).squaredNorm() < bd) {
      bd = (g - p).squaredNorm();
      best = t;
      *centroid = g;
    }
  }
  return best;
}

}  // namespace pliant::test
