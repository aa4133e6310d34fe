// SPDX-License-Identifier: Apache-2.0
// The scene's tools inside a particle body's substeps (ToolBoundary): a fast tool catches what it
// sweeps through, the tool takes minus the momentum the particles gained from it, friction carries
// a resting cloth along with a moving or a spinning tool, a turning tool sweeps what its turn
// crosses, and bad tools are refused.
#include "pliant/cloth.hpp"
#include "pliant/coupling.hpp"
#include "pliant/fluid.hpp"
#include "pliant/interaction.hpp"
#include "pliant/particle_body.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>
#include <memory>
#include <vector>

using namespace pliant;

namespace {

constexpr double kTick = 1.0 / 60;

// A 20 cm rope of 20 links hanging straight down from a pin at the origin, 2 mm thick.
std::unique_ptr<ConstraintBody> hanging_rope(const Vec3& gravity = Vec3(0, -9.81, 0), bool pinned = true) {
  ConstraintBodySettings s;
  s.thickness = 0.002;
  s.gravity = gravity;
  auto rope = ConstraintBody::rope({Vec3(0, 0, 0), Vec3(0, -0.2, 0)}, 20, 0.01, s);
  if (pinned) rope->pin(0);
  return rope;
}

// A 1 cm sphere crossing the rope at half its length along x at 3 m/s: over one tick it goes from
// 2.5 cm on one side of the rope to 2.5 cm on the other, so that where the tick ends it is clear
// of the rope.
RigidTool crossing_tool() {
  RigidTool t = RigidTool::sphere(Vec3(0.025, -0.1, 0), 0.01);
  t.velocity = Vec3(3.0, 0, 0);
  return t;
}

// One tick of `body` (its own substeps) meeting `tool` inside them: its report and the tool's
// boundary after the call (the impulse, the particles it pushed).
struct Met {
  ParticleStepReport report;
  ToolBoundary boundary;
};
Met tick_with(ParticleBody& body, const RigidTool& tool) {
  Met m;
  const RigidTool tools[] = {tool};
  m.boundary.tools = tools;
  m.report = body.advance(kTick, body.substeps(), {}, true, nullptr, &m.boundary);
  m.boundary.tools = {};
  return m;
}

// `ticks` ticks of `body`, the tool moved by its velocity before each: the body's state after them
// and the tool's impulse in each.
std::pair<ParticleState, std::vector<Vec3>> moving_ticks(ParticleBody& body, RigidTool tool, int ticks) {
  std::vector<Vec3> impulses;
  for (int k = 0; k < ticks; ++k) {
    tool.position += tool.velocity * kTick;
    impulses.push_back(tick_with(body, tool).boundary.impulse[0]);
  }
  return {body.state(), impulses};
}

// A square cloth of n x n particles, `size` a side, lying in the plane y = origin.y.
std::unique_ptr<ConstraintBody> square_cloth(int n, double size, const Vec3& origin, const ConstraintBodySettings& s) {
  ClothGridSpec g;
  g.nx = g.ny = n;
  g.size_x = g.size_y = size;
  g.origin = origin;
  return ConstraintBody::cloth_grid(g, s);
}

Vec3 momentum(const ParticleState& s, std::span<const double> w) {
  Vec3 p = Vec3::Zero();
  for (size_t i = 0; i < s.v.size(); ++i)
    if (w[i] > 0) p += s.v[i] / w[i];
  return p;
}

}  // namespace

TEST(ToolInSubsteps, AFastToolCatchesTheRopeItSweepsThrough) {
  const RigidTool tool = crossing_tool();
  // Inside the substeps: the tool meets the rope on its way and carries its middle along.
  auto rope = hanging_rope();
  const auto [r, tb] = tick_with(*rope, tool);
  double ahead = -1.0;
  for (const Vec3& p : rope->state().x) ahead = std::max(ahead, p.x());
  const double reach = tool.radius + rope->contact_radius();
  EXPECT_GT(ahead, tool.position.x() + 0.5 * reach) << "the rope's middle stayed behind the tool";
  EXPECT_GT(r.tool_contacts, 0u);
  ASSERT_EQ(tb.impulse.size(), 1u);
  EXPECT_GT(tb.impulse[0].x(), 0.0) << "the rope gained momentum along the tool's motion";
  for (const Vec3& p : rope->state().x)
    EXPECT_GE((p - tool.position).norm(), reach - 1e-9) << "a particle ended inside the tool";
  // The contact after the step alone sees the tool only where the tick ends, past the rope.
  auto after = hanging_rope();
  const std::vector<Vec3> start = after->state().x;
  after->step(kTick, {});
  ParticleState ps = after->state();
  ToolReaction reaction;
  EXPECT_EQ(couple_particles_to_tool(ps, after->inverse_masses(), tool, after->contact_radius(), kTick, start, reaction),
            0u);
  for (const Vec3& p : ps.x) EXPECT_LT(std::abs(p.x()), 1e-6) << "the rope should not have moved sideways";
}

TEST(ToolInSubsteps, TheToolTakesWhatTheParticlesGainFromIt) {
  // No gravity, no pin, no damping, nothing else touching: every change of the particles' total
  // momentum over the call is the tool's push, and the boundary says so.
  {
    auto rope = hanging_rope(Vec3::Zero(), false);
    rope->set_state([&] {
      ParticleState s = rope->state();
      for (Vec3& v : s.v) v = Vec3(0.2, 0.1, -0.05);
      return s;
    }());
    const Vec3 before = momentum(rope->state(), rope->inverse_masses());
    const ToolBoundary tb = tick_with(*rope, crossing_tool()).boundary;
    const Vec3 gained = momentum(rope->state(), rope->inverse_masses()) - before;
    ASSERT_GT(gained.norm(), 1e-5) << "the tool did not push the rope";
    EXPECT_NEAR((gained - tb.impulse[0]).norm(), 0.0, 1e-12 * gained.norm());
  }
  {
    FluidSettings fs;
    fs.spacing = 0.01;
    fs.gravity = Vec3::Zero();
    fs.substeps = 4;
    FluidBody water(fs, {FluidBlock{Vec3(-0.03, -0.13, -0.03), Vec3(0.03, -0.07, 0.03)}});
    const std::vector<double> w(water.inverse_masses().begin(), water.inverse_masses().end());
    const Vec3 before = momentum(water.state(), w);
    RigidTool t = crossing_tool();
    t.position = Vec3(0.0, -0.1, 0.0);  // ends in the middle of the block
    const auto [r, tb] = tick_with(water, t);
    const Vec3 gained = momentum(water.state(), w) - before;
    ASSERT_GT(r.tool_contacts, 0u);
    EXPECT_EQ(r.contacts, 0u) << "no collider: the tool's pushes are counted apart";
    ASSERT_GT(gained.norm(), 1e-4) << "the tool did not push the water";
    // The fluid's pair terms are single precision but each pair's two entries exactly opposite.
    EXPECT_NEAR((gained - tb.impulse[0]).norm(), 0.0, 1e-9 * gained.norm());
    EXPECT_GT(tb.impulse[0].x(), 0.9 * gained.norm());
    for (const Vec3& p : water.state().x)
      EXPECT_GE((p - t.position).norm(), t.radius + water.contact_radius() - 1e-9);
  }
}

TEST(ToolInSubsteps, FrictionCarriesAClothAlongWithItsTool) {
  // A 12 cm cloth dropped across the middle of a 60 cm capsule lying along x, which then moves
  // along its own axis at 10 cm/s for 1.5 s: only friction can carry the cloth along (the
  // capsule's normals there have no x part). With the tool's friction it rides on it; without,
  // the capsule slides along under it.
  auto ride = [](double mu) {
    ConstraintBodySettings s;
    s.self_collision = false;
    auto cloth = square_cloth(8, 0.12, Vec3(-0.06, 0.035, -0.06), s);
    RigidTool tool = RigidTool::capsule(Vec3(0, 0, 0), Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitY())),
                                        0.03, 0.3);
    tool.static_friction = tool.dynamic_friction = mu;
    for (int k = 0; k < 120; ++k) {
      if (k >= 30) {
        tool.velocity = Vec3(0.1, 0, 0);
        tool.position += tool.velocity * kTick;
      }
      tick_with(*cloth, tool);
    }
    Vec3 c = Vec3::Zero();
    for (const Vec3& p : cloth->state().x) c += p;
    return std::pair(c.x() / double(cloth->size()), tool.position.x());
  };
  const auto [with, tool_x] = ride(0.8);
  const auto [without, tool_x0] = ride(0.0);
  ASSERT_NEAR(tool_x, 0.15, 1e-9);
  EXPECT_NEAR(with, tool_x, 0.01) << "the cloth did not ride on the tool";
  EXPECT_NEAR(without, 0.0, 0.01) << "without friction the tool should slide along under the cloth";
}

TEST(ToolInSubsteps, ASpinningCapsuleCarriesTheClothLyingOnIt) {
  // A 12 cm cloth dropped across a 6 cm capsule lying along z, which then turns about its own
  // axis in place at 2 rad/s for 0.5 s: its top moves along -x at 3 cm/s, and only friction with
  // that motion can move the cloth along x. Spinning, the cloth goes along with it and gains
  // momentum along -x; held still, it stays. The tool's pushes have no moment about its axis
  // (their normals meet it), so the angular impulse about the axis the cloth takes from the tool
  // is friction's: with the moment of its weight it makes the change of its angular momentum.
  struct Ride {
    double x = 0, angular = 0, weight_moment = 0, gained = 0;
    Vec3 impulse = Vec3::Zero();
  };
  auto angular_z = [](const ConstraintBody& c) {
    double l = 0;
    const auto w = c.inverse_masses();
    for (size_t i = 0; i < c.size(); ++i) l += c.state().x[i].cross(c.state().v[i]).z() / w[i];
    return l;
  };
  auto ride = [&](double rate) {
    ConstraintBodySettings s;
    s.self_collision = false;
    auto cloth = square_cloth(8, 0.12, Vec3(-0.06, 0.035, -0.06), s);
    RigidTool tool = RigidTool::capsule(Vec3(0, 0, 0), Eigen::Quaterniond::Identity(), 0.03, 0.3);
    tool.static_friction = tool.dynamic_friction = 0.8;
    const auto w = cloth->inverse_masses();
    auto weight_moment = [&] {  // about the axis, N m
      double m = 0;
      for (size_t i = 0; i < cloth->size(); ++i) m += cloth->state().x[i].cross(s.gravity).z() / w[i];
      return m;
    };
    Ride r;
    for (int k = 0; k < 60; ++k) {
      if (k >= 30) {
        tool.angular_velocity = Vec3(0, 0, rate);
        tool.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(rate * kTick, Vec3::UnitZ())) * tool.orientation;
      }
      if (k == 30) r.gained = -angular_z(*cloth);
      const double before = weight_moment();
      const ToolBoundary tb = tick_with(*cloth, tool).boundary;
      if (k >= 30) {
        r.impulse += tb.impulse[0];
        r.angular += tb.angular_impulse[0].z();
        r.weight_moment += 0.5 * (before + weight_moment()) * kTick;
      }
    }
    r.gained += angular_z(*cloth);
    for (const Vec3& p : cloth->state().x) r.x += p.x() / double(cloth->size());
    return r;
  };
  const Ride spinning = ride(2.0), held = ride(0.0);
  std::cout << "[ spin ] cloth x " << spinning.x << " m (held " << held.x << "); about the axis: from the tool "
            << spinning.angular << " N m s, weight " << spinning.weight_moment << ", gained " << spinning.gained
            << " (held: " << held.angular << ", " << held.weight_moment << ", " << held.gained << ")\n";
  EXPECT_LT(spinning.x, -0.005) << "the cloth did not go along with the spinning tool";
  EXPECT_NEAR(held.x, 0.0, 1e-3) << "held still, the tool should leave the cloth where it lies";
  EXPECT_LT(spinning.impulse.x(), held.impulse.x() - 0.5 * std::abs(spinning.impulse.x()));
  EXPECT_NEAR(spinning.angular + spinning.weight_moment, spinning.gained, 0.02 * std::abs(spinning.weight_moment));
  EXPECT_GT(std::abs(spinning.angular), 0.2 * std::abs(spinning.weight_moment)) << "friction's moment is not small";
  EXPECT_LT(std::abs(held.angular), 0.01 * std::abs(spinning.angular));
}

TEST(ToolInSubsteps, ATurningToolSweepsThroughTheRopeOnItsWay) {
  // A capsule 3 cm beside the rope's middle (8 cm long, 5 mm radius), its axis along z, turned
  // half a turn about the vertical in one tick: where the tick starts and ends it is clear of
  // the rope, but half-way its axis lies along x through the rope, whose middle it sweeps along
  // +z (the arm from the centre to the rope, -3 cm along x, turning about +y). A tool that only
  // jumped from pose to pose would leave the rope alone.
  auto sweep = [](double rate) {
    auto rope = hanging_rope();
    RigidTool tool = RigidTool::capsule(Vec3(0.03, -0.1, 0), Eigen::Quaterniond::Identity(), 0.005, 0.04);
    tool.angular_velocity = Vec3(0, rate, 0);
    tool.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(rate * kTick, Vec3::UnitY()));
    const Met m = tick_with(*rope, tool);
    double z = 0;
    for (const Vec3& p : rope->state().x) z = std::max(z, p.z());
    return std::pair(z, m.boundary.impulse[0]);
  };
  const auto [turned, impulse] = sweep(M_PI / kTick);
  const auto [jumped, none] = sweep(0.0);
  EXPECT_GT(turned, 0.005) << "the turning tool passed through the rope";
  EXPECT_GT(impulse.z(), 0.0);
  EXPECT_LT(std::abs(jumped), 1e-9);
  EXPECT_EQ(none.norm(), 0.0);
}

TEST(ToolInSubsteps, AToolBetweenTheParticlesMeetsTheLinkOrTheFace) {
  // A 1 cm sphere rising at 1.8 m/s onto the middle of a 10 cm link of a rope pinned at both ends
  // (no gravity): it never comes near a particle, but the link between them catches it, moves the
  // free end of the link up, and the tool feels the push, the pin's share included.
  {
    ConstraintBodySettings s;
    s.thickness = 0.002;
    s.gravity = Vec3::Zero();
    auto rope = ConstraintBody::rope({Vec3(0, 0, 0), Vec3(0.2, 0, 0)}, 2, 0.01, s);
    rope->pin(0);
    rope->pin(2);
    RigidTool t = RigidTool::sphere(Vec3(0.05, 0.0, 0), 0.01);
    t.velocity = Vec3(0, 1.8, 0);
    const ToolBoundary tb = tick_with(*rope, t).boundary;
    const auto& x = rope->state().x;
    EXPECT_GT(x[1].y(), 0.005) << "the link did not catch the tool";
    // The link keeps the tool's grown radius from its centre, within the last substep's
    // constraint moves.
    const Vec3 a = x[0], b = x[1];
    const double u = std::clamp((t.position - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
    EXPECT_GT((a + u * (b - a) - t.position).norm(), t.radius + s.thickness - 1e-3);
    EXPECT_GT(tb.impulse[0].y(), 0.0);
    // More than the free particle's momentum: the pinned end's share is felt too.
    EXPECT_GT(tb.impulse[0].y(), rope->state().v[1].y() * rope->masses()[1]);
  }
  // A 20 cm cloth of two triangles, nothing pinned, no gravity, and the sphere rising into the
  // middle of one triangle: the face catches it, and the cloth gains exactly the tool's impulse.
  {
    ConstraintBodySettings s;
    s.gravity = Vec3::Zero();
    s.self_collision = false;
    auto cloth = square_cloth(2, 0.2, Vec3(0, 0, 0), s);
    ASSERT_EQ(cloth->size(), 4u);
    RigidTool t = RigidTool::sphere(Vec3(0.07, 0.0, 0.07), 0.01);
    t.velocity = Vec3(0, 1.8, 0);
    const std::vector<double> w(cloth->inverse_masses().begin(), cloth->inverse_masses().end());
    const Vec3 before = momentum(cloth->state(), w);
    const ToolBoundary tb = tick_with(*cloth, t).boundary;
    const Vec3 gained = momentum(cloth->state(), w) - before;
    EXPECT_GT(gained.y(), 0.0) << "the face did not catch the tool";
    EXPECT_NEAR((gained - tb.impulse[0]).norm(), 0.0, 1e-12 * gained.norm());
    double lowest = 1e9;
    for (const Vec3& p : cloth->state().x) lowest = std::min(lowest, p.y());
    EXPECT_GT(lowest, 0.0) << "every corner went up with the face";
  }
}

TEST(ToolInSubsteps, ResultsDoNotDependOnTheThreadCount) {
  // A 64 x 64 cloth of 4 m (6 cm triangles) falling onto a thin capsule that sweeps under it
  // (its particles and, between them, its faces meet the tool), and a fluid block a sphere moves
  // through, each with 1 and 3 threads: the same positions, velocities and tool impulses to the
  // last bit.
  auto cloth_run = [](int threads) {
    ConstraintBodySettings s;
    s.threads = threads;
    auto cloth = square_cloth(64, 4.0, Vec3(-2.0, 0.02, -2.0), s);
    RigidTool t = RigidTool::capsule(Vec3(-0.1, 0, 0), Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Vec3::UnitY())),
                                     0.005, 0.3);
    t.velocity = Vec3(0.6, 0, 0);
    return moving_ticks(*cloth, t, 6);
  };
  // The runs with 1 and 3 threads: the tool met the body, and both end alike to the last bit.
  auto expect_alike = [](const auto& one, const auto& three, const char* body) {
    const auto& [s1, j1] = one;
    const auto& [s3, j3] = three;
    EXPECT_GT(j1.back().norm(), 0.0) << "the tool should have met the " << body;
    EXPECT_EQ(j1, j3) << body;
    EXPECT_EQ(s1.x, s3.x) << body;
    EXPECT_EQ(s1.v, s3.v) << body;
  };
  expect_alike(cloth_run(1), cloth_run(3), "cloth");

  auto fluid_run = [](int threads) {
    FluidSettings fs;
    fs.threads = threads;
    fs.spacing = 0.01;
    fs.container = Collider::box(Vec3(0, 0.05, 0), Vec3(0.06, 0.1, 0.06));
    FluidBody water(fs, {FluidBlock{Vec3(-0.05, -0.045, -0.05), Vec3(0.05, 0.04, 0.05)}});
    RigidTool t = RigidTool::sphere(Vec3(-0.05, 0.0, 0.0), 0.015);
    t.velocity = Vec3(0.5, 0, 0);
    return moving_ticks(water, t, 6);
  };
  expect_alike(fluid_run(1), fluid_run(3), "water");
}

TEST(ToolInSubsteps, RefusesToolsThatAreNotFinite) {
  auto rope = hanging_rope();
  RigidTool t = crossing_tool();
  t.velocity.x() = std::numeric_limits<double>::quiet_NaN();
  ToolBoundary tb;
  const RigidTool tools[] = {t};
  tb.tools = tools;
  const ParticleState before = rope->state();
  EXPECT_THROW(rope->advance(kTick, rope->substeps(), {}, true, nullptr, &tb), std::invalid_argument);
  EXPECT_EQ(rope->state().x, before.x) << "a refused call leaves the body as it was";
  FluidSettings fs;
  FluidBody water(fs, {FluidBlock{Vec3(0, 0, 0), Vec3(0.1, 0.1, 0.1)}});
  EXPECT_THROW(water.advance(kTick, fs.substeps, {}, true, nullptr, &tb), std::invalid_argument);
  RigidTool turning = crossing_tool();
  turning.angular_velocity.z() = std::numeric_limits<double>::infinity();
  const RigidTool turning_tools[] = {turning};
  tb.tools = turning_tools;
  EXPECT_THROW(rope->advance(kTick, rope->substeps(), {}, true, nullptr, &tb), std::invalid_argument);
}
