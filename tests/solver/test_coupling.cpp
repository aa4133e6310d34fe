// SPDX-License-Identifier: Apache-2.0
// Two-way contact between particles and the soft body's surface: particles end at least the
// contact radius outside the surface, the corrections carry equal and opposite momentum,
// fixed vertices stay, and friction takes back tangential slip.
#include "pliant/builtin_meshes.hpp"
#include "pliant/cloth.hpp"
#include "pliant/coupling.hpp"
#include "pliant/fluid.hpp"
#include "pliant/interaction.hpp"
#include "pliant/stepper.hpp"
#include "pliant/vtu_recording.hpp"

#include "drape_obstacle.hpp"
#include "particles/surface_contact.hpp"
#include "particles/triangle_grid.hpp"
#include "pliant/test/segment_distance.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <iostream>
#include <memory>
#include <random>
#include <set>
#include <vector>

using namespace pliant;

namespace {

// beam1 is 0.1 x 0.01 x 0.01 m from the origin: particles over its top face (y = 0.01), some a
// little inside, some within the radius above it, all moving.
struct Touching {
  std::shared_ptr<const BodyModel> model;
  BodyState body;
  ParticleState particles;
  std::vector<double> w;
};

Touching over_the_top(bool all_fixed) {
  TetMesh mesh = *builtin_mesh("beam1");
  FixedSelection fixed;
  if (all_fixed) fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(1, 1, 1)});
  Touching s;
  s.model = build_model(mesh, Material{1e5, 0.4, 1000}, fixed);
  s.body = rest_state(*s.model);
  for (size_t i = 0; i < s.body.v.size(); ++i)
    if (s.model->inv_mass[i] > 0) s.body.v[i] = Vec3(0.01 * std::sin(double(i)), -0.02, 0.005 * std::cos(double(i)));
  for (int i = 0; i < 12; ++i)
    for (int k = 0; k < 4; ++k) {
      // A third 0.4 mm inside, a third 0.3 mm above (within a 1 mm radius), a third clear.
      const double y = 0.01 + ((i + k) % 3 == 0 ? -0.0004 : (i + k) % 3 == 1 ? 0.0003 : 0.0015);
      s.particles.x.push_back(Vec3(0.015 + 0.006 * i, y, 0.002 + 0.002 * k));
      s.particles.v.push_back(Vec3(0.1, -0.5 - 0.01 * i, 0.02 * k));
      s.w.push_back(1.0 / 2e-5);  // 20 mg
    }
  return s;
}

Vec3 momentum(const Touching& s) {
  Vec3 p = Vec3::Zero();
  for (size_t i = 0; i < s.body.v.size(); ++i)
    if (s.model->inv_mass[i] > 0) p += s.body.v[i] / s.model->inv_mass[i];
  for (size_t i = 0; i < s.particles.v.size(); ++i) p += s.particles.v[i] / s.w[i];
  return p;
}

// The particle's distance outside the surface (negative inside), by brute force over every
// surface triangle: the closest one, signed by its outward normal.
double outside_distance(const BodyModel& m, const std::vector<Vec3>& x, const Vec3& p) {
  double best = INFINITY, signed_d = 0;
  for (const Triangle& t : m.surface) {
    std::array<double, 3> b;
    const Vec3 q = closest_point_on_triangle(p, x[t[0]], x[t[1]], x[t[2]], b);
    const double d = (p - q).norm();
    if (d < best) {
      best = d;
      const Vec3 n = (x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]);
      signed_d = (p - q).dot(n) >= 0 ? d : -d;
    }
  }
  return signed_d;
}

}  // namespace

TEST(Coupling, PushesParticlesOutOfTheBodyWithEqualAndOppositeMomentum) {
  Touching s = over_the_top(false);
  const Vec3 before = momentum(s);
  const std::vector<Vec3> particles_start = s.particles.x, body_start = s.body.x;
  CouplingSettings cs;
  cs.radius = 0.001;
  const CouplingReport r = couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, 1.0 / 60);
  EXPECT_EQ(r.contacts, 32u);
  EXPECT_NEAR(r.max_depth, 0.0014, 1e-9);
  // Momentum: what the particles gained the body lost (free body, no other force).
  const Vec3 after = momentum(s);
  double scale = 0;
  for (size_t i = 0; i < s.particles.v.size(); ++i) scale += s.particles.v[i].norm() / s.w[i];
  EXPECT_LT((after - before).norm(), 1e-12 * scale);
  // The body was pushed down: the push on it points down (-y) and it is what the particles'
  // momentum change says, over dt.
  EXPECT_LT(r.force_on_body.y(), 0);
  // The body's positions stay (it took velocity); every particle ends the radius outside, the
  // clear ones untouched.
  EXPECT_EQ(s.body.x, body_start);
  for (size_t i = 0; i < s.particles.x.size(); ++i) {
    EXPECT_GT(outside_distance(*s.model, s.body.x, s.particles.x[i]), cs.radius * (1 - 1e-9)) << i;
    if (particles_start[i].y() > 0.0105) {
      EXPECT_EQ(s.particles.x[i], particles_start[i]) << i;
    }
  }
}

TEST(Coupling, ASegmentAcrossTheBodyIsPushedOutAlongItsLengthWithEqualAndOppositeMomentum) {
  // Two particles 1 cm either side of beam1 (z = -0.01 and 0.02, the beam spans z 0-0.01), the
  // segment between them 0.5 mm under the top face: both particles are clear of the surface, the
  // segment's middle runs through the body. Unequal masses, a moving free body.
  Touching s = over_the_top(false);
  s.particles.x = {Vec3(0.05, 0.0095, -0.01), Vec3(0.05, 0.0095, 0.02)};
  s.particles.v = {Vec3(0, -0.1, 0), Vec3(0.01, -0.05, 0)};
  s.w = {1.0 / 2e-5, 1.0 / 6e-5};
  const std::array<uint32_t, 2> link{0, 1};
  CouplingSettings cs;
  cs.radius = 0.001;
  const double dt = 1.0 / 60;
  Touching without = s;
  const CouplingReport alone = couple_particles_to_body(*without.model, without.body, without.particles, without.w, cs, dt);
  EXPECT_EQ(alone.contacts + alone.segment_contacts, 0u);  // the particles alone see nothing
  EXPECT_EQ(without.particles.x, s.particles.x);

  const Vec3 before = momentum(s);
  const std::vector<Vec3> body_start = s.body.x;
  const CouplingReport r =
      couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, dt, {}, std::span(&link, 1));
  EXPECT_EQ(r.contacts, 0u);
  EXPECT_GT(r.segment_contacts, 0u);
  EXPECT_NEAR(r.max_depth, 0.0015, 1e-9);  // 0.5 mm inside, plus the radius
  // The whole segment ends about the radius outside (it was lifted over the top face; the
  // points are corrected in turn, each tilting the segment a little, so the earlier ones may end
  // a few micrometres short of the radius; before, the middle was 0.5 mm inside).
  for (int k = 0; k <= 100; ++k) {
    const Vec3 p = s.particles.x[0] + (k / 100.0) * (s.particles.x[1] - s.particles.x[0]);
    EXPECT_GT(outside_distance(*s.model, s.body.x, p), 0.99 * cs.radius) << k;
  }
  // Lifted, the lighter particle more (a point's correction goes by inverse mass).
  const double up0 = s.particles.x[0].y() - 0.0095, up1 = s.particles.x[1].y() - 0.0095;
  EXPECT_GT(up1, 0);
  EXPECT_GT(up0, up1);
  // Momentum: what the particles gained the body lost; the body's positions stay.
  double scale = 0;
  for (size_t i = 0; i < s.particles.v.size(); ++i) scale += s.particles.v[i].norm() / s.w[i];
  EXPECT_LT((momentum(s) - before).norm(), 1e-12 * scale);
  EXPECT_LT(r.force_on_body.y(), 0);
  EXPECT_EQ(s.body.x, body_start);
}

namespace {

// A fixed regular tetrahedron (edges 2.83 cm) and points beside its edges: in the region whose
// closest surface point is on an edge (0.3 and 0.6 mm from it, in directions between the two
// faces' normals), half of them behind the plane of one of the two faces, half behind the
// other's (the faces meet at 70.5 degrees, so a point outside near one face lies behind the
// other's plane). `expected`: each point moved straight away from its edge point to `radius`.
struct BesideEdges {
  std::shared_ptr<const BodyModel> model;
  BodyState body;
  std::vector<Vec3> points, expected;
};

BesideEdges beside_sharp_edges(double radius) {
  TetMesh mesh;
  mesh.name = "tetrahedron";
  mesh.vertices = {Vec3(0.01, 0.01, 0.01), Vec3(0.01, -0.01, -0.01), Vec3(-0.01, 0.01, -0.01), Vec3(-0.01, -0.01, 0.01)};
  mesh.tets = {{0, 1, 2, 3}};
  const auto& v = mesh.vertices;
  if ((v[1] - v[0]).cross(v[2] - v[0]).dot(v[3] - v[0]) < 0) mesh.tets = {{0, 2, 1, 3}};
  FixedSelection fixed;
  fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(1, 1, 1)});
  BesideEdges e;
  e.model = build_model(mesh, Material{1e5, 0.3, 1000}, fixed);
  e.body = rest_state(*e.model);
  for (int i = 0; i < 4; ++i)
    for (int j = i + 1; j < 4; ++j) {
      int others[2], n = 0;
      for (int k = 0; k < 4; ++k)
        if (k != i && k != j) others[n++] = k;
      // The faces along edge i-j are those opposite the other two corners; the tetrahedron is
      // centred on the origin, so the face opposite corner k faces away from it.
      const Vec3 n1 = -v[size_t(others[0])].normalized(), n2 = -v[size_t(others[1])].normalized();
      for (double t : {0.3, 0.5, 0.7})
        for (double s : {0.05, 0.15, 0.85, 0.95})  // near face 1 (behind face 2's plane) .. near face 2
          for (double r0 : {0.3 * radius, 0.6 * radius}) {
            const Vec3 edge_point = v[size_t(i)] + t * (v[size_t(j)] - v[size_t(i)]);
            const Vec3 away = ((1 - s) * n1 + s * n2).normalized();
            e.points.push_back(edge_point + r0 * away);
            e.expected.push_back(edge_point + radius * away);
          }
    }
  return e;
}

}  // namespace

TEST(Coupling, APointBesideASharpEdgeIsPushedStraightAwayFromItNotThroughAFacesPlane) {
  // Each point is outside the body, within the radius of the edge: it belongs the radius away
  // from its edge point, along the line it already lies on. Read as inside (by the normal of
  // whichever equally close face came first) it went the radius out through that face instead,
  // ending off that line and farther than the radius from the body: a cloth lying beside a
  // sagging beam's clamped end was thrown 5 mm a substep that way, about 5 m/s.
  const double radius = 0.001;
  BesideEdges e = beside_sharp_edges(radius);
  ParticleState ps;
  ps.x = e.points;
  ps.v.assign(ps.x.size(), Vec3::Zero());
  const std::vector<double> w(ps.x.size(), 1e4);
  CouplingSettings cs;
  cs.radius = radius;
  const CouplingReport r = couple_particles_to_body(*e.model, e.body, ps, w, cs, 1.0 / 60, e.points);
  EXPECT_EQ(r.contacts, e.points.size());
  for (size_t k = 0; k < ps.x.size(); ++k)
    EXPECT_LT((ps.x[k] - e.expected[k]).norm(), 1e-9 * radius) << "point " << k << " at " << e.points[k].transpose();

  // The surface a particle body meets inside its substeps reads the same points outside, at
  // their distance from the edge, the direction away from it.
  SurfaceBoundary boundary;
  boundary.triangles = e.model->surface;
  boundary.x = e.body.x;
  boundary.v = e.body.v;
  boundary.radius = radius;
  detail::SurfaceMeeting meeting(boundary, e.points, radius, radius);
  for (size_t k = 0; k < e.points.size(); ++k) {
    detail::FaceHit hit;
    double distance = 0;
    ASSERT_TRUE(meeting.closest(e.points[k], hit, distance)) << k;
    const Vec3 away = (e.expected[k] - e.points[k]).normalized();
    EXPECT_NEAR(distance, radius - (e.expected[k] - e.points[k]).norm(), 1e-12) << k;
    EXPECT_GT(hit.n.dot(away), 1 - 1e-9) << k;
  }
}

TEST(Coupling, RefusesASegmentOutsideTheParticles) {
  Touching s = over_the_top(false);
  CouplingSettings cs;
  cs.radius = 0.001;
  const std::array<uint32_t, 2> bad{0, uint32_t(s.particles.x.size())};
  try {
    couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, 1.0 / 60, {}, std::span(&bad, 1));
    FAIL() << "accepted a segment past the last particle";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("segment 0"), std::string::npos) << e.what();
  }
}

TEST(Coupling, FixedVerticesTakeNoMomentum) {
  Touching s = over_the_top(true);
  const std::vector<Vec3> body_start = s.body.x;
  CouplingSettings cs;
  cs.radius = 0.001;
  const std::vector<Vec3> body_v = s.body.v;
  const CouplingReport r = couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, 1.0 / 60);
  EXPECT_EQ(r.contacts, 32u);
  EXPECT_EQ(s.body.x, body_start);
  EXPECT_EQ(s.body.v, body_v);
  EXPECT_EQ(r.force_on_body, Vec3::Zero());
  for (const Vec3& p : s.particles.x) EXPECT_GT(outside_distance(*s.model, s.body.x, p), cs.radius * (1 - 1e-9));
}

TEST(Coupling, FrictionTakesBackTheSlipOfATouchingParticle) {
  // One particle 0.2 mm inside the fixed body's top face, having slid 1 cm/s along x over the
  // step while pressing in.
  auto slide = [](double friction) {
    Touching s = over_the_top(true);
    s.particles.x = {Vec3(0.05, 0.0098, 0.005)};
    s.particles.v = {Vec3(0.01, -0.05, 0)};
    s.w = {1.0 / 2e-5};
    CouplingSettings cs;
    cs.radius = 0.0005;
    cs.friction = friction;
    const double dt = 1.0 / 60;
    couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, dt);
    return s.particles.v[0];
  };
  const Vec3 frictionless = slide(0), rough = slide(1.0), sticky = slide(100.0);
  EXPECT_NEAR(frictionless.x(), 0.01, 1e-12);  // no friction: the slip stays
  // Pushed out by 0.7 mm over the step: the inward velocity loses 0.7 mm / dt.
  EXPECT_NEAR(frictionless.y(), -0.05 + 0.0007 * 60, 1e-9);
  // Friction up to mu x the normal correction (0.7 mm over the step): mu = 1 removes at most
  // that much of the 0.17 mm slip, so all of it; the tangential velocity goes to zero both times.
  EXPECT_NEAR(rough.x(), 0.0, 1e-9);
  EXPECT_NEAR(sticky.x(), 0.0, 1e-9);
  // A weak friction takes back only its share of the slip.
  const Vec3 weak = slide(0.1);
  EXPECT_GT(weak.x(), 0.0);
  EXPECT_LT(weak.x(), 0.01);
}

TEST(Coupling, RefusesBadSettingsNamingTheField) {
  Touching s = over_the_top(false);
  CouplingSettings cs;
  cs.radius = -1;
  try {
    couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, 1.0 / 60);
    FAIL() << "accepted a negative radius";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("coupling.radius"), std::string::npos) << e.what();
  }
  cs.radius = 0.001;
  s.w.pop_back();
  EXPECT_THROW(couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, 1.0 / 60), std::invalid_argument);
}

namespace {

// No gravity, no container, nothing fixed, no damping: a 6 x 3 x 3 block of 4 mm fluid particles
// thrown down at 0.2 m/s (3.3 mm per tick: less than half the 1 cm beam, which a tick-level
// contact needs) onto beam1's top face.
struct FluidThrow {
  std::shared_ptr<const BodyModel> model = build_model(*builtin_mesh("beam1"), Material{1e5, 0.4, 1000});
  BodyState body = rest_state(*model);
  SolverSettings s;
  std::unique_ptr<FluidBody> fluid;
  CouplingSettings contact;

  explicit FluidThrow(int fluid_substeps) {
    s.gravity.setZero();
    s.damping = Damping::None;
    FluidSettings fs;
    fs.spacing = 0.004;
    fs.gravity.setZero();
    fs.substeps = fluid_substeps;
    fluid = std::make_unique<FluidBody>(
        fs, std::vector<FluidBlock>{FluidBlock{Vec3(0.03, 0.0125, 0.0), Vec3(0.054, 0.0245, 0.012), Vec3(0, -0.2, 0)}});
    contact.radius = 0.5 * fs.spacing;
  }
  // The total momentum; the body's share in *of_body when given.
  Vec3 momentum(Vec3* of_body = nullptr) const {
    Vec3 pb = Vec3::Zero(), pf = Vec3::Zero();
    for (size_t i = 0; i < body.v.size(); ++i) pb += body.v[i] / model->inv_mass[i];
    const auto w = fluid->inverse_masses();
    for (size_t i = 0; i < fluid->size(); ++i) pf += fluid->state().v[i] / w[i];
    if (of_body) *of_body = pb;
    return pb + pf;
  }
  // The fluid's step (or part) of length h in n substeps meeting the body's surface inside it,
  // and the body's side of that contact.
  size_t advance_meeting(double h, int n, bool ends_step) {
    SurfaceBoundary surface;
    surface.triangles = model->surface;
    surface.x = body.x;
    surface.v = body.v;
    surface.radius = contact.radius;
    const size_t touched = fluid->advance(h, n, {}, ends_step, &surface).soft_body_contacts;
    take_surface_impulse(*model, body, surface);
    return touched;
  }
  // 30 ticks of the body stepping in `parts` parts, part(h, substeps, ends_step) the fluid's
  // share after each (the particles it touched): the total momentum must stay within 1e-6 of the
  // initial every tick. Returns the particles touched in all.
  template <class Part>
  size_t run_in_parts(int parts, const Part& part) {
    const Vec3 p0 = momentum();
    Stepper stepper;
    size_t touched = 0;
    for (int k = 0; k < 30; ++k) {
      const Vec3 before = momentum();
      stepper.step_in_parts(*model, body, s, {}, parts, [&](int i, const StepReport&, StepInputs&) {
        touched += part(s.dt / parts, fluid->substeps() / parts, i + 1 == parts);
      });
      EXPECT_LT((momentum() - before).norm(), 1e-6 * p0.norm()) << "step " << k;
    }
    return touched;
  }
  // The fluid's contact with the body over a step of length h from `start`.
  size_t couple(double h, std::span<const Vec3> start = {}) {
    ParticleState ps = fluid->state();
    const size_t touched = couple_particles_to_body(*model, body, ps, fluid->inverse_masses(), contact, h, start).contacts;
    fluid->set_state(ps);
    return touched;
  }
};

}  // namespace

TEST(Coupling, AFluidThrownAtAFreeBodyPushesItAndTheTotalMomentumStays) {
  // Each step: the fluid, the soft body (XPBD, or vertex block descent at the default budget with
  // its translation step), then their contact. Every part conserves momentum, so the sum must
  // stay; the body must take up the fluid's downward momentum.
  for (Method method : {Method::Xpbd, Method::Vbd}) {
    SCOPED_TRACE(std::string(to_string(method)));
    FluidThrow t(2);
    t.s.method = method;
    ASSERT_EQ(t.fluid->size(), 6u * 3u * 3u);
    const Vec3 p0 = t.momentum();
    ASSERT_LT(p0.y(), 0);
    Stepper stepper;
    size_t touched = 0;
    for (int k = 0; k < 30; ++k) {
      const Vec3 before = t.momentum();
      t.fluid->step(t.s.dt, {});
      stepper.step(*t.model, t.body, t.s, {});
      touched += t.couple(t.s.dt);
      EXPECT_LT((t.momentum() - before).norm(), 1e-6 * p0.norm()) << "step " << k;
    }
    EXPECT_GT(touched, 0u);
    Vec3 pb;
    t.momentum(&pb);
    EXPECT_LT(pb.y(), 0.1 * p0.y());  // the body carries a good part of the downward momentum
  }
}

TEST(Coupling, AFluidAndAFreeBodyInPartsKeepTheTotalMomentum) {
  // The same throw with the fluid and the body stepping in parts as a scene steps them
  // (Stepper::step_in_parts, the fluid's part and their contact after each of the body's parts):
  // every part conserves momentum, so the sum stays, in 2 parts and in the fluid's 4 substeps'
  // worth of 4, with the body's XPBD or vertex block descent; and the contact is met within the tick.
  for (Method method : {Method::Xpbd, Method::Vbd})
    for (int parts : {2, 4}) {
      SCOPED_TRACE(std::string(to_string(method)) + ", " + std::to_string(parts) + " parts");
      FluidThrow t(4);
      t.s.method = method;
      const size_t touched = t.run_in_parts(parts, [&](double h, int n, bool ends_step) {
        const std::vector<Vec3> start = t.fluid->state().x;
        t.fluid->advance(h, n, {}, ends_step);
        return t.couple(h, start);
      });
      EXPECT_GT(touched, 0u);
    }
}

namespace {

// Every particle on the outer side of the body's surface face closest to it (within 1e-9 m).
void expect_outside(const BodyModel& model, std::span<const Vec3> body_x, std::span<const Vec3> particles) {
  for (const Vec3& x : particles) {
    double best = INFINITY, side = 0;
    for (const Triangle& f : model.surface) {
      const Vec3 &a = body_x[f[0]], &b = body_x[f[1]], &c = body_x[f[2]];
      std::array<double, 3> w;
      const Vec3 q = closest_point_on_triangle(x, a, b, c, w);
      if ((x - q).norm() < best) {
        best = (x - q).norm();
        side = (x - q).dot((b - a).cross(c - a).normalized());
      }
    }
    EXPECT_GT(side, -1e-9) << x.transpose();
  }
}

}  // namespace

TEST(SurfaceBoundary, AFluidMeetingAFreeBodyInsideItsStepKeepsTheTotalMomentum) {
  // The throw again, the fluid meeting the body's surface inside its substeps and the body taking
  // the impulses after (XPBD or vertex block descent): in one piece after the body's step and in
  // 2 and 4 parts, the sum stays,
  // the water is kept out of the body, and the body takes up the fluid's downward momentum.
  for (Method method : {Method::Xpbd, Method::Vbd})
    for (int parts : {1, 2, 4}) {
      SCOPED_TRACE(std::string(to_string(method)) + ", " + std::to_string(parts) + " parts");
      FluidThrow t(4);
      t.s.method = method;
      const Vec3 p0 = t.momentum();
      const size_t touched =
          t.run_in_parts(parts, [&](double h, int n, bool ends_step) { return t.advance_meeting(h, n, ends_step); });
      EXPECT_GT(touched, 0u);
      Vec3 pb;
      t.momentum(&pb);
      EXPECT_LT(pb.y(), 0.1 * p0.y());
      // No particle inside the body (the light beam moved off: measured against where it is now).
      expect_outside(*t.model, t.body.x, t.fluid->state().x);
    }
}

TEST(SurfaceBoundary, WaterPouredOnABodyFromATapStaysOnIt) {
  // A tap 1 cm over beam1's top (y 1 cm) pours at 1 m/s for half a second, the surface met inside
  // the water's substeps: its particles (the layers it adds during a step included) land and
  // spread on the beam, none inside it or through it.
  const auto model = build_model(*builtin_mesh("beam1"), Material{1e5, 0.4, 1000});
  const BodyState body = rest_state(*model);
  FluidSettings fs;
  fs.spacing = 0.002;
  FluidEmitter tap;
  tap.centre = Vec3(0.06, 0.02, 0.005);
  tap.radius = 0.003;
  tap.speed = 1.0;
  FluidBody water(fs, {}, {tap});
  size_t touching = 0;
  for (int k = 0; k < 30; ++k) {
    SurfaceBoundary surface;
    surface.triangles = model->surface;
    surface.x = body.x;
    surface.v = body.v;
    surface.radius = water.contact_radius();
    touching = water.advance(1.0 / 60, fs.substeps, {}, true, &surface).soft_body_contacts;
  }
  ASSERT_GT(water.size(), 100u);
  EXPECT_GT(touching, 10u);
  expect_outside(*model, body.x, water.state().x);
  // None went through the top to come out below (the beam is 12 x 1 x 1 cm; one within 3 mm of a
  // side may be rounding its edge: 0.14 mm below the top and 1.9 mm beyond the end face in one
  // build).
  for (const Vec3& x : water.state().x)
    if (x.x() > 0.003 && x.x() < 0.117 && x.z() > 0.003 && x.z() < 0.007) {
      EXPECT_GT(x.y(), 0.01) << x.transpose();
    }
}

TEST(SurfaceBoundary, RefusesBadSettingsNamingTheField) {
  const auto model = build_model(*builtin_mesh("beam1"), Material{1e5, 0.4, 1000});
  const BodyState body = rest_state(*model);
  FluidSettings fs;
  fs.spacing = 0.004;
  FluidBody water(fs, {FluidBlock{Vec3(0.01, 0.010, 0.001), Vec3(0.018, 0.014, 0.009)}});
  auto refused = [&](const std::function<void(SurfaceBoundary&)>& spoil, const std::string& field) {
    SurfaceBoundary surface;
    surface.triangles = model->surface;
    surface.x = body.x;
    surface.v = body.v;
    surface.radius = 0.002;
    spoil(surface);
    try {
      water.advance(1.0 / 60, 2, {}, true, &surface);
      ADD_FAILURE() << field << " accepted";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  refused([](SurfaceBoundary& s) { s.radius = 0; }, "radius");
  refused([](SurfaceBoundary& s) { s.friction = NAN; }, "friction");
  refused([&](SurfaceBoundary& s) { s.v = std::span<const Vec3>(body.v).first(3); }, "velocities");
  const std::vector<Triangle> bad{{0, 1, int32_t(body.x.size())}};
  refused([&](SurfaceBoundary& s) { s.triangles = bad; }, "triangle 0");
  EXPECT_EQ(water.state().steps, 0u);  // nothing stepped
}

TEST(SurfaceBoundary, FrictionPullsRestingParticlesToTheSurfacesSpeedAtMuG) {
  // Four particles of water resting on beam1's top (y 1 cm; radius 2 mm) near its end, the surface held in
  // place but moving at 0.2 m/s along x (`v`): Coulomb friction speeds each up at mu g (the
  // weight presses it into the surface by g h^2 a substep) until it moves with the surface; the
  // surface takes exactly the momentum the particles gain along x; without friction they stay.
  const auto model = build_model(*builtin_mesh("beam1"), Material{1e5, 0.4, 1000});
  const BodyState body = rest_state(*model);
  const std::vector<Vec3> moving(body.x.size(), Vec3(0.2, 0, 0));
  for (double mu : {0.0, 0.1, 1.0}) {
    SCOPED_TRACE("friction " + std::to_string(mu));
    FluidSettings fs;
    fs.spacing = 0.004;
    fs.substeps = 2;
    FluidBody water(fs, {FluidBlock{Vec3(0.01, 0.010, 0.001), Vec3(0.018, 0.014, 0.009)}});
    ASSERT_EQ(water.size(), 4u);
    Vec3 given = Vec3::Zero();
    auto mean_vx = [&] {
      double sum = 0;
      for (const Vec3& v : water.state().v) sum += v.x();
      return sum / double(water.size());
    };
    for (int k = 0; k < 20; ++k) {
      SurfaceBoundary surface;
      surface.triangles = model->surface;
      surface.x = body.x;
      surface.v = moving;
      surface.radius = 0.5 * fs.spacing;
      surface.friction = mu;
      EXPECT_EQ(water.advance(1.0 / 60, fs.substeps, {}, true, &surface).soft_body_contacts, 4u);
      for (const Vec3& j : surface.impulse) given += j;
      if (k == 4 && mu == 0.1) {
        EXPECT_NEAR(mean_vx(), 0.1 * 9.81 * 5.0 / 60, 0.03 * 0.0817);
      }
    }
    const double m = water.particle_mass();
    EXPECT_NEAR(given.x(), 4 * m * mean_vx(), 1e-12);  // what the surface gave along x
    if (mu == 0.0) {
      EXPECT_NEAR(mean_vx(), 0.0, 1e-12);
    }
    if (mu == 1.0) {
      EXPECT_NEAR(mean_vx(), 0.2, 1e-6);
    }
    for (const Vec3& x : water.state().x) EXPECT_NEAR(x.y(), 0.012, 1e-6);
  }
}

TEST(SurfaceBoundary, ARopeFallingOnABodyIsStoppedOnItInsideItsStep) {
  // A rope of 1 g falling at 0.5 m/s, gravity off, 1 mm over beam1's top (y 1 cm): its particles
  // meet the surface inside the substeps of its step (not after it), stop on it 2 mm up, and
  // the surface takes exactly the momentum they lost (the body takes minus the impulses).
  const auto model = build_model(*builtin_mesh("beam1"), Material{1e5, 0.4, 1000});
  const BodyState body = rest_state(*model);
  ConstraintBodySettings rs;
  rs.gravity = Vec3::Zero();
  rs.thickness = 0.002;
  auto rope = ConstraintBody::rope({Vec3(0.02, 0.013, 0.005), Vec3(0.10, 0.013, 0.005)}, 10, 0.0125, rs);
  ParticleState st = rope->state();
  for (Vec3& v : st.v) v = Vec3(0, -0.5, 0);
  rope->set_state(st);
  const double mass = rope->total_mass();
  SurfaceBoundary surface;
  surface.triangles = model->surface;
  surface.x = body.x;
  surface.v = body.v;
  surface.radius = rs.thickness;
  rope->advance(1.0 / 60, rs.substeps, {}, true, &surface);
  for (const Vec3& x : rope->state().x) EXPECT_NEAR(x.y(), 0.012, 1e-9) << x.transpose();
  for (const Vec3& v : rope->state().v) EXPECT_NEAR(v.y(), 0.0, 1e-9);
  Vec3 given = Vec3::Zero();
  for (const Vec3& j : surface.impulse) given += j;
  EXPECT_NEAR((given - mass * Vec3(0, 0.5, 0)).norm(), 0.0, 1e-12 * mass) << "the surface gave what the rope lost";
}

TEST(Coupling, LeavesBlownUpParticlesToTheCaller) {
  // A body that blew up this tick (NaN, or far away) is the caller's to roll back: the contact
  // skips those particles and handles the others as ever.
  Touching s = over_the_top(false);
  s.particles.x[1] = Vec3(NAN, 0, 0);
  s.particles.x[2] = Vec3(1e300, -1e300, 1e300);
  s.particles.v[5] = Vec3(INFINITY, 0, 0);
  CouplingSettings cs;
  cs.radius = 0.001;
  const CouplingReport r = couple_particles_to_body(*s.model, s.body, s.particles, s.w, cs, 1.0 / 60);
  EXPECT_GT(r.contacts, 0u);
  EXPECT_TRUE(std::isnan(s.particles.x[1].x()));
  EXPECT_EQ(s.particles.x[2], Vec3(1e300, -1e300, 1e300));
  for (const Vec3& v : s.body.v) EXPECT_TRUE(v.allFinite());
}

namespace {

// 60 particles of 10 g around a 2 cm sphere tool moving at 0.3 m/s along x: some inside it, some
// just outside its grown radius; one pinned particle inside.
struct AroundATool {
  ParticleState particles;
  std::vector<double> w;
  RigidTool tool = RigidTool::sphere(Vec3(0.01, 0.02, 0.0), 0.02);
};

AroundATool around_a_tool() {
  AroundATool s;
  s.tool.velocity = Vec3(0.3, 0.0, 0.0);
  for (int i = 0; i < 60; ++i) {
    const double a = 0.7 * i, b = 0.31 * i;
    const double r = 0.012 + 0.0003 * (i % 40);  // 12 .. 23.7 mm from the centre
    s.particles.x.push_back(s.tool.position + r * Vec3(std::cos(a) * std::sin(b + 0.2), std::cos(b + 0.2), std::sin(a) * std::sin(b + 0.2)));
    s.particles.v.push_back(Vec3(0.05 * std::sin(double(i)), -0.1, 0.02 * std::cos(double(i))));
    s.w.push_back(i == 7 ? 0.0 : 100.0);
  }
  return s;
}

}  // namespace

TEST(ToolCoupling, PushesParticlesOutAndTheToolFeelsMinusTheirMomentum) {
  AroundATool s = around_a_tool();
  const ParticleState before = s.particles;
  const double radius = 0.001, dt = 1.0 / 60;
  ToolReaction r;
  r.force = Vec3(1, 2, 3);  // the tet body's part: the particles' is added to it
  const size_t pushed = couple_particles_to_tool(s.particles, s.w, s.tool, radius, dt, {}, r);
  EXPECT_GT(pushed, 10u);
  Vec3 gained = Vec3::Zero(), angular = Vec3::Zero();
  size_t moved = 0;
  for (size_t i = 0; i < s.w.size(); ++i) {
    if (s.w[i] == 0) {
      EXPECT_EQ(s.particles.x[i], before.x[i]) << "a pinned particle stays";
      EXPECT_EQ(s.particles.v[i], before.v[i]);
      continue;
    }
    EXPECT_GE((s.particles.x[i] - s.tool.position).norm(), s.tool.radius + radius - 1e-12) << "particle " << i;
    const Vec3 dp = (s.particles.v[i] - before.v[i]) / s.w[i];
    // The velocity change is the correction over dt.
    EXPECT_NEAR((s.particles.x[i] - before.x[i] - dt * (s.particles.v[i] - before.v[i])).norm(), 0, 1e-15);
    moved += s.particles.x[i] != before.x[i];
    gained += dp;
    angular += (s.particles.x[i] - s.tool.position).cross(dp);
  }
  EXPECT_EQ(moved, pushed);
  // Newton's third law: what the particles gained, per second of the step, pushes the tool.
  EXPECT_NEAR((r.force - Vec3(1, 2, 3) + gained / dt).norm(), 0, 1e-12 * gained.norm() / dt);
  EXPECT_NEAR((r.torque + angular / dt).norm(), 0, 1e-12 * angular.norm() / dt + 1e-15);
  EXPECT_TRUE(r.contacts.empty());
  // Once out, nothing more.
  ToolReaction again;
  EXPECT_EQ(couple_particles_to_tool(s.particles, s.w, s.tool, radius, dt, {}, again), 0u);
  EXPECT_EQ(again.force, Vec3::Zero());
}

TEST(ToolCoupling, StaticFrictionCarriesATouchingParticleAlongWithTheTool) {
  // A particle 1 mm inside the bottom of a sphere that moved 2 mm along x during the step while
  // the particle stood still: the slip (2 mm) is below mu_s x depth with mu_s 3, so the particle
  // ends on the surface having moved with the tool; with no friction it only moves out.
  for (double mu : {3.0, 0.0}) {
    RigidTool tool = RigidTool::sphere(Vec3(0, 0.019, 0), 0.02);
    tool.static_friction = tool.dynamic_friction = mu;
    const double dt = 0.01;
    tool.velocity = Vec3(0.2, 0, 0);
    ParticleState p;
    p.x = {Vec3(0, 0, 0)};
    p.v = {Vec3::Zero()};
    const std::vector<double> w = {1.0};
    ToolReaction r;
    ASSERT_EQ(couple_particles_to_tool(p, w, tool, 0.0, dt, std::vector<Vec3>{Vec3(0, 0, 0)}, r), 1u);
    EXPECT_NEAR(p.x[0].y(), -0.001, 1e-12);
    EXPECT_NEAR(p.x[0].x(), mu > 0 ? 0.002 : 0.0, 1e-12) << "mu " << mu;
    EXPECT_NEAR(r.force.x(), mu > 0 ? -0.002 / dt / dt : 0.0, 1e-9);
  }
}

TEST(ToolCoupling, RefusesMismatchedSizesAndBadRadiusOrStep) {
  AroundATool s = around_a_tool();
  ToolReaction r;
  EXPECT_THROW(couple_particles_to_tool(s.particles, s.w, s.tool, -1.0, 0.01, {}, r), std::invalid_argument);
  EXPECT_THROW(couple_particles_to_tool(s.particles, s.w, s.tool, 0.0, 0.0, {}, r), std::invalid_argument);
  EXPECT_THROW(couple_particles_to_tool(s.particles, s.w, s.tool, 0.0, 0.01, std::vector<Vec3>(3), r),
               std::invalid_argument);
  s.w.pop_back();
  EXPECT_THROW(couple_particles_to_tool(s.particles, s.w, s.tool, 0.0, 0.01, {}, r), std::invalid_argument);
}

namespace {

// Signed distance of p from the closest of the cloth's triangles, positive on the side of `up`.
double above_cloth(const ParticleState& cloth, std::span<const std::array<uint32_t, 3>> triangles, const Vec3& p,
                   const Vec3& up) {
  double best = INFINITY, signed_d = 0;
  for (const auto& t : triangles) {
    std::array<double, 3> b;
    const Vec3 q = closest_point_on_triangle(p, cloth.x[t[0]], cloth.x[t[1]], cloth.x[t[2]], b);
    const double d = (p - q).norm();
    if (d < best) {
      best = d;
      signed_d = (p - q).dot(up) >= 0 ? d : -d;
    }
  }
  return signed_d;
}

// A free, flat 0.4 m cloth (8 x 8, 0.5 g particles) at y = 0 that moved up 2 mm over the step.
struct FlatCloth {
  std::unique_ptr<ConstraintBody> body;
  ParticleState state;
  std::vector<Vec3> start;
  std::vector<double> w;
};

FlatCloth flat_cloth() {
  ClothGridSpec g;
  g.nx = g.ny = 8;
  g.size_x = g.size_y = 0.4;
  g.origin = Vec3(-0.2, 0.0, -0.2);
  FlatCloth c;
  c.body = ConstraintBody::cloth_grid(g, ConstraintBodySettings{});
  c.state = c.body->state();
  c.start = c.state.x;
  for (size_t i = 0; i < c.state.x.size(); ++i) {
    c.state.x[i].y() += 0.002;
    c.state.v[i] = Vec3(0, 0.12, 0);
  }
  c.w.assign(c.body->inverse_masses().begin(), c.body->inverse_masses().end());
  return c;
}

}  // namespace

TEST(ClothContact, KeepsParticlesOnTheirSideAndConservesMomentum) {
  // 10 g particles over the cloth's interior that ended: through it from above or from below,
  // within the contact radius of either side, or clear.
  FlatCloth cloth = flat_cloth();
  const double radius = 0.005, dt = 1.0 / 60;
  ParticleState ps;
  std::vector<Vec3> start;
  std::vector<double> from;  // +1: started above, -1: below
  const double ends[][2] = {{0.02, -0.01}, {0.02, 0.004}, {-0.02, -0.001}, {-0.02, 0.015}, {0.05, 0.03}};
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      const auto& e = ends[(i + 2 * j) % 5];
      const Vec3 xz(-0.15 + 0.1 * i + 0.013 * j, 0, -0.15 + 0.1 * j + 0.007 * i);
      start.push_back(xz + Vec3(0, e[0], 0));
      ps.x.push_back(xz + Vec3(0.003, e[1], -0.002));
      ps.v.push_back((ps.x.back() - start.back()) / dt);
      from.push_back(e[0] > 0 ? 1 : -1);
    }
  const std::vector<double> wp(ps.x.size(), 100.0);
  auto momentum = [&](const ParticleState& c) {
    Vec3 m = Vec3::Zero();
    for (size_t i = 0; i < c.v.size(); ++i) m += c.v[i] / cloth.w[i];
    return m;
  };
  const Vec3 cloth_before = momentum(cloth.state);
  Vec3 p0 = cloth_before;
  for (size_t i = 0; i < ps.v.size(); ++i) p0 += ps.v[i] / wp[i];
  const std::vector<Vec3> cloth_x = cloth.state.x;
  CouplingSettings set;
  set.radius = radius;
  const CouplingReport rep = couple_particles_to_cloth(ps, wp, start, cloth.state, cloth.w, cloth.body->triangles(),
                                                       cloth.start, set, dt);
  EXPECT_EQ(rep.contacts, 13u);  // all but the clear ones
  EXPECT_GT(rep.max_depth, 0.01);  // a crossing particle was deep on the wrong side
  EXPECT_EQ(cloth.state.x, cloth_x) << "the cloth takes momentum, not a position correction";
  Vec3 p1 = momentum(cloth.state);
  for (size_t i = 0; i < ps.v.size(); ++i) p1 += ps.v[i] / wp[i];
  EXPECT_NEAR((p1 - p0).norm(), 0, 1e-12 * p0.norm());
  EXPECT_NEAR((rep.force_on_body * dt - (momentum(cloth.state) - cloth_before)).norm(), 0, 1e-12 * p0.norm());
  for (size_t p = 0; p < ps.x.size(); ++p)
    EXPECT_GT(from[p] * above_cloth(cloth.state, cloth.body->triangles(), ps.x[p], Vec3(0, 1, 0)), radius - 1e-12)
        << "particle " << p << " started " << (from[p] > 0 ? "above" : "below") << ", ends at " << ps.x[p].transpose();
}

TEST(ClothContact, AClothSpringingBackPastAParticleStillHoldsIt) {
  // The particle barely moved (1 mm down) while the cloth under it sprang up 3 cm past it: on
  // neither the cloth's start nor its end does the particle's path cross a triangle, yet it is
  // behind the cloth by the two's relative motion; it goes back on top.
  FlatCloth cloth = flat_cloth();
  for (size_t i = 0; i < cloth.start.size(); ++i) cloth.start[i].y() = cloth.state.x[i].y() - 0.03;
  ParticleState ps;
  ps.x = {Vec3(0.01, -0.011, 0.02)};
  ps.v = {Vec3(0, -0.06, 0)};
  const std::vector<Vec3> start = {Vec3(0.01, -0.01, 0.02)};
  const std::vector<double> wp = {100.0};
  Vec3 momentum_before = ps.v[0] / wp[0];
  for (size_t i = 0; i < cloth.state.v.size(); ++i) momentum_before += cloth.state.v[i] / cloth.w[i];
  CouplingSettings set;
  set.radius = 0.004;
  const auto rep = couple_particles_to_cloth(ps, wp, start, cloth.state, cloth.w, cloth.body->triangles(), cloth.start,
                                             set, 1.0 / 60);
  EXPECT_EQ(rep.contacts, 1u);
  EXPECT_NEAR(ps.x[0].y(), 0.002 + 0.004, 1e-12);
  // Inelastic: the 10 g particle slows the light cloth's rise and is slowed less than it (it
  // keeps moving down), and the momentum is the same before and after.
  Vec3 after = ps.v[0] / wp[0];
  for (size_t i = 0; i < cloth.state.v.size(); ++i) after += cloth.state.v[i] / cloth.w[i];
  EXPECT_NEAR((after - momentum_before).norm(), 0, 1e-12 * momentum_before.norm());
  EXPECT_LT(ps.v[0].y(), 0) << "the heavy particle stops the light cloth's rise rather than the reverse";
  EXPECT_GT(ps.v[0].y(), -0.06);
}

TEST(ClothContact, PinnedCornersTakeThePushAndBadInputsAreRefused) {
  FlatCloth cloth = flat_cloth();
  std::fill(cloth.w.begin(), cloth.w.end(), 0.0);
  std::fill(cloth.state.v.begin(), cloth.state.v.end(), Vec3::Zero());
  const ParticleState before = cloth.state;
  ParticleState ps;
  ps.x = {Vec3(0.01, -0.02, 0.01)};
  ps.v = {Vec3(0, -3, 0)};
  const std::vector<Vec3> start = {Vec3(0.01, 0.03, 0.01)};
  const std::vector<double> wp = {50.0};  // 20 g
  CouplingSettings set;
  set.radius = 0.002;
  const double dt = 0.01;
  const auto rep = couple_particles_to_cloth(ps, wp, start, cloth.state, cloth.w, cloth.body->triangles(), cloth.start,
                                             set, dt);
  EXPECT_EQ(rep.contacts, 1u);
  EXPECT_NEAR(ps.x[0].y(), 0.004, 1e-12);
  EXPECT_EQ(cloth.state.v, before.v);
  EXPECT_NEAR(ps.v[0].y(), 0.0, 1e-12) << "stopped on the pinned cloth";
  // Its 3 m/s x 20 g went into the cloth, whose pins take it all.
  EXPECT_NEAR(rep.force_on_body.y(), -0.06 / dt, 1e-9);
  set.radius = 0;
  EXPECT_THROW(couple_particles_to_cloth(ps, wp, start, cloth.state, cloth.w, cloth.body->triangles(), cloth.start, set, dt),
               std::invalid_argument);
  set.radius = 0.002;
  EXPECT_THROW(couple_particles_to_cloth(ps, wp, {}, cloth.state, cloth.w, cloth.body->triangles(), cloth.start, set, dt),
               std::invalid_argument);
  const std::array<uint32_t, 3> bad{0, 1, 99};
  EXPECT_THROW(couple_particles_to_cloth(ps, wp, start, cloth.state, cloth.w, std::span(&bad, 1), cloth.start, set, dt),
               std::invalid_argument);
}

TEST(RopeContact, ParticlesCrossingARopeGoBackToTheirSideWithMomentumExact) {
  // A rope of 10 segments along x (10 g beads), still; 5 g particles fall 3.5 cm in the step:
  // those within the contact radius of its axis in z cross a segment (from above to below it),
  // those further out pass beside it. The crossers end above the rope at the radius, the others
  // are untouched, and the momentum of the two bodies is unchanged.
  ParticleState rope;
  for (int i = 0; i <= 10; ++i) {
    rope.x.emplace_back(0.05 * i, 0, 0);
    rope.v.emplace_back(0, 0, 0);
  }
  const std::vector<Vec3> rope_start = rope.x;
  std::vector<double> wr(rope.x.size(), 100.0);
  ParticleState ps;
  std::vector<Vec3> start;
  const double zs[] = {0.0, 0.004, -0.003, 0.02};
  for (int i = 0; i < 8; ++i)
    for (double z : zs) {
      start.emplace_back(0.03 + 0.06 * i, 0.02, z);
      ps.x.emplace_back(0.03 + 0.06 * i + 0.002, -0.015, z);
      ps.v.push_back((ps.x.back() - start.back()) * 60.0);
    }
  const std::vector<double> wp(ps.x.size(), 200.0);
  auto momentum = [&] {
    Vec3 m = Vec3::Zero();
    for (size_t i = 0; i < ps.v.size(); ++i) m += ps.v[i] / wp[i];
    for (size_t i = 0; i < rope.v.size(); ++i) m += rope.v[i] / wr[i];
    return m;
  };
  const Vec3 p0 = momentum();
  const ParticleState before = ps;
  CouplingSettings set;
  set.radius = 0.006;
  const CouplingReport rep = couple_particles_to_rope(ps, wp, start, rope, wr, rope_start, set, 1.0 / 60);
  EXPECT_EQ(rep.contacts, 24u);  // 8 x the three within 6 mm of the axis
  auto distance = [&](const Vec3& p) {
    double best = INFINITY;
    for (size_t k = 0; k + 1 < rope.x.size(); ++k) {
      const Vec3 d = rope.x[k + 1] - rope.x[k];
      const double s = std::clamp((p - rope.x[k]).dot(d) / d.squaredNorm(), 0.0, 1.0);
      best = std::min(best, (p - (rope.x[k] + s * d)).norm());
    }
    return best;
  };
  for (size_t i = 0; i < ps.x.size(); ++i) {
    if (std::abs(before.x[i].z()) >= set.radius) {
      EXPECT_EQ(ps.x[i], before.x[i]) << "particle " << i << " passes beside the rope";
      EXPECT_EQ(ps.v[i], before.v[i]);
      continue;
    }
    EXPECT_GT(ps.x[i].y(), 0) << "particle " << i << " stays above the rope";
    EXPECT_GT(distance(ps.x[i]), set.radius - 1e-12) << "particle " << i;
    EXPECT_GT(ps.v[i].y(), before.v[i].y()) << "particle " << i << " is slowed";
  }
  const Vec3 p1 = momentum();
  EXPECT_NEAR((p1 - p0).norm(), 0, 1e-12 * p0.norm()) << (p1 - p0).transpose();
  EXPECT_LT(rope.v[5].y(), 0) << "the rope is pushed down";
  EXPECT_NEAR((rep.force_on_body / 60.0 - [&] {
                Vec3 m = Vec3::Zero();
                for (size_t i = 0; i < rope.v.size(); ++i) m += rope.v[i] / wr[i];
                return m;
              }()).norm(), 0, 1e-12 * p0.norm());
}

TEST(RopeContact, APinnedRopeHoldsATouchingParticleAndBadInputsAreRefused) {
  // Both ends pinned: a particle resting 2 mm above the middle of the one segment, sinking at
  // 0.1 m/s, goes up to the radius and stops; the rope does not move.
  ParticleState rope;
  rope.x = {Vec3(0, 0, 0), Vec3(0.1, 0, 0)};
  rope.v = {Vec3::Zero(), Vec3::Zero()};
  const std::vector<Vec3> rope_start = rope.x;
  const std::vector<double> wr{0.0, 0.0};
  ParticleState ps;
  ps.x = {Vec3(0.05, 0.002, 0)};
  ps.v = {Vec3(0.02, -0.1, 0)};
  const std::vector<Vec3> start{Vec3(0.05, 0.004, 0)};
  const std::vector<double> wp{100.0};
  CouplingSettings set;
  set.radius = 0.005;
  set.friction = 0.0;
  const CouplingReport rep = couple_particles_to_rope(ps, wp, start, rope, wr, rope_start, set, 1.0 / 60);
  EXPECT_EQ(rep.contacts, 1u);
  EXPECT_NEAR(ps.x[0].y(), 0.005, 1e-12);
  EXPECT_NEAR(ps.v[0].y(), 0.0, 1e-12);
  EXPECT_NEAR(ps.v[0].x(), 0.02, 1e-12);  // no friction: it slides on
  EXPECT_EQ(rope.v[0], Vec3::Zero());
  EXPECT_EQ(rope.x[1], Vec3(0.1, 0, 0));
  EXPECT_LT(rep.force_on_body.y(), 0);
  set.radius = 0;
  EXPECT_THROW(couple_particles_to_rope(ps, wp, start, rope, wr, rope_start, set, 1.0 / 60), std::invalid_argument);
  set.radius = 0.005;
  const std::vector<Vec3> short_start;
  EXPECT_THROW(couple_particles_to_rope(ps, wp, short_start, rope, wr, rope_start, set, 1.0 / 60),
               std::invalid_argument);
}

// A link of two 10 g beads (inverse mass 100) that moved from `from` to `to` in a 60 Hz step.
struct Link {
  ParticleState ps;
  std::vector<Vec3> start;
  std::vector<double> w{100.0, 100.0};
  std::vector<std::array<uint32_t, 2>> segments{{0, 1}};
  Link(const std::array<Vec3, 2>& from, const std::array<Vec3, 2>& to) {
    start = {from[0], from[1]};
    ps.x = {to[0], to[1]};
    ps.v = {(to[0] - from[0]) * 60.0, (to[1] - from[1]) * 60.0};
  }
  Vec3 momentum() const { return ps.v[0] / w[0] + ps.v[1] / w[1]; }
};

// A link along z, 10 cm long, falling 3.5 cm in the step across x = x0: its beads pass 5 cm
// either side of whatever it crosses at its middle, farther than any contact radius here, so
// only the points along the link can see that.
Link falling_link(double x0) {
  return Link({Vec3(x0, 0.02, -0.05), Vec3(x0, 0.02, 0.05)},
              {Vec3(x0 + 0.002, -0.015, -0.05), Vec3(x0 + 0.002, -0.015, 0.05)});
}

// A still strip of cloth 20 cm along x and 2 x half_width wide (two triangles, corners of 5 g)
// at y = 0, as the contact sees it: its state, where it started, triangles and inverse masses.
struct Strip {
  ParticleState state;
  std::vector<Vec3> start;
  std::vector<std::array<uint32_t, 3>> triangles{{0, 1, 2}, {1, 3, 2}};
  std::vector<double> w = std::vector<double>(4, 200.0);
  explicit Strip(double half_width) {
    state.x = {Vec3(0, 0, -half_width), Vec3(0.2, 0, -half_width), Vec3(0, 0, half_width), Vec3(0.2, 0, half_width)};
    state.v.assign(4, Vec3::Zero());
    start = state.x;
  }
};

TEST(RopeContact, ALinkCrossingARopeBetweenTheirBeadsIsHeldAlongItsLengthWithMomentumExact) {
  // A free rope of one 10 cm link along x (beads of 10 g), still; the falling link crosses its
  // middle. Bead against link finds nothing; with the falling body's segments the link's inside
  // points go back above the rope: the two links end no closer than the points' spacing allows
  // (points at most a radius apart: sqrt(3)/2 of the radius for links crossing square), and the
  // momentum of the two bodies is unchanged.
  const double radius = 0.006, dt = 1.0 / 60;
  auto fresh_rope = [] {
    ParticleState rope;
    rope.x = {Vec3(0, 0, 0), Vec3(0.1, 0, 0)};
    rope.v = {Vec3::Zero(), Vec3::Zero()};
    return rope;
  };
  const std::vector<double> wr{100.0, 100.0};
  CouplingSettings set;
  set.radius = radius;
  {
    ParticleState rope = fresh_rope();
    const std::vector<Vec3> rope_start = rope.x;
    Link link = falling_link(0.05);
    const ParticleState before = link.ps;
    const CouplingReport rep = couple_particles_to_rope(link.ps, link.w, link.start, rope, wr, rope_start, set, dt);
    EXPECT_EQ(rep.contacts + rep.segment_contacts, 0u) << "the beads alone pass beside the rope";
    EXPECT_EQ(link.ps.x, before.x);
  }
  ParticleState rope = fresh_rope();
  const std::vector<Vec3> rope_start = rope.x;
  Link link = falling_link(0.05);
  const Vec3 p0 = link.momentum();
  const CouplingReport rep =
      couple_particles_to_rope(link.ps, link.w, link.start, rope, wr, rope_start, set, dt, link.segments);
  EXPECT_EQ(rep.contacts, 0u);
  EXPECT_GT(rep.segment_contacts, 0u);
  EXPECT_GT(rep.max_depth, 0.01) << "the link had crossed to the far side";
  EXPECT_GT(link.ps.x[0].y() + link.ps.x[1].y(), 0) << "the link stays above the rope";
  EXPECT_GT(test::segment_distance(link.ps.x[0], link.ps.x[1], rope.x[0], rope.x[1]), std::sqrt(3.0) / 2 * radius - 1e-12);
  EXPECT_GE((link.ps.v[0] + link.ps.v[1]).y(), (rope.v[0] + rope.v[1]).y() - 1e-12)
      << "the link no longer falls onto the rope's middle";
  const Vec3 rope_momentum = rope.v[0] / wr[0] + rope.v[1] / wr[1];
  EXPECT_LT(rope_momentum.y(), 0) << "the rope is pushed down";
  EXPECT_NEAR((link.momentum() + rope_momentum - p0).norm(), 0, 1e-12 * p0.norm());
  EXPECT_NEAR((rep.force_on_body * dt - rope_momentum).norm(), 0, 1e-12 * p0.norm());
  const std::vector<std::array<uint32_t, 2>> bad{{0, 2}};
  EXPECT_THROW(couple_particles_to_rope(link.ps, link.w, link.start, rope, wr, rope_start, set, dt, bad),
               std::invalid_argument);
}

TEST(ClothContact, ALinkFallingAcrossAClothStripBetweenItsBeadsStaysOnItsSide) {
  // A free strip of cloth 20 cm along x and 2 cm wide (two triangles, corners of 5 g), still;
  // the falling link crosses it at x = 0.1 with its beads 4 cm beyond either long edge. With the
  // link's segments its points over the strip end above it at the radius or more, both beads
  // with them, and the momentum is unchanged; without them the link falls through.
  const double radius = 0.006, dt = 1.0 / 60;
  CouplingSettings set;
  set.radius = radius;
  {
    Strip free(0.01);
    Link link = falling_link(0.1);
    const CouplingReport rep = couple_particles_to_cloth(link.ps, link.w, link.start, free.state, free.w,
                                                         free.triangles, free.start, set, dt);
    EXPECT_EQ(rep.contacts + rep.segment_contacts, 0u);
    EXPECT_LT(link.ps.x[0].y(), 0) << "without its segments the link falls through the strip";
  }
  Strip cloth(0.01);
  ParticleState& strip = cloth.state;
  const std::vector<double>& wc = cloth.w;
  Link link = falling_link(0.1);
  Vec3 p0 = link.momentum();
  const CouplingReport rep = couple_particles_to_cloth(link.ps, link.w, link.start, strip, wc, cloth.triangles,
                                                       cloth.start, set, dt, link.segments);
  EXPECT_EQ(rep.contacts, 0u);
  EXPECT_GT(rep.segment_contacts, 0u);
  EXPECT_EQ(strip.x, cloth.start) << "the cloth takes momentum, not a position correction";
  for (int k = 0; k <= 100; ++k) {
    const Vec3 p = link.ps.x[0] + (link.ps.x[1] - link.ps.x[0]) * (k / 100.0);
    if (std::abs(p.z()) <= 0.01) {
      EXPECT_GT(p.y(), std::sqrt(3.0) / 2 * radius - 1e-12) << "at z = " << p.z();
    }
  }
  EXPECT_GT(link.ps.x[0].y(), 0);
  EXPECT_GT(link.ps.x[1].y(), 0);
  Vec3 cloth_momentum = Vec3::Zero();
  for (size_t i = 0; i < strip.v.size(); ++i) cloth_momentum += strip.v[i] / wc[i];
  EXPECT_LT(cloth_momentum.y(), 0) << "the strip is pushed down";
  EXPECT_NEAR((link.momentum() + cloth_momentum - p0).norm(), 0, 1e-12 * p0.norm());
  EXPECT_NEAR((rep.force_on_body * dt - cloth_momentum).norm(), 0, 1e-12 * p0.norm());
}

TEST(ClothContact, ALinkThreadedThroughTheClothIsLeftToItsParticles) {
  // A still link through the middle of a still strip, its beads 2 cm above and below it (out of
  // the radius): threaded through the cloth, as a rope sewn through a drape. Its points near the
  // crossing are within the radius of the strip on both sides; pushing them out would drag the
  // beads, each on its own side, towards the cloth every tick. They are left alone.
  Strip strip(0.01);
  const std::array<Vec3, 2> still{Vec3(0.05, 0.02, 0), Vec3(0.15, -0.02, 0)};
  Link link(still, still);
  CouplingSettings set;
  set.radius = 0.006;
  const CouplingReport rep = couple_particles_to_cloth(link.ps, link.w, link.start, strip.state, strip.w,
                                                       strip.triangles, strip.start, set, 1.0 / 60, link.segments);
  EXPECT_EQ(rep.contacts + rep.segment_contacts, 0u);
  EXPECT_EQ(link.ps.x, link.start);
  EXPECT_EQ(strip.state.v[0], Vec3::Zero());
}

TEST(ClothContact, ALinkWhoseParticleTouchesIsLeftToItsParticles) {
  // A link settling onto the strip across its width: one bead over the strip, 4 mm above it
  // (inside the 6 mm radius), the other 4 cm beyond its edge, the link's middle over the strip.
  // The bead's own contact holds it; the link's points are not pushed as well (where a rope
  // lies in a crumpled cloth that pushed its beads back into triangles their contacts had just
  // cleared).
  Strip strip(0.02);
  Link link({Vec3(0.1, 0.006, -0.01), Vec3(0.1, 0.006, 0.06)}, {Vec3(0.1, 0.004, -0.01), Vec3(0.1, 0.004, 0.06)});
  CouplingSettings set;
  set.radius = 0.006;
  const CouplingReport rep = couple_particles_to_cloth(link.ps, link.w, link.start, strip.state, strip.w,
                                                       strip.triangles, strip.start, set, 1.0 / 60, link.segments);
  EXPECT_EQ(rep.contacts, 1u);
  EXPECT_EQ(rep.segment_contacts, 0u);
  EXPECT_NEAR(link.ps.x[0].y(), 0.006, 1e-12);
  EXPECT_EQ(link.ps.x[1], Vec3(0.1, 0.004, 0.06));
}

TEST(ClothContact, ALinkANarrowFastStripSweptThroughIsNotThrownFartherThanItsLength) {
  // A still link of 12 mm, 20 degrees off the vertical, and a strip 8 mm wide sweeping up 6 cm
  // and sideways 20 cm in the step: it passes under the link's middle points as it crosses their
  // height, but beside either bead when it crosses theirs. Those points end 3.5 cm behind the
  // strip; across the steep link that is 11 cm (depth / sin 20 degrees), nine times the link's
  // length, and the link was thrown that far. Such points are left to the beads: neither moves,
  // and momentum stays exact.
  Strip strip(0.004);
  const Vec3 sweep(0, 0.06, 0.2);
  for (size_t k = 0; k < 4; ++k) {
    strip.start[k] = strip.state.x[k] + Vec3(0, -0.06, -0.1);
    strip.state.x[k] = strip.start[k] + sweep;
    strip.state.v[k] = sweep * 60.0;
  }
  const double length = 0.012;
  const Vec3 top(0.1, -0.029, -0.0167);
  const Vec3 bottom = top + length * Vec3(std::sin(0.35), -std::cos(0.35), 0);
  Link link({top, bottom}, {top, bottom});
  CouplingSettings set;
  set.radius = 0.002;
  Vec3 before = link.momentum();
  for (size_t k = 0; k < 4; ++k) before += strip.state.v[k] / strip.w[k];
  const CouplingReport rep = couple_particles_to_cloth(link.ps, link.w, link.start, strip.state, strip.w,
                                                       strip.triangles, strip.start, set, 1.0 / 60, link.segments);
  EXPECT_EQ(rep.contacts, 0u);
  EXPECT_EQ(rep.segment_contacts, 0u);
  EXPECT_EQ(link.ps.x[0], top);
  EXPECT_EQ(link.ps.x[1], bottom);
  Vec3 after = link.momentum();
  for (size_t k = 0; k < 4; ++k) after += strip.state.v[k] / strip.w[k];
  EXPECT_LT((after - before).norm(), 1e-12 * before.norm());
}

TEST(ClothContact, ATriangleSweptFromFarAwayDoesNotStallTheSearch) {
  // One corner of a strip starts the step 10,000 km away (a body that jumped; finite): its
  // triangle's swept box would span about 1e17 cells of the contact's size. The search grows its
  // cells instead (at most 64 entries a triangle), and a particle falling through the strip's
  // other triangle is still held.
  Strip strip(0.01);
  strip.start[0] = Vec3(1e7, 1e7, 1e7);
  ParticleState ps;
  ps.x = {Vec3(0.15, -0.01, 0.005)};
  ps.v = {Vec3(0, -1.2, 0)};
  const std::vector<Vec3> start{Vec3(0.15, 0.01, 0.005)};
  const std::vector<double> wp{100.0};
  CouplingSettings set;
  set.radius = 0.005;
  const CouplingReport rep =
      couple_particles_to_cloth(ps, wp, start, strip.state, strip.w, strip.triangles, strip.start, set, 1.0 / 60);
  EXPECT_EQ(rep.contacts, 1u);
  EXPECT_NEAR(ps.x[0].y(), 0.005, 1e-12);
}

TEST(ObstacleContact, ASaggingBodyRestsOnADrapeAndPushesItWithItsWeight) {
  // The families that project the contact (newton's penalty contact: test_newton_family.cpp).
  for (Method method : {Method::Xpbd, Method::Vbd}) test::expect_rests_on_the_drape(method);
  // Without the drape the same beam sags through where it was.
  const auto model = test::soft_clamped_beam(*builtin_mesh("beam1"));
  BodyState free = rest_state(*model);
  SolverSettings s;
  s.damping_coefficient = 5;
  Stepper plain;
  for (int k = 0; k < 90; ++k) plain.step(*model, free, s, {});
  double free_lowest = INFINITY;
  for (const Vec3& x : free.x) free_lowest = std::min(free_lowest, x.y());
  EXPECT_LT(free_lowest, -0.025);
}

// beam1 (0.115 x 0.01 x 0.01 m from the origin), free and without gravity, at `speed` (m/s, along
// y) towards the drape of drape_under_the_beam at height y: the beam after `ticks` ticks of
// `substeps` x 1, and the impulses the drape took.
struct DrapeMeeting {
  Vec3 momentum = Vec3::Zero(), impulse = Vec3::Zero();
  std::vector<Vec3> x;
};
DrapeMeeting meet_drape(const BodyModel& model, double y, const std::vector<double>& corner_w, Method method,
                        double speed, int substeps, int ticks) {
  TriangleObstacle drape = test::drape_under_the_beam();
  for (Vec3& c : drape.x) c.y() = y;
  drape.inverse_mass = corner_w;
  BodyState state = rest_state(model);
  for (Vec3& v : state.v) v = Vec3(0, speed, 0);
  SolverSettings s;
  s.method = method;
  s.gravity = Vec3::Zero();
  s.damping_coefficient = 0;
  s.substeps = substeps;
  s.iterations = 1;
  StepInputs in;
  in.obstacles.push_back(drape);
  Stepper stepper;
  DrapeMeeting out;
  for (int k = 0; k < ticks; ++k) {
    const StepReport rep = stepper.step(model, state, s, in);
    for (const Vec3& j : rep.obstacle_impulses.at(0)) out.impulse += j;
  }
  for (size_t v = 0; v < state.v.size(); ++v) out.momentum += state.v[v] / model.inv_mass[v];
  out.x = state.x;
  return out;
}

TEST(ObstacleContact, AVertexMakesItsShareOfTheMoveByTheInverseMassesAndTheMomentumIsExchanged) {
  // With the corners' inverse masses a contact is shared by the two bodies: a vertex 1 mm inside
  // the radius of a drape of 1 mg corners (inverse mass 1e6 /kg) moves w_v / (w_v + w_t) of the
  // 1 mm a fixed drape asks, w_t = sum b_k^2 w_k between a third of 1e6 and 1e6 (b: the contact
  // point's barycentric weights); the drape takes the momentum of that move, so the beam and the drape exchange it
  // exactly (xpbd, whose constraints conserve it); pinned corners (inverse mass 0) are the fixed
  // drape to the last bit.
  const auto model = build_model(*builtin_mesh("beam1"), Material{1e5, 0.4, 1000}, FixedSelection{});
  const std::vector<double> light(4, 1e6), pinned(4, 0.0), fixed;
  for (Method method : {Method::Xpbd, Method::Vbd}) {
    SCOPED_TRACE(std::string(to_string(method)));
    const DrapeMeeting a = meet_drape(*model, -0.003, fixed, method, 0.0, 1, 1);
    const DrapeMeeting b = meet_drape(*model, -0.003, light, method, 0.0, 1, 1);
    int bottom = 0;
    for (size_t v = 0; v < model->vertex_count(); ++v) {
      if (model->rest_positions[v].y() != 0) continue;
      ++bottom;
      const double wv = model->inv_mass[v];
      ASSERT_NEAR(a.x[v].y(), 0.001, 1e-9) << "vertex " << v << ": out to the radius of the fixed drape";
      const double share = b.x[v].y() / a.x[v].y();
      EXPECT_GE(share, wv / (wv + 1e6) * (1 - 1e-9)) << "vertex " << v;
      EXPECT_LE(share, wv / (wv + 1e6 / 3) * (1 + 1e-9)) << "vertex " << v;
    }
    EXPECT_GT(bottom, 10);
    EXPECT_EQ(meet_drape(*model, -0.003, pinned, method, 0.0, 1, 1).x, a.x);
  }
  // Falling at 0.5 m/s onto it, 64 x 1: what the beam loses the drape takes, fixed or light
  // (vbd through its translation step: its one vertex sweep a substep does not sum to the
  // momentum by itself).
  double mass = 0;
  for (double w : model->inv_mass) mass += 1 / w;
  for (Method method : {Method::Xpbd, Method::Vbd})
    for (const std::vector<double>* w : {&fixed, &light}) {
      SCOPED_TRACE(std::string(to_string(method)) + (w == &fixed ? ", fixed drape" : ", light drape"));
      const DrapeMeeting f = meet_drape(*model, -0.006, *w, method, -0.5, 64, 2);
      EXPECT_LT(f.impulse.y(), -0.1 * 0.5 * mass) << "the drape is pushed down, N s";
      EXPECT_NEAR(f.momentum.y() + f.impulse.y(), -0.5 * mass, 1e-12 * mass) << "N s";
      EXPECT_NEAR(f.momentum.x() + f.impulse.x(), 0, 1e-12 * mass);
      EXPECT_NEAR(f.momentum.z() + f.impulse.z(), 0, 1e-12 * mass);
    }
}

TEST(ObstacleContact, BadObstaclesAreRefused) {
  TetMesh mesh = *builtin_mesh("beam1");
  const auto model = build_model(mesh, Material{1e5, 0.4, 1000}, FixedSelection{});
  BodyState state = rest_state(*model);
  StepInputs in;
  in.obstacles.push_back(test::drape_under_the_beam());
  in.obstacles[0].radius = 0;
  Stepper stepper;
  try {
    stepper.step(*model, state, SolverSettings{}, in);
    ADD_FAILURE() << "no throw for a zero radius";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("obstacles[0].radius"), std::string::npos) << e.what();
  }
  in.obstacles[0] = test::drape_under_the_beam();
  in.obstacles[0].triangles.push_back({0, 1, 9});
  EXPECT_THROW(stepper.step(*model, state, SolverSettings{}, in), std::invalid_argument);
  for (const std::vector<double>& w : {std::vector<double>(3, 1.0), std::vector<double>{1, 1, -1, 1},
                                       std::vector<double>{1, 1, 1, NAN}}) {
    in.obstacles[0] = test::drape_under_the_beam();
    in.obstacles[0].inverse_mass = w;
    try {
      stepper.step(*model, state, SolverSettings{}, in);
      ADD_FAILURE() << "no throw for inverse masses of " << w.size() << " corners";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("obstacles[0].inverse_mass"), std::string::npos) << e.what();
    }
  }
}

// The pair stepped as a scene steps it: in the shared parts, or in a count given that divides
// both bodies' substeps; another count is refused, naming it.
TEST(ClothContact, AStepWithTheContactInPartsRefusesPartsThatDoNotDivideTheSubsteps) {
  ClothGridSpec g;
  g.nx = g.ny = 4;
  auto cloth = ConstraintBody::cloth_grid(g, ConstraintBodySettings{});  // 16 substeps
  FluidSettings fs;
  fs.spacing = 0.02;  // 2 substeps
  FluidBody water(fs, {FluidBlock{Vec3(-0.02, 0.1, -0.02), Vec3(0.02, 0.14, 0.02), Vec3::Zero()}});
  CouplingSettings contact;
  contact.radius = water.contact_radius() + cloth->contact_radius();
  EXPECT_NO_THROW(step_with_cloth_contact(water, *cloth, contact, 1.0 / 60, {}));
  EXPECT_NO_THROW(step_with_cloth_contact(water, *cloth, contact, 1.0 / 60, {}, 1));
  try {
    step_with_cloth_contact(water, *cloth, contact, 1.0 / 60, {}, 4);
    ADD_FAILURE() << "4 parts of 2 substeps accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("parts 4"), std::string::npos) << e.what();
  }
  EXPECT_EQ(water.state().steps, 2u);
  EXPECT_EQ(cloth->state().steps, 2u);
}

TEST(TriangleGrid, ASegmentGetsEachTriangleOfItsCellsOnceInTheOrderOfItsFirstCell) {
  // beam3's surface, shaken and swept from its rest shape (boxes over several cells), and paths
  // of every length over it: near_segment gives the triangles of the cells its box touches, in
  // the walk's order (x outermost, z innermost), each at its first cell only. The reference walks
  // the same cells through near() at their centres and keeps each triangle's first appearance.
  auto model = build_model(*builtin_mesh("beam3"), Material{1e6, 0.4, 1000});
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> shake(-1.5e-3, 1.5e-3), u(0, 1);
  std::vector<Vec3> x = model->rest_positions;
  for (Vec3& p : x) p += Vec3(shake(rng), shake(rng), shake(rng));
  const detail::TriangleGrid grid(model->surface, std::span<const Vec3>(x), 0.001,
                                  std::span<const Vec3>(model->rest_positions));
  const double cell = grid.cell_size();
  const Vec3 lo(-0.005, -0.005, -0.005), hi(0.105, 0.015, 0.015);
  auto anywhere = [&] { return Vec3(lo.array() + Vec3(u(rng), u(rng), u(rng)).array() * (hi - lo).array()); };
  std::vector<int32_t> got;
  size_t repeats_left_out = 0, longest = 0;
  for (int k = 0; k < 600; ++k) {
    const Vec3 a = anywhere(), b = a + (k % 3 == 0 ? 1.0 : 0.05) * (anywhere() - a);
    grid.near_segment(a, b, 1u << 20, got);
    std::vector<int32_t> all;
    const Vec3 m = a.cwiseMin(b), M = a.cwiseMax(b);
    for (double i = std::floor(m.x() / cell); i <= std::floor(M.x() / cell); ++i)
      for (double j = std::floor(m.y() / cell); j <= std::floor(M.y() / cell); ++j)
        for (double l = std::floor(m.z() / cell); l <= std::floor(M.z() / cell); ++l) {
          const auto c = grid.near(Vec3((i + 0.5) * cell, (j + 0.5) * cell, (l + 0.5) * cell));
          all.insert(all.end(), c.begin(), c.end());
        }
    std::vector<int32_t> first;
    std::set<int32_t> seen;
    for (int32_t t : all)
      if (seen.insert(t).second) first.push_back(t);
    ASSERT_EQ(got, first) << "path " << k;
    repeats_left_out += all.size() - first.size();
    longest = std::max(longest, got.size());
  }
  EXPECT_GT(repeats_left_out, 1000u);  // the long paths share many cells with each triangle
  EXPECT_GT(longest, 100u);
}

TEST(TriangleGrid, ARegionKeepsWhatEveryQueryInsideItFinds) {
  // beam3's surface, shaken, with a region that holds one end of it and the air beside: every
  // point and path inside the region gets the same triangles, in the same order, from the grid
  // binned for the region as from the whole grid; and the region's grid holds fewer entries.
  auto model = build_model(*builtin_mesh("beam3"), Material{1e6, 0.4, 1000});
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> shake(-4e-4, 4e-4);
  std::vector<Vec3> x = model->rest_positions;
  for (Vec3& p : x) p += Vec3(shake(rng), shake(rng), shake(rng));
  const double reach = 0.002;
  const std::pair<Vec3, Vec3> region{Vec3(0.07, -0.004, -0.003), Vec3(0.11, 0.006, 0.012)};
  const detail::TriangleGrid whole(model->surface, std::span<const Vec3>(x), reach);
  const detail::TriangleGrid near_region(model->surface, std::span<const Vec3>(x), reach, {}, &region);
  std::uniform_real_distribution<double> u(0, 1);
  auto inside = [&] {
    const Vec3 t(u(rng), u(rng), u(rng));
    return Vec3(region.first.array() + t.array() * (region.second - region.first).array());
  };
  std::vector<int32_t> a, b;
  size_t found = 0;
  for (int k = 0; k < 2000; ++k) {
    const Vec3 p = inside(), q = inside();
    const auto na = whole.near(p), nb = near_region.near(p);
    ASSERT_EQ(std::vector<int32_t>(na.begin(), na.end()), std::vector<int32_t>(nb.begin(), nb.end())) << k;
    const Vec3 r = p + 0.1 * (q - p);  // a short path, and a long one
    whole.near_segment(p, r, 4096, a);
    near_region.near_segment(p, r, 4096, b);
    ASSERT_EQ(a, b) << k;
    whole.near_segment(p, q, 4096, a);
    near_region.near_segment(p, q, 4096, b);
    ASSERT_EQ(a, b) << k;
    found += a.size();
  }
  EXPECT_GT(found, 0u);  // the region meets the body
  EXPECT_LT(near_region.entries(), whole.entries() / 2);
}
