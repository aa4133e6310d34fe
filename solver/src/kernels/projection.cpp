// SPDX-License-Identifier: Apache-2.0
#include "kernels/projection.hpp"

#include "kernels/strain_kernel.hpp"

#include <cmath>

namespace pliant::detail {

void strain_increment(const TetRest& tet, const Vec3* const p[4], const double w[4],
                      const Vec6& lambda_t, const ProjectionParams& params, Vec6& dlambda,
                      Vec3 dx[4], double* det_f) {
  TetOne one = tet_lanes(tet, w);
  for (int k = 0; k < 4; ++k) one.v[k][0] = k;
  const std::vector<Vec3> x = {*p[0], *p[1], *p[2], *p[3]};
  double lam[6];
  for (int r = 0; r < 6; ++r) lam[r] = lambda_t[r];
  StrainStep<double> st;
  strain_step(one, x, lam, params.model, params.alpha_tilde, params.lambda_scale, params.line_search, st);
  if (det_f) *det_f = st.det;
  const bool ok = st.ok & 1;
  for (int r = 0; r < 6; ++r) dlambda[r] = ok ? st.dlambda[r] : 0.0;
  for (int k = 0; k < 4; ++k)
    for (int c = 0; c < 3; ++c) dx[k][c] = ok ? st.dx[k][c] : 0.0;
}

bool enforce_volume_floor(const TetRest& tet, std::vector<Vec3>& x, const std::vector<double>& inv_mass,
                          double floor) {
  const double w[4] = {inv_mass[tet.v[0]], inv_mass[tet.v[1]], inv_mass[tet.v[2]], inv_mass[tet.v[3]]};
  const Vec3 d0 = x[tet.v[0]] - x[tet.v[3]], d1 = x[tet.v[1]] - x[tet.v[3]], d2 = x[tet.v[2]] - x[tet.v[3]];
  const Mat3& B = tet.dm_inv;
  Vec3 f[3], b[4];
  for (int i = 0; i < 3; ++i) f[i] = d0 * B(0, i) + d1 * B(1, i) + d2 * B(2, i);
  for (int k = 0; k < 3; ++k) b[k] = B.row(k).transpose();
  b[3] = -(b[0] + b[1] + b[2]);
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
  const double w[4] = {0, 0, 0, 0};
  TetOne one = tet_lanes(tet, w);
  const std::vector<Vec6> lambda = {lambda_t};
  return residual_squared_lanes(one, x, lambda, alpha_tilde, model);
}

}  // namespace pliant::detail
