// SPDX-License-Identifier: Apache-2.0
// The hot loop of the solver: the fused strain-constraint projection of one tet, the position
// update from a given multiplier increment, and the constraint residual. Algebraically equal to
// the readable forms in strain_constraint.cpp (tests compare them), but written on the
// deformation gradient's columns: with S = F^T F and Q = sum_k w_k b_k b_k^T, the 6x6 system
// matrix is V0 * (bilinear terms in S and Q) + alpha~, and the position update is
// dx_k = w_k sqrt(V0) F P b_k with P the symmetric 3x3 built from the increment.
#pragma once

#include "pliant/model.hpp"

#include <Eigen/Core>

#include <vector>

namespace pliant::detail {

struct ProjectionParams {
  ElasticModel model = ElasticModel::StVK;  // which strain the constraint measures
  Mat6 alpha_tilde;          // compliance / h^2
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

// Computes the multiplier increment of one tet at positions x (does not move anything).
// Returns the increment in dlambda and the per-vertex corrections in dx (already scaled by
// inverse masses); lambda_t is read, not written.
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

// The corotated constraint's Jacobian, written for the kernels (T = double or a 4-lane vector):
// row i's gradient in F is R P_i with P_i = E_i - 2 [u_i]x, u_i = Ginv axial(skew(E_i S))
// (strain_jacobian in strain_constraint.cpp), so dC_i/dx_k = sqrt(V0) R Y_ik with
// Y_ik = P_i b_k. S and Ginv (the inverse of tr(S) I - S) are symmetric, stored 00 11 22 12 02 01.
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
  for (int i = 0; i < 6; ++i) {
    T t[3];
    if (i < 3) {
      cross_e(row[i], i, a[i]);
      for (int c = 0; c < 3; ++c) a[i][c] = 0.5 * a[i][c];
    } else {
      cross_e(row[kC[i]], kA[i], a[i]);
      cross_e(row[kA[i]], kC[i], t);
      for (int c = 0; c < 3; ++c) a[i][c] = 0.5 * (a[i][c] + t[c]);
    }
  }
}

// u_i = Ginv axial(skew(E_i S)): the rotation's share of row i (see corotated_rows).
template <class T>
inline void corotated_axes(const T S[6], const T Ginv[6], T u[6][3]) {
  T a[6][3];
  corotated_axials(S, a);
  for (int i = 0; i < 6; ++i) {
    u[i][0] = Ginv[0] * a[i][0] + Ginv[5] * a[i][1] + Ginv[4] * a[i][2];
    u[i][1] = Ginv[5] * a[i][0] + Ginv[1] * a[i][1] + Ginv[3] * a[i][2];
    u[i][2] = Ginv[4] * a[i][0] + Ginv[3] * a[i][1] + Ginv[2] * a[i][2];
  }
}

template <class T>
inline void corotated_rows(const T S[6], const T Ginv[6], const T b[4][3], T Y[6][4][3]) {
  constexpr int kA[6] = {0, 1, 2, 1, 0, 0}, kC[6] = {0, 1, 2, 2, 2, 1};
  T u[6][3];
  corotated_axes(S, Ginv, u);
  for (int i = 0; i < 6; ++i)
    for (int k = 0; k < 4; ++k) {
      const T* bk = b[k];
      // E_i b_k - 2 u_i x b_k
      T y[3] = {-2.0 * (u[i][1] * bk[2] - u[i][2] * bk[1]), -2.0 * (u[i][2] * bk[0] - u[i][0] * bk[2]),
                -2.0 * (u[i][0] * bk[1] - u[i][1] * bk[0])};
      if (i < 3) y[i] += bk[i];
      else {
        y[kA[i]] += bk[kC[i]];
        y[kC[i]] += bk[kA[i]];
      }
      for (int c = 0; c < 3; ++c) Y[i][k][c] = y[c];
    }
}

// The StVK 6x6 system, lower triangle: A = V0 (bilinear terms in S = F^T F and
// Q = sum_k w_k b_k b_k^T) + alpha~, for one tet (T = double) or a pack (T = 4-lane vector).
// S and Q are stored 00 11 22 01 02 12.
template <class T>
inline void stvk_system(const T S[6], const T Q[6], const T& V, const Mat6& at, T A[6][6]) {
  const T &S00 = S[0], &S11 = S[1], &S22 = S[2], &S01 = S[3], &S02 = S[4], &S12 = S[5];
  const T &Q00 = Q[0], &Q11 = Q[1], &Q22 = Q[2], &Q01 = Q[3], &Q02 = Q[4], &Q12 = Q[5];
  A[0][0] = V * (S00 * Q00) + at(0, 0);
  A[1][0] = V * (S01 * Q01) + at(1, 0);
  A[1][1] = V * (S11 * Q11) + at(1, 1);
  A[2][0] = V * (S02 * Q02) + at(2, 0);
  A[2][1] = V * (S12 * Q12) + at(2, 1);
  A[2][2] = V * (S22 * Q22) + at(2, 2);
  A[3][0] = V * (S02 * Q01 + S01 * Q02) + at(3, 0);
  A[3][1] = V * (S12 * Q11 + S11 * Q12) + at(3, 1);
  A[3][2] = V * (S22 * Q12 + S12 * Q22) + at(3, 2);
  A[3][3] = V * (S22 * Q11 + S12 * Q12 + S12 * Q12 + S11 * Q22) + at(3, 3);
  A[4][0] = V * (S02 * Q00 + S00 * Q02) + at(4, 0);
  A[4][1] = V * (S12 * Q01 + S01 * Q12) + at(4, 1);
  A[4][2] = V * (S22 * Q02 + S02 * Q22) + at(4, 2);
  A[4][3] = V * (S22 * Q01 + S12 * Q02 + S02 * Q12 + S01 * Q22) + at(4, 3);
  A[4][4] = V * (S22 * Q00 + S02 * Q02 + S02 * Q02 + S00 * Q22) + at(4, 4);
  A[5][0] = V * (S01 * Q00 + S00 * Q01) + at(5, 0);
  A[5][1] = V * (S11 * Q01 + S01 * Q11) + at(5, 1);
  A[5][2] = V * (S12 * Q02 + S02 * Q12) + at(5, 2);
  A[5][3] = V * (S12 * Q01 + S11 * Q02 + S02 * Q11 + S01 * Q12) + at(5, 3);
  A[5][4] = V * (S12 * Q00 + S01 * Q02 + S02 * Q01 + S00 * Q12) + at(5, 4);
  A[5][5] = V * (S11 * Q00 + S01 * Q01 + S01 * Q01 + S00 * Q11) + at(5, 5);
}

}  // namespace pliant::detail
