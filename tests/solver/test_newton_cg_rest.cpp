// SPDX-License-Identifier: Apache-2.0
// Inexact Newton on a thesis model: the hippo hanging from its first 10% of x, stepped at 60 Hz
// with a few CG-Newton iterations per tick (what a realtime budget runs; fixed counts here so
// that the test does not depend on the machine's speed), comes to rest where the direct Newton
// static solve puts it.
#include "pliant/experiments.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/stepper.hpp"

#include <gtest/gtest.h>

using namespace pliant;

TEST(NewtonCgRest, HippoHangsWithinFivePercentOfNewtonsStaticTip) {
  const TetMesh mesh = resolve_mesh("hippo");
  const Aabb box = bounding_box(mesh.vertices);
  auto m = build_model(mesh, Material{1e6, 0.4, 1000}, clamp_below_x(box.min.x() + 0.1 * box.extent().x()));
  SolverSettings s;
  s.method = Method::Newton;
  s.newton_linear_solver = NewtonLinearSolver::Auto;
  s.substeps = 1;
  s.iterations = 3;
  s.damping_coefficient = 5;
  s.threads = 2;
  s.record_residuals = false;
  const RestResult rest = run_to_rest(*m, s, 400, 1e-3);
  ASSERT_FALSE(rest.diverged);
  EXPECT_TRUE(rest.at_rest) << "max speed " << rest.max_speed << " after " << rest.steps << " ticks";
  EXPECT_GT(rest.last_report.linear_iterations, 0) << "auto did not choose cg for the hippo";
  const NewtonResult ref = solve_static(*m, m->rest_positions, s.gravity);
  ASSERT_TRUE(ref.converged);
  const double tip = tip_displacement(*m, rest.state.x).norm();
  const double tip_ref = tip_displacement(*m, ref.x).norm();
  EXPECT_NEAR(tip / tip_ref, 1.0, 0.05) << "tip " << tip << " m, Newton's " << tip_ref << " m";
  EXPECT_EQ(count_inverted(*m, rest.state.x), 0u);
}
