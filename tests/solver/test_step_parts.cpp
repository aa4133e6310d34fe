// SPDX-License-Identifier: Apache-2.0
// A tet body's step in parts (Stepper::step_in_parts): what a scene uses to step its particle
// bodies beside the tet body and resolve their contacts within the tick.
#include "beam1_fixtures.hpp"
#include "pliant/stepper.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>

using namespace pliant;

namespace {

bool same_bits(const std::vector<Vec3>& a, const std::vector<Vec3>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(Vec3)) == 0;
}

double max_distance(const std::vector<Vec3>& a, const std::vector<Vec3>& b) {
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d = std::max(d, (a[i] - b[i]).norm());
  return d;
}

// beam1 clamped, sagging onto a sphere under it, its tip's top held by a grab, over a floor plane.
StepInputs pushed_beam(const BodyModel& m, bool moving_tool) {
  StepInputs in;
  in.colliders.push_back(Collider::plane(Vec3(0, -0.004, 0), Vec3(0, 1, 0)));  // under the tip once it bends
  const int32_t tip = test::nearest_vertex(m, Vec3(0.115, 0.01, 0.005));
  in.attachments.push_back(Attachment::vertex(tip, m.rest_positions[size_t(tip)] + Vec3(0, -0.001, 0), 1e-6));
  RigidTool tool = RigidTool::sphere(Vec3(0.08, -0.0035, 0.005), 0.004);
  if (moving_tool) tool.velocity = Vec3(0, 0.05, 0);
  in.tools.push_back(tool);
  return in;
}

}  // namespace

TEST(StepParts, AStepInPartsIsTheStepInOnePiece) {
  // Each family with substeps, a grab, a static tool and a floor: three steps in 2 and 4 parts
  // (of whole substeps) end where three steps in one piece do, to the last bit, with the same
  // multipliers, time and counts, and the same grab and tool forces and contacts.
  auto model = test::clamped_beam(1e7);
  struct Case {
    Method method;
    int substeps, iterations;
  };
  for (const Case& c : {Case{Method::Xpbd, 16, 2}, Case{Method::AndersonSor, 8, 4}, Case{Method::Vbd, 8, 2},
                        Case{Method::Newton, 4, 2}}) {
    SolverSettings s;
    s.method = c.method;
    s.substeps = c.substeps;
    s.iterations = c.iterations;
    if (c.method == Method::AndersonSor) s.omega = 1.5;
    const StepInputs in = pushed_beam(*model, false);
    BodyState whole = rest_state(*model);
    Stepper one;
    StepReport rw;
    for (int k = 0; k < 3; ++k) rw = one.step(*model, whole, s, in);
    for (int parts : {2, 4}) {
      SCOPED_TRACE(std::string(to_string(c.method)) + " in " + std::to_string(parts) + " parts");
      BodyState cut = rest_state(*model);
      Stepper stepper;
      StepReport rp;
      int calls = 0;
      for (int k = 0; k < 3; ++k)
        rp = stepper.step_in_parts(*model, cut, s, in, parts, [&](int part, const StepReport& r, StepInputs&) {
          EXPECT_EQ(part, calls % parts);
          EXPECT_EQ(r.substeps, c.substeps / parts);
          ++calls;
        });
      EXPECT_EQ(calls, 3 * parts);
      EXPECT_TRUE(same_bits(cut.x, whole.x)) << max_distance(cut.x, whole.x);
      EXPECT_TRUE(same_bits(cut.v, whole.v)) << max_distance(cut.v, whole.v);
      ASSERT_EQ(cut.lambda.size(), whole.lambda.size());
      EXPECT_EQ(std::memcmp(cut.lambda.data(), whole.lambda.data(), cut.lambda.size() * sizeof(Vec6)), 0);
      EXPECT_EQ(cut.time, whole.time);
      EXPECT_EQ(cut.steps, whole.steps);
      EXPECT_EQ(rp.substeps, rw.substeps);
      EXPECT_EQ(rp.iterations, rw.iterations);
      EXPECT_EQ(rp.residual_final, rw.residual_final);
      ASSERT_EQ(rp.attachment_forces.size(), 1u);
      EXPECT_NEAR((rp.attachment_forces[0] - rw.attachment_forces[0]).norm(), 0.0,
                  1e-12 * rw.attachment_forces[0].norm());
      ASSERT_EQ(rp.tools.size(), 1u);
      EXPECT_GT(rw.tools[0].force.norm(), 0.0);
      EXPECT_NEAR((rp.tools[0].force - rw.tools[0].force).norm(), 0.0, 1e-12 * rw.tools[0].force.norm());
      EXPECT_EQ(rp.tools[0].contacts.size(), rw.tools[0].contacts.size());
      double contact_force = 0;
      for (const ToolContact& tc : rw.tools[0].contacts) contact_force += tc.force.norm();
      for (const ToolContact& tc : rp.tools[0].contacts) contact_force -= tc.force.norm();
      EXPECT_NEAR(contact_force, 0.0, 1e-9 * rw.tools[0].force.norm());
    }
  }
}

TEST(StepParts, AMovingToolAndRigidDampingGoAsInOnePieceToRounding) {
  // The tool is posed at each part's end (its velocity over the part), and a damping given per
  // step is shared out per part: 3 parts (not a power of two: the substep's length rounds
  // differently too). With the tool at the step's end in every part the positions differ by
  // 0.3 mm (checked).
  auto model = test::clamped_beam(1e7);
  SolverSettings s;
  s.substeps = 12;
  s.iterations = 2;
  s.damping = Damping::RigidPreserving;
  s.damping_coefficient = 0.2;
  const StepInputs in = pushed_beam(*model, true);
  BodyState whole = rest_state(*model), cut = rest_state(*model);
  Stepper one, stepper;
  StepReport rw, rp;
  for (int k = 0; k < 5; ++k) {
    rw = one.step(*model, whole, s, in);
    rp = stepper.step_in_parts(*model, cut, s, in, 3, nullptr);
  }
  EXPECT_GT(rw.tools[0].force.norm(), 0.0);
  EXPECT_LT(max_distance(cut.x, whole.x), 1e-12);
  EXPECT_LT(max_distance(cut.v, whole.v), 1e-9);
  EXPECT_NEAR((rp.tools[0].force - rw.tools[0].force).norm(), 0.0, 1e-6 * rw.tools[0].force.norm());
  EXPECT_EQ(cut.steps, whole.steps);
}

TEST(StepParts, RefusesPartsThatDoNotDivideTheSubsteps) {
  auto model = test::clamped_beam(1e7);
  SolverSettings s;
  s.substeps = 6;
  BodyState state = rest_state(*model);
  Stepper stepper;
  try {
    stepper.step_in_parts(*model, state, s, {}, 4, nullptr);
    FAIL() << "4 parts of 6 substeps accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("parts 4, substeps 6"), std::string::npos) << e.what();
  }
  EXPECT_EQ(state.steps, 0u);
}
