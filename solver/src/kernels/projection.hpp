// SPDX-License-Identifier: Apache-2.0
// Parameters and shared pieces of the strain projection (the kernel itself, for one tet or a
// pack of four: strain_kernel.hpp): the line search's constants, the corotated Jacobian's
// algebra, the inversion floor, and one-tet entry points for the tests.
#pragma once

#include "kernels/strain_kernel.hpp"
#include "pliant/model.hpp"

#include <Eigen/Core>

#include <vector>

namespace pliant::detail {

struct ProjectionParams {
  ElasticModel model = ElasticModel::StVK;  // which strain the constraint measures
  KernelCompliance alpha_tilde;  // compliance / h^2
  double lambda_scale = 1;   // over-relaxation of the increment (lambda-SOR), 1 otherwise
  double inversion_floor = 0;
  bool line_search = false;  // shorten a tet's step until its residual does not grow
};

// Line search of one tet's projection (both kernels, both strain models; for the corotated
// strain the trial residual takes the rotation of the trial F): the step is halved at most
// kMaxHalvings times until the tet's own residual ||C + alpha~ lambda|| does not grow. Steps
// that change F by less than kSmallStep (Frobenius) are taken whole: their quadratic remainder is below
// kSmallStep^2 / 2 in strain, and testing them would only compare round-off near convergence.
// Why: the Green strain is quadratic in x, so the linearised step overshoots when a tet is
// compressed (correcting a singular value s costs (1 - s^2) / 2s: 2.4 rest heights for a tet
// squashed to 20%), and in a Gauss-Seidel sweep that overshoot reaches the neighbours as
// velocity. The corotated strain is linear in x apart from the rotation, but on slivers the
// rotation turns fast (the thesis hippo at 10 MPa: a vertex at 6.9 m/s after 600 ticks without
// it, 2.5 cm/s with it). Near rest the full step passes and nothing changes.
constexpr int kMaxHalvings = 5;
constexpr double kSmallStep = 0.1;

// The kernel on one tet at positions p (does not move anything): the increment in dlambda and
// the per-vertex corrections in dx (already scaled by inverse masses; both zero when the system
// is not positive definite); lambda_t is read, not written.
void strain_increment(const TetRest& tet, const Vec3* const p[4], const double w[4],
                      const Vec6& lambda_t, const ProjectionParams& params, Vec6& dlambda,
                      Vec3 dx[4], double* det_f = nullptr);

// Unilateral volume constraint det(F) >= floor for one tet, solved as a hard constraint.
// Returns true if it acted.
bool enforce_volume_floor(const TetRest& tet, std::vector<Vec3>& x, const std::vector<double>& inv_mass,
                          double floor);

// r_t = C_t(x) + alpha~ lambda_t, squared norm.
double residual_squared(const TetRest& tet, const std::vector<Vec3>& x, const Vec6& lambda_t,
                        const Mat6& alpha_tilde, ElasticModel model = ElasticModel::StVK);

// The corotated constraint's Jacobian, written for the kernel (T = double or a 4-lane vector):
// row i's gradient in F is R P_i with P_i = E_i - 2 [u_i]x, u_i = Ginv axial(skew(E_i S))
// (strain_jacobian in strain_constraint.cpp), so dC_i/dx_k = sqrt(V0) R Y_ik with
// Y_ik = P_i b_k = E_i b_k - 2 u_i x b_k. S and Ginv (the inverse of tr(S) I - S) are symmetric,
// stored 00 11 22 12 02 01.
// a_i = axial(skew(E_i M)) for the six E_i and a symmetric M (00 11 22 12 02 01): with E_i's
// rows e_r s^T, a_i = 1/2 sum_r (row r of M) x e_r.
template <class T>
inline void corotated_axials(const T M[6], T a[6][3]) {
  const T row[3][3] = {{M[0], M[5], M[4]}, {M[5], M[1], M[3]}, {M[4], M[3], M[2]}};
  auto cross_e = [](const T s[3], int r, T out[3]) {  // s x e_r
    if (r == 0) { out[0] = s[0] * 0.0; out[1] = s[2]; out[2] = -s[1]; }
    else if (r == 1) { out[0] = -s[2]; out[1] = s[0] * 0.0; out[2] = s[0]; }
    else { out[0] = s[1]; out[1] = -s[0]; out[2] = s[0] * 0.0; }
  };
  constexpr int kA[6] = {0, 1, 2, 1, 0, 0}, kC[6] = {0, 1, 2, 2, 2, 1};
  PLIANT_UNROLL
  for (int i = 0; i < 6; ++i) {
    T t[3];
    if (i < 3) {
      cross_e(row[i], i, a[i]);
      PLIANT_UNROLL
      for (int c = 0; c < 3; ++c) a[i][c] = 0.5 * a[i][c];
    } else {
      cross_e(row[kC[i]], kA[i], a[i]);
      cross_e(row[kA[i]], kC[i], t);
      PLIANT_UNROLL
      for (int c = 0; c < 3; ++c) a[i][c] = 0.5 * (a[i][c] + t[c]);
    }
  }
}

// u_i = Ginv axial(skew(E_i S)): the rotation's share of row i.
template <class T>
inline void corotated_axes(const T S[6], const T Ginv[6], T u[6][3]) {
  T a[6][3];
  corotated_axials(S, a);
  PLIANT_UNROLL
  for (int i = 0; i < 6; ++i) {
    u[i][0] = Ginv[0] * a[i][0] + Ginv[5] * a[i][1] + Ginv[4] * a[i][2];
    u[i][1] = Ginv[5] * a[i][0] + Ginv[1] * a[i][1] + Ginv[3] * a[i][2];
    u[i][2] = Ginv[4] * a[i][0] + Ginv[3] * a[i][1] + Ginv[2] * a[i][2];
  }
}

}  // namespace pliant::detail
