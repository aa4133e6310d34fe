// SPDX-License-Identifier: Apache-2.0
// A soft body sagging onto a cloth's triangles (StepInputs::obstacles), checked the same way for
// every solver family: the unit tests run the families that project the contact (xpbd, vbd), the
// physics tests newton's penalty contact (seconds on beam1).
#pragma once

#include "pliant/builtin_meshes.hpp"
#include "pliant/interaction.hpp"
#include "pliant/stepper.hpp"
#include "pliant/vtu_recording.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace pliant::test {

// A drape of two triangles 2 cm below beam1 (0.12 x 0.015 x 0.015 m from the origin), its
// corners far from the beam.
inline TriangleObstacle drape_under_the_beam() {
  TriangleObstacle ob;
  ob.x = {Vec3(-0.1, -0.02, -0.2), Vec3(0.3, -0.02, -0.2), Vec3(-0.1, -0.02, 0.2), Vec3(0.3, -0.02, 0.2)};
  ob.triangles = {{0, 1, 2}, {1, 3, 2}};
  ob.radius = 0.004;
  ob.friction = 0.3;
  return ob;
}

// beam1 (the mesh given) clamped at x <= 0.01, E 100 kPa: it sags far.
inline auto soft_clamped_beam(const TetMesh& mesh) {
  FixedSelection fixed;
  fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(0.01, 1, 1)});
  return build_model(mesh, Material{1e5, 0.4, 1000}, fixed);
}

// 90 ticks onto the drape: every vertex, the surface's and the inside's, ends above it by the
// radius (less a hair), no tet inverted, and once at rest the impulse the beam puts on the drape
// in a step is the weight of the part it carries: between none and all of the beam's weight,
// downwards.
inline void expect_rests_on_the_drape(Method method) {
  SCOPED_TRACE(std::string(to_string(method)));
  const TetMesh mesh = *builtin_mesh("beam1");
  const auto model = soft_clamped_beam(mesh);
  BodyState state = rest_state(*model);
  SolverSettings s;
  s.method = method;
  s.damping_coefficient = 5;
  StepInputs in;
  in.obstacles.push_back(drape_under_the_beam());
  Stepper stepper;
  StepReport rep;
  for (int k = 0; k < 90; ++k) rep = stepper.step(*model, state, s, in);
  double lowest = INFINITY;
  for (const Vec3& x : state.x) lowest = std::min(lowest, x.y());
  EXPECT_GT(lowest, -0.02 + 0.004 - 2e-4) << "the lowest vertex, m";
  EXPECT_LT(lowest, -0.02 + 0.004 + 2e-3) << "the beam reaches the drape";
  int inverted = 0;
  for (double r : tet_volume_ratios(model->rest_positions, mesh.tets, state.x)) inverted += r <= 0;
  EXPECT_EQ(inverted, 0);
  EXPECT_GT(rep.contacts, 0);
  ASSERT_EQ(rep.obstacle_impulses.size(), 1u);
  ASSERT_EQ(rep.obstacle_impulses[0].size(), 4u) << "one impulse per corner";
  Vec3 push = Vec3::Zero();
  for (const Vec3& j : rep.obstacle_impulses[0]) push += j;
  double weight = 0;
  for (double mass : model->mass) weight += mass * 9.81;
  EXPECT_LT(push.y() / s.dt, -0.05 * weight) << "N";
  EXPECT_GT(push.y() / s.dt, -1.05 * weight) << "N";
}

}  // namespace pliant::test
