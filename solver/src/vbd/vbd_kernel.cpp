// SPDX-License-Identifier: Apache-2.0
// One tet's contribution to one vertex's 3x3 Newton system, without the 12x12 Hessian.
//
// F = D_s D_m^-1, so a change dx of corner k changes F by dF = dx b (b the row 3-vector of
// shape derivatives: row k of D_m^-1 for k < 3, minus their sum for k = 3). With the energy
// E = V0 psi(F) and P = dpsi/dF (first Piola-Kirchhoff stress):
//   dE/dx_k = V0 P b^T,   d2E/dx_k^2 = V0 d(P b^T)/dx along dF = dx b.
// StVK (psi = 1/2 c^T K c, c the Green strain in Voigt order with engineering shears): the
// second Piola-Kirchhoff stress S is the symmetric matrix of s = K c, P = F S. With u = F^T dx,
// dc = A u, A = [b0 0 0; 0 b1 0; 0 0 b2; 0 b2 b1; b2 0 b0; b1 b0 0] (6x3), and dS b^T = A^T ds,
// so d(P b^T) = dF S b^T + F dS b^T = (b S b^T) dx + F A^T K A F^T dx:
//   H = V0 [ (b S b^T) I + M^T K M ],  M = A F^T   (the second term is the Gauss-Newton part).
// Corotated (psi = mu |S - I|^2 + lambda/2 tr(S - I)^2, F = R S): P = 2 mu (F - R) +
// lambda tr(S - I) R. The rotation's change is R^T dR = [w]x with (tr(S) I - S) w =
// 2 axial(R^T dF) = b x (R^T dx), so dR b^T = R Q R^T dx with Q = [b]x^T Ginv [b]x
// (Ginv = (tr(S) I - S)^-1), and d tr(S) = (R b^T) . dx:
//   H = V0 [ 2 mu |b|^2 I + lambda q q^T + (lambda tr(S - I) - 2 mu) R Q R^T ],  q = R b^T
// (R held fixed drops the last term: that is the Gauss-Newton choice here).
#include "vbd/vbd.hpp"

#include "pliant/strain_constraint.hpp"

#include <Eigen/Dense>

namespace pliant::detail {

namespace {

Mat3 cross_matrix(const Vec3& v) {
  Mat3 m;
  m << 0, -v[2], v[1], v[2], 0, -v[0], -v[1], v[0], 0;
  return m;
}

Eigen::RowVector3d shape_row(const TetRest& tet, int k) {
  if (k < 3) return tet.dm_inv.row(k);
  return -(tet.dm_inv.row(0) + tet.dm_inv.row(1) + tet.dm_inv.row(2));
}

// The symmetric matrix of a Voigt stress vector (shears at (1,2), (0,2), (0,1)).
Mat3 voigt_matrix(const Vec6& s) {
  Mat3 S;
  S << s[0], s[5], s[4], s[5], s[1], s[3], s[4], s[3], s[2];
  return S;
}

// sigma I + N (N symmetric) with its eigenvalues clamped at 0.
Mat3 clamp_psd(const Mat3& H) {
  Eigen::SelfAdjointEigenSolver<Mat3> eig;
  eig.computeDirect(H);
  if (eig.eigenvalues()[0] >= 0) return H;
  const Vec3 ev = eig.eigenvalues().cwiseMax(0.0);
  return eig.eigenvectors() * ev.asDiagonal() * eig.eigenvectors().transpose();
}

void stvk_vertex(const TetRest& tet, const Eigen::RowVector3d& b, const Mat3& F, const Mat6& K,
                 VbdHessian mode, Vec3& g, Mat3& H) {
  const Vec6 s = K * strain_vector(F);
  const Mat3 S = voigt_matrix(s);
  const Vec3 Sb = S * b.transpose();
  g = tet.volume * (F * Sb);
  Eigen::Matrix<double, 6, 3> A;
  A << b[0], 0, 0, 0, b[1], 0, 0, 0, b[2], 0, b[2], b[1], b[2], 0, b[0], b[1], b[0], 0;
  const Eigen::Matrix<double, 6, 3> M = A * F.transpose();
  H = tet.volume * (M.transpose() * K * M);
  if (mode == VbdHessian::GaussNewton) return;
  H.diagonal().array() += tet.volume * b.dot(Sb.transpose());
  if (mode == VbdHessian::Projected) H = clamp_psd(H);
}

void corotated_vertex(const TetRest& tet, const Eigen::RowVector3d& b, const Mat3& F, const Mat6& K,
                      VbdHessian mode, Vec3& g, Mat3& H) {
  const double lambda = K(0, 1), mu = K(3, 3);
  const Mat3 R = polar_rotation(F);
  const Mat3 S = corotated_stretch(F, R);
  const double tr = S.trace() - 3.0;
  const Vec3 q = R * b.transpose();
  g = tet.volume * (2.0 * mu * (F * b.transpose() - q) + lambda * tr * q);
  H = tet.volume * (2.0 * mu * b.squaredNorm() * Mat3::Identity() + lambda * q * q.transpose());
  if (mode == VbdHessian::GaussNewton) return;
  const Mat3 bx = cross_matrix(b.transpose());
  const Mat3 Q = bx.transpose() * corotated_rotation_inverse(S) * bx;
  H += tet.volume * (lambda * tr - 2.0 * mu) * (R * Q * R.transpose());
  if (mode == VbdHessian::Projected) H = clamp_psd(H);
}

}  // namespace

void tet_vertex_derivatives(const TetRest& tet, int corner, const std::array<Vec3, 4>& p,
                            const Mat6& K, ElasticModel model, VbdHessian mode, Vec3& g, Mat3& H) {
  const Mat3 F = deformation_gradient(tet, p);
  const Eigen::RowVector3d b = shape_row(tet, corner);
  if (model == ElasticModel::Corotated) corotated_vertex(tet, b, F, K, mode, g, H);
  else stvk_vertex(tet, b, F, K, mode, g, H);
}

double tet_energy(const TetRest& tet, const std::array<Vec3, 4>& p, const Mat6& K, ElasticModel model) {
  const Vec6 c = strain_vector(deformation_gradient(tet, p), model);
  return 0.5 * tet.volume * c.dot(K * c);
}

double incremental_potential(const BodyModel& m, const std::vector<Vec3>& x, const std::vector<Vec3>& y,
                             double h) {
  double e = 0;
  for (size_t i = 0; i < m.vertex_count(); ++i)
    if (m.inv_mass[i] > 0) e += 0.5 * m.inertia[i] / (h * h) * (x[i] - y[i]).squaredNorm();
  for (const TetRest& t : m.tets) e += tet_energy(t, gather(x, t.v), m.stiffness, m.material.model);
  return e;
}

}  // namespace pliant::detail
