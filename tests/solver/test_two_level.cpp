// SPDX-License-Identifier: Apache-2.0
// The two-level preconditioner of inexact Newton (newton_linear_solver cg-twolevel, and cg above
// 20,000 free dofs): symmetric positive definite, exact on rigid motions of the whole body (they
// lie in its coarse space), and a hanging beam stepped with one CG-Newton iteration per tick comes
// to rest at Newton's static shape, keeping its Hessian once it has stopped moving.
#include "newton/two_level.hpp"

#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/stepper.hpp"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <random>

using namespace pliant;

namespace {

// A symmetric positive definite matrix with full 3x3 blocks on a mesh's vertex graph: per edge a
// spring's 3x3 stiffness k n n^T + 0.1 k I (n the edge's direction), plus a small mass term. Its
// block pattern as the Newton family stores it (both triangles; block column q lists its block
// rows ascending, q included).
struct BlockSystem {
  Eigen::SparseMatrix<double> H;
  std::vector<int32_t> begin, row;
  std::vector<Vec3> position;
};

BlockSystem springs_on(const TetMesh& mesh) {
  const size_t n = mesh.vertices.size();
  std::vector<Eigen::Triplet<double>> trip;
  std::vector<std::vector<int32_t>> adj(n);
  auto add_block = [&](size_t a, size_t b, const Eigen::Matrix3d& k) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) trip.emplace_back(int(3 * a + i), int(3 * b + j), k(i, j));
  };
  for (size_t v = 0; v < n; ++v) {
    add_block(v, v, 1e-3 * Eigen::Matrix3d::Identity());
    adj[v].push_back(int32_t(v));
  }
  for (const auto& t : mesh.tets)
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) {
        const size_t p = size_t(t[a]), q = size_t(t[b]);
        const Vec3 d = (mesh.vertices[q] - mesh.vertices[p]).normalized();
        const Eigen::Matrix3d k = d * d.transpose() + 0.1 * Eigen::Matrix3d::Identity();
        add_block(p, p, k);
        add_block(q, q, k);
        add_block(p, q, -k);
        add_block(q, p, -k);
        adj[p].push_back(int32_t(q));
        adj[q].push_back(int32_t(p));
      }
  BlockSystem s;
  s.H.resize(int(3 * n), int(3 * n));
  s.H.setFromTriplets(trip.begin(), trip.end());
  s.H.makeCompressed();
  s.begin.push_back(0);
  for (auto& a : adj) {
    std::sort(a.begin(), a.end());
    a.erase(std::unique(a.begin(), a.end()), a.end());
    s.row.insert(s.row.end(), a.begin(), a.end());
    s.begin.push_back(int32_t(s.row.size()));
  }
  s.position = mesh.vertices;
  return s;
}

Eigen::VectorXd block_jacobi(const BlockSystem& s, const Eigen::VectorXd& r) {
  Eigen::VectorXd z(r.size());
  const Eigen::MatrixXd dense = Eigen::MatrixXd(s.H);
  for (Eigen::Index q = 0; q < r.size() / 3; ++q)
    z.segment<3>(3 * q) = dense.block<3, 3>(3 * q, 3 * q).inverse() * r.segment<3>(3 * q);
  return z;
}

}  // namespace

TEST(TwoLevel, IsSymmetricPositiveDefiniteAndExactOnRigidMotions) {
  const TetMesh mesh = *builtin_mesh("beam2");
  const BlockSystem s = springs_on(mesh);
  detail::TwoLevelPreconditioner p;
  p.build(s.begin, s.row, s.position, 2);
  p.update_blocks(s.H);
  ASSERT_TRUE(p.refresh_coarse(s.H));
  const int n = int(s.H.rows());
  EXPECT_GT(p.aggregates(), 1);
  EXPECT_LT(p.coarse_dofs(), n / 4);

  std::mt19937 rng(7);
  std::normal_distribution<double> normal;
  auto random = [&] {
    Eigen::VectorXd v(n);
    for (int i = 0; i < n; ++i) v[i] = normal(rng);
    return v;
  };
  for (int k = 0; k < 5; ++k) {
    const Eigen::VectorXd a = random(), b = random();
    Eigen::VectorXd ma, mb;
    p.apply(a, ma);
    p.apply(b, mb);
    EXPECT_NEAR(a.dot(mb), b.dot(ma), 1e-10 * std::abs(a.dot(mb)));
    EXPECT_GT(a.dot(ma), 0);
  }
  // A rigid motion u of the whole body (a translation plus an infinitesimal rotation) is a sum
  // of the aggregates' rigid modes: the coarse part of M^-1 (H u) gives u back.
  const Aabb box = bounding_box(mesh.vertices);
  const Vec3 c = 0.5 * (box.min + box.max);
  for (const auto& [t, w] : {std::pair{Vec3(1, 0, 0), Vec3(0, 0, 0)}, std::pair{Vec3(0.2, -0.5, 1), Vec3(3, 1, -2)}}) {
    Eigen::VectorXd u(n);
    for (size_t v = 0; v < mesh.vertices.size(); ++v) u.segment<3>(Eigen::Index(3 * v)) = t + w.cross(mesh.vertices[v] - c);
    const Eigen::VectorXd r = s.H * u;
    Eigen::VectorXd z;
    p.apply(r, z);
    const Eigen::VectorXd coarse = z - block_jacobi(s, r);
    EXPECT_LT((coarse - u).norm(), 1e-8 * u.norm()) << "translation " << t.transpose() << " rotation " << w.transpose();
  }
}

TEST(TwoLevel, AHangingBeamComesToRestAtNewtonsShapeAndKeepsItsHessian) {
  TetMesh mesh = *builtin_mesh("beam3");
  auto m = build_model(mesh, Material{1e6, 0.4, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
  SolverSettings s;
  s.method = Method::Newton;
  s.newton_linear_solver = NewtonLinearSolver::CgTwoLevel;
  s.substeps = 1;
  s.iterations = 1;
  s.damping_coefficient = 5;
  s.record_residuals = false;
  const RestResult rest = run_to_rest(*m, s, 1000, 1e-4);
  ASSERT_FALSE(rest.diverged);
  EXPECT_TRUE(rest.at_rest) << "max speed " << rest.max_speed << " after " << rest.steps << " ticks";
  EXPECT_GT(rest.last_report.linear_iterations, 0);
  EXPECT_EQ(rest.last_report.hessian_reused, 1) << "a body at rest keeps its Hessian";
  const NewtonResult ref = solve_static(*m, m->rest_positions, s.gravity);
  ASSERT_TRUE(ref.converged);
  const double tip = tip_displacement(*m, rest.state.x).norm();
  const double tip_ref = tip_displacement(*m, ref.x).norm();
  EXPECT_NEAR(tip / tip_ref, 1.0, 0.005) << "tip " << tip << " m, Newton's " << tip_ref << " m";

  // A grab's penalty goes into the Hessian: a body held by one assembles it every iteration.
  StepInputs in;
  int32_t tip_vertex = 0;
  for (size_t i = 0; i < m->vertex_count(); ++i)
    if (m->rest_positions[i].x() > m->rest_positions[size_t(tip_vertex)].x()) tip_vertex = int32_t(i);
  in.attachments.push_back(Attachment::vertex(tip_vertex, rest.state.x[size_t(tip_vertex)]));
  BodyState held = rest.state;
  Stepper stepper;
  for (int k = 0; k < 5; ++k) EXPECT_EQ(stepper.step(*m, held, s, in).hessian_reused, 0);
}
