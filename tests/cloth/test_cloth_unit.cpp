// SPDX-License-Identifier: Apache-2.0
// Constraint bodies (cloth, rope) below the scene: constraint gradients against finite
// differences, momentum conservation of the internal constraints, state round trips, input
// checks, and results that do not depend on the thread count.
#include "pliant/cloth.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <string>

using namespace pliant;

namespace {

Vec3 random_vec(std::mt19937& rng, double scale = 1.0) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  return Vec3(u(rng), u(rng), u(rng)) * scale;
}

// Central differences of f with respect to each coordinate of x[k].
template <class F>
Vec3 numeric_gradient(F f, std::vector<Vec3> x, size_t k, double eps = 1e-6) {
  Vec3 g;
  for (int d = 0; d < 3; ++d) {
    const double keep = x[k][d];
    x[k][d] = keep + eps;
    const double fp = f(x);
    x[k][d] = keep - eps;
    const double fm = f(x);
    x[k][d] = keep;
    g[d] = (fp - fm) / (2 * eps);
  }
  return g;
}

template <class Fn>
std::string thrown_message(Fn fn) {
  try {
    fn();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "(nothing thrown)";
}

}  // namespace

TEST(ClothMath, DihedralGradientMatchesFiniteDifferences) {
  std::mt19937 rng(7);
  int checked = 0;
  for (int trial = 0; trial < 200; ++trial) {
    // a hinge near a random fold: edge along x, wings on either side, then a rigid jitter
    const double fold = std::uniform_real_distribution<double>(-2.8, 2.8)(rng);
    std::vector<Vec3> x = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0.4, 1, 0),
                           Vec3(0.6, -std::cos(fold), std::sin(fold))};
    for (auto& p : x) p += random_vec(rng, 0.05);
    auto f = [](const std::vector<Vec3>& y) { return cloth_math::dihedral_angle(y[0], y[1], y[2], y[3]); };
    const double theta = f(x);
    if (std::abs(std::abs(theta) - M_PI) < 0.05) continue;  // atan2's branch cut
    const auto g = cloth_math::dihedral_gradient(x[0], x[1], x[2], x[3]);
    Vec3 sum = Vec3::Zero();
    for (size_t k = 0; k < 4; ++k) {
      const Vec3 n = numeric_gradient(f, x, k);
      EXPECT_LT((g[k] - n).norm(), 1e-6 * std::max(1.0, n.norm()))
          << "trial " << trial << " vertex " << k << " analytic " << g[k].transpose() << " numeric " << n.transpose();
      sum += g[k];
    }
    EXPECT_LT(sum.norm(), 1e-12);
    ++checked;
  }
  EXPECT_GT(checked, 150);
}

TEST(ClothMath, DihedralAngleIsZeroFlatAndSignedWhenFolded) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(0.5, 1, 0);
  EXPECT_NEAR(cloth_math::dihedral_angle(a, b, c, Vec3(0.5, -1, 0)), 0.0, 1e-15);
  const double up = cloth_math::dihedral_angle(a, b, c, Vec3(0.5, -1, 1));
  const double down = cloth_math::dihedral_angle(a, b, c, Vec3(0.5, -1, -1));
  EXPECT_NEAR(std::abs(up), M_PI / 4, 1e-12);
  EXPECT_NEAR(up, -down, 1e-12);
}

// The bending constraint's value: the angle turned back by the rest angle, against atan2 and a
// wrap into (-pi, pi], on both sides of the series' reach and in every quadrant.
TEST(ClothMath, AngleFromRestIsTheWrappedDifferenceOfAngles) {
  auto wrap = [](double a) {
    while (a > M_PI) a -= 2.0 * M_PI;
    while (a <= -M_PI) a += 2.0 * M_PI;
    return a;
  };
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> angle(-M_PI, M_PI), scale(1e-6, 1e6), near(-0.3, 0.3);
  double worst = 0.0;
  int series = 0;
  for (int k = 0; k < 200000; ++k) {
    const double rest = angle(rng);
    // Half the cases within 0.3 rad of the rest angle (the series' reach is atan(1/4) = 0.245).
    const double theta = k % 2 ? angle(rng) : rest + near(rng);
    const double r = scale(rng);
    const double s = r * std::sin(theta), c = r * std::cos(theta);
    const double got = cloth_math::angle_from_rest(s, c, std::cos(rest), std::sin(rest));
    const double want = wrap(std::atan2(s, c) - rest);
    // Near +-pi the two may land on either side of the cut.
    const double diff = std::abs(wrap(got - want));
    worst = std::max(worst, diff);
    series += std::abs(want) < 0.24;
    ASSERT_LE(diff, 2e-15) << "s " << s << " c " << c << " rest " << rest;
    ASSERT_GT(got, -M_PI - 1e-15);
    ASSERT_LE(got, M_PI + 1e-15);
  }
  EXPECT_GT(series, 50000) << "too few cases within the series' reach";
  EXPECT_EQ(cloth_math::angle_from_rest(0.0, 1.0, 1.0, 0.0), 0.0);
}

TEST(ClothMath, RopeBendGradientMatchesFiniteDifferences) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 100; ++trial) {
    std::vector<Vec3> x = {random_vec(rng), random_vec(rng), random_vec(rng)};
    auto f = [](const std::vector<Vec3>& y) { return cloth_math::rope_bend_value(y[0], y[1], y[2]); };
    const auto g = cloth_math::rope_bend_gradient(x[0], x[1], x[2]);
    for (size_t k = 0; k < 3; ++k) {
      const Vec3 n = numeric_gradient(f, x, k);
      EXPECT_LT((g[k] - n).norm(), 1e-6) << "trial " << trial << " vertex " << k;
    }
  }
}

TEST(ClothMath, DistanceGradientMatchesFiniteDifferences) {
  // the distance constraint's gradient as the solver applies it: +-(xi - xj)/|xi - xj|
  std::mt19937 rng(3);
  for (int trial = 0; trial < 50; ++trial) {
    std::vector<Vec3> x = {random_vec(rng), random_vec(rng)};
    auto f = [](const std::vector<Vec3>& y) { return (y[0] - y[1]).norm() - 0.3; };
    const Vec3 gi = (x[0] - x[1]).normalized();
    EXPECT_LT((numeric_gradient(f, x, 0) - gi).norm(), 1e-8);
    EXPECT_LT((numeric_gradient(f, x, 1) + gi).norm(), 1e-8);
  }
}

TEST(ClothMath, VolumeGradientMatchesFiniteDifferences) {
  // an octahedron, jittered
  std::mt19937 rng(5);
  std::vector<Vec3> x = {Vec3(1, 0, 0), Vec3(-1, 0, 0), Vec3(0, 1, 0), Vec3(0, -1, 0), Vec3(0, 0, 1), Vec3(0, 0, -1)};
  for (auto& p : x) p += random_vec(rng, 0.1);
  const std::vector<std::array<uint32_t, 3>> t = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4},
                                                  {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
  auto f = [&](const std::vector<Vec3>& y) { return cloth_math::enclosed_volume(y, t); };
  EXPECT_GT(f(x), 1.0);  // outward winding: about 4/3
  std::vector<Vec3> g;
  cloth_math::enclosed_volume_gradient(x, t, g);
  for (size_t k = 0; k < x.size(); ++k) EXPECT_LT((numeric_gradient(f, x, k) - g[k]).norm(), 1e-8) << k;
}

TEST(ClothMath, CatenaryMatchesItsDefinition) {
  const double a = cloth_math::catenary_parameter(1.0, 1.2);
  EXPECT_NEAR(2 * a * std::sinh(0.5 / a), 1.2, 1e-10);
  // a nearly taut rope: the parabola's sag sqrt(3 S (L - S) / 8) to first order
  const double sag = cloth_math::catenary_sag(1.0, 1.0001);
  EXPECT_NEAR(sag, std::sqrt(3.0 * 0.0001 / 8.0), 1e-3 * sag);
  EXPECT_THROW(cloth_math::catenary_parameter(1.0, 0.9), std::invalid_argument);
}

namespace {

std::unique_ptr<ConstraintBody> small_cloth(int threads, bool self_collision = true, int n = 32, double size = 0.5) {
  ClothGridSpec spec;
  spec.nx = n;
  spec.ny = n;
  spec.size_x = size;
  spec.size_y = size;
  ConstraintBodySettings s;
  s.threads = threads;
  s.self_collision = self_collision;
  s.substeps = 4;
  s.iterations = 2;
  return ConstraintBody::cloth_grid(spec, s);
}

void shake(ConstraintBody& body, unsigned seed, double jitter = 0.01, double speed = 1.0) {
  std::mt19937 rng(seed);
  ParticleState st = body.state();
  for (size_t i = 0; i < st.x.size(); ++i) {
    st.x[i] += random_vec(rng, jitter);
    st.v[i] = random_vec(rng, speed) + Vec3(0.3, -0.2, 0.1);
  }
  body.set_state(st);
}

}  // namespace

TEST(ConstraintBody, InternalConstraintsConserveLinearMomentum) {
  // no gravity, no pins, no colliders, no damping: stretch, shear, bending and self-collision
  // move particles by equal and opposite mass-weighted amounts
  for (bool self : {false, true}) {
    auto body = small_cloth(1, self);
    ConstraintBodySettings s = body->settings();
    s.gravity = Vec3::Zero();
    s.damping = 0.0;
    body->set_settings(s);
    shake(*body, 1);
    const Vec3 p0 = body->linear_momentum();
    double scale = 0.0;
    for (size_t i = 0; i < body->size(); ++i) scale += body->masses()[i] * body->state().v[i].norm();
    for (int k = 0; k < 30; ++k) body->step(1.0 / 60, {});
    const Vec3 p1 = body->linear_momentum();
    EXPECT_LT((p1 - p0).norm() / scale, 1e-12) << "self-collision " << self << ": p0 " << p0.transpose()
                                                << " p1 " << p1.transpose();
  }
  // a rope with bending
  ConstraintBodySettings s;
  s.gravity = Vec3::Zero();
  auto rope = ConstraintBody::rope({Vec3(0, 0, 0), Vec3(1, 0.2, 0), Vec3(1.5, -0.3, 0.4)}, 40, 0.1, s);
  shake(*rope, 2);
  const Vec3 p0 = rope->linear_momentum();
  double scale = 0.0;
  for (size_t i = 0; i < rope->size(); ++i) scale += rope->masses()[i] * rope->state().v[i].norm();
  for (int k = 0; k < 30; ++k) rope->step(1.0 / 60, {});
  EXPECT_LT((rope->linear_momentum() - p0).norm() / scale, 1e-12);
}

TEST(ConstraintBody, ResultsDoNotDependOnTheThreadCount) {
  // 64 x 64 over 1 m: the distance colours are large enough to be split over the pool
  auto one = small_cloth(1, true, 64, 1.0), three = small_cloth(3, true, 64, 1.0);
  shake(*one, 4, 0.003, 0.3);
  shake(*three, 4, 0.003, 0.3);
  const std::vector<Collider> colliders = {Collider::sphere(Vec3(0, -0.2, 0), 0.15)};
  for (int k = 0; k < 4; ++k) {
    one->step(1.0 / 60, colliders);
    three->step(1.0 / 60, colliders);
  }
  for (size_t i = 0; i < one->size(); ++i) {
    ASSERT_EQ(one->state().x[i], three->state().x[i]) << "particle " << i;
    ASSERT_EQ(one->state().v[i], three->state().v[i]) << "particle " << i;
  }
}

TEST(ConstraintBody, GridCounts) {
  auto body = small_cloth(1);
  EXPECT_GT(body->colours(), 3u);
  EXPECT_EQ(body->state().lambda.size(), body->constraint_count());
  EXPECT_EQ(body->kind(), "cloth");
  EXPECT_EQ(body->triangles().size(), size_t(2 * 31 * 31));
  // stretch 2 x 31 x 32 + one diagonal per quad, shear: the other diagonal
  EXPECT_EQ(body->distance_constraints(), size_t(2 * 31 * 32 + 2 * 31 * 31));
}

TEST(ConstraintBody, SetStateRoundTrip) {
  auto a = small_cloth(1), b = small_cloth(1);
  shake(*a, 9);
  for (int k = 0; k < 3; ++k) a->step(1.0 / 60, {});
  const ParticleState saved = a->state();
  b->set_state(saved);
  EXPECT_EQ(b->state().x, saved.x);
  EXPECT_EQ(b->state().v, saved.v);
  EXPECT_EQ(b->state().lambda, saved.lambda);
  EXPECT_EQ(b->state().time, saved.time);
  EXPECT_EQ(b->state().steps, saved.steps);
  for (int k = 0; k < 5; ++k) {
    a->step(1.0 / 60, {});
    b->step(1.0 / 60, {});
  }
  EXPECT_EQ(a->state().x, b->state().x);

  ParticleState bad = saved;
  bad.x.pop_back();
  EXPECT_NE(thrown_message([&] { b->set_state(bad); }).find("ParticleState.x"), std::string::npos);
  bad = saved;
  bad.v.push_back(Vec3::Zero());
  EXPECT_NE(thrown_message([&] { b->set_state(bad); }).find("ParticleState.v"), std::string::npos);
  bad = saved;
  bad.lambda.clear();
  EXPECT_NE(thrown_message([&] { b->set_state(bad); }).find("ParticleState.lambda"), std::string::npos);
}

TEST(ConstraintBody, BadInputThrowsNamingTheField) {
  ConstraintBodySettings s;
  ClothGridSpec g;
  g.nx = 8;
  g.ny = 8;
  auto expect = [](const std::string& field, auto fn) {
    const std::string m = thrown_message(fn);
    EXPECT_NE(m.find(field), std::string::npos) << "expected '" << field << "' in: " << m;
  };
  auto with = [&](auto change) {
    ConstraintBodySettings t = s;
    change(t);
    return t;
  };
  expect("stretch_compliance", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.stretch_compliance = -1; })); });
  expect("bend_compliance", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.bend_compliance = NAN; })); });
  expect("substeps", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.substeps = 0; })); });
  expect("iterations", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.iterations = 0; })); });
  expect("thickness", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.thickness = 0; })); });
  expect("threads", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.threads = 0; })); });
  expect("damping", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.damping = -0.5; })); });
  expect("volume", [&] { ConstraintBody::cloth_grid(g, with([](auto& t) { t.volume = true; })); });
  expect("nx", [&] {
    ClothGridSpec b = g;
    b.nx = 1;
    ConstraintBody::cloth_grid(b, s);
  });
  expect("mass_per_area", [&] {
    ClothGridSpec b = g;
    b.mass_per_area = 0;
    ConstraintBody::cloth_grid(b, s);
  });
  expect("triangles", [&] { ConstraintBody::cloth({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)}, {{0, 1, 5}}, 1.0, s); });
  expect("segments", [&] { ConstraintBody::rope({Vec3(0, 0, 0), Vec3(1, 0, 0)}, 0, 0.1, s); });
  expect("linear_density", [&] { ConstraintBody::rope({Vec3(0, 0, 0), Vec3(1, 0, 0)}, 4, -1, s); });
  expect("polyline", [&] { ConstraintBody::rope({Vec3(0, 0, 0)}, 4, 0.1, s); });
  auto body = ConstraintBody::cloth_grid(g, s);
  expect("dt", [&] { body->step(0.0, {}); });
  expect("particle", [&] { body->grab(1, 1000, Vec3::Zero(), 0.0); });
  expect("compliance", [&] { body->grab(1, 0, Vec3::Zero(), -1.0); });
}

TEST(ConstraintBody, PinnedParticlesStayAndGrabsPull) {
  ConstraintBodySettings s;
  auto rope = ConstraintBody::rope({Vec3(0, 0, 0), Vec3(1, 0, 0)}, 10, 0.1, s);
  EXPECT_EQ(rope->kind(), "rope");
  EXPECT_TRUE(rope->triangles().empty());
  rope->pin(0);
  EXPECT_EQ(rope->inverse_masses()[0], 0.0);
  rope->grab(7, 10, Vec3(1, 0, 0), 0.0);
  for (int k = 0; k < 20; ++k) rope->step(1.0 / 60, {});
  EXPECT_EQ(rope->state().x[0], Vec3(0, 0, 0));
  EXPECT_LT((rope->state().x[10] - Vec3(1, 0, 0)).norm(), 1e-9);
  EXPECT_GT(rope->grab_force(7).norm(), 0.0);
  EXPECT_TRUE(rope->move_grab(7, Vec3(0.9, 0, 0)));
  EXPECT_TRUE(rope->release(7));
  EXPECT_FALSE(rope->release(7));
  EXPECT_EQ(rope->grab_force(7), Vec3::Zero());
}

TEST(ConstraintBody, VolumeConstraintKeepsAClosedSurfaceAtItsPressure) {
  // an octahedron of distance constraints with soft edges, no gravity: the volume constraint
  // (pressure 1.3) inflates it to 1.3 x its rest volume against the edges' compliance
  std::vector<Vec3> x = {Vec3(1, 0, 0), Vec3(-1, 0, 0), Vec3(0, 1, 0), Vec3(0, -1, 0), Vec3(0, 0, 1), Vec3(0, 0, -1)};
  const std::vector<Triangle> t = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};
  ConstraintBodySettings s;
  s.gravity = Vec3::Zero();
  s.volume = true;
  s.pressure = 1.3;
  s.stretch_compliance = 1e-2;
  s.bending = false;
  s.damping = 5.0;
  s.self_collision = false;
  auto body = ConstraintBody::cloth(x, t, 1.0, s);
  EXPECT_NEAR(body->rest_volume(), 4.0 / 3.0, 1e-12);
  EXPECT_EQ(body->constraint_count(), 12u + 1u);  // edges and the volume
  for (int k = 0; k < 120; ++k) body->step(1.0 / 60, {});
  EXPECT_NEAR(body->volume() / body->rest_volume(), 1.3, 1e-3);
  // an open surface cannot carry a volume constraint
  EXPECT_THROW(ConstraintBody::cloth({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)}, {{0, 1, 2}}, 1.0, s),
               std::invalid_argument);
}

TEST(ConstraintBody, ClothFromASurfaceFile) {
  // two triangles as an OBJ in centimetres, read with assimp
  const std::string path = ::testing::TempDir() + "pliant_cloth_quad.obj";
  {
    std::FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("v 0 0 0\nv 10 0 0\nv 10 0 10\nv 0 0 10\nf 1 2 3\nf 1 3 4\n", f);
    std::fclose(f);
  }
  ConstraintBodySettings s;
  auto body = ConstraintBody::cloth_from_file(path, 0.01, 0.5, s);
  EXPECT_EQ(body->size(), 4u);
  EXPECT_EQ(body->triangles().size(), 2u);
  EXPECT_EQ(body->distance_constraints(), 5u);
  EXPECT_EQ(body->bending_constraints(), 1u);
  EXPECT_NEAR(body->total_mass(), 0.1 * 0.1 * 0.5, 1e-12);
  std::remove(path.c_str());
}

// A scene steps bodies in contact in parts (whole substeps each) to resolve their contacts in
// between: a body alone must step the same in parts as in one piece, to the last bit.
TEST(ConstraintBodyParts, AStepInPartsIsTheStepInOnePiece) {
  ClothGridSpec g;
  g.nx = g.ny = 8;
  g.size_x = g.size_y = 0.3;
  g.origin = Vec3(-0.15, 0.2, -0.15);
  ConstraintBodySettings cs;
  cs.self_collision = false;
  cs.damping = 0.5;
  const std::vector<Collider> floor = {Collider::plane(Vec3(0, 0, 0), Vec3(0, 1, 0))};
  for (int parts : {2, 4, 16}) {
    SCOPED_TRACE("parts " + std::to_string(parts));
    auto whole = ConstraintBody::cloth_grid(g, cs);
    auto cut = ConstraintBody::cloth_grid(g, cs);
    whole->pin(0);
    cut->pin(0);
    ASSERT_EQ(whole->substeps() % parts, 0);
    const double dt = 1.0 / 60;
    for (int k = 0; k < 40; ++k) {  // falls onto the floor and folds over its pinned corner
      whole->step(dt, floor);
      for (int p = 0; p < parts; ++p) cut->advance(dt / parts, cut->substeps() / parts, floor, p + 1 == parts);
    }
    EXPECT_EQ(cut->state().x, whole->state().x);
    EXPECT_EQ(cut->state().v, whole->state().v);
    EXPECT_EQ(cut->state().lambda, whole->state().lambda);
    EXPECT_EQ(cut->state().steps, 40u);
    EXPECT_NEAR(cut->state().time, whole->state().time, 1e-12);  // dt / parts added parts times
  }
  auto body = ConstraintBody::cloth_grid(g, cs);
  EXPECT_THROW(body->advance(0.01, 0, {}, true), std::invalid_argument);
}

TEST(ConstraintBodyParts, SharedPartsDivideEveryBodysSubsteps) {
  EXPECT_EQ(shared_step_parts(std::vector<int>{16, 2}), 2);
  EXPECT_EQ(shared_step_parts(std::vector<int>{16, 8, 16}), 8);
  EXPECT_EQ(shared_step_parts(std::vector<int>{3, 2}), 1);
  EXPECT_EQ(shared_step_parts(std::vector<int>{5}), 5);
  EXPECT_EQ(shared_step_parts(std::vector<int>{}), 1);
}
