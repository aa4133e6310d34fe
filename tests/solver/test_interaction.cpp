// SPDX-License-Identifier: Apache-2.0
// beam1 spans [0, 0.115] x [0, 0.01] x [0, 0.01] m, clamped at x = 0.
// Interaction in the solver: grabs pull points to their targets, a rigid tool pressed into a
// clamped beam feels a force that grows with depth and stiffness and equals, at rest, the
// external load that holds the beam in the same shape; the tool's force is exactly the
// momentum the body receives (Newton's third law). The contact geometry and a single
// projection pass: test_tool_contact.cpp.
#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/interaction.hpp"
#include "pliant/stepper.hpp"
#include "pliant/strain_constraint.hpp"

#include "beam1_fixtures.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>

using namespace pliant;
using namespace pliant::test;

namespace {

// Small substeps, one iteration each: XPBD's rest state is close to the elastic equilibrium
// only when the substeps are small (with 32 x 2 the beam feels several times too soft and
// barely stiffer for a higher E; docs/haptics.md has the figures).
SolverSettings quiet_settings(bool gravity) {
  SolverSettings s;
  s.substeps = 256;
  s.iterations = 1;
  s.damping_coefficient = 50;
  s.record_residuals = false;
  if (!gravity) s.gravity.setZero();
  return s;
}

struct Settled {
  BodyState state;
  StepReport report;
  bool at_rest = false;
};

// Steps with fixed inputs until the body stops (every vertex slower than 1e-5 m/s).
Settled settle(const BodyModel& m, const SolverSettings& s, const StepInputs& in, int max_steps = 300) {
  Settled out;
  out.state = rest_state(m);
  Stepper stepper;
  int calm = 0;
  for (int i = 0; i < max_steps; ++i) {
    out.report = stepper.step(m, out.state, s, in);
    calm = max_speed(out.state) < 1e-5 ? calm + 1 : 0;
    if (calm >= 5) {
      out.at_rest = true;
      break;
    }
  }
  return out;
}

// A sphere of radius 1 cm over the beam's top face near the tip, pushed `depth` below it.
RigidTool sphere_over_tip(double depth) {
  return RigidTool::sphere(Vec3(0.1, 0.01 + 0.01 - depth, 0.005), 0.01);
}

}  // namespace

TEST(ToolContact, ASmallToolCannotSinkBetweenTheVerticesOfACoarseFace) {
  // The stepper projects the triangle contacts: a sphere of radius 1 mm, 1 mm below the middle
  // of a 5 mm face (no vertex inside it), held there until the beam is at rest, is pushed
  // back by the body and dents the face. Vertex-only contact feels nothing here.
  auto m = clamped_beam(1e6);
  Vec3 g;
  const Triangle tri = top_triangle_near(*m, Vec3(0.06, 0.01, 0.004), &g);
  StepInputs in;
  in.tools.push_back(RigidTool::sphere(g + Vec3(0, 0.001 - 0.001, 0), 0.001));
  in.tools[0].static_friction = in.tools[0].dynamic_friction = 0;
  const Settled r = settle(*m, quiet_settings(false), in);
  EXPECT_TRUE(r.at_rest);
  const ToolReaction& t = r.report.tools[0];
  ASSERT_FALSE(t.contacts.empty());
  EXPECT_GT(t.force.y(), 0);
  EXPECT_LT(std::abs(t.force.x()), 0.2 * t.force.y());
  double corner_y = 0;
  for (int32_t k : tri) corner_y += r.state.x[k].y() / 3;
  EXPECT_LT(corner_y, 0.01 - 0.0002);  // the face is dented
  Vec3 sum = Vec3::Zero();
  for (const ToolContact& c : t.contacts) sum += c.force;
  EXPECT_NEAR((sum - t.force).norm(), 0, 1e-9 * t.force.norm());
}

TEST(Grab, MovesAVertexToItsTargetAndSeveralGrabsHoldAtOnce) {
  auto m = clamped_beam(1e6);
  const int32_t tip = nearest_vertex(*m, Vec3(0.115, 0.01, 0.01));
  const int32_t mid = nearest_vertex(*m, Vec3(0.06, 0.0, 0.0));
  StepInputs in;
  const Vec3 tip_target = m->rest_positions[tip] + Vec3(0, 0.01, 0);
  const Vec3 mid_target = m->rest_positions[mid] + Vec3(0, -0.002, 0.001);
  in.attachments.push_back(Attachment::vertex(tip, tip_target));
  in.attachments.push_back(Attachment::vertex(mid, mid_target));
  ASSERT_EQ(validate_interaction(in.attachments, in.tools, *m), "");
  const Settled r = settle(*m, quiet_settings(false), in);
  ASSERT_TRUE(r.at_rest);
  EXPECT_LT((r.state.x[tip] - tip_target).norm(), 1e-5);
  EXPECT_LT((r.state.x[mid] - mid_target).norm(), 1e-5);
  ASSERT_EQ(r.report.attachment_forces.size(), 2u);
  // Lifting the tip: the grab pulls the body up. Gravity is off and the beam is at rest, so
  // the grab forces and the clamp are the only loads: the clamp takes minus their sum, and the
  // tip grab carries a force of the order of the beam's bending stiffness times the lift.
  EXPECT_GT(r.report.attachment_forces[0].y(), 0);
  EXPECT_TRUE(r.report.attachment_forces[0].allFinite());
}

TEST(Grab, APointInsideATetFollowsAMovingTarget) {
  auto m = clamped_beam(1e6);
  // The last tet (at the free end), grabbed at its centroid.
  const Tet tet = m->tets.back().v;
  Vec3 centroid = Vec3::Zero();
  for (int k = 0; k < 4; ++k) centroid += 0.25 * m->rest_positions[tet[k]];
  StepInputs in;
  in.attachments.push_back(Attachment::in_tet(tet, {0.25, 0.25, 0.25, 0.25}, centroid, 1e-6));
  SolverSettings s = quiet_settings(false);
  BodyState st = rest_state(*m);
  Stepper stepper;
  // Drag the target down 1 cm over 30 steps, then hold it there.
  for (int i = 0; i < 200; ++i) {
    in.attachments[0].target = centroid + Vec3(0, -0.01 * std::min(1.0, i / 30.0), 0);
    stepper.step(*m, st, s, in);
  }
  const Vec3 p = in.attachments[0].point(st.x);
  // Compliant: the point lags its target by compliance * force, a few micrometres here.
  const StepReport rep = stepper.step(*m, st, s, in);
  const double lag = (in.attachments[0].point(st.x) - in.attachments[0].target).norm();
  EXPECT_LT(lag, 2e-4);
  EXPECT_NEAR(lag, 1e-6 * rep.attachment_forces[0].norm(), 1e-5);
  EXPECT_LT(p.y(), centroid.y() - 0.009);
}

TEST(ToolContact, ForceGrowsWithDepthAndWithStiffness) {
  SolverSettings s = quiet_settings(false);
  auto force = [&](double young, double depth) {
    auto m = clamped_beam(young);
    StepInputs in;
    in.tools.push_back(sphere_over_tip(depth));
    in.tools[0].static_friction = in.tools[0].dynamic_friction = 0;  // the normal force only
    const Settled r = settle(*m, s, in);
    EXPECT_TRUE(r.at_rest) << young << " " << depth;
    EXPECT_FALSE(r.report.tools[0].contacts.empty());
    return r.report.tools[0].force;
  };
  const Vec3 soft_shallow = force(1e6, 0.001), soft_deep = force(1e6, 0.002), stiff_deep = force(2e6, 0.002);
  // The beam pushes the tool up, out of the body.
  EXPECT_GT(soft_shallow.y(), 0);
  EXPECT_GT(soft_deep.y(), 1.5 * soft_shallow.y());  // about linear in depth for small depths
  EXPECT_GT(stiff_deep.y(), 1.5 * soft_deep.y());    // about linear in E
  EXPECT_LT(std::abs(soft_deep.x()), 0.2 * soft_deep.y());
}

TEST(ToolContact, AtRestTheToolForceIsTheExternalLoadThatHoldsTheSameShape) {
  // A sphere under the tip holds the beam up against gravity. Let it settle; then replace the
  // tool by the contact forces it reported, applied as constant external point forces on the
  // same vertices: the beam must settle into the same shape (tip within a few percent), and
  // the tool must carry part of the weight (less than all of it: the clamp takes the rest).
  auto m = clamped_beam(1e7);
  SolverSettings s = quiet_settings(true);
  StepInputs held;
  held.tools.push_back(RigidTool::sphere(Vec3(0.1, -0.01 + 0.001, 0.005), 0.01));
  const Settled a = settle(*m, s, held);
  ASSERT_TRUE(a.at_rest);
  const ToolReaction& tool = a.report.tools[0];
  ASSERT_GE(tool.contacts.size(), 1u);
  EXPECT_LT(tool.force.y(), 0);  // the beam presses the tool down
  const double weight = m->total_mass() * 9.81;
  EXPECT_LT(-tool.force.y(), weight);
  StepInputs loaded;
  loaded.external_forces.assign(m->vertex_count(), Vec3::Zero());
  Vec3 sum = Vec3::Zero();
  for (const ToolContact& c : tool.contacts) {
    loaded.external_forces[c.vertex] = -c.force;  // the force on the body
    sum += c.force;
  }
  EXPECT_NEAR((sum - tool.force).norm(), 0, 1e-9 * tool.force.norm());
  const Settled b = settle(*m, s, loaded);
  ASSERT_TRUE(b.at_rest);
  const Vec3 tip_held = tip_displacement(*m, a.state.x), tip_loaded = tip_displacement(*m, b.state.x);
  const Vec3 tip_free = tip_displacement(*m, settle(*m, s, StepInputs{}).state.x);
  // Global balance from independent multipliers: the strain multipliers give the force the
  // body puts on its clamped vertices (f_c = sum of grad C^T lambda / h^2 there); at rest
  // contact + gravity on the free part + clamp reaction (-f_c) = 0, so the force on the tool
  // (minus the contact force on the body) is M_free g - f_c.
  Vec3 f_clamp = Vec3::Zero(), weight_free = Vec3::Zero();
  const double h2 = a.state.lambda_h * a.state.lambda_h;
  const std::vector<Vec6> lambda = multipliers_per_tet(*m, a.state.lambda);
  for (size_t t = 0; t < m->tet_count(); ++t) {
    const TetRest& tet = m->tets[t];
    const Vec12 g = strain_jacobian(tet, gather(a.state.x, tet.v)).transpose() * lambda[t];
    for (int k = 0; k < 4; ++k)
      if (m->fixed[tet.v[k]]) f_clamp += g.segment<3>(3 * k) / h2;
  }
  for (size_t i = 0; i < m->vertex_count(); ++i)
    if (!m->fixed[i]) weight_free += m->mass[i] * s.gravity;
  const Vec3 expected = weight_free - f_clamp;
  EXPECT_NEAR((tool.force - expected).norm(), 0, 0.03 * tool.force.norm())
      << "tool " << tool.force.transpose() << " balance " << expected.transpose();
  // The tool lifts the tip visibly above its sag under gravity alone.
  EXPECT_GT(tip_held.y(), tip_free.y() + 0.0005);
  EXPECT_NEAR(tip_loaded.y(), tip_held.y(), 0.03 * std::abs(tip_held.y() - tip_free.y()));
}

TEST(ToolContact, NewtonsThirdLawTheBodyGainsMinusTheToolImpulse) {
  // A free body (no clamp, no gravity, no damping) hit by a tool: over one step its momentum
  // changes by exactly -F_tool * dt (strain constraints are internal and conserve momentum).
  // Momentum is that of the inertias the solver moves (the free beam's four one-tet corners
  // are raised by the inertia floor).
  TetMesh mesh = *builtin_mesh("beam1");
  auto m = build_model(mesh, Material{1e6, 0.4, 1000});
  SolverSettings s = quiet_settings(false);
  s.damping = Damping::None;
  StepInputs in;
  in.tools.push_back(sphere_over_tip(0.002));
  BodyState st = rest_state(*m);
  Stepper stepper;
  for (int i = 0; i < 3; ++i) {
    Vec3 p0 = Vec3::Zero();
    for (size_t v = 0; v < m->vertex_count(); ++v) p0 += m->inertia[v] * st.v[v];
    const StepReport r = stepper.step(*m, st, s, in);
    Vec3 p1 = Vec3::Zero();
    for (size_t v = 0; v < m->vertex_count(); ++v) p1 += m->inertia[v] * st.v[v];
    const Vec3 tool_impulse = r.tools[0].force * s.dt;
    if (i > 0 && r.tools[0].contacts.empty()) break;  // knocked away: nothing more to check
    ASSERT_GT(tool_impulse.norm(), 0) << "step " << i;
    EXPECT_NEAR((p1 - p0 + tool_impulse).norm(), 0, 1e-6 * tool_impulse.norm()) << "step " << i;
    EXPECT_GT(r.tools[0].force.y(), 0);  // the tool is pushed up, the body down
  }
}

TEST(ToolContact, FrictionDragsTheSurfaceWithASlidingTool) {
  // A sphere pressed 1 mm into the top face slides along +x at 2 cm/s (its velocity given, so
  // friction sees the motion relative to the tool). With friction the body pulls the tool
  // back (F_x < 0) and the touched vertices are dragged along +x; without, neither.
  auto m = clamped_beam(1e6);
  SolverSettings s = quiet_settings(false);
  auto slide = [&](double mu, double* dragged) {
    BodyState st = rest_state(*m);
    Stepper stepper;
    StepInputs in;
    in.tools.push_back(RigidTool::sphere(Vec3(0.04, 0.02 - 0.001, 0.005), 0.01));
    in.tools[0].static_friction = in.tools[0].dynamic_friction = mu;
    in.tools[0].velocity = Vec3(0.02, 0, 0);
    double fx = 0;
    *dragged = 0;
    for (int i = 0; i < 60; ++i) {
      in.tools[0].position.x() = 0.04 + 0.02 * s.dt * (i + 1);
      const StepReport r = stepper.step(*m, st, s, in);
      if (i >= 30) {
        fx += r.tools[0].force.x() / 30;
        for (const ToolContact& c : r.tools[0].contacts)
          *dragged += (st.x[c.vertex].x() - m->rest_positions[c.vertex].x()) / (30.0 * r.tools[0].contacts.size());
      }
    }
    return fx;
  };
  double drag_friction = 0, drag_free = 0;
  const double fx_friction = slide(1.0, &drag_friction), fx_free = slide(0.0, &drag_free);
  EXPECT_LT(fx_friction, 0);
  EXPECT_LT(fx_friction, fx_free - 0.2 * std::abs(fx_friction));
  EXPECT_GT(drag_friction, drag_free);
  EXPECT_GT(drag_friction, 0);
}

TEST(ToolContact, TorqueIsLeverArmCrossForce) {
  // A capsule lying across the beam, touching it off its centre: torque = r x F about the pose.
  auto m = clamped_beam(1e6);
  StepInputs in;
  const Vec3 centre(0.09, 0.01 + 0.004 - 0.001, 0.005);
  in.tools.push_back(RigidTool::capsule(centre, Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX()),
                                        0.004, 0.03));
  const Settled r = settle(*m, quiet_settings(false), in);
  const ToolReaction& t = r.report.tools[0];
  ASSERT_FALSE(t.contacts.empty());
  Vec3 expected = Vec3::Zero();
  for (const ToolContact& c : t.contacts) expected += (c.point - centre).cross(c.force);
  EXPECT_NEAR((t.torque - expected).norm(), 0, 0.02 * expected.norm() + 1e-12);
  EXPECT_GT(t.force.y(), 0);
}

// A capsule of 4 mm radius lying across the beam's top face near the tip, 1 mm into it, with
// friction 1, turning about its own axis (z) in place at `rate` rad/s for 1 s; the second half's
// means of the tool's reaction and of the touched vertices' displacement along x.
struct Turned {
  double torque = 0, force = 0, dragged = 0, pressing = 0;  // about z, along x, along x, along y
};
constexpr double kCapsuleRadius = 0.004;
Turned turn_capsule(const BodyModel& m, const SolverSettings& s, double rate) {
  const double r = kCapsuleRadius;
  BodyState st = rest_state(m);
  Stepper stepper;
  StepInputs in;
  in.tools.push_back(RigidTool::capsule(Vec3(0.09, 0.01 + r - 0.001, 0.005), Eigen::Quaterniond::Identity(), r, 0.03));
  in.tools[0].static_friction = in.tools[0].dynamic_friction = 1.0;
  in.tools[0].angular_velocity = Vec3(0, 0, rate);
  Turned f;
  const int steps = int(std::lround(1.0 / s.dt)), half = steps / 2;
  for (int i = 0; i < steps; ++i) {
    in.tools[0].orientation = Eigen::Quaterniond(Eigen::AngleAxisd(rate * s.dt * (i + 1), Vec3::UnitZ()));
    const StepReport rep = stepper.step(m, st, s, in);
    if (i < half) continue;
    f.torque += rep.tools[0].torque.z() / half;
    f.force += rep.tools[0].force.x() / half;
    f.pressing += rep.tools[0].force.y() / half;
    for (const ToolContact& c : rep.tools[0].contacts)
      f.dragged += (st.x[c.vertex].x() - m.rest_positions[c.vertex].x()) / (double(half) * rep.tools[0].contacts.size());
  }
  return f;
}

void print_turned(const std::string& what, const Turned& spinning, const Turned& held) {
  std::cout << "[ spin ] " << what << ": about the axis " << spinning.torque << " N m (held " << held.torque
            << "), along x " << spinning.force << " N (held " << held.force << "), touched vertices along x "
            << spinning.dragged << " m (held " << held.dragged << "), pressing " << spinning.pressing << " N (held "
            << held.pressing << ")\n";
}

TEST(ToolContact, ASpinningCapsuleDragsTheSurfaceAndFeelsATorqueAgainstItsSpin) {
  // The capsule turning at 5 rad/s: its bottom, where it touches, moves along +x at 2 cm/s. With
  // friction the body is dragged along +x under it and holds the tool back: a force along -x and
  // a torque about its axis against the spin. Held still, neither (the beam's bending alone
  // moves the touched vertices). Without its angular velocity the step would see a tool that
  // does not move. In every solver family (vertex block descent's and the Newton step's smoothed
  // friction give a small part of sliding friction here: docs/haptics.md).
  auto m = clamped_beam(1e6);
  SolverSettings s = quiet_settings(false);
  for (Method method : {Method::Xpbd, Method::Vbd, Method::Newton}) {
    SCOPED_TRACE(std::string(to_string(method)));
    s.method = method;
    if (method == Method::Newton) {  // converged per substep: fewer do; friction from the second iteration
      s.substeps = 32;
      s.iterations = 3;
    }
    const Turned spinning = turn_capsule(*m, s, 5.0), held = turn_capsule(*m, s, 0.0);
    print_turned(std::string(to_string(method)), spinning, held);
    // The pushes have no moment about the axis (their normals meet it): the torque is friction's.
    EXPECT_LT(spinning.torque, 0.0) << "the body should hold the spin back";
    EXPECT_LT(spinning.torque, held.torque - 0.5 * std::abs(spinning.torque));
    EXPECT_GT(spinning.dragged, held.dragged);
    if (method == Method::Xpbd) {
      // Hard contact with Coulomb friction: sliding, mu x the normal force at the radius, and
      // the force that holds the tool back along -x.
      const double r = kCapsuleRadius;
      EXPECT_NEAR(spinning.torque, -1.0 * spinning.pressing * r, 0.1 * spinning.pressing * r);
      EXPECT_LT(spinning.force, held.force - 0.5 * std::abs(spinning.force));
    }
  }
}

TEST(ToolContact, TheHapticBridgesNewtonStepFeelsTheFrictionOfATurningTool) {
  // The same capsule on beam1 at 100 kPa with the haptic bridge's budget: one Newton iteration a
  // 1 ms tick, residuals recorded (as the server does). The torque about the axis is about sliding
  // friction's, mu x the normal force at the radius; held, about nil.
  auto m = clamped_beam(1e5);
  SolverSettings s = quiet_settings(false);
  s.method = Method::Newton;
  s.dt = 1e-3;
  s.substeps = 1;
  s.iterations = 1;
  s.record_residuals = true;
  const Turned spinning = turn_capsule(*m, s, 5.0), held = turn_capsule(*m, s, 0.0);
  print_turned("newton 1 x 1 at 1 kHz, 100 kPa", spinning, held);
  const double sliding = spinning.pressing * kCapsuleRadius;
  ASSERT_GT(sliding, 0.0);
  EXPECT_NEAR(spinning.torque, -sliding, 0.5 * sliding);
  EXPECT_LT(std::abs(held.torque), 0.01 * sliding);
}
