// SPDX-License-Identifier: Apache-2.0
#include "kernels/projection.hpp"

#include "pliant/strain_constraint.hpp"

#include <cmath>

namespace pliant::detail {

namespace {

inline void geometry(const TetRest& tet, const Vec3* const p[4], Vec3 f[3], Vec3 b[4]) {
  const Vec3 d0 = *p[0] - *p[3], d1 = *p[1] - *p[3], d2 = *p[2] - *p[3];
  const Mat3& B = tet.dm_inv;
  for (int i = 0; i < 3; ++i) f[i] = d0 * B(0, i) + d1 * B(1, i) + d2 * B(2, i);
  for (int k = 0; k < 3; ++k) b[k] = B.row(k).transpose();
  b[3] = -(b[0] + b[1] + b[2]);
}

// Green strain from F's columns; S receives F^T F (00 11 22 01 02 12).
inline Vec6 strain_from_columns(const Vec3 f[3], double S[6]) {
  S[0] = f[0].squaredNorm(), S[1] = f[1].squaredNorm(), S[2] = f[2].squaredNorm();
  S[3] = f[0].dot(f[1]), S[4] = f[0].dot(f[2]), S[5] = f[1].dot(f[2]);
  Vec6 c;
  c << 0.5 * (S[0] - 1.0), 0.5 * (S[1] - 1.0), 0.5 * (S[2] - 1.0), S[5], S[4], S[3];
  return c;
}

inline Mat3 matrix_of_columns(const Vec3 f[3]) {
  Mat3 F;
  for (int i = 0; i < 3; ++i) F.col(i) = f[i];
  return F;
}

// Solves A y = rhs for symmetric positive definite 6x6 A (lower triangle used) by LDL^T with
// reciprocal pivots (6 divisions, no square roots). False if a pivot is not positive.
inline bool ldlt_solve6(const double A[6][6], const double rhs[6], double y[6]) {
  double L[6][6], D[6], invD[6];
  for (int j = 0; j < 6; ++j) {
    double d = A[j][j];
    for (int k = 0; k < j; ++k) d -= L[j][k] * L[j][k] * D[k];
    if (!(d > 0)) return false;
    D[j] = d;
    invD[j] = 1.0 / d;
    for (int i = j + 1; i < 6; ++i) {
      double s = A[i][j];
      for (int k = 0; k < j; ++k) s -= L[i][k] * L[j][k] * D[k];
      L[i][j] = s * invD[j];
    }
  }
  double z[6];
  for (int i = 0; i < 6; ++i) {
    double s = rhs[i];
    for (int k = 0; k < i; ++k) s -= L[i][k] * z[k];
    z[i] = s;
  }
  for (int i = 5; i >= 0; --i) {
    double s = z[i] * invD[i];
    for (int k = i + 1; k < 6; ++k) s -= L[k][i] * y[k];
    y[i] = s;
  }
  return true;
}

// StVK: dx_k = w_k sqrt(V0) (F P) b_k, P the symmetric 3x3 of the increment.
inline void position_corrections(const TetRest& tet, const Vec3 f[3], const Vec3 b[4],
                                 const double w[4], const Vec6& dl, Vec3 dx[4]) {
  double P[3][3] = {{dl[0], dl[5], dl[4]}, {dl[5], dl[1], dl[3]}, {dl[4], dl[3], dl[2]}};
  Vec3 M[3];  // columns of F P
  for (int i = 0; i < 3; ++i) M[i] = f[0] * P[0][i] + f[1] * P[1][i] + f[2] * P[2][i];
  for (int k = 0; k < 4; ++k) {
    const double s = w[k] * tet.sqrt_volume;
    dx[k] = s * (M[0] * b[k][0] + M[1] * b[k][1] + M[2] * b[k][2]);
  }
}

// Step length for one tet's increment (see kMaxHalvings in projection.hpp).
double residual_decreasing_step(ElasticModel model, const TetRest& tet, const Vec3 f[3], const Vec6& C, const Vec6& lambda_t,
                                const Vec6& dlambda, const Vec3 dx[4], const Mat6& at) {
  const Mat3& B = tet.dm_inv;
  const Vec3 d0 = dx[0] - dx[3], d1 = dx[1] - dx[3], d2 = dx[2] - dx[3];
  Vec3 dF[3];
  double n2 = 0;
  for (int i = 0; i < 3; ++i) {
    dF[i] = d0 * B(0, i) + d1 * B(1, i) + d2 * B(2, i);
    n2 += dF[i].squaredNorm();
  }
  if (n2 <= kSmallStep * kSmallStep) return 1.0;
  const double before = (C + at * lambda_t).squaredNorm();
  double a = 1.0;
  for (int h = 0; h <= kMaxHalvings; ++h) {
    const Vec3 fn[3] = {f[0] + a * dF[0], f[1] + a * dF[1], f[2] + a * dF[2]};
    const Vec6 r = tet.sqrt_volume * strain_vector(matrix_of_columns(fn), model) + at * (lambda_t + a * dlambda);
    if (r.squaredNorm() <= before || h == kMaxHalvings) break;
    a *= 0.5;
  }
  return a;
}

// dlambda from A dlambda = -C - alpha~ lambda (scaled by lambda_scale); false (and everything
// zero) when A is not positive definite.
bool solve_increment(const double A[6][6], const Vec6& C, const Vec6& lambda_t, const ProjectionParams& params,
                     Vec6& dlambda, Vec3 dx[4]) {
  const Vec6 rhs_v = -C - params.alpha_tilde * lambda_t;
  double rhs[6], y[6];
  for (int i = 0; i < 6; ++i) rhs[i] = rhs_v[i];
  if (!ldlt_solve6(A, rhs, y)) {
    dlambda.setZero();
    for (int k = 0; k < 4; ++k) dx[k].setZero();
    return false;
  }
  for (int i = 0; i < 6; ++i) dlambda[i] = params.lambda_scale * y[i];
  return true;
}

// Shortens the step (dlambda and dx together) when the line search asks for it.
void apply_line_search(const TetRest& tet, const Vec3 f[3], const Vec6& C, const Vec6& lambda_t,
                       const ProjectionParams& params, Vec6& dlambda, Vec3 dx[4]) {
  if (!params.line_search) return;
  const double a = residual_decreasing_step(params.model, tet, f, C, lambda_t, dlambda, dx, params.alpha_tilde);
  if (a == 1.0) return;
  dlambda *= a;
  for (int k = 0; k < 4; ++k) dx[k] *= a;
}

// The corotated projection of one tet: A = V0 sum_k w_k Y_k^T Y_k + alpha~ (Y from
// corotated_rows), dx_k = w_k sqrt(V0) R sum_i dlambda_i Y_ik, with the line search.
void corotated_increment(const TetRest& tet, const Vec3 f[3], const Vec3 b[4], const double w[4],
                         const Vec6& lambda_t, const ProjectionParams& params, Vec6& dlambda, Vec3 dx[4]) {
  const Mat3 F = matrix_of_columns(f);
  const Mat3 R = polar_rotation(F);
  const Mat3 Sm = corotated_stretch(F, R);
  const Mat3 Gm = corotated_rotation_inverse(Sm);
  const Vec6 C = tet.sqrt_volume * corotated_strain_vector(Sm);
  // Symmetric matrices as corotated_rows takes them: 00 11 22 12 02 01.
  const double S[6] = {Sm(0, 0), Sm(1, 1), Sm(2, 2), Sm(1, 2), Sm(0, 2), Sm(0, 1)};
  const double Ginv[6] = {Gm(0, 0), Gm(1, 1), Gm(2, 2), Gm(1, 2), Gm(0, 2), Gm(0, 1)};
  double bk[4][3];
  for (int k = 0; k < 4; ++k)
    for (int c = 0; c < 3; ++c) bk[k][c] = b[k][c];
  double Y[6][4][3];
  corotated_rows(S, Ginv, bk, Y);
  double A[6][6];
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j <= i; ++j) {
      double sum = 0;
      for (int k = 0; k < 4; ++k)
        sum += w[k] * (Y[i][k][0] * Y[j][k][0] + Y[i][k][1] * Y[j][k][1] + Y[i][k][2] * Y[j][k][2]);
      A[i][j] = tet.volume * sum + params.alpha_tilde(i, j);
    }
  if (!solve_increment(A, C, lambda_t, params, dlambda, dx)) return;
  for (int k = 0; k < 4; ++k) {
    double v[3] = {0, 0, 0};
    for (int i = 0; i < 6; ++i)
      for (int c = 0; c < 3; ++c) v[c] += dlambda[i] * Y[i][k][c];
    dx[k] = (w[k] * tet.sqrt_volume) * (R * Vec3(v[0], v[1], v[2]));
  }
  apply_line_search(tet, f, C, lambda_t, params, dlambda, dx);
}

}  // namespace

void strain_increment(const TetRest& tet, const Vec3* const p[4], const double w[4],
                      const Vec6& lambda_t, const ProjectionParams& params, Vec6& dlambda,
                      Vec3 dx[4], double* det_f) {
  Vec3 f[3], b[4];
  geometry(tet, p, f, b);
  if (det_f) *det_f = f[0].dot(f[1].cross(f[2]));
  if (params.model == ElasticModel::Corotated) {
    corotated_increment(tet, f, b, w, lambda_t, params, dlambda, dx);
    return;
  }
  double S[6];
  const Vec6 C = tet.sqrt_volume * strain_from_columns(f, S);
  double Q[6] = {0, 0, 0, 0, 0, 0};  // 00 11 22 01 02 12
  for (int k = 0; k < 4; ++k) {
    if (w[k] == 0) continue;
    Q[0] += w[k] * b[k][0] * b[k][0], Q[1] += w[k] * b[k][1] * b[k][1], Q[2] += w[k] * b[k][2] * b[k][2];
    Q[3] += w[k] * b[k][0] * b[k][1], Q[4] += w[k] * b[k][0] * b[k][2], Q[5] += w[k] * b[k][1] * b[k][2];
  }
  double A[6][6];
  stvk_system(S, Q, tet.volume, params.alpha_tilde, A);
  if (!solve_increment(A, C, lambda_t, params, dlambda, dx)) return;
  position_corrections(tet, f, b, w, dlambda, dx);
  apply_line_search(tet, f, C, lambda_t, params, dlambda, dx);
}

bool enforce_volume_floor(const TetRest& tet, std::vector<Vec3>& x, const std::vector<double>& inv_mass,
                          double floor) {
  const double w[4] = {inv_mass[tet.v[0]], inv_mass[tet.v[1]], inv_mass[tet.v[2]], inv_mass[tet.v[3]]};
  const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
  Vec3 f[3], b[4];
  geometry(tet, p, f, b);
  const Vec3 cof[3] = {f[1].cross(f[2]), f[2].cross(f[0]), f[0].cross(f[1])};
  const double J = f[0].dot(cof[0]);
  if (J >= floor) return false;
  Vec3 grad[4];
  double denom = 0;
  for (int k = 0; k < 4; ++k) {
    grad[k] = cof[0] * b[k][0] + cof[1] * b[k][1] + cof[2] * b[k][2];
    denom += w[k] * grad[k].squaredNorm();
  }
  if (!(denom > 1e-300)) return false;
  const double dl = -(J - floor) / denom;
  for (int k = 0; k < 4; ++k) x[tet.v[k]] += w[k] * dl * grad[k];
  return true;
}

double residual_squared(const TetRest& tet, const std::vector<Vec3>& x, const Vec6& lambda_t,
                        const Mat6& alpha_tilde, ElasticModel model) {
  const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
  Vec3 f[3], b[4];
  geometry(tet, p, f, b);
  const Vec6 r = tet.sqrt_volume * strain_vector(matrix_of_columns(f), model) + alpha_tilde * lambda_t;
  return r.squaredNorm();
}

}  // namespace pliant::detail
