// SPDX-License-Identifier: Apache-2.0
// The strain constraint as physics: derivatives against finite differences, invariance under
// rigid motions, the energy identity 1/2 C^T K C = V psi_StVK, and the fused solver kernel
// against the readable definition.
#include "pliant/material.hpp"
#include "pliant/model.hpp"
#include "pliant/strain_constraint.hpp"
#include "kernels/strain_kernel.hpp"
#include "kernels/projection.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

using namespace pliant;

namespace {

TetRest make_rest(const std::array<Vec3, 4>& X) {
  TetMesh mesh;
  mesh.vertices.assign(X.begin(), X.end());
  mesh.tets = {{0, 1, 2, 3}};
  auto model = build_model(mesh, Material{});
  return model->tets[0];
}

// Three draws in a fixed order (the order in which a constructor's arguments are evaluated is
// unspecified: gcc and clang differ, and would test different tets).
template <class Dist>
Vec3 draw3(Dist& u, std::mt19937& rng) {
  const double a = u(rng), b = u(rng), c = u(rng);
  return Vec3(a, b, c);
}

std::array<Vec3, 4> random_tet(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::array<Vec3, 4> X = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)};
  for (auto& p : X) p += draw3(u, rng) * 0.5;
  if (signed_tet_volume(X[0], X[1], X[2], X[3]) < 0) std::swap(X[2], X[3]);
  return X;
}

std::array<Vec3, 4> deform(const std::array<Vec3, 4>& X, std::mt19937& rng, double amount) {
  std::uniform_real_distribution<double> u(-amount, amount);
  auto x = X;
  for (auto& p : x) p += draw3(u, rng);
  return x;
}

// Tets side by side, 3 apart along x, sharing no vertex: they land in one colour, so up to four
// of them make one SIMD pack.
TetMesh disjoint_tets(const std::vector<std::array<Vec3, 4>>& rest) {
  TetMesh mesh;
  for (size_t t = 0; t < rest.size(); ++t) {
    for (const Vec3& p : rest[t]) mesh.vertices.push_back(p + Vec3(3.0 * double(t), 0, 0));
    const int32_t v = int32_t(4 * t);
    mesh.tets.push_back({v, v + 1, v + 2, v + 3});
  }
  return mesh;
}

// The inverse masses of a tet's corners, as the kernels take them.
std::array<double, 4> corner_inverse_masses(const BodyModel& model, const TetRest& tet) {
  return {model.inv_mass[tet.v[0]], model.inv_mass[tet.v[1]], model.inv_mass[tet.v[2]], model.inv_mass[tet.v[3]]};
}

// psi_StVK from the Green strain tensor, written independently of the 6-vector form.
double stvk_density(const Mat3& F, const Lame& l) {
  const Mat3 E = 0.5 * (F.transpose() * F - Mat3::Identity());
  return l.mu * (E.array() * E.array()).sum() + 0.5 * l.lambda * E.trace() * E.trace();
}

// 1/2 C^T K C of the model equals V0 x an independent density for 50 random deformations (the
// last `strong` of them deformed by 0.8 instead of 0.3, enough to invert some tets).
template <class Density>
void expect_energy_equals_density(ElasticModel model, Density density, unsigned seed, int strong, double rel) {
  std::mt19937 rng(seed);
  const Lame l = lame_parameters(2.5e5, 0.42);
  const Mat6 K = stvk_stiffness(l);
  for (int trial = 0; trial < 50; ++trial) {
    const auto X = random_tet(rng);
    const TetRest tet = make_rest(X);
    const auto x = deform(X, rng, trial < 50 - strong ? 0.3 : 0.8);
    const double expected = tet.volume * density(deformation_gradient(tet, x), l);
    EXPECT_NEAR(strain_energy(tet, K, x, model), expected, rel * std::abs(expected) + 1e-12);
  }
}

}  // namespace

TEST(Material, LameParametersForKnownValues) {
  const Lame l = lame_parameters(1e6, 0.4);
  EXPECT_NEAR(l.lambda, 0.4e6 / (1.4 * 0.2), 1e-6);
  EXPECT_NEAR(l.mu, 1e6 / 2.8, 1e-6);
  const Mat6 K = stvk_stiffness(l);
  EXPECT_DOUBLE_EQ(K(0, 0), l.lambda + 2 * l.mu);
  EXPECT_DOUBLE_EQ(K(0, 1), l.lambda);
  EXPECT_DOUBLE_EQ(K(3, 3), l.mu);
  EXPECT_DOUBLE_EQ(K(0, 3), 0.0);
  // Compliance is the inverse: uniaxial stress sigma along x gives strain sigma / E along x and
  // -nu sigma / E across (linear elasticity), a check independent of how K was written.
  const Mat6 alpha = K.inverse();
  EXPECT_NEAR(alpha(0, 0) * 1e6, 1.0, 1e-9);
  EXPECT_NEAR(alpha(1, 0) * 1e6, -0.4, 1e-9);
  EXPECT_NEAR(alpha(3, 3) * l.mu, 1.0, 1e-9);  // engineering shear: gamma = tau / mu
}

TEST(Material, ValidationNamesFieldAndValue) {
  EXPECT_NE(validate(Material{-1, 0.3, 1000}).find("material.young"), std::string::npos);
  EXPECT_NE(validate(Material{1e6, 0.5, 1000}).find("0.5"), std::string::npos);
  EXPECT_NE(validate(Material{1e6, 0.3, 0}).find("material.density"), std::string::npos);
  EXPECT_TRUE(validate(Material{1e6, 0.3, 1000}).empty());
}

TEST(StrainConstraint, JacobianMatchesFiniteDifferences) {
  std::mt19937 rng(1);
  for (int trial = 0; trial < 20; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    const auto x = deform(random_tet(rng), rng, 0.2);
    const Mat6x12 J = strain_jacobian(tet, x);
    const double eps = 1e-6;
    for (int c = 0; c < 12; ++c) {
      auto xp = x, xm = x;
      xp[c / 3][c % 3] += eps;
      xm[c / 3][c % 3] -= eps;
      const Vec6 fd = (strain_constraint(tet, xp) - strain_constraint(tet, xm)) / (2 * eps);
      for (int r = 0; r < 6; ++r) EXPECT_NEAR(J(r, c), fd[r], 1e-7 * (1 + std::abs(fd[r]))) << r << "," << c;
    }
  }
}

TEST(StrainConstraint, EnergyHessianMatchesFiniteDifferencesOfGradient) {
  std::mt19937 rng(2);
  const Mat6 K = stvk_stiffness(lame_parameters(1.0, 0.3));
  for (int trial = 0; trial < 10; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    const auto x = deform(random_tet(rng), rng, 0.2);
    Vec12 g;
    Mat12 H;
    strain_energy_derivatives(tet, K, x, &g, &H, false);
    const double eps = 1e-6;
    for (int c = 0; c < 12; ++c) {
      auto xp = x, xm = x;
      xp[c / 3][c % 3] += eps;
      xm[c / 3][c % 3] -= eps;
      EXPECT_NEAR(g[c], (strain_energy(tet, K, xp) - strain_energy(tet, K, xm)) / (2 * eps), 1e-6);
      Vec12 gp, gm;
      strain_energy_derivatives(tet, K, xp, &gp, nullptr, false);
      strain_energy_derivatives(tet, K, xm, &gm, nullptr, false);
      const Vec12 col = (gp - gm) / (2 * eps);
      for (int r = 0; r < 12; ++r) EXPECT_NEAR(H(r, c), col[r], 1e-5 * (1 + std::abs(col[r])));
    }
  }
}

TEST(StrainConstraint, GradientAloneIsTheJacobianFormsGradient) {
  // Asked for the gradient alone, the Green-strain energy takes a shorter form (the stress times
  // the shape rows, no Jacobian): the same vector as J^T K C to round-off, and the energy's
  // finite differences, on stretched, squashed and inverted tets.
  std::mt19937 rng(5);
  const Mat6 K = stvk_stiffness(lame_parameters(1.0, 0.3));
  for (int trial = 0; trial < 20; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    const auto x = deform(random_tet(rng), rng, trial % 4 == 0 ? 1.5 : 0.3);
    Vec12 alone, with_hessian;
    Mat12 H;
    strain_energy_derivatives(tet, K, x, &alone, nullptr, false);
    strain_energy_derivatives(tet, K, x, &with_hessian, &H, false);
    EXPECT_LE((alone - with_hessian).norm(), 1e-12 * (1 + with_hessian.norm())) << trial;
    const double eps = 1e-6;
    for (int c = 0; c < 12; ++c) {
      auto xp = x, xm = x;
      xp[c / 3][c % 3] += eps;
      xm[c / 3][c % 3] -= eps;
      const double fd = (strain_energy(tet, K, xp) - strain_energy(tet, K, xm)) / (2 * eps);
      EXPECT_NEAR(alone[c], fd, 1e-6 * (1 + std::abs(fd))) << trial << "," << c;
    }
  }
}

TEST(StrainConstraint, PsdPartsHessianIsPsdAndExactWhereTheStressIsTensile) {
  // Newton's per-tet Hessian: J^T K J plus the stress term with its negative curvature removed.
  // Stretched along the world axes (F = R diag(s), s > 1: every stress component tensile) the
  // exact Hessian is already positive semi-definite and must come back unchanged; squashed and
  // sheared, the exact one is indefinite and the projected one must not be.
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> stretch(1.02, 1.3);
  const Mat6 K = stvk_stiffness(lame_parameters(1.0, 0.3));
  int indefinite = 0;
  for (int trial = 0; trial < 40; ++trial) {
    const auto X = random_tet(rng);
    const TetRest tet = make_rest(X);
    const bool tensile = trial % 2 == 0;
    std::array<Vec3, 4> x;
    if (tensile) {
      const Mat3 F = Eigen::Quaterniond::UnitRandom().toRotationMatrix() *
                     Vec3(stretch(rng), stretch(rng), stretch(rng)).asDiagonal();
      for (int k = 0; k < 4; ++k) x[k] = F * X[k];
    } else {
      x = deform(X, rng, 0.25);
      for (auto& p : x) p *= 0.8;
    }
    Vec12 g_exact, g_parts;
    Mat12 H_exact, H_parts;
    strain_energy_derivatives(tet, K, x, &g_exact, &H_exact, false);
    strain_energy_derivatives_psd_parts(tet, K, x, &g_parts, &H_parts);
    EXPECT_LT((g_parts - g_exact).norm(), 1e-14 * (1 + g_exact.norm())) << trial;
    const double scale = H_exact.norm();
    Eigen::SelfAdjointEigenSolver<Mat12> eig(H_parts, Eigen::EigenvaluesOnly);
    EXPECT_GE(eig.eigenvalues().minCoeff(), -1e-12 * scale) << trial;
    // The reference: the stress term sqrt(V0) G (x) I3 read off the exact Hessian, G's negative
    // eigenvalues clamped by a plain 4x4 eigen decomposition.
    const Mat6x12 J = strain_jacobian(tet, x);
    const Mat12 material = J.transpose() * K * J;
    Eigen::Matrix4d G;
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l) G(k, l) = (H_exact - material)(3 * k, 3 * l) / tet.sqrt_volume;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> g_eig(G);
    const Eigen::Matrix4d G_clamped = g_eig.eigenvectors() * g_eig.eigenvalues().cwiseMax(0.0).asDiagonal() *
                                      g_eig.eigenvectors().transpose();
    Mat12 H_reference = material;
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l)
        H_reference.block<3, 3>(3 * k, 3 * l).diagonal().array() += tet.sqrt_volume * G_clamped(k, l);
    EXPECT_LT((H_parts - H_reference).norm(), 1e-9 * scale) << trial;
    if (tensile) {
      EXPECT_LT((H_parts - H_exact).norm(), 1e-12 * scale) << trial;
    } else {
      Eigen::SelfAdjointEigenSolver<Mat12> exact(H_exact, Eigen::EigenvaluesOnly);
      indefinite += exact.eigenvalues().minCoeff() < -1e-6 * scale;
    }
  }
  EXPECT_GE(indefinite, 5) << "the squashed cases must need the projection, or they test nothing";
}

TEST(StrainConstraint, RigidMotionGivesZeroStrainAndZeroResidual) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 20; ++trial) {
    const auto X = random_tet(rng);
    const TetRest tet = make_rest(X);
    const Eigen::Quaterniond q = Eigen::Quaterniond::UnitRandom();
    const Vec3 t(rng() % 7 - 3.0, 0.25, -1.5);
    std::array<Vec3, 4> x;
    for (int k = 0; k < 4; ++k) x[k] = q * X[k] + t;
    EXPECT_LT(strain_constraint(tet, x).norm(), 1e-13);
    // Residual C + alpha~ lambda with lambda = 0, through the solver's own kernel.
    std::vector<Vec3> xs(x.begin(), x.end());
    EXPECT_LT(detail::residual_squared(tet, xs, Vec6::Zero(), Mat6::Identity()), 1e-26);
  }
}

TEST(StrainConstraint, EnergyEqualsVolumeTimesStvkDensity) {
  expect_energy_equals_density(ElasticModel::StVK, stvk_density, 4, 0, 1e-10);
}

namespace {

// The projection by its definition: [J W J^T + alpha~] dl = -C - alpha~ lambda, the vertices
// moved by W J^T dl (in `move`).
Vec6 defined_increment(const TetRest& tet, const std::array<Vec3, 4>& x, const double w[4], const Mat6& at,
                       const Vec6& lambda, Vec12& move) {
  const Mat6x12 J = strain_jacobian(tet, x);
  Eigen::Matrix<double, 12, 12> W = Eigen::Matrix<double, 12, 12>::Zero();
  for (int k = 0; k < 4; ++k) W.block<3, 3>(3 * k, 3 * k) = w[k] * Mat3::Identity();
  const Vec6 dl = (J * W * J.transpose() + at).ldlt().solve(-strain_constraint(tet, x) - at * lambda);
  move = W * J.transpose() * dl;
  return dl;
}

// The same by the kernel's one-tet entry point (line search off): the increment, the moves in dx.
Vec6 kernel_increment(const TetRest& tet, const std::array<Vec3, 4>& x, const double w[4],
                      const detail::KernelCompliance& at, const Vec6& lambda, Vec3 dx[4]) {
  detail::ProjectionParams params;
  params.alpha_tilde = at;
  const Vec3* p[4] = {&x[0], &x[1], &x[2], &x[3]};
  Vec6 dl;
  detail::strain_increment(tet, p, w, lambda, params, dl, dx);
  return dl;
}

}  // namespace

TEST(StrainConstraint, TheSixBySixSolveIsAccurateToItsConditionNumber) {
  // Random symmetric positive definite systems of condition number 1e2 to 1e10 (random
  // orthogonal eigenvectors): the solution's relative error stays within a few condition numbers
  // times the rounding unit, as LDL^T's does, against the same system solved in long double;
  // every pivot is positive; so for the four-lane solve. Inverting 3x3 or 2x2
  // blocks by their adjugates (fewer divisions) fails it, from 1e4 and 1e6 on: errors of the
  // condition number squared.
  std::mt19937 rng(11);
  std::normal_distribution<double> normal(0.0, 1.0);
  const double eps = std::numeric_limits<double>::epsilon();
  for (double cond : {1e2, 1e4, 1e6, 1e8, 1e10}) {
    double worst = 0.0;
    for (int trial = 0; trial < 400; ++trial) {
      Mat6 g;
      for (int i = 0; i < 6; ++i)
        for (int j = 0; j < 6; ++j) g(i, j) = normal(rng);
      const Mat6 u = Eigen::HouseholderQR<Mat6>(g).householderQ();
      Vec6 ev;
      for (int i = 0; i < 6; ++i) ev[i] = 40.0 * std::pow(cond, -i / 5.0);
      std::shuffle(ev.data(), ev.data() + 6, rng);
      const Mat6 a = u * ev.asDiagonal() * u.transpose();
      Vec6 r;
      for (int i = 0; i < 6; ++i) r[i] = normal(rng);
      double A[6][6], rhs[6], d[6], y[6];
      for (int i = 0; i < 6; ++i) {
        rhs[i] = r[i];
        for (int j = 0; j < 6; ++j) A[i][j] = a(i, j);
      }
      detail::ldlt_solve(A, rhs, 1.0, d, y);
      for (int i = 0; i < 6; ++i) ASSERT_GT(d[i], 0.0) << "cond " << cond << ", pivot " << i;
      using Mat6l = Eigen::Matrix<long double, 6, 6>;
      using Vec6l = Eigen::Matrix<long double, 6, 1>;
      const Vec6l exact = Mat6l(a.cast<long double>()).ldlt().solve(Vec6l(r.cast<long double>()));
      long double err = 0;
      for (int i = 0; i < 6; ++i) err += (y[i] - exact[i]) * (y[i] - exact[i]);
      worst = std::max(worst, double(std::sqrt(err) / exact.norm()));
      if (trial == 0) {
        // The same system in every lane, scaled per lane by a power of two (which leaves every
        // step of the solve exact up to that power): the lanes' solutions are equal to the bit
        // and as accurate as the one-lane solve's.
        detail::v4d A4[6][6], rhs4[6], d4[6], y4[6];
        const double scale[4] = {1.0, 2.0, 0.5, 4.0};
        for (int i = 0; i < 6; ++i) {
          for (int l = 0; l < 4; ++l) rhs4[i][l] = rhs[i] * scale[l];
          for (int j = 0; j < 6; ++j)
            for (int l = 0; l < 4; ++l) A4[i][j][l] = A[i][j] * scale[l];
        }
        detail::ldlt_solve(A4, rhs4, 1.0, d4, y4);
        long double err4 = 0;
        for (int i = 0; i < 6; ++i) {
          for (int l = 1; l < 4; ++l) ASSERT_EQ(y4[i][l], y4[i][0]) << "lane " << l << ", row " << i;
          err4 += (y4[i][0] - exact[i]) * (y4[i][0] - exact[i]);
        }
        worst = std::max(worst, double(std::sqrt(err4) / exact.norm()));
      }
    }
    EXPECT_LT(worst, 8.0 * cond * eps) << "condition number " << cond;
  }
}

TEST(StrainConstraint, FusedKernelMatchesDefinition) {
  // The solver's projection must solve [J W J^T + alpha~] dl = -C - alpha~ lambda and move the
  // vertices by W J^T dl.
  std::mt19937 rng(5);
  for (int trial = 0; trial < 20; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    const auto x = deform(random_tet(rng), rng, 0.2);
    const double w[4] = {1.3, 0.0, 2.1, 0.7};
    const Mat6 at = stvk_stiffness(lame_parameters(3.0, 0.35)).inverse() * 0.8;
    Vec6 lambda;
    lambda << 0.1, -0.2, 0.05, 0.3, -0.1, 0.02;
    Vec3 dx[4];
    const Vec6 dl = kernel_increment(tet, x, w, at, lambda, dx);
    Vec12 move;
    const Vec6 expected = defined_increment(tet, x, w, at, lambda, move);
    EXPECT_LT((dl - expected).norm(), 1e-10 * (1 + expected.norm()));
    for (int k = 0; k < 4; ++k) EXPECT_LT((dx[k] - move.segment<3>(3 * k)).norm(), 1e-10 * (1 + move.norm()));
  }
}

namespace {

// One pack of n disjoint random tets (n < 4: padding lanes) projected by the SIMD kernel against
// each tet by the scalar kernel, from multipliers that differ in every slot and row (a pack's
// slots are moved into rows and back in registers).
void expect_pack_matches_scalar_kernel(int n) {
  std::mt19937 rng(6 + n);
  std::vector<std::array<Vec3, 4>> tets;
  for (int t = 0; t < n; ++t) tets.push_back(random_tet(rng));
  const TetMesh mesh = disjoint_tets(tets);
  auto model = build_model(mesh, Material{2e5, 0.35, 900});
  ASSERT_EQ(model->colours.size(), 1u);
  const detail::PackedModel& packed = detail::packed(*model);
  ASSERT_EQ(packed.packs.size(), 1u);
  EXPECT_EQ(packed.packs[0].lanes, n);
  std::vector<Vec3> x = mesh.vertices;
  for (auto& p : x) p += 0.05 * Vec3(std::sin(7 * p.x()), std::cos(5 * p.y()), std::sin(3 * p.z()));
  std::uniform_real_distribution<double> u(-2e-4, 2e-4);
  std::vector<Vec6> lambda(packed.slot_count()), dl(packed.slot_count(), Vec6::Constant(7.0));
  for (Vec6& l : lambda)
    for (int r = 0; r < 6; ++r) l[r] = u(rng);
  const Mat6 at = model->compliance * 3600.0;
  std::vector<Vec3> xp = x;
  std::vector<Vec6> lp = lambda;
  detail::project_pack(packed.packs[0], xp, lp, &dl, *model, at, 1.0, 0.0, false);
  for (int t = 0; t < n; ++t) {
    const int32_t slot = model->tet_slot[t];
    const TetRest& tet = model->tets[t];
    const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
    const std::array<double, 4> wa = corner_inverse_masses(*model, tet);
    const double* w = wa.data();
    detail::ProjectionParams params;
    params.alpha_tilde = at;
    Vec6 expected;
    Vec3 dx[4];
    detail::strain_increment(tet, p, w, lambda[slot], params, expected, dx);
    EXPECT_LT((dl[slot] - expected).norm(), 1e-12 * (1 + expected.norm())) << t;
    EXPECT_LT((lp[slot] - lambda[slot] - expected).norm(), 1e-12 * (1 + expected.norm())) << t;
    for (int k = 0; k < 4; ++k)
      EXPECT_LT((xp[tet.v[k]] - x[tet.v[k]] - dx[k]).norm(), 1e-12 * (1 + dx[k].norm())) << t << "," << k;
  }
  for (size_t s = size_t(n); s < packed.slot_count(); ++s) {  // padding slots are never written
    EXPECT_EQ(lp[s], lambda[s]) << s;
    EXPECT_EQ(dl[s], Vec6::Constant(7.0)) << s;
  }
}

}  // namespace

TEST(StrainConstraint, PackedKernelMatchesScalarKernel) {
  // The SIMD Gauss-Seidel pack (4 tets of one colour) must give each tet the same increment
  // and corrections as the scalar kernel; padding lanes must not write.
  expect_pack_matches_scalar_kernel(3);
  expect_pack_matches_scalar_kernel(4);
}

TEST(StrainConstraint, TheKernelSkipsOnlyTheComplianceEntriesThatAreZero) {
  // An isotropic material's alpha~ couples the normal rows among themselves and each shear row
  // with itself only; the kernels then leave out the products with the other entries. That must
  // change nothing to the last bit (both strain models, with and without the line search; stiff
  // slivers moved by a few % of an edge, where the line search shortens some steps), and a
  // compliance that couples a normal row with a shear row must take the full product: the step
  // then solves its own system.
  std::mt19937 rng(21);
  for (ElasticModel model : {ElasticModel::StVK, ElasticModel::Corotated}) {
    bool searched = false;  // the line search shortened a step in some pack
    for (int trial = 0; trial < 10; ++trial) {
      std::vector<std::array<Vec3, 4>> slivers(4);
      for (auto& X : slivers) {
        X = random_tet(rng);
        X[3] = (X[0] + X[1] + X[2]) / 3.0 + 0.01 * (X[1] - X[0]).cross(X[2] - X[0]).normalized();
      }
      const TetMesh mesh = disjoint_tets(slivers);
      Material mat{1e9, 0.35, 900};  // stiff: the constraint dominates
      mat.model = model;
      auto body = build_model(mesh, mat);
      const detail::TetPack& pack = detail::packed(*body).packs[0];
      std::vector<Vec3> x = mesh.vertices;
      std::uniform_real_distribution<double> move(-0.05, 0.05), u(-2e-4, 2e-4);
      for (auto& p : x) p += draw3(move, rng);
      std::vector<Vec6> lambda(detail::packed(*body).slot_count());
      for (Vec6& l : lambda)
        for (int r = 0; r < 6; ++r) l[r] = u(rng);
      const detail::KernelCompliance skipping(Mat6(body->compliance * 3600.0));
      ASSERT_TRUE(skipping.normal_and_shear);
      detail::KernelCompliance full = skipping;
      full.normal_and_shear = false;
      std::vector<Vec6> without_search;
      for (bool line_search : {false, true}) {
        std::vector<Vec3> xa = x, xb = x;
        std::vector<Vec6> la = lambda, lb = lambda, da(lambda.size()), db(lambda.size());
        detail::project_pack(pack, xa, la, &da, *body, skipping, 1.0, 0.0, line_search);
        detail::project_pack(pack, xb, lb, &db, *body, full, 1.0, 0.0, line_search);
        EXPECT_EQ(xa, xb) << int(model) << line_search;
        EXPECT_EQ(la, lb) << int(model) << line_search;
        EXPECT_EQ(da, db) << int(model) << line_search;
        ASSERT_GT(da[0].norm(), 0.0);
        if (!line_search) without_search = da;
        else searched = searched || da != without_search;
      }
    }
    EXPECT_TRUE(searched) << int(model) << ": the line search shortened no step, so it was not compared";
  }
  // A compliance with normal-shear coupling (still symmetric positive definite).
  Mat6 coupled = stvk_stiffness(lame_parameters(3.0, 0.35)).inverse() * 0.8;
  coupled(0, 3) = coupled(3, 0) = 0.2 * coupled(0, 0);
  coupled(2, 5) = coupled(5, 2) = -0.1 * coupled(0, 0);
  ASSERT_GT(coupled.ldlt().vectorD().minCoeff(), 0.0);
  EXPECT_FALSE(detail::KernelCompliance(coupled).normal_and_shear);
  Mat6 shear_pair = stvk_stiffness(lame_parameters(3.0, 0.35)).inverse();
  shear_pair(3, 4) = shear_pair(4, 3) = 1e-300;
  EXPECT_FALSE(detail::KernelCompliance(shear_pair).normal_and_shear);
  for (int trial = 0; trial < 10; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    const auto x = deform(random_tet(rng), rng, 0.2);
    const double w[4] = {1.3, 0.4, 2.1, 0.7};
    Vec6 lambda;
    lambda << 0.1, -0.2, 0.05, 0.3, -0.1, 0.02;
    Vec12 move;
    const Vec6 expected = defined_increment(tet, x, w, coupled, lambda, move);
    Vec3 dx[4];
    detail::KernelCompliance at(coupled);
    EXPECT_LT((kernel_increment(tet, x, w, at, lambda, dx) - expected).norm(), 1e-10 * (1 + expected.norm())) << trial;
    at.normal_and_shear = true;  // wrongly skipping the coupling: another step
    EXPECT_GT((kernel_increment(tet, x, w, at, lambda, dx) - expected).norm(), 1e-6 * (1 + expected.norm())) << trial;
  }
}

TEST(StrainConstraint, LineSearchKeepsASquashedTetFromOvershooting) {
  // A tet squashed to 20% of its height: the linearised Green-strain step stretches it far past
  // its rest shape (the correction of a singular value s is (1 - s^2) / 2s = 2.4) and its own
  // residual grows. With the line search the step is shortened until that residual does not
  // grow; a mildly strained tet (step below kSmallStep) is projected exactly as before. Both
  // kernels (SIMD pack and scalar) must agree.
  const double squash[3] = {0.2, 0.5, 0.97};
  const std::array<Vec3, 4> X = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)};
  const TetMesh mesh = disjoint_tets({X, X, X});
  auto model = build_model(mesh, Material{1e9, 0.3, 1000});  // stiff: the constraint dominates
  const detail::PackedModel& packed = detail::packed(*model);
  ASSERT_EQ(packed.packs.size(), 1u);
  std::vector<Vec3> x = mesh.vertices;
  for (int t = 0; t < 3; ++t)
    for (int k = 0; k < 4; ++k) x[4 * t + k].z() *= squash[t];
  const Mat6 at = model->compliance * 3600.0;
  const std::vector<Vec6> lambda(packed.slot_count(), Vec6::Zero());
  auto det_f = [&](const std::vector<Vec3>& y, int t) {
    return signed_tet_volume(y[4 * t], y[4 * t + 1], y[4 * t + 2], y[4 * t + 3]) / model->tets[t].volume;
  };
  std::vector<Vec3> with = x, without = x;
  std::vector<Vec6> lw = lambda, lo = lambda, dl(packed.slot_count(), Vec6::Zero());
  detail::project_pack(packed.packs[0], with, lw, &dl, *model, at, 1.0, 0.0, true);
  detail::project_pack(packed.packs[0], without, lo, &dl, *model, at, 1.0, 0.0, false);
  for (int t = 0; t < 3; ++t) {
    const TetRest& tet = model->tets[t];
    const double before = detail::residual_squared(tet, x, lambda[t], at);
    const double after_with = detail::residual_squared(tet, with, lw[t], at);
    const double after_without = detail::residual_squared(tet, without, lo[t], at);
    EXPECT_LE(after_with, before) << t;
    if (t == 0) {
      EXPECT_GT(after_without, before) << "the full step should overshoot here, or the test shows nothing";
      EXPECT_GT(det_f(without, 0), 2.0);
      EXPECT_GT(det_f(with, 0), 0.2);
      EXPECT_LT(det_f(with, 0), 1.5);
    }
    if (t == 2) {
      for (int k = 0; k < 4; ++k) EXPECT_EQ(with[tet.v[k]], without[tet.v[k]]);
    }
    // The scalar kernel (Jacobi sweep) takes the same shortened step.
    const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
    const std::array<double, 4> wa = corner_inverse_masses(*model, tet);
    const double* w = wa.data();
    detail::ProjectionParams params;
    params.alpha_tilde = at;
    params.line_search = true;
    Vec6 inc;
    Vec3 dx[4];
    detail::strain_increment(tet, p, w, lambda[t], params, inc, dx);
    EXPECT_LT((lw[t] - lambda[t] - inc).norm(), 1e-10 * (1 + inc.norm())) << t;
    for (int k = 0; k < 4; ++k)
      EXPECT_LT((with[tet.v[k]] - x[tet.v[k]] - dx[k]).norm(), 1e-10 * (1 + dx[k].norm())) << t << "," << k;
  }
}

// ---- The corotated strain (ElasticModel::Corotated) ----

namespace {

// F with chosen singular values between two random rotations; a negative value inverts it.
Mat3 f_with_singular_values(double s0, double s1, double s2) {
  const Mat3 U = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
  const Mat3 V = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
  return U * Vec3(s0, s1, s2).asDiagonal() * V.transpose();
}

// mu |S - I|^2 + lambda/2 tr(S - I)^2 from the singular values s of F (S's eigenvalues, the
// smallest negated when det F < 0), written independently of the 6-vector form.
double corotated_density(const Mat3& F, const Lame& l) {
  Eigen::SelfAdjointEigenSolver<Mat3> eig(F.transpose() * F);  // ascending
  Vec3 s = eig.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  if (F.determinant() < 0) s[0] = -s[0];
  const Vec3 e = s - Vec3::Ones();
  return l.mu * e.squaredNorm() + 0.5 * l.lambda * e.sum() * e.sum();
}

}  // namespace

TEST(Corotated, PolarRotationIsProperAndLeavesASymmetricStretch) {
  // R must be a rotation (R^T R = I, det R = +1) with S = R^T F symmetric; for det F > 0 S is
  // positive definite, for det F < 0 exactly its smallest-magnitude eigenvalue is negative.
  srand(11);  // Quaterniond::UnitRandom draws from rand()
  const double cases[][3] = {{1, 1, 1},       {1.01, 0.99, 1},  {2, 1, 0.5},     {5.5, 1, 0.07},
                             {1e3, 1, 1},     {1, 1, 1e-4},     {1, 1, -0.3},    {2, 0.5, -0.1},
                             {1, 1, -1},      {3, 1, -1e-6},    {1, 0.999999, 1}};
  for (const auto& c : cases)
    for (int rep = 0; rep < 5; ++rep) {
      const Mat3 F = f_with_singular_values(c[0], c[1], c[2]);
      const Mat3 R = polar_rotation(F);
      EXPECT_LT((R.transpose() * R - Mat3::Identity()).norm(), 1e-12) << c[0] << " " << c[1] << " " << c[2];
      EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
      const Mat3 S = R.transpose() * F;
      EXPECT_LT((S - S.transpose()).norm(), 1e-10 * F.norm()) << c[0] << " " << c[1] << " " << c[2];
      Eigen::SelfAdjointEigenSolver<Mat3> eig(0.5 * (S + S.transpose()));
      const Vec3 ev = eig.eigenvalues();  // ascending
      const Vec3 expect = Vec3(std::abs(c[0]), std::abs(c[1]), std::abs(c[2]));
      // The eigenvalues of S are the singular values, the smallest negated when inverted.
      std::array<double, 3> sv = {expect[0], expect[1], expect[2]};
      std::sort(sv.begin(), sv.end());
      if (c[2] < 0) sv[0] = -sv[0];
      std::sort(sv.begin(), sv.end());
      for (int i = 0; i < 3; ++i) EXPECT_NEAR(ev[i], sv[i], 1e-9 * expect.maxCoeff()) << c[0] << " " << c[1] << " " << c[2];
    }
}

TEST(Corotated, RigidMotionGivesZeroStrainButAMirrorImageDoesNot) {
  // Rotations of any angle (up to half a turn) give zero strain and zero residual through both
  // the reference and the solver's kernel. A mirror image (det F = -1) has zero Green strain:
  // the thesis's constraint cannot tell an inverted tet from its rest shape. The corotated
  // strain sees it flipped through one direction: one principal strain of -2.
  std::mt19937 rng(12);
  srand(12);
  for (int trial = 0; trial < 20; ++trial) {
    const auto X = random_tet(rng);
    const TetRest tet = make_rest(X);
    const Eigen::Quaterniond q = Eigen::Quaterniond::UnitRandom();
    std::array<Vec3, 4> x, mirrored;
    for (int k = 0; k < 4; ++k) {
      x[k] = q * X[k] + Vec3(0.5, -2, 1);
      mirrored[k] = Vec3(-X[k].x(), X[k].y(), X[k].z());
    }
    EXPECT_LT(strain_constraint(tet, x, ElasticModel::Corotated).norm(), 1e-12);
    std::vector<Vec3> xs(x.begin(), x.end());
    EXPECT_LT(detail::residual_squared(tet, xs, Vec6::Zero(), Mat6::Identity(), ElasticModel::Corotated), 1e-24);
    EXPECT_LT(strain_constraint(tet, mirrored, ElasticModel::StVK).norm(), 1e-12);
    const Vec6 c = strain_vector(deformation_gradient(tet, mirrored), ElasticModel::Corotated);
    // Trace of S - I is -2, its Frobenius norm 2 (engineering shears count twice in c).
    EXPECT_NEAR(c[0] + c[1] + c[2], -2.0, 1e-9);
    const double frob2 = c.head<3>().squaredNorm() + 0.5 * c.tail<3>().squaredNorm();
    EXPECT_NEAR(frob2, 4.0, 1e-9);
  }
}

TEST(Corotated, EnergyEqualsVolumeTimesCorotatedDensity) {
  expect_energy_equals_density(ElasticModel::Corotated, corotated_density, 13, 10, 1e-9);  // some inverted
}

TEST(Corotated, JacobianMatchesFiniteDifferences) {
  // dC/dx including the rotation's change, against central differences of C (R recomputed).
  std::mt19937 rng(17);
  for (int trial = 0; trial < 20; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    auto x = deform(random_tet(rng), rng, 0.25);
    if (trial >= 15) std::swap(x[0], x[1]);  // inverted
    const Mat6x12 J = strain_jacobian(tet, x, ElasticModel::Corotated);
    const double eps = 1e-6;
    for (int c = 0; c < 12; ++c) {
      auto xp = x, xm = x;
      xp[c / 3][c % 3] += eps;
      xm[c / 3][c % 3] -= eps;
      const Vec6 fd = (strain_constraint(tet, xp, ElasticModel::Corotated) -
                       strain_constraint(tet, xm, ElasticModel::Corotated)) / (2 * eps);
      for (int r = 0; r < 6; ++r) EXPECT_NEAR(J(r, c), fd[r], 1e-6 * (1 + std::abs(fd[r]))) << trial << ": " << r << "," << c;
    }
  }
}

TEST(Corotated, GradientAndHessianMatchFiniteDifferences) {
  // The gradient J^T K C is the exact energy gradient; the Hessian carries the rotation's
  // derivative. Both against central differences, on deformed and inverted tets.
  std::mt19937 rng(14);
  const Mat6 K = stvk_stiffness(lame_parameters(1.0, 0.3));
  int inverted = 0;
  for (int trial = 0; trial < 16; ++trial) {
    const TetRest tet = make_rest(random_tet(rng));
    auto x = deform(random_tet(rng), rng, 0.2);
    if (trial >= 12) std::swap(x[0], x[1]);  // mirrored order: det F < 0
    inverted += volume_ratio(tet, x) < 0;
    Vec12 g;
    Mat12 H;
    strain_energy_derivatives(tet, K, x, &g, &H, false, ElasticModel::Corotated);
    const double eps = 1e-6;
    for (int c = 0; c < 12; ++c) {
      auto xp = x, xm = x;
      xp[c / 3][c % 3] += eps;
      xm[c / 3][c % 3] -= eps;
      const double fd = (strain_energy(tet, K, xp, ElasticModel::Corotated) -
                         strain_energy(tet, K, xm, ElasticModel::Corotated)) / (2 * eps);
      EXPECT_NEAR(g[c], fd, 1e-6 * (1 + std::abs(fd))) << trial << "," << c;
      Vec12 gp, gm;
      strain_energy_derivatives(tet, K, xp, &gp, nullptr, false, ElasticModel::Corotated);
      strain_energy_derivatives(tet, K, xm, &gm, nullptr, false, ElasticModel::Corotated);
      const Vec12 col = (gp - gm) / (2 * eps);
      for (int r = 0; r < 12; ++r) EXPECT_NEAR(H(r, c), col[r], 1e-5 * (1 + std::abs(col[r]))) << trial << "," << r << "," << c;
    }
  }
  EXPECT_GE(inverted, 3) << "the inverted cases must be inverted, or they test nothing";
}

TEST(Corotated, AgreesWithStvkAtSmallStrainAndResistsCompressionWhereStvkGivesWay) {
  // Same K: for F = R (I + e H) the two strains differ by O(e^2). Squashed along one axis to a
  // stretch s, StVK's stress there ((lambda + 2 mu) (s^2 - 1) s / 2 for a uniaxial squash)
  // falls back to zero as s -> 0; the corotated one ((lambda + 2 mu)(s - 1)) keeps growing.
  std::mt19937 rng(15);
  srand(15);
  for (int trial = 0; trial < 10; ++trial) {
    Mat3 H = Mat3::Random();
    const Mat3 R = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
    for (double e : {1e-2, 1e-3}) {
      const Mat3 F = R * (Mat3::Identity() + e * H);
      const double diff = (strain_vector(F, ElasticModel::Corotated) - strain_vector(F, ElasticModel::StVK)).norm();
      EXPECT_LT(diff, 10 * e * e * H.squaredNorm()) << e;
    }
  }
  const TetRest tet = make_rest({Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1)});
  const Mat6 K = stvk_stiffness(lame_parameters(1.0, 0.3));
  auto force_on_apex = [&](double s, ElasticModel m) {  // -dE/dz of vertex 3 of the squashed tet
    const std::array<Vec3, 4> y = {Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, s)};
    Vec12 g;
    strain_energy_derivatives(tet, K, y, &g, nullptr, false, m);
    return -g[11];
  };
  // The push back (+z on the apex) at 60%, 30% and 5% of the height: StVK's is smaller at 5%
  // than at 60%, the corotated one grows as the tet is squashed.
  EXPECT_GT(force_on_apex(0.6, ElasticModel::StVK), force_on_apex(0.05, ElasticModel::StVK));
  EXPECT_GT(force_on_apex(0.05, ElasticModel::Corotated), force_on_apex(0.3, ElasticModel::Corotated));
  EXPECT_GT(force_on_apex(0.3, ElasticModel::Corotated), force_on_apex(0.6, ElasticModel::Corotated));
  EXPECT_GT(force_on_apex(0.6, ElasticModel::Corotated), 0.0);
}

TEST(Corotated, BothKernelsSolveTheLinearisedSystem) {
  // Scalar kernel (Jacobi) and SIMD pack (Gauss-Seidel) against [J W J^T + alpha~] dl =
  // -C - alpha~ lambda, dx = W J^T dl, with the corotated J of the current positions (line
  // search off); with the line search on, the two kernels take the same steps.
  std::mt19937 rng(16);
  const TetMesh mesh = disjoint_tets({random_tet(rng), random_tet(rng), random_tet(rng)});
  Material mat{2e5, 0.35, 900};
  mat.model = ElasticModel::Corotated;
  auto model = build_model(mesh, mat);
  const detail::PackedModel& packed = detail::packed(*model);
  ASSERT_EQ(packed.packs.size(), 1u);
  std::vector<Vec3> x = mesh.vertices;
  for (auto& p : x) p += 0.2 * Vec3(std::sin(7 * p.x()), std::cos(5 * p.y()), std::sin(3 * p.z()));
  std::vector<Vec6> lambda(packed.slot_count(), Vec6::Constant(1e-4)), dl(packed.slot_count(), Vec6::Zero());
  const Mat6 at = model->compliance * 3600.0;
  std::vector<Vec3> xp = x;
  std::vector<Vec6> lp = lambda;
  detail::project_pack(packed.packs[0], xp, lp, &dl, *model, at, 1.0, 0.0, false);
  std::vector<Vec3> xs = x;  // the pack with the line search
  std::vector<Vec6> ls = lambda, dls(packed.slot_count(), Vec6::Zero());
  detail::project_pack(packed.packs[0], xs, ls, &dls, *model, at, 1.0, 0.0, true);
  for (int t = 0; t < 3; ++t) {
    const TetRest& tet = model->tets[t];
    const auto xt = gather(x, tet.v);
    const std::array<double, 4> wa = corner_inverse_masses(*model, tet);
    const double* w = wa.data();
    const Mat6x12 J = strain_jacobian(tet, xt, ElasticModel::Corotated);
    Eigen::Matrix<double, 12, 12> W = Eigen::Matrix<double, 12, 12>::Zero();
    for (int k = 0; k < 4; ++k) W.block<3, 3>(3 * k, 3 * k) = w[k] * Mat3::Identity();
    const Vec6 expected = (J * W * J.transpose() + at).ldlt().solve(
        -strain_constraint(tet, xt, ElasticModel::Corotated) - at * lambda[t]);
    const Vec12 move = W * J.transpose() * expected;
    ASSERT_GT(expected.norm(), 1e-8);
    EXPECT_LT((dl[t] - expected).norm(), 1e-10 * expected.norm()) << t;
    for (int k = 0; k < 4; ++k)
      EXPECT_LT((xp[tet.v[k]] - x[tet.v[k]] - move.segment<3>(3 * k)).norm(), 1e-10 * move.norm()) << t << "," << k;
    detail::ProjectionParams params;
    params.model = ElasticModel::Corotated;
    params.alpha_tilde = at;
    const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
    Vec6 inc;
    Vec3 dx[4];
    detail::strain_increment(tet, p, w, lambda[t], params, inc, dx);
    EXPECT_LT((inc - expected).norm(), 1e-10 * expected.norm()) << t;
    for (int k = 0; k < 4; ++k) EXPECT_LT((dx[k] - move.segment<3>(3 * k)).norm(), 1e-10 * move.norm());
    params.line_search = true;
    detail::strain_increment(tet, p, w, lambda[t], params, inc, dx);
    EXPECT_LT((inc - dls[t]).norm(), 1e-10 * inc.norm()) << t;
    for (int k = 0; k < 4; ++k) EXPECT_LT((xs[tet.v[k]] - x[tet.v[k]] - dx[k]).norm(), 1e-10 * move.norm());
  }
}

TEST(Corotated, LineSearchShortensStepsThatWouldRaiseTheResidual) {
  // Slivers (one corner 1% of the edge above the opposite face, as the thesis hippo has) moved
  // by a few % of an edge, stiff material (the constraint dominates): there F is far from a
  // rotation and the exact-Jacobian step can overshoot where the rotation turns fast. With the
  // line search no tet's own residual grows, some steps are shortened, and both kernels agree.
  std::mt19937 rng(18);
  int shortened = 0, grew_without = 0;
  for (int trial = 0; trial < 40; ++trial) {
    std::vector<std::array<Vec3, 4>> slivers(4);
    for (auto& X : slivers) {
      X = random_tet(rng);
      const Vec3 n = (X[1] - X[0]).cross(X[2] - X[0]).normalized();
      X[3] = (X[0] + X[1] + X[2]) / 3.0 + 0.01 * n;  // a sliver
    }
    const TetMesh mesh = disjoint_tets(slivers);
    Material mat{1e9, 0.3, 1000};
    mat.model = ElasticModel::Corotated;
    auto model = build_model(mesh, mat);
    const detail::PackedModel& packed = detail::packed(*model);
    std::vector<Vec3> x = mesh.vertices;
    std::uniform_real_distribution<double> u(-0.05, 0.05);
    for (auto& p : x) p += draw3(u, rng);
    const Mat6 at = model->compliance * 3600.0;
    const std::vector<Vec6> lambda(4, Vec6::Zero());
    std::vector<Vec3> with = x, without = x;
    std::vector<Vec6> lw = lambda, lo = lambda, dl(4, Vec6::Zero()), dlo(4, Vec6::Zero());
    detail::project_pack(packed.packs[0], with, lw, &dl, *model, at, 1.0, 0.0, true);
    detail::project_pack(packed.packs[0], without, lo, &dlo, *model, at, 1.0, 0.0, false);
    for (int t = 0; t < 4; ++t) {
      const TetRest& tet = model->tets[t];
      const double before = detail::residual_squared(tet, x, lambda[t], at, ElasticModel::Corotated);
      EXPECT_LE(detail::residual_squared(tet, with, lw[t], at, ElasticModel::Corotated), before * (1 + 1e-12));
      grew_without += detail::residual_squared(tet, without, lo[t], at, ElasticModel::Corotated) > before;
      shortened += dl[t].norm() < 0.99 * dlo[t].norm();
      const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
      const std::array<double, 4> wa = corner_inverse_masses(*model, tet);
      const double* w = wa.data();
      detail::ProjectionParams params;
      params.model = ElasticModel::Corotated;
      params.alpha_tilde = at;
      params.line_search = true;
      Vec6 inc;
      Vec3 dx[4];
      detail::strain_increment(tet, p, w, lambda[t], params, inc, dx);
      // The two kernels solve the same 6x6 system [J W J^T + alpha~] with their operations in a
      // different order (lanes vs scalars, and whatever the compiler contracts into FMAs or
      // vectorises), so they differ by rounding, amplified by the system's condition number and
      // by the corotated Jacobian's rotation, whose sensitivity to F is 1/(s2 + s3) (F's two
      // smallest signed singular values), large for squashed slivers. A kernel taking a
      // different step differs by a share of the step.
      const auto xt = gather(x, tet.v);
      const Mat6x12 J = strain_jacobian(tet, xt, ElasticModel::Corotated);
      Eigen::Matrix<double, 12, 12> W = Eigen::Matrix<double, 12, 12>::Zero();
      for (int k = 0; k < 4; ++k) W.block<3, 3>(3 * k, 3 * k) = w[k] * Mat3::Identity();
      const Eigen::JacobiSVD<Mat6> svd(J * W * J.transpose() + at);
      const double cond = svd.singularValues()(0) / svd.singularValues()(5);
      Mat3 Ds;
      for (int k = 0; k < 3; ++k) Ds.col(k) = xt[k] - xt[3];
      const Mat3 F = Ds * tet.dm_inv;
      const Vec3 sf = Eigen::JacobiSVD<Mat3>(F).singularValues();
      const double s3 = F.determinant() < 0 ? -sf(2) : sf(2);
      const double rotation = sf(0) / std::max(std::abs(sf(1) + s3), 1e-12 * sf(0));
      // Measured on these 160 steps: at most 0.42 of cond * rotation * epsilon * |step| with gcc
      // 12 (-O3) and with clang 14 (ASan, -O1), 1e-13 to 1.3e-8 in absolute terms.
      const double rounding = 16 * cond * rotation * std::numeric_limits<double>::epsilon();
      const double d_inc = (inc - dl[t]).norm();
      EXPECT_LT(d_inc, 1e-9 * (1 + inc.norm()) + rounding * inc.norm()) << trial << "," << t << ": condition number " << cond << ", rotation sensitivity " << rotation;
      for (int k = 0; k < 4; ++k)
        EXPECT_LT((with[tet.v[k]] - x[tet.v[k]] - dx[k]).norm(), 1e-9 * (1 + dx[k].norm()) + rounding * dx[k].norm())
            << trial << "," << t << "," << k << ": condition number " << cond << ", rotation sensitivity " << rotation;
    }
  }
  EXPECT_GE(grew_without, 1) << "no full step raised a residual: the cases test nothing";
  EXPECT_GE(shortened, 1) << "line search: " << shortened << " of 160 steps shortened, " << grew_without
                          << " full steps raised the residual";
}
