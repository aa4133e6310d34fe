// SPDX-License-Identifier: Apache-2.0
// Tool contact without stepping: closest points on triangles, sphere and capsule geometry, one
// projection pass of the contacts on beam1 (faces pushed out of a small tool, vertices put on
// a big tool's surface), a tool posed along its velocities, and interaction inputs validated
// with the field and value named.
#include "pliant/interaction.hpp"
#include "pliant/model.hpp"

#include "beam1_fixtures.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

using namespace pliant;
using namespace pliant::test;

TEST(ToolContact, ClosestPointOnTriangleInEveryRegion) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  std::array<double, 3> w{};
  // Face interior: straight below.
  Vec3 q = closest_point_on_triangle(Vec3(0.2, 0.3, 0.5), a, b, c, w);
  EXPECT_NEAR((q - Vec3(0.2, 0.3, 0)).norm(), 0, 1e-12);
  EXPECT_NEAR(w[0], 0.5, 1e-12);
  EXPECT_NEAR(w[1], 0.2, 1e-12);
  EXPECT_NEAR(w[2], 0.3, 1e-12);
  // Edge bc and corner regions.
  q = closest_point_on_triangle(Vec3(1, 1, 0.3), a, b, c, w);
  EXPECT_NEAR((q - Vec3(0.5, 0.5, 0)).norm(), 0, 1e-12);
  EXPECT_NEAR(w[0], 0, 1e-12);
  q = closest_point_on_triangle(Vec3(-1, -1, 0), a, b, c, w);
  EXPECT_EQ(q, a);
  EXPECT_EQ(w[0], 1.0);
  q = closest_point_on_triangle(Vec3(2, -0.5, 0), a, b, c, w);
  EXPECT_EQ(q, b);
}

TEST(ToolContact, ClosestPointOnADegenerateTriangleIsOneOfItsPoints) {
  // The mesh embedding, the contacts and the cloth share one closest-point query; a triangle
  // collapsed to a segment or a point must give a point of it with weights that sum to 1, not
  // a division by zero.
  std::array<double, 3> w{};
  auto check = [&](const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& expected) {
    const Vec3 q = closest_point_on_triangle(p, a, b, c, w);
    ASSERT_TRUE(q.allFinite());
    EXPECT_NEAR((q - expected).norm(), 0, 1e-12);
    EXPECT_NEAR(w[0] + w[1] + w[2], 1.0, 1e-12);
    for (double x : w) EXPECT_GE(x, 0.0);
    EXPECT_NEAR((w[0] * a + w[1] * b + w[2] * c - q).norm(), 0, 1e-12);
  };
  const Vec3 o(0.1, 0.2, 0.3);
  check(Vec3(1, 2, 3), o, o, o, o);                                  // a point
  check(Vec3(0.5, 0.7, 0.3), o, o, Vec3(1.1, 0.2, 0.3), Vec3(0.5, 0.2, 0.3));  // a segment, a = b
  check(Vec3(0.5, 0.7, 0.3), o, Vec3(1.1, 0.2, 0.3), o, Vec3(0.5, 0.2, 0.3));  // a = c
  check(Vec3(0.5, 0.7, 0.3), Vec3(1.1, 0.2, 0.3), o, o, Vec3(0.5, 0.2, 0.3));  // b = c
  check(Vec3(0.5, 0.7, 0.3), o, Vec3(0.6, 0.2, 0.3), Vec3(1.1, 0.2, 0.3), Vec3(0.5, 0.2, 0.3));  // collinear
}

TEST(ToolContact, ASmallSpherePressedIntoACoarseFacePushesItsTriangle) {
  // beam1's faces are 5 mm right triangles: a sphere of radius 1 mm pressed 0.5 mm into the
  // middle of one has no vertex inside it (the nearest corner is 2.4 mm from the centroid), so
  // vertex-only contact lets it sink in unopposed. With triangle contact the face is pushed
  // out of it by one projection, and the multipliers (the force on the body) point into the
  // body and sum to the momentum the corners received. (Fails with vertex-only contact.)
  auto m = clamped_beam(1e6);
  Vec3 g;
  const Triangle tri = top_triangle_near(*m, Vec3(0.06, 0.01, 0.004), &g);
  const RigidTool tool = RigidTool::sphere(g + Vec3(0, 0.001 - 0.0005, 0), 0.001);
  for (size_t i = 0; i < m->vertex_count(); ++i) {
    Vec3 q, n;
    double d;
    ASSERT_FALSE(tool_contact(tool, m->rest_positions[i], q, n, d)) << "vertex " << i << " is inside the tool";
  }
  std::vector<Vec3> x = m->rest_positions;
  const std::vector<Vec3> x_start = m->rest_positions;
  Vec3 lambda = Vec3::Zero();
  std::vector<int32_t> touched;
  // The tool's outward normal at the contact points into the body (-y).
  auto record = [&](int32_t v, const Vec3& dl, const Vec3& normal) {
    lambda += dl;
    touched.push_back(v);
    EXPECT_LT(normal.y(), -0.9);
  };
  EXPECT_GE(project_tool_contacts(*m, x, x_start, tool, 1.0 / 600, record), 1);
  // The corners move by different amounts (b_k), so the face tilts and a few more passes
  // (iterations, in the solver) finish the job, as for any linearised constraint.
  for (int pass = 0; pass < 20; ++pass) project_tool_contacts(*m, x, x_start, tool, 1.0 / 600, record);
  EXPECT_LT(lambda.y(), 0);  // the body is pushed down, the tool up
  Vec3 momentum = Vec3::Zero();
  for (size_t i = 0; i < x.size(); ++i) momentum += m->inertia[i] * (x[i] - x_start[i]);
  EXPECT_NEAR((momentum - lambda).norm(), 0, 1e-12 * lambda.norm());
  for (int32_t k : tri) EXPECT_NE(std::find(touched.begin(), touched.end(), k), touched.end()) << "corner " << k;
  // The triangle left the tool: its point nearest the centre is on the tool's surface.
  std::array<double, 3> w{};
  const Vec3 q = closest_point_on_triangle(tool.position, x[tri[0]], x[tri[1]], x[tri[2]], w);
  EXPECT_NEAR((q - tool.position).norm(), tool.radius, 1e-3 * tool.radius);
  EXPECT_LT(q.y(), 0.01 - 0.0004);
}

TEST(ToolContact, FacesAroundAVertexInContactAreLeftToTheVertex) {
  // A 2 cm sphere pressed 2 mm onto a top vertex of beam1 (its top neighbours are inside
  // too): one pass (a solver iteration) puts every vertex that was inside on the sphere's
  // surface and no further; the faces between them are chords of the sphere and are theirs. Its faces are chords of the sphere; pushing them out as well would
  // push the vertex past the surface (and, in a stiff body at few iterations, crush the tets
  // under it).
  auto m = clamped_beam(1e6);
  const int32_t v = nearest_vertex(*m, Vec3(0.06, 0.01, 0.005));
  const Vec3 centre = m->rest_positions[v] + Vec3(0, 0.02 - 0.002, 0);
  const RigidTool tool = RigidTool::sphere(centre, 0.02);
  std::vector<int32_t> inside;
  for (size_t i = 0; i < m->vertex_count(); ++i) {
    Vec3 q, n;
    double d;
    if (tool_contact(tool, m->rest_positions[i], q, n, d)) inside.push_back(int32_t(i));
  }
  ASSERT_GE(inside.size(), 5u);
  std::vector<Vec3> x = m->rest_positions;
  project_tool_contacts(*m, x, m->rest_positions, tool, 1.0 / 600, [](int32_t, const Vec3&, const Vec3&) {});
  for (int32_t i : inside) EXPECT_NEAR((x[i] - centre).norm(), tool.radius, 1e-9) << "vertex " << i;
}

TEST(ToolContact, ACapsuleLyingBetweenVertexRowsTouchesTheFaces) {
  // A thin capsule (r = 0.5 mm) lying along z on the top face, between two vertex columns,
  // pressed 0.3 mm in: only the segment-triangle test finds it.
  auto m = clamped_beam(1e6);
  const Vec3 centre(0.0625, 0.01 + 0.0005 - 0.0003, 0.005);
  const RigidTool tool = RigidTool::capsule(centre, Eigen::Quaterniond::Identity(), 0.0005, 0.004);
  std::vector<Vec3> x = m->rest_positions;
  Vec3 lambda = Vec3::Zero();
  const int n = project_tool_contacts(*m, x, m->rest_positions, tool, 1.0 / 600,
                                      [&](int32_t, const Vec3& dl, const Vec3&) { lambda += dl; });
  EXPECT_GE(n, 2);
  EXPECT_LT(lambda.y(), 0);
  EXPECT_LT(std::abs(lambda.x()), 0.05 * std::abs(lambda.y()));
}

TEST(ToolContact, SphereAndCapsuleGeometry) {
  Vec3 q, n;
  double d;
  const RigidTool s = RigidTool::sphere(Vec3(0, 0, 0), 1.0);
  ASSERT_TRUE(tool_contact(s, Vec3(0.5, 0, 0), q, n, d));
  EXPECT_NEAR(d, 0.5, 1e-12);
  EXPECT_NEAR((q - Vec3(1, 0, 0)).norm(), 0, 1e-12);
  EXPECT_FALSE(tool_contact(s, Vec3(0, 1.5, 0), q, n, d));
  // Capsule along x (z rotated onto x): a point beside the middle of the shaft.
  const RigidTool c = RigidTool::capsule(Vec3(0, 0, 0), Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX()),
                                         0.1, 1.0);
  ASSERT_TRUE(tool_contact(c, Vec3(0.7, 0.05, 0), q, n, d));
  EXPECT_NEAR(d, 0.05, 1e-12);
  EXPECT_NEAR((n - Vec3(0, 1, 0)).norm(), 0, 1e-12);
  EXPECT_FALSE(tool_contact(c, Vec3(1.2, 0, 0), q, n, d));  // beyond the end cap
  ASSERT_TRUE(tool_contact(c, Vec3(1.05, 0, 0), q, n, d));  // inside the end cap
  EXPECT_NEAR((n - Vec3(1, 0, 0)).norm(), 0, 1e-12);
}

TEST(Interaction, ValidationNamesFieldAndValue) {
  auto m = clamped_beam(1e6);
  std::vector<Attachment> a{Attachment::vertex(int32_t(m->vertex_count()) + 5, Vec3::Zero())};
  EXPECT_NE(validate_interaction(a, {}, *m).find("attachments[0].vertices[0] = " + std::to_string(m->vertex_count() + 5)),
            std::string::npos);
  std::vector<RigidTool> t{RigidTool::sphere(Vec3::Zero(), -1)};
  EXPECT_NE(validate_interaction({}, t, *m).find("tools[0].radius = -1"), std::string::npos);
  a[0] = Attachment::vertex(0, Vec3::Zero(), -2);
  EXPECT_NE(validate_interaction(a, {}, *m).find("attachments[0].compliance = -2"), std::string::npos);
}

TEST(ToolContact, AToolIsPosedBackAlongItsVelocitiesAndItsSurfaceMovesWithThem) {
  // A capsule along x (its local z turned onto x) moving at v and turning about z at 3 rad/s:
  // 0.1 s before the pose it is at p - 0.1 v with its axis turned back by 0.3 rad; a point of its
  // surface moves by h (v + w x (q - p)).
  RigidTool t = RigidTool::capsule(Vec3(0.1, 0.2, 0.3), Eigen::Quaterniond::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX()),
                                   0.01, 0.05);
  t.velocity = Vec3(0.5, -0.2, 0.1);
  t.angular_velocity = Vec3(0, 0, 3.0);
  const RigidTool back = t.at(-0.1);
  EXPECT_NEAR((back.position - Vec3(0.05, 0.22, 0.29)).norm(), 0.0, 1e-15);
  const Vec3 axis = back.orientation * Vec3::UnitZ();
  EXPECT_NEAR((axis - Vec3(std::cos(0.3), -std::sin(0.3), 0)).norm(), 0.0, 1e-12);
  EXPECT_NEAR(back.orientation.norm(), 1.0, 1e-12);
  EXPECT_EQ(back.radius, t.radius);
  EXPECT_EQ(back.half_length, t.half_length);
  const RigidTool same = t.at(0.0);
  EXPECT_EQ(same.position, t.position);
  EXPECT_TRUE(same.orientation.coeffs().isApprox(t.orientation.coeffs(), 1e-15));
  // The end of the axis, 5 cm along x from the centre, moves along y at 3 x 0.05 m/s besides v.
  const Vec3 tip = t.position + Vec3(0.05, 0, 0);
  EXPECT_NEAR((t.motion(tip, 0.01) - 0.01 * (t.velocity + Vec3(0, 0.15, 0))).norm(), 0.0, 1e-15);
  // Over a small step the motion matches the poses' difference at that point.
  const double h = 1e-5;
  const Vec3 end_tip = t.position + t.orientation * Vec3(0, 0, 0.05);
  const RigidTool earlier = t.at(-h);
  const Vec3 start_tip = earlier.position + earlier.orientation * Vec3(0, 0, 0.05);
  EXPECT_NEAR((end_tip - start_tip - t.motion(end_tip, h)).norm(), 0.0, 1e-9);
  // Not finite: refused by the step's validation, naming the field.
  t.angular_velocity.y() = std::nan("");
  EXPECT_NE(validate_interaction({}, {t}, *clamped_beam(1e6)).find("tools[0].angular_velocity is not finite"),
            std::string::npos);
}
