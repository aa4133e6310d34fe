// SPDX-License-Identifier: Apache-2.0
// Inexact Newton (method newton, newton_linear_solver cg): conjugate gradients on the Hessian
// reach the same implicit-Euler step as the sparse factorisation, every Newton iteration lowers
// the incremental potential, a step stopped by its time budget ends no worse than it began, and
// grabs and a floor act as with the direct solve.
#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/stepper.hpp"
#include "pliant/strain_constraint.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

using namespace pliant;

namespace {

std::shared_ptr<const BodyModel> clamped(const char* name, double young) {
  TetMesh mesh = *builtin_mesh(name);
  return build_model(mesh, Material{young, 0.4, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
}

SolverSettings newton(NewtonLinearSolver linear, int iterations) {
  SolverSettings s;
  s.method = Method::Newton;
  s.newton_linear_solver = linear;
  s.substeps = 1;
  s.iterations = iterations;
  s.damping = Damping::None;
  return s;
}

double distance(const std::vector<Vec3>& a, const std::vector<Vec3>& b) {
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d += (a[i] - b[i]).squaredNorm();
  return std::sqrt(d);
}

// A bent, moving beam: a step with work in the inertia, elasticity and gravity terms.
BodyState bent_moving(const BodyModel& m) {
  BodyState state = rest_state(m);
  const double x_clamp = default_clamp_x(m.rest_positions);
  state.x = cantilever_bend(m, x_clamp, 0.008);
  const double length = bounding_box(m.rest_positions).extent().x();
  for (size_t i = 0; i < state.v.size(); ++i)
    if (m.inv_mass[i] > 0) state.v[i] = Vec3(0, 0.1, 0.05) * (m.rest_positions[i].x() / length);
  return state;
}

// The incremental potential of one step from `state` (no grabs or contacts):
// sum_i I_i / (2 h^2) |x_i - y_i|^2 + sum_tets E(x), y the prediction under gravity.
struct Potential {
  const BodyModel& m;
  std::vector<Vec3> y;
  double h;
  Potential(const BodyModel& model, const BodyState& state, const SolverSettings& s) : m(model), h(s.dt) {
    y = state.x;
    for (size_t i = 0; i < y.size(); ++i)
      if (m.inv_mass[i] > 0) y[i] += h * (state.v[i] + h * s.gravity * (m.mass[i] / m.inertia[i]));
  }
  double operator()(const std::vector<Vec3>& x) const {
    double e = 0;
    for (const TetRest& t : m.tets) e += strain_energy(t, m.stiffness, gather(x, t.v), m.material.model);
    for (size_t i = 0; i < x.size(); ++i)
      if (m.inv_mass[i] > 0) e += 0.5 / (h * h) * m.inertia[i] * (x[i] - y[i]).squaredNorm();
    return e;
  }
};

}  // namespace

TEST(NewtonCg, ReachesTheSameStepAsTheDirectSolve) {
  for (NewtonLinearSolver linear : {NewtonLinearSolver::Cg, NewtonLinearSolver::CgJacobi, NewtonLinearSolver::CgFactor,
                                    NewtonLinearSolver::CgTwoLevel})
  for (const char* mesh : {"beam1", "beam3"})
    for (double young : {1e5, 1e7}) {
      auto m = clamped(mesh, young);
      const BodyState start = bent_moving(*m);
      SolverSettings direct = newton(NewtonLinearSolver::Direct, 50);
      direct.tolerance = 1e-11;
      SolverSettings cg = direct;
      cg.newton_linear_solver = linear;
      BodyState a = start, b = start;
      Stepper sa, sb;
      const StepReport ra = sa.step(*m, a, direct);
      const StepReport rb = sb.step(*m, b, cg);
      ASSERT_FALSE(ra.diverged);
      ASSERT_FALSE(rb.diverged);
      EXPECT_EQ(ra.linear_iterations, 0);
      EXPECT_GE(rb.linear_iterations, rb.iterations);
      EXPECT_LT(distance(a.x, b.x), 1e-6 * distance(start.x, a.x)) << to_string(linear) << " " << mesh << " E " << young;
    }
}

TEST(NewtonCg, EveryIterationLowersThePotential) {
  for (NewtonLinearSolver linear : {NewtonLinearSolver::Cg, NewtonLinearSolver::CgJacobi, NewtonLinearSolver::CgTwoLevel}) {
  auto m = clamped("beam3", 1e6);
  const BodyState start = bent_moving(*m);
  SolverSettings s = newton(linear, 12);
  const Potential G(*m, start, s);
  std::vector<double> energies{G(start.x)};
  Stepper stepper;
  stepper.set_iteration_hook([&](int, const std::vector<Vec3>& x, double, double) { energies.push_back(G(x)); });
  BodyState state = start;
  const StepReport rep = stepper.step(*m, state, s);
  ASSERT_FALSE(rep.diverged);
  ASSERT_GE(energies.size(), 4u);
  for (size_t k = 1; k < energies.size(); ++k)
    EXPECT_LE(energies[k], energies[k - 1] + 1e-12 * std::abs(energies[0])) << to_string(linear) << " iteration " << k;
  EXPECT_LT(energies.back(), energies.front());
  }
}

TEST(NewtonCg, AStepStoppedByItsBudgetEndsNoWorseThanItsStart) {
  for (NewtonLinearSolver linear : {NewtonLinearSolver::Cg, NewtonLinearSolver::CgJacobi, NewtonLinearSolver::CgTwoLevel})
  for (double young : {1e5, 1e7}) {
    auto m = clamped("beam3", young);
    const BodyState start = bent_moving(*m);
    SolverSettings s = newton(linear, 1000);
    s.time_budget_ms = 1e-6;  // spent before the first CG iteration ends
    const Potential G(*m, start, s);
    BodyState state = start;
    Stepper stepper;
    const StepReport rep = stepper.step(*m, state, s);
    ASSERT_FALSE(rep.diverged);
    EXPECT_TRUE(rep.stopped_by_budget);
    EXPECT_EQ(rep.iterations, 1);
    EXPECT_EQ(rep.linear_iterations, 1);
    // The warm start's candidates: the start and the prediction.
    EXPECT_LE(G(state.x), G(start.x)) << to_string(linear) << " E " << young;
    EXPECT_LE(G(state.x), G(G.y)) << to_string(linear) << " E " << young;
  }
}

TEST(NewtonCg, AutoChoosesByTheNumberOfFreeDofs) {
  EXPECT_FALSE(newton_uses_cg(NewtonLinearSolver::Auto, kNewtonDirectMaxDofs));
  EXPECT_TRUE(newton_uses_cg(NewtonLinearSolver::Auto, kNewtonDirectMaxDofs + 3));
  EXPECT_TRUE(newton_uses_cg(NewtonLinearSolver::Cg, 3));
  EXPECT_FALSE(newton_uses_cg(NewtonLinearSolver::Direct, 1 << 30));
  EXPECT_EQ(parse_newton_linear_solver("cg"), NewtonLinearSolver::Cg);
  EXPECT_EQ(parse_newton_linear_solver("direct"), NewtonLinearSolver::Direct);
  EXPECT_EQ(parse_newton_linear_solver("auto"), NewtonLinearSolver::Auto);
  EXPECT_EQ(parse_newton_linear_solver("cg-jacobi"), NewtonLinearSolver::CgJacobi);
  EXPECT_EQ(parse_newton_linear_solver("cg-factor"), NewtonLinearSolver::CgFactor);
  EXPECT_TRUE(newton_uses_cg(NewtonLinearSolver::CgFactor, 3));
  EXPECT_EQ(parse_newton_linear_solver("cg-twolevel"), NewtonLinearSolver::CgTwoLevel);
  EXPECT_TRUE(newton_uses_cg(NewtonLinearSolver::CgTwoLevel, 3));
  EXPECT_FALSE(parse_newton_linear_solver("ldlt"));
  // beam3 stays with the factorisation under auto.
  auto m = clamped("beam3", 1e6);
  BodyState state = bent_moving(*m);
  Stepper stepper;
  EXPECT_EQ(stepper.step(*m, state, newton(NewtonLinearSolver::Auto, 3)).linear_iterations, 0);
}

TEST(NewtonCg, AHardGrabReachesItsTargetAndAFloorHoldsTheBody) {
  for (NewtonLinearSolver linear : {NewtonLinearSolver::Cg, NewtonLinearSolver::CgJacobi, NewtonLinearSolver::CgTwoLevel}) {
    // The grab's penalty is 1e6 x the stiffness it holds: the worst conditioning CG meets.
    auto m = clamped("beam1", 1e6);
    SolverSettings s = newton(linear, 30);
    s.gravity.setZero();
    int32_t tip = 0;
    for (size_t i = 0; i < m->vertex_count(); ++i)
      if (m->rest_positions[i].x() > m->rest_positions[tip].x()) tip = int32_t(i);
    StepInputs in;
    const Vec3 target = m->rest_positions[tip] + Vec3(0, 0.005, 0);
    in.attachments.push_back(Attachment::vertex(tip, target));
    BodyState state = rest_state(*m);
    Stepper stepper;
    StepReport rep;
    for (int k = 0; k < 5; ++k) rep = stepper.step(*m, state, s, in);
    EXPECT_FALSE(rep.diverged);
    EXPECT_LT((state.x[tip] - target).norm(), 1e-3 * 0.005) << to_string(linear);
    ASSERT_EQ(rep.attachment_forces.size(), 1u);
    EXPECT_GT(rep.attachment_forces[0].y(), 0);

    // A free beam dropped on a floor comes to rest on it (penalty contacts with friction). With
    // the vertex blocks alone it lands but still moved at 2.9 mm/s after 240 ticks: cg only.
    if (linear != NewtonLinearSolver::Cg) continue;
    TetMesh mesh = *builtin_mesh("beam1");
    auto free_beam = build_model(mesh, Material{1e5, 0.4, 1000});
    SolverSettings f = newton(linear, 10);
    f.damping = Damping::Simple;
    f.damping_coefficient = 5;
    StepInputs floor;
    floor.colliders.push_back(Collider::plane(Vec3(0, -0.01, 0), Vec3(0, 1, 0)));
    BodyState fs = rest_state(*free_beam);
    Stepper fstepper;
    for (int k = 0; k < 240; ++k) rep = fstepper.step(*free_beam, fs, f, floor);
    EXPECT_FALSE(rep.diverged);
    EXPECT_GT(rep.contacts, 0);
    double lowest = 1e300;
    for (const Vec3& x : fs.x) lowest = std::min(lowest, x.y());
    EXPECT_GT(lowest, -0.01 - 1e-5) << to_string(linear);
    EXPECT_LT(lowest, -0.01 + 1e-3) << to_string(linear);
    EXPECT_LT(max_speed(fs), 1e-3) << to_string(linear);
  }
}

TEST(NewtonCg, ABodyPropedOnAFloorKeepsItsHessianAtRestAndRestsWhereTheDirectSolveDoes) {
  // beam3 at 1 MPa hanging from its clamp, its free end propped by a frictionless floor 4 mm above
  // where it would hang: at rest the floor's penalties act every tick. Inexact Newton keeps its
  // elastic Hessian there (the penalties are taken off and put back fresh each iteration), and
  // one CG-Newton iteration a tick brings it to the rest the direct solve reaches.
  auto m = clamped("beam3", 1e6);
  auto rest_on = [&](const StepInputs& in, NewtonLinearSolver linear, int iterations, StepReport& rep) {
    SolverSettings s = newton(linear, iterations);
    s.damping = Damping::Simple;
    s.damping_coefficient = 5;
    BodyState state = rest_state(*m);
    Stepper stepper;
    for (int k = 0; k < 300; ++k) rep = stepper.step(*m, state, s, in);
    EXPECT_FALSE(rep.diverged) << to_string(linear);
    EXPECT_LT(max_speed(state), 1e-4) << to_string(linear);
    return state.x;
  };
  StepReport rep;
  double tip_y = 1e300;
  for (const Vec3& x : rest_on(StepInputs{}, NewtonLinearSolver::Direct, 10, rep)) tip_y = std::min(tip_y, x.y());
  Collider floor = Collider::plane(Vec3(0, tip_y + 0.004, 0), Vec3(0, 1, 0));
  floor.static_friction = floor.dynamic_friction = 0;
  StepInputs in;
  in.colliders.push_back(floor);
  auto rest_on_floor = [&](NewtonLinearSolver linear, int iterations, StepReport& rep) {
    const std::vector<Vec3> x = rest_on(in, linear, iterations, rep);
    EXPECT_GT(rep.contacts, 0) << to_string(linear);
    return x;
  };
  const std::vector<Vec3> reference = rest_on_floor(NewtonLinearSolver::Direct, 10, rep);
  const double sag = distance(reference, m->rest_positions);
  for (NewtonLinearSolver linear : {NewtonLinearSolver::Cg, NewtonLinearSolver::CgTwoLevel}) {
    const std::vector<Vec3> x = rest_on_floor(linear, 1, rep);
    EXPECT_EQ(rep.hessian_reused, 1) << to_string(linear);
    EXPECT_LT(distance(x, reference), 1e-3 * sag) << to_string(linear);
  }
}
