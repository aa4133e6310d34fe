// SPDX-License-Identifier: Apache-2.0
// Constraint bodies as physics: a rope hanging between two pins against the analytic
// catenary, a 64 x 64 cloth draped over a sphere (no particle inside, no explosion at a stiff
// stretch compliance), two falling layers kept apart by self-collision, and a grab's force
// against the weight it holds; a budget too small for the stretch compliance said in the log.
#include "pliant/cloth.hpp"
#include "pliant/coupling.hpp"
#include "pliant/fluid.hpp"
#include "pliant/interaction.hpp"

#include <gtest/gtest.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <iostream>
#include <string>
#include <utility>

using namespace pliant;

namespace {

struct CatenaryResult {
  double sag = 0, expected_sag = 0, sag_error = 0, shape_error = 0, max_stretch = 0;
};

// A rope of `segments` links and length `length` hung between pins `span` apart at equal
// height, started as a V, damped to rest over `seconds`.
CatenaryResult hang_rope(int segments, double span, double length, double seconds) {
  ConstraintBodySettings s;
  s.stretch_compliance = 0.0;  // inextensible
  s.bending = false;           // a chain: the catenary has no bending stiffness
  s.damping = 2.0;
  s.substeps = 100;
  s.iterations = 1;
  const double drop = std::sqrt(length * length - span * span) / 2.0;
  auto rope = ConstraintBody::rope({Vec3(-span / 2, 0, 0), Vec3(0, -drop, 0), Vec3(span / 2, 0, 0)}, segments, 0.05, s);
  rope->pin(0);
  rope->pin(rope->size() - 1);
  const int steps = int(std::lround(seconds * 60));
  for (int k = 0; k < steps; ++k) rope->step(1.0 / 60, {});
  CatenaryResult r;
  const double a = cloth_math::catenary_parameter(span, length);
  r.expected_sag = cloth_math::catenary_sag(span, length);
  const auto& x = rope->state().x;
  double lowest = 0.0, worst = 0.0;
  for (const Vec3& p : x) {
    lowest = std::min(lowest, p.y());
    const double y = a * (std::cosh(p.x() / a) - std::cosh(span / (2 * a)));
    worst = std::max(worst, std::abs(p.y() - y));
  }
  r.sag = -lowest;
  r.sag_error = std::abs(r.sag - r.expected_sag) / r.expected_sag;
  r.shape_error = worst / r.expected_sag;
  r.max_stretch = rope->max_stretch();
  return r;
}

}  // namespace

TEST(RopePhysics, HangsAsTheCatenary) {
  const CatenaryResult r = hang_rope(100, 1.0, 1.2, 10.0);
  EXPECT_LT(r.sag_error, 0.02) << "sag " << r.sag << " m, catenary " << r.expected_sag << " m";
  EXPECT_LT(r.shape_error, 0.02) << "largest |y - y_catenary| / sag";
  EXPECT_LT(r.max_stretch, 5e-3);
}

TEST(RopePhysics, GrabForceCarriesTheWeight) {
  ConstraintBodySettings s;
  s.damping = 3.0;
  s.substeps = 20;
  auto rope = ConstraintBody::rope({Vec3(0, 0, 0), Vec3(0, -0.5, 0)}, 20, 0.2, s);
  rope->grab(1, 0, Vec3(0, 0, 0), 0.0);
  for (int k = 0; k < 300; ++k) rope->step(1.0 / 60, {});
  const Vec3 f = rope->grab_force(1);
  const double weight = rope->total_mass() * 9.81;
  EXPECT_NEAR(f.y(), weight, 0.01 * weight) << "force " << f.transpose() << " N, weight " << weight << " N";
  EXPECT_LT(std::hypot(f.x(), f.z()), 1e-6 * weight);
}

TEST(ClothPhysics, DrapesOverASphereWithoutTunnellingOrExploding) {
  ClothGridSpec g;  // 64 x 64, 1 m x 1 m, horizontal
  g.origin = Vec3(-0.5, 0.35, -0.5);
  ConstraintBodySettings s;
  s.stretch_compliance = 1e-9;
  s.threads = 2;
  auto cloth = ConstraintBody::cloth_grid(g, s);
  const Vec3 centre(0, 0, 0);
  const double radius = 0.3;
  const std::vector<Collider> colliders = {Collider::sphere(centre, radius)};
  double closest = 1e300, worst_stretch = 0.0, fastest = 0.0;
  size_t touching = 0;
  for (int k = 0; k < 180; ++k) {
    const auto rep = cloth->step(1.0 / 60, colliders);
    touching = rep.contacts;
    for (size_t i = 0; i < cloth->size(); ++i) {
      const Vec3& p = cloth->state().x[i];
      ASSERT_TRUE(p.allFinite() && cloth->state().v[i].allFinite()) << "step " << k << " particle " << i;
      closest = std::min(closest, (p - centre).norm());
      fastest = std::max(fastest, cloth->state().v[i].norm());
    }
    for (const auto& t : cloth->triangles()) {
      const Vec3 c = (cloth->state().x[t[0]] + cloth->state().x[t[1]] + cloth->state().x[t[2]]) / 3.0;
      closest = std::min(closest, (c - centre).norm());
    }
    worst_stretch = std::max(worst_stretch, cloth->max_stretch());
  }
  EXPECT_GE(closest, radius) << "a particle or triangle centre went inside the sphere";
  EXPECT_GE(closest, radius + 0.5 * s.thickness) << "closest " << closest;
  // no explosion: edges stay within a bounded stretch at this budget (1 iteration, 16
  // substeps: the draping swing stretches the free edges for a moment), and end near rest
  EXPECT_LT(worst_stretch, 0.5) << "largest relative stretch of an edge over the run";
  EXPECT_LT(cloth->step(1.0 / 60, colliders).constraint_error, 0.03) << "RMS relative stretch at the end";
  EXPECT_LT(fastest, 20.0) << "largest particle speed, m/s";
  EXPECT_GT(touching, 100u) << "the cloth should lie on the sphere at the end";
}

namespace {

// The 32 x 32 cloth, 0.3 m wide, 3 mm thick, 10 cm over a 5 cm sphere, with `substeps` of one
// iteration per 1/60 s step.
std::unique_ptr<ConstraintBody> coarse_drop(int substeps) {
  ClothGridSpec g;
  g.nx = g.ny = 32;
  g.size_x = g.size_y = 0.3;
  g.origin = Vec3(-0.15, 0.1, -0.15);
  ConstraintBodySettings s;
  s.substeps = substeps;
  s.thickness = 0.003;
  return ConstraintBody::cloth_grid(g, s);
}

const std::vector<Collider> kDropSphere = {Collider::sphere(Vec3::Zero(), 0.05)};

}  // namespace

// A 32 x 32 cloth, 0.3 m wide, dropped on a 5 cm sphere: most of it hangs in chains of about
// 11 links. With one iteration per substep a hanging chain of N links of length l stretches by
// about N^2 g h^2 / l (h the substep): 4 substeps of 1/60 s leave edges at about three times
// their length before any self-contact, 16 keep them within 30%. The first is said once in the
// log (docs/cloth.md, "Substeps and stretch"), the second not at all.
TEST(ClothPhysics, AnUnderResolvedStretchIsSaidOnceInTheLog) {
  auto sink = std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(64);
  auto logger = std::make_shared<spdlog::logger>("cloth-test", sink);
  const auto previous = spdlog::default_logger();
  spdlog::set_default_logger(logger);
  auto warnings = [&] {
    size_t k = 0;
    for (const std::string& line : sink->last_formatted())
      if (line.find("[warning] scene 'ward' body 'drape' (cloth): an edge is stretched to") != std::string::npos &&
          line.find("with 4 substeps x 1 iterations") != std::string::npos)
        ++k;
    return k;
  };
  auto drop = [&](int substeps, int steps) {
    auto cloth = coarse_drop(substeps);
    cloth->set_log_name("scene 'ward' body 'drape' (cloth)");
    double worst = 0.0;
    for (int k = 0; k < steps; ++k) worst = std::max(worst, cloth->step(1.0 / 60, kDropSphere).max_constraint_error);
    return worst;
  };
  const double coarse = drop(4, 17);
  const size_t said_coarse = warnings();
  const double fine = drop(16, 60);
  const size_t said_fine = warnings() - said_coarse;
  spdlog::set_default_logger(previous);
  EXPECT_GT(coarse, 1.0) << "largest relative stretch with 4 substeps";
  EXPECT_EQ(said_coarse, 1u) << "one warning while the edges stay over-stretched";
  EXPECT_LT(fine, 0.5) << "largest relative stretch with 16 substeps";
  EXPECT_EQ(said_fine, 0u);
}

// The coarse drop above for 4 s: the steps that start with an edge past twice its rest length
// leave self-collision out, so the over-stretched fabric does not crumple into itself and blow
// up (with self-collision kept it reached 61 m/s and 200,000 self-contacts in a step: docs/cloth.md,
// "Substeps and stretch"); the 16-substep drop never leaves it out.
TEST(ClothPhysics, AnOverstretchedClothLeavesSelfCollisionOutInsteadOfBlowingUp) {
  struct Run {
    int suspended_steps = 0;
    size_t most_self_contacts = 0;
    double fastest = 0.0, worst = 0.0;
  };
  auto drop = [](int substeps) {
    auto cloth = coarse_drop(substeps);
    Run r;
    for (int k = 0; k < 240; ++k) {
      const ParticleStepReport rep = cloth->step(1.0 / 60, kDropSphere);
      r.worst = std::max(r.worst, rep.max_constraint_error);
      r.suspended_steps += rep.self_collision_suspended ? 1 : 0;
      r.most_self_contacts = std::max(r.most_self_contacts, cloth->self_contacts());
      for (const Vec3& v : cloth->state().v) r.fastest = std::max(r.fastest, v.norm());
    }
    return r;
  };
  const Run coarse = drop(4), fine = drop(16);
  EXPECT_GT(coarse.suspended_steps, 0);
  EXPECT_GT(coarse.worst, 1.0) << "the coarse drop does over-stretch";
  EXPECT_LT(coarse.fastest, 15.0) << "m/s";
  EXPECT_LT(coarse.most_self_contacts, 2000u);
  EXPECT_EQ(fine.suspended_steps, 0);
  EXPECT_LT(fine.worst, 0.5);
}

TEST(ClothPhysics, AFineClothKeepsSelfCollisionWithinItsEdgesAndStaysWhole) {
  // A 32 x 32 cloth of 12 cm (3.9 mm edges) at the defaults (5 mm thickness, 16 substeps) dropped
  // 2 cm onto a 3 cm sphere for 2 s. Self-collision kept the whole thickness and its reach (1.5
  // times it) passed the particles two edges apart (7.8 mm at rest): as the cloth folded over
  // the sphere they were pushed apart across its plane and the cloth blew up (an edge 10.9 times
  // its length longer, 44 m/s). Now self-collision keeps at most half the shortest edge: the
  // cloth drapes (an edge at most 46% longer while its chains hang, 3.1 m/s at most), never
  // nearer the sphere than the thickness, which the colliders keep whole (the test prints these).
  ClothGridSpec g;
  g.nx = g.ny = 32;
  g.size_x = g.size_y = 0.12;
  g.origin = Vec3(-0.06, 0.05, -0.06);
  ConstraintBodySettings s;
  auto cloth = ConstraintBody::cloth_grid(g, s);
  const std::vector<Collider> sphere = {Collider::sphere(Vec3::Zero(), 0.03)};
  double worst = 0, fastest = 0, nearest = INFINITY;
  for (int k = 0; k < 120; ++k) {
    worst = std::max(worst, cloth->step(1.0 / 60, sphere).max_constraint_error);
    for (const Vec3& v : cloth->state().v) fastest = std::max(fastest, v.norm());
    for (const Vec3& x : cloth->state().x) nearest = std::min(nearest, x.norm() - 0.03);
  }
  std::cout << "[ fine cloth ] largest stretch " << worst << ", fastest " << fastest << " m/s, nearest the sphere "
            << nearest << " m\n";
  EXPECT_LT(worst, 1.0) << "no edge past twice its length";
  EXPECT_LT(fastest, 5.0) << "m/s";
  EXPECT_GT(nearest, 0.95 * s.thickness) << "the sphere keeps the whole thickness";
}

TEST(ClothPhysics, AClothRestingOnAToolWeighsOnIt) {
  // A 0.4 m cloth dropped on a 0.3 m sphere tool and nothing else (no collider, no pin), the tool
  // met inside the cloth's substeps as the scene does (ToolBoundary), and coupled after each step
  // only: once the cloth rests on it, the force on the tool averaged over a second is the cloth's
  // weight, straight down.
  for (bool in_substeps : {true, false}) {
    SCOPED_TRACE(in_substeps ? "inside the substeps" : "after each step");
    ClothGridSpec g;
    g.nx = g.ny = 16;
    g.size_x = g.size_y = 0.4;
    g.origin = Vec3(-0.2, 0.32, -0.2);
    ConstraintBodySettings s;
    s.damping = 0.0;  // damping is a drag against the world: the tool would carry less than the weight
    auto cloth = ConstraintBody::cloth_grid(g, s);
    const RigidTool tool = RigidTool::sphere(Vec3(0, 0, 0), 0.3);
    const double dt = 1.0 / 60;
    Vec3 felt = Vec3::Zero();
    size_t touching = 0;
    for (int k = 0; k < 300; ++k) {
      ToolReaction r;
      if (in_substeps) {
        ToolBoundary tb;
        const RigidTool tools[] = {tool};
        tb.tools = tools;
        touching = cloth->advance(dt, cloth->substeps(), {}, true, nullptr, &tb).tool_contacts;
        r.force = -tb.impulse[0] / dt;
      } else {
        const std::vector<Vec3> start = cloth->state().x;
        cloth->step(dt, {});
        ParticleState ps = cloth->state();
        touching = couple_particles_to_tool(ps, cloth->inverse_masses(), tool, cloth->contact_radius(), dt, start, r);
        cloth->set_state(ps);
      }
      if (k >= 240) felt += r.force / 60;
    }
    const double weight = cloth->total_mass() * 9.81;
    EXPECT_GT(touching, 20u);
    double lowest = 1e300;
    for (const Vec3& p : cloth->state().x) lowest = std::min(lowest, p.y());
    EXPECT_GT(lowest, -0.3) << "the cloth slid off the tool";
    EXPECT_NEAR(felt.y(), -weight, 1e-3 * weight) << "felt " << felt.transpose() << " N, weight " << weight << " N";
    EXPECT_LT(std::hypot(felt.x(), felt.z()), 0.02 * weight);
  }
}

TEST(ClothPhysics, AHammockHoldsTheWaterPouredIntoIt) {
  // A 0.6 m cloth of 1 kg/m^2 pinned at its four corners and a 27-particle block of water
  // (spacing 2 cm, 0.22 kg) dropped into it from 15 cm, stepped in turn and coupled as a scene
  // does (each step in the parts shared_step_parts gives, the contact after each part): no water
  // particle passes under the cloth, and the cloth carries the water's weight (the contact's
  // push, averaged over the last two seconds).
  ClothGridSpec g;
  g.nx = g.ny = 16;
  g.size_x = g.size_y = 0.6;
  g.mass_per_area = 1.0;
  g.origin = Vec3(-0.3, 0.0, -0.3);
  ConstraintBodySettings cset;
  cset.damping = 1.0;
  cset.self_collision = false;
  auto cloth = ConstraintBody::cloth_grid(g, cset);
  for (size_t corner : {size_t(0), size_t(15), size_t(240), size_t(255)}) cloth->pin(corner);
  FluidSettings fs;
  fs.spacing = 0.02;
  FluidBody water(fs, {FluidBlock{Vec3(-0.03, 0.15, -0.03), Vec3(0.03, 0.21, 0.03), Vec3::Zero()}});
  ASSERT_EQ(water.size(), 27u);
  const double dt = 1.0 / 60;
  CouplingSettings contact;
  contact.radius = water.contact_radius() + cloth->contact_radius();
  contact.friction = 0.3;
  Vec3 push = Vec3::Zero();
  const int ticks = 600, averaged = 120;
  size_t through = 0;
  const int substeps[] = {water.substeps(), cloth->substeps()};
  ASSERT_EQ(shared_step_parts(substeps), 2);
  for (int k = 0; k < ticks; ++k) {
    const CouplingReport rep = step_with_cloth_contact(water, *cloth, contact, dt, {});
    if (k >= ticks - averaged) push += rep.force_on_body / averaged;
    const ParticleState &ws = water.state(), &cs = cloth->state();
    for (const Vec3& p : ws.x) {
      // Under the cloth: below its lowest point while over its middle.
      double lowest = 1e300;
      for (const Vec3& q : cs.x) lowest = std::min(lowest, q.y());
      through += p.y() < lowest - 0.01 && std::abs(p.x()) < 0.25 && std::abs(p.z()) < 0.25;
    }
  }
  EXPECT_EQ(through, 0u) << "particle-ticks with water under the cloth";
  const double weight = water.particle_mass() * double(water.size()) * 9.81;
  EXPECT_NEAR(push.y(), -weight, 0.02 * weight) << "push " << push.transpose() << " N, weight " << weight << " N";
  EXPECT_LT(std::hypot(push.x(), push.z()), 0.02 * weight);
}

namespace {

// Two 16 x 16 sheets 2 cm apart in one body, dropped on the floor: the smallest height of a
// top particle above its bottom twin over the run and at the end.
std::pair<double, double> stacked_layers_gap(bool self_collision) {
  const int n = 16;
  std::vector<Vec3> x;
  std::vector<Triangle> t;
  for (int layer = 0; layer < 2; ++layer) {
    const int32_t base = int32_t(x.size());
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) x.push_back(Vec3(-0.2 + 0.4 * i / (n - 1), 0.1 + 0.02 * layer, -0.2 + 0.4 * j / (n - 1)));
    for (int j = 0; j + 1 < n; ++j)
      for (int i = 0; i + 1 < n; ++i) {
        const int32_t a = base + j * n + i, b = a + 1, c = a + n + 1, d = a + n;
        t.push_back({a, b, c});
        t.push_back({a, c, d});
      }
  }
  ConstraintBodySettings s;
  s.self_collision = self_collision;
  s.damping = 0.5;
  auto body = ConstraintBody::cloth(x, t, 0.2, s);
  // the bottom layer stops on the floor, the top one lands on it
  const std::vector<Collider> colliders = {Collider::plane(Vec3(0, 0, 0), Vec3(0, 1, 0))};
  double gap = 1e300, last = 1e300;
  for (int k = 0; k < 90; ++k) {
    body->step(1.0 / 60, colliders);
    last = 1e300;
    for (int i = 0; i < n * n; ++i) last = std::min(last, body->state().x[n * n + i].y() - body->state().x[i].y());
    gap = std::min(gap, last);
  }
  return {gap, last};
}

}  // namespace

TEST(ClothPhysics, SelfCollisionKeepsTwoFallingLayersApart) {
  const double thickness = ConstraintBodySettings{}.thickness;
  const auto [with, with_end] = stacked_layers_gap(true);
  EXPECT_GT(with, 0.0) << "smallest height of the top layer above the bottom one over the run, m";
  EXPECT_GT(with_end, 0.8 * thickness) << "at rest the layers lie a thickness apart, m";
  const auto [without, without_end] = stacked_layers_gap(false);
  EXPECT_LT(without_end, 0.1 * thickness) << "without self-collision the layers should meet (the check can fail)";
}
