// SPDX-License-Identifier: Apache-2.0
// The global Newton step (method newton): it reaches the converged implicit-Euler step of the
// reference solver, converges quadratically near it, conserves linear momentum, holds fixed
// vertices, pulls grabs to their targets, keeps bodies out of colliders and off a cloth's
// triangles, and feels a tool with the force the body puts on it.
#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/method_choice.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/stepper.hpp"
#include "pliant/strain_constraint.hpp"

#include "drape_obstacle.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace pliant;

namespace {

std::shared_ptr<const BodyModel> clamped_beam1(double young) {
  TetMesh mesh = *builtin_mesh("beam1");
  return build_model(mesh, Material{young, 0.4, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
}

SolverSettings newton_settings(int iterations) {
  SolverSettings s;
  s.method = Method::Newton;
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

// The prediction of one step from `state` under gravity (the reference's target x~).
std::vector<Vec3> predicted(const BodyModel& m, const BodyState& state, const SolverSettings& s) {
  std::vector<Vec3> y = state.x;
  for (size_t i = 0; i < y.size(); ++i)
    if (m.inv_mass[i] > 0) y[i] += s.dt * (state.v[i] + s.dt * s.gravity * (m.mass[i] / m.inertia[i]));
  return y;
}

}  // namespace

TEST(NewtonStep, ReachesTheReferenceImplicitStep) {
  for (double young : {1e5, 1e7}) {
    auto m = clamped_beam1(young);
    const SolverSettings s = newton_settings(30);
    BodyState state = rest_state(*m);
    // Start from a bent, moving beam so that the step has work in every term.
    state.x = cantilever_bend(*m, default_clamp_x(m->rest_positions), 0.004);
    for (size_t i = 0; i < state.v.size(); ++i)
      if (m->inv_mass[i] > 0) state.v[i] = Vec3(0, 0.05, 0.02) * (m->rest_positions[i].x() / 0.115);
    const std::vector<Vec3> x0 = state.x;
    NewtonOptions tight;
    tight.tolerance = 1e-12;
    const NewtonResult ref = solve_implicit_step(*m, x0, predicted(*m, state, s), s.dt, tight);
    ASSERT_TRUE(ref.converged);
    Stepper stepper;
    const StepReport rep = stepper.step(*m, state, s, {});
    EXPECT_FALSE(rep.diverged);
    EXPECT_LT(distance(state.x, ref.x), 1e-6 * distance(x0, ref.x)) << "E " << young;
    // The velocity is the step's displacement over dt (implicit Euler).
    for (size_t i = 0; i < state.x.size(); ++i)
      ASSERT_NEAR((state.v[i] - (state.x[i] - x0[i]) / s.dt).norm(), 0, 1e-9);
  }
}

TEST(NewtonStep, ConvergesQuadraticallyNearTheSolution) {
  auto m = clamped_beam1(1e6);
  SolverSettings s = newton_settings(12);
  BodyState state = rest_state(*m);
  state.x = cantilever_bend(*m, default_clamp_x(m->rest_positions), 0.01);
  Stepper stepper;
  const StepReport rep = stepper.step(*m, state, s, {});
  const std::vector<double>& r = rep.residuals;
  ASSERT_GE(r.size(), 3u);
  // The order p = log(r_{k+1} / r_k) / log(r_k / r_{k-1}) over the last three residuals still
  // above the round-off floor: 2 for Newton, 1 for a linearly convergent method.
  const double floor = 1e-9 * rep.residual_initial;
  int k = -1;
  for (size_t i = 2; i < r.size(); ++i)
    if (r[i] > floor) k = int(i);
  ASSERT_GE(k, 2) << "converged before three residuals above round-off";
  const double p = std::log(r[k] / r[k - 1]) / std::log(r[k - 1] / r[k - 2]);
  EXPECT_GT(p, 1.6) << r[k - 2] << " " << r[k - 1] << " " << r[k];
  EXPECT_LT(r.back(), 1e-8 * rep.residual_initial);
}

TEST(NewtonStep, ConservesLinearMomentumWithoutExternalForces) {
  TetMesh mesh = *builtin_mesh("beam1");
  auto m = build_model(mesh, Material{1e6, 0.4, 1000});  // nothing fixed
  SolverSettings s = newton_settings(20);
  s.gravity.setZero();
  BodyState state = rest_state(*m);
  // A deformed, spinning and drifting start.
  for (size_t i = 0; i < state.x.size(); ++i) {
    const Vec3 p = m->rest_positions[i];
    state.x[i] = p + Vec3(0.002 * std::sin(40 * p.x()), 0.001 * p.x() / 0.115, 0);
    state.v[i] = Vec3(0.3, -0.1, 0.2) + Vec3(0, 0, 1).cross(p - Vec3(0.0575, 0.005, 0.005));
  }
  auto momentum = [&](const BodyState& st) {
    Vec3 p = Vec3::Zero();
    for (size_t i = 0; i < st.v.size(); ++i) p += m->inertia[i] * st.v[i];
    return p;
  };
  const Vec3 p0 = momentum(state);
  Stepper stepper;
  for (int k = 0; k < 5; ++k) {
    const StepReport rep = stepper.step(*m, state, s, {});
    ASSERT_FALSE(rep.diverged);
  }
  EXPECT_LT((momentum(state) - p0).norm(), 1e-9 * p0.norm());
}

TEST(NewtonStep, FixedVerticesStayAndAHardGrabReachesItsTarget) {
  auto m = clamped_beam1(1e6);
  SolverSettings s = newton_settings(20);
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
  for (int k = 0; k < 3; ++k) rep = stepper.step(*m, state, s, in);
  for (size_t i = 0; i < m->vertex_count(); ++i)
    if (m->fixed[i]) {
      ASSERT_EQ(state.x[i], m->rest_positions[i]);
    }
  EXPECT_LT((state.x[tip] - target).norm(), 1e-4 * 0.005);
  // The grab pulls the body up, towards its target.
  ASSERT_EQ(rep.attachment_forces.size(), 1u);
  EXPECT_GT(rep.attachment_forces[0].y(), 0);
  // A compliant grab stretches: the force is the spring's, (target - point) / compliance.
  // beam1's tip stiffness at 1 MPa is about 3EI/L^3 = 1.6 N/m: a 1 N/m spring meets it half way.
  in.attachments[0].compliance = 1.0;
  state = rest_state(*m);
  for (int k = 0; k < 3; ++k) rep = stepper.step(*m, state, s, in);
  const Vec3 expected = (target - state.x[tip]) / 1.0;
  EXPECT_NEAR((rep.attachment_forces[0] - expected).norm(), 0, 1e-9 * expected.norm());
  EXPECT_GT((state.x[tip] - target).norm(), 1e-3);
  EXPECT_GT(state.x[tip].y() - m->rest_positions[tip].y(), 1e-3);
}

TEST(NewtonStep, ABodyDroppedOnAFloorComesToRestOnIt) {
  TetMesh mesh = *builtin_mesh("beam1");
  auto m = build_model(mesh, Material{1e5, 0.4, 1000});
  SolverSettings s = newton_settings(10);
  s.damping_coefficient = 5;
  StepInputs in;
  in.colliders.push_back(Collider::plane(Vec3(0, -0.01, 0), Vec3(0, 1, 0)));
  BodyState state = rest_state(*m);
  Stepper stepper;
  StepReport rep;
  for (int k = 0; k < 240; ++k) rep = stepper.step(*m, state, s, in);
  EXPECT_FALSE(rep.diverged);
  EXPECT_GT(rep.contacts, 0);
  double lowest = 1e300;
  for (const Vec3& x : state.x) lowest = std::min(lowest, x.y());
  // The penalty leaves a penetration far below the body's size.
  EXPECT_GT(lowest, -0.01 - 1e-5);
  EXPECT_LT(lowest, -0.01 + 1e-3);  // it did fall onto the floor
  EXPECT_LT(max_speed(state), 1e-3);
}

TEST(NewtonStep, AToolFeelsTheForceThatHoldsTheBodyInItsShape) {
  // A sphere pressed 2 mm into the top of the clamped beam near its tip, no gravity, no
  // friction. At rest the force on the tool is the elastic force of the dent: the same force,
  // applied as external loads at the contact vertices, holds the body in the same shape (the
  // static equilibrium of the reference solver with those loads reproduces the positions).
  auto m = clamped_beam1(1e6);
  SolverSettings s = newton_settings(20);
  s.gravity.setZero();
  s.damping_coefficient = 20;
  StepInputs in;
  in.tools.push_back(RigidTool::sphere(Vec3(0.1, 0.02 - 0.002, 0.005), 0.01));
  in.tools[0].static_friction = in.tools[0].dynamic_friction = 0;
  BodyState state = rest_state(*m);
  Stepper stepper;
  StepReport rep;
  for (int k = 0; k < 300 && (k < 5 || max_speed(state) > 1e-7); ++k) rep = stepper.step(*m, state, s, in);
  ASSERT_EQ(rep.tools.size(), 1u);
  const ToolReaction& t = rep.tools[0];
  ASSERT_FALSE(t.contacts.empty());
  EXPECT_GT(t.force.y(), 0);  // the body pushes the tool up
  std::vector<Vec3> loads(m->vertex_count(), Vec3::Zero());
  Vec3 sum = Vec3::Zero();
  for (const ToolContact& c : t.contacts) {
    loads[c.vertex] -= c.force;
    sum += c.force;
  }
  EXPECT_NEAR((sum - t.force).norm(), 0, 1e-9 * t.force.norm());
  NewtonOptions tight;
  tight.tolerance = 1e-11;
  const NewtonResult eq = solve_static(*m, m->rest_positions, Vec3::Zero(), loads, tight);
  ASSERT_TRUE(eq.converged);
  EXPECT_LT(distance(eq.x, state.x), 1e-3 * distance(state.x, m->rest_positions));
}

TEST(NewtonStep, AToolLiftedAwayFeelsNoMoreThanItsPress) {
  // The haptic bridge's scene (soft, nearly incompressible beam1 lying on its bottom face, 1 kHz
  // ticks, one Newton iteration per tick): a 5 mm sphere pressed 3 mm into the top over the
  // tip, held, then lifted out along the same cosine ramp. The dent springs back after the
  // tool; the force on the tool must fall from the press's force to zero, not jump above it.
  TetMesh mesh = *builtin_mesh("beam1");
  FixedSelection bottom;
  for (size_t i = 0; i < mesh.vertices.size(); ++i)
    if (mesh.vertices[i].y() <= 1e-3) bottom.indices.push_back(int32_t(i));
  auto m = build_model(mesh, Material{1e5, 0.49, 1000}, bottom);
  SolverSettings s = newton_settings(1);
  s.dt = 1e-3;
  s.gravity.setZero();
  s.damping = Damping::Simple;
  s.damping_coefficient = 20;
  BodyState state = rest_state(*m);
  Stepper stepper;
  const double top = 0.01 + 0.005, low = top - 0.003;
  Vec3 previous(0.1, top, 0.005);
  auto tick = [&](double y) {
    StepInputs in;
    RigidTool tool = RigidTool::sphere(Vec3(0.1, y, 0.005), 0.005);
    tool.velocity = (tool.position - previous) / s.dt;
    previous = tool.position;
    in.tools.push_back(tool);
    const StepReport rep = stepper.step(*m, state, s, in);
    EXPECT_FALSE(rep.diverged);
    return rep.tools.at(0).force.norm();
  };
  auto ramp = [](int k) { return 0.5 * (1 - std::cos(M_PI * std::min(k / 500.0, 1.0))); };
  double held = 0;
  for (int k = 1; k <= 750; ++k) held = tick(top - (top - low) * ramp(k));
  ASSERT_GT(held, 0.5);  // pressed: about 1.24 N
  double lifting = 0;
  for (int k = 1; k <= 500; ++k) lifting = std::max(lifting, tick(low + (top - low) * ramp(k)));
  // The converged step's force while lifting never exceeds the press's (pliant_haptic_fidelity's
  // reference); one iteration's transient adds about a tenth. The penalty at the final iterate
  // alone gave 21 N here.
  EXPECT_LT(lifting, 1.25 * held);
  EXPECT_LT(tick(top + 0.001), 1e-12);  // out of contact: nothing
}

TEST(NewtonStep, ASaggingBodyRestsOnADrapeAndPushesItWithItsWeight) {
  // The cloth's triangles as a penalty contact: the same checks as the projecting families'
  // (ObstacleContact in test_coupling.cpp), the push on the drape the force that holds the body.
  test::expect_rests_on_the_drape(Method::Newton);
}

TEST(NewtonStep, StopsWhenCancelled) {
  auto m = clamped_beam1(1e6);
  SolverSettings s = newton_settings(50);
  s.substeps = 4;
  std::atomic<bool> cancel{true};
  StepInputs in;
  in.cancel = &cancel;
  BodyState state = rest_state(*m);
  Stepper stepper;
  const StepReport rep = stepper.step(*m, state, s, in);
  EXPECT_TRUE(rep.cancelled);
  EXPECT_EQ(rep.iterations, 1);
  EXPECT_EQ(rep.substeps, 1);
  EXPECT_NEAR(state.time, s.dt / 4, 1e-15);
}

TEST(MethodAuto, MeasuresEachFamilyAndKeepsTheMostAccurate) {
  auto m = clamped_beam1(1e6);
  SolverSettings base;
  base.method = Method::Auto;
  const MethodChoice c = choose_method(*m, base, 5.0);
  ASSERT_EQ(c.trials.size(), 3u);
  EXPECT_EQ(c.trials[0].settings.method, Method::Newton);
  EXPECT_EQ(c.trials[1].settings.method, Method::Vbd);
  EXPECT_EQ(c.trials[2].settings.method, Method::Xpbd);
  EXPECT_EQ(c.trials[2].settings.substeps, base.substeps);
  // The winner is the trial of least error, and it runs with the budget it was measured at.
  double best = INFINITY;
  for (const MethodTrial& t : c.trials)
    if (t.failure.empty()) best = std::min(best, t.error);
  bool found = false;
  for (const MethodTrial& t : c.trials)
    if (t.failure.empty() && t.error == best) found |= t.settings.method == c.settings.method;
  EXPECT_TRUE(found) << c.summary;
  EXPECT_EQ(c.settings.time_budget_ms, 5.0);
  EXPECT_NE(c.settings.method, Method::Auto);
  EXPECT_TRUE(validate(c.settings).empty()) << validate(c.settings);
  // On a stiff beam one tick of the projection family is far from the converged step.
  EXPECT_GT(c.trials[2].error, 0.1);
  EXPECT_NE(c.summary.find(std::string(to_string(c.settings.method))), std::string::npos);
  // Without a budget, half the tick.
  EXPECT_NEAR(choose_method(*m, base, 0).settings.time_budget_ms, 0.5 * base.dt * 1e3, 1e-12);
}
