// SPDX-License-Identifier: Apache-2.0
#include "kernels/packed_projection.hpp"

#include "kernels/projection.hpp"

#include "pliant/strain_constraint.hpp"

#include <algorithm>
#include <cmath>

namespace pliant::detail {

namespace {

inline v4d splat(double a) { return v4d{a, a, a, a}; }

}  // namespace

void compile_solve_order(BodyModel& m) {
  auto pm = std::make_shared<PackedModel>();
  pm->colour_begin.assign(1, 0);
  m.tet_slot.assign(m.tets.size(), 0);
  m.tet_colour.assign(m.tets.size(), 0);
  for (size_t c = 0; c < m.colours.size(); ++c) {
    // Within a colour the order is free: sort by lowest vertex index so that neighbouring packs
    // touch nearby memory (the thesis armadillo's numbering is otherwise scattered).
    std::vector<int32_t> colour = m.colours[c];
    auto lowest = [&](int32_t t) { return *std::min_element(m.tets[t].v.begin(), m.tets[t].v.end()); };
    std::sort(colour.begin(), colour.end(), [&](int32_t a, int32_t b) { return lowest(a) < lowest(b); });
    for (size_t start = 0; start < colour.size(); start += 4) {
      TetPack p{};
      p.lanes = int(std::min<size_t>(4, colour.size() - start));
      p.slot = int32_t(4 * pm->packs.size());
      for (int l = 0; l < 4; ++l) {
        const int32_t t = colour[start + std::min(l, p.lanes - 1)];
        const TetRest& tr = m.tets[t];
        p.tet[l] = t;
        if (l < p.lanes) {
          m.tet_slot[t] = p.slot + l;
          m.tet_colour[t] = int32_t(c);
        }
        for (int k = 0; k < 4; ++k) {
          p.v[k][l] = tr.v[k];
          p.w[k][l] = m.inv_mass[tr.v[k]];
        }
        for (int k = 0; k < 3; ++k)
          for (int i = 0; i < 3; ++i) p.B[3 * k + i][l] = tr.dm_inv(k, i);
        p.volume[l] = tr.volume;
        p.sqrt_volume[l] = tr.sqrt_volume;
        Vec3 b[4];
        for (int k = 0; k < 3; ++k) b[k] = tr.dm_inv.row(k).transpose();
        b[3] = -(b[0] + b[1] + b[2]);
        double Q[3][3] = {};
        for (int k = 0; k < 4; ++k)
          for (int i = 0; i < 3; ++i)
            for (int j = i; j < 3; ++j) Q[i][j] += m.inv_mass[tr.v[k]] * b[k][i] * b[k][j];
        p.Q[0][l] = Q[0][0];
        p.Q[1][l] = Q[1][1];
        p.Q[2][l] = Q[2][2];
        p.Q[3][l] = Q[0][1];
        p.Q[4][l] = Q[0][2];
        p.Q[5][l] = Q[1][2];
      }
      pm->packs.push_back(p);
    }
    pm->colour_begin.push_back(pm->packs.size());
  }
  pm->vertex_slot_entry.resize(m.vertex_tet_entry.size());
  for (size_t a = 0; a < m.vertex_tet_entry.size(); ++a)
    pm->vertex_slot_entry[a] = 4 * m.tet_slot[m.vertex_tet_entry[a] / 4] + m.vertex_tet_entry[a] % 4;
  m.packed = std::move(pm);
}

namespace {

struct PackGeometry {
  v4d f[3][3];  // f[i][c]: component c of column i of F
  v4d r[3][3];  // Corotated: R's columns, same layout
  v4d S[6];     // StVK: F^T F, 00 11 22 01 02 12 (what its 6x6 system is built from)
  v4d stretch[6];  // Corotated: S = sym(R^T F), 00 11 22 12 02 01 (what its system is built from)
  v4d c[6];     // strain vector (no sqrt(V0))
};

inline v4d column_dot(const v4d a[3], const v4d b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// Green strain from g.f (StVK).
inline void green_strain(PackGeometry& g) {
  g.S[0] = column_dot(g.f[0], g.f[0]);
  g.S[1] = column_dot(g.f[1], g.f[1]);
  g.S[2] = column_dot(g.f[2], g.f[2]);
  g.S[3] = column_dot(g.f[0], g.f[1]);
  g.S[4] = column_dot(g.f[0], g.f[2]);
  g.S[5] = column_dot(g.f[1], g.f[2]);
  g.c[0] = 0.5 * g.S[0] - 0.5;
  g.c[1] = 0.5 * g.S[1] - 0.5;
  g.c[2] = 0.5 * g.S[2] - 0.5;
  g.c[3] = g.S[5];
  g.c[4] = g.S[4];
  g.c[5] = g.S[3];
}

inline v4d pack_det(const v4d f[3][3]) {
  return f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1]) - f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0]) +
         f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0]);
}

inline void cross(const v4d a[3], const v4d b[3], v4d out[3]) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

// The rotation of F = R S for 4 lanes at once: the scaled Newton iteration of polar_rotation
// (strain_constraint.cpp), same steps and stopping test per lane, iterated until every lane has
// converged (a converged lane stays put). Lanes with det F <= 0 or that do not converge take the
// scalar polar_rotation (SVD); they are rare (inverted or degenerate tets).
inline void pack_rotation(const v4d f[3][3], v4d r[3][3]) {
  v4d X[3][3];
  for (int i = 0; i < 3; ++i)
    for (int c = 0; c < 3; ++c) X[i][c] = f[i][c];
  int pending = 0xF, failed = 0;
  for (int it = 0; it < kMaxPolarIterations && pending; ++it) {
    v4d cof[3][3];
    cross(X[1], X[2], cof[0]);
    cross(X[2], X[0], cof[1]);
    cross(X[0], X[1], cof[2]);
    const v4d det = column_dot(X[0], cof[0]);
    v4d nx = splat(0.0), nc = splat(0.0);
    for (int i = 0; i < 3; ++i)
      for (int c = 0; c < 3; ++c) {
        nx += X[i][c] * X[i][c];
        nc += cof[i][c] * cof[i][c];
      }
    v4d g, inv;  // g and 1 / (g det) per lane
    for (int l = 0; l < 4; ++l) {
      if (!(det[l] > 0)) {  // inverted or degenerate: the SVD handles this lane
        failed |= pending & (1 << l);
        pending &= ~(1 << l);
        g[l] = 1.0;
        inv[l] = 0.0;
        continue;
      }
      g[l] = std::abs(nx[l] - 3.0) > kPolarScalingBand ? std::sqrt(std::sqrt(nc[l] / (det[l] * det[l]) / nx[l])) : 1.0;
      inv[l] = 1.0 / (g[l] * det[l]);
    }
    v4d change = splat(0.0);
    for (int i = 0; i < 3; ++i)
      for (int c = 0; c < 3; ++c) {
        const v4d next = 0.5 * (g * X[i][c] + inv * cof[i][c]);
        const v4d d = next - X[i][c];
        change += d * d;
        X[i][c] = next;
      }
    for (int l = 0; l < 4; ++l)
      if ((pending & (1 << l)) && change[l] < kPolarConverged) pending &= ~(1 << l);
  }
  failed |= pending;
  for (int l = 0; l < 4; ++l) {
    if (failed & (1 << l)) {
      Mat3 F;
      for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 3; ++c) F(c, i) = f[i][c][l];
      const Mat3 R = polar_rotation(F);
      for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 3; ++c) X[i][c][l] = R(c, i);
    }
  }
  for (int i = 0; i < 3; ++i)
    for (int c = 0; c < 3; ++c) r[i][c] = X[i][c];
}

// Corotated strain from g.f: R's columns in g.r, the stretch S = sym(R^T F) in g.stretch, and
// c = (S_ii - 1, 2 S_ac).
inline void corotated_strain(PackGeometry& g) {
  pack_rotation(g.f, g.r);
  v4d* S = g.stretch;
  for (int i = 0; i < 3; ++i) S[i] = column_dot(g.r[i], g.f[i]);
  S[3] = 0.5 * (column_dot(g.r[1], g.f[2]) + column_dot(g.r[2], g.f[1]));
  S[4] = 0.5 * (column_dot(g.r[0], g.f[2]) + column_dot(g.r[2], g.f[0]));
  S[5] = 0.5 * (column_dot(g.r[0], g.f[1]) + column_dot(g.r[1], g.f[0]));
  for (int i = 0; i < 3; ++i) g.c[i] = S[i] - 1.0;
  for (int i = 3; i < 6; ++i) g.c[i] = 2.0 * S[i];
}

// The strain of the model from g.f.
inline void pack_strain(PackGeometry& g, ElasticModel model) {
  if (model == ElasticModel::Corotated) corotated_strain(g);
  else green_strain(g);
}

// F's columns of the pack's tets at x.
inline void pack_deformation(const TetPack& p, const std::vector<Vec3>& x, v4d f[3][3]) {
  v4d px[4][3];
  for (int k = 0; k < 4; ++k)
    for (int l = 0; l < 4; ++l) {
      const Vec3& q = x[p.v[k][l]];
      px[k][0][l] = q[0];
      px[k][1][l] = q[1];
      px[k][2][l] = q[2];
    }
  v4d d[3][3];
  for (int k = 0; k < 3; ++k)
    for (int c = 0; c < 3; ++c) d[k][c] = px[k][c] - px[3][c];
  for (int i = 0; i < 3; ++i)
    for (int c = 0; c < 3; ++c) f[i][c] = d[0][c] * p.B[i] + d[1][c] * p.B[3 + i] + d[2][c] * p.B[6 + i];
}

inline void pack_geometry(const TetPack& p, const std::vector<Vec3>& x, PackGeometry& g, ElasticModel model) {
  pack_deformation(p, x, g.f);
  pack_strain(g, model);
}

inline void pack_constraint(const TetPack& p, const PackGeometry& g, v4d C[6]) {
  for (int r = 0; r < 6; ++r) C[r] = p.sqrt_volume * g.c[r];
}

inline void gather_lambda(const TetPack& p, const std::vector<Vec6>& lambda, v4d lam[6]) {
  for (int l = 0; l < 4; ++l) {
    const Vec6& a = lambda[p.slot + l];
    for (int r = 0; r < 6; ++r) lam[r][l] = a[r];
  }
}

// dx_k = w_k sqrt(V0) (G P) b_k for a 3x3 P (P[m][i]) and G's columns.
inline void pack_move_corners(const TetPack& p, const v4d G[3][3], const v4d P[3][3], v4d dx[4][3]) {
  v4d M[3][3];  // M[i][c]: component c of column i of G P
  for (int i = 0; i < 3; ++i)
    for (int c = 0; c < 3; ++c) M[i][c] = G[0][c] * P[0][i] + G[1][c] * P[1][i] + G[2][c] * P[2][i];
  v4d b[4][3];
  for (int k = 0; k < 3; ++k)
    for (int i = 0; i < 3; ++i) b[k][i] = p.B[3 * k + i];
  for (int i = 0; i < 3; ++i) b[3][i] = -(b[0][i] + b[1][i] + b[2][i]);
  for (int k = 0; k < 4; ++k) {
    const v4d s = p.w[k] * p.sqrt_volume;
    for (int c = 0; c < 3; ++c) dx[k][c] = s * (M[0][c] * b[k][0] + M[1][c] * b[k][1] + M[2][c] * b[k][2]);
  }
}

// StVK: dx_k = w_k sqrt(V0) (F P) b_k, P the symmetric 3x3 of the increment y.
inline void pack_corrections(const TetPack& p, const PackGeometry& g, const v4d y[6], v4d dx[4][3]) {
  const v4d P[3][3] = {{y[0], y[5], y[4]}, {y[5], y[1], y[3]}, {y[4], y[3], y[2]}};
  pack_move_corners(p, g.f, P, dx);
}

// ||C + alpha~ lambda||^2 per lane.
inline v4d lane_residual_squared(const v4d C[6], const v4d lam[6], const Mat6& at) {
  v4d sum = splat(0.0);
  for (int r = 0; r < 6; ++r) {
    v4d s = C[r];
    for (int c = 0; c < 6; ++c) s += at(r, c) * lam[c];
    sum += s * s;
  }
  return sum;
}

// Step length along the projection's increment (y for lambda, dx for the corners), per lane:
// see kMaxHalvings in projection.hpp.
v4d residual_decreasing_step(ElasticModel model, const TetPack& p, const PackGeometry& g, const v4d C[6], const v4d lam[6],
                             const v4d y[6], const v4d dx[4][3], const Mat6& at) {
  const v4d before = lane_residual_squared(C, lam, at);
  // dF[i][c]: change of column i, component c of F for the full step.
  v4d dd[3][3];
  for (int k = 0; k < 3; ++k)
    for (int c = 0; c < 3; ++c) dd[k][c] = dx[k][c] - dx[3][c];
  v4d dF[3][3];
  for (int i = 0; i < 3; ++i)
    for (int c = 0; c < 3; ++c) dF[i][c] = dd[0][c] * p.B[i] + dd[1][c] * p.B[3 + i] + dd[2][c] * p.B[6 + i];
  v4d step = splat(1.0);
  v4d trial = splat(1.0);
  // Lanes whose full step changes F by less than kSmallStep keep it.
  int pending = 0;
  for (int l = 0; l < p.lanes; ++l) {
    double n2 = 0;
    for (int i = 0; i < 3; ++i)
      for (int c = 0; c < 3; ++c) n2 += dF[i][c][l] * dF[i][c][l];
    if (n2 > kSmallStep * kSmallStep) pending |= 1 << l;
  }
  for (int h = 0; h <= kMaxHalvings && pending; ++h) {
    PackGeometry n;
    for (int i = 0; i < 3; ++i)
      for (int c = 0; c < 3; ++c) n.f[i][c] = g.f[i][c] + trial * dF[i][c];
    pack_strain(n, model);
    v4d Cn[6], ln[6];
    pack_constraint(p, n, Cn);
    for (int r = 0; r < 6; ++r) ln[r] = lam[r] + trial * y[r];
    const v4d after = lane_residual_squared(Cn, ln, at);
    for (int l = 0; l < p.lanes; ++l) {
      if (!(pending & (1 << l))) continue;
      step[l] = trial[l];
      if (after[l] <= before[l]) pending &= ~(1 << l);
    }
    trial *= 0.5;
  }
  return step;
}

// Solves A y = rhs lane-wise (LDL^T, lower triangle of A), y scaled by lambda_scale; D gets the
// pivots (a lane with a non-positive pivot is not positive definite).
inline void ldlt_solve(const v4d A[6][6], const v4d rhs[6], double lambda_scale, v4d D[6], v4d y[6]) {
  v4d L[6][6], invD[6];
  for (int j = 0; j < 6; ++j) {
    v4d d = A[j][j];
    for (int k = 0; k < j; ++k) d -= L[j][k] * L[j][k] * D[k];
    D[j] = d;
    invD[j] = 1.0 / d;
    for (int i = j + 1; i < 6; ++i) {
      v4d s = A[i][j];
      for (int k = 0; k < j; ++k) s -= L[i][k] * L[j][k] * D[k];
      L[i][j] = s * invD[j];
    }
  }
  v4d z[6];
  for (int i = 0; i < 6; ++i) {
    v4d s = rhs[i];
    for (int k = 0; k < i; ++k) s -= L[i][k] * z[k];
    z[i] = s;
  }
  for (int i = 5; i >= 0; --i) {
    v4d s = z[i] * invD[i];
    for (int k = i + 1; k < 6; ++k) s -= L[k][i] * y[k];
    y[i] = lambda_scale * s;
  }
}

// The corotated constraint for a pack (corotated_rows in projection.hpp gives the rows
// Y_ik = E_i b_k - 2 u_i x b_k): from the stretch S = sym(R^T F) in g, Ginv per lane,
// the rotation axes u_i, and the lower triangle of A = V0 sum_k w_k Y_ik . Y_jk + alpha~ summed
// over the corners in closed form with Q = sum_k w_k b_k b_k^T:
//   sum_k w_k Y_ik . Y_jk = tr(E_i E_j Q) - 2 (u_j . v_i + u_i . v_j) + 4 ((u_i . u_j) tr Q - u_i^T Q u_j),
// v_i = sum_k w_k b_k x (E_i b_k) = 2 axial(skew(E_i Q)).
inline void pack_corotated_axes(const PackGeometry& g, v4d u[6][3]) {
  const v4d* S = g.stretch;
  // Ginv = (tr(S) I - S)^-1 by cofactors, zero in the lanes where corotated_rotation_inverse
  // gives zero (same test).
  const v4d G00 = S[1] + S[2], G11 = S[0] + S[2], G22 = S[0] + S[1], G12 = -S[3], G02 = -S[4], G01 = -S[5];
  v4d Ginv[6] = {G11 * G22 - G12 * G12, G00 * G22 - G02 * G02, G00 * G11 - G01 * G01,
                 G02 * G01 - G00 * G12, G01 * G12 - G11 * G02, G02 * G12 - G22 * G01};
  const v4d det = G00 * Ginv[0] + G01 * Ginv[5] + G02 * Ginv[4];
  const v4d third = (G00 + G11 + G22) * (1.0 / 3.0);
  for (int l = 0; l < 4; ++l) {
    const bool ok = det[l] > kRotationConditionLimit * third[l] * third[l] * third[l];
    const double inv = ok ? 1.0 / det[l] : 0.0;
    for (int i = 0; i < 6; ++i) Ginv[i][l] *= inv;
  }
  corotated_axes(S, Ginv, u);
}

inline void pack_corotated_system(const TetPack& p, const PackGeometry& g, const Mat6& at, v4d A[6][6],
                                  v4d u[6][3]) {
  pack_corotated_axes(g, u);
  // Q in the 00 11 22 12 02 01 order of corotated_axials (the pack stores 00 11 22 01 02 12).
  const v4d Q00 = p.Q[0], Q11 = p.Q[1], Q22 = p.Q[2], Q01 = p.Q[3], Q02 = p.Q[4], Q12 = p.Q[5];
  const v4d Qs[6] = {Q00, Q11, Q22, Q12, Q02, Q01};
  v4d v[6][3];
  corotated_axials(Qs, v);  // half of v_i
  const v4d trQ = Q00 + Q11 + Q22;
  v4d Qu[6][3];
  for (int i = 0; i < 6; ++i) {
    Qu[i][0] = Q00 * u[i][0] + Q01 * u[i][1] + Q02 * u[i][2];
    Qu[i][1] = Q01 * u[i][0] + Q11 * u[i][1] + Q12 * u[i][2];
    Qu[i][2] = Q02 * u[i][0] + Q12 * u[i][1] + Q22 * u[i][2];
  }
  // tr(E_i E_j Q): the StVK system's Q terms with F^T F = I.
  const v4d zero = splat(0.0);
  const v4d A0[6][6] = {
      {Q00, zero, zero, zero, zero, zero},
      {zero, Q11, zero, zero, zero, zero},
      {zero, zero, Q22, zero, zero, zero},
      {zero, Q12, Q12, Q11 + Q22, zero, zero},
      {Q02, zero, Q02, Q01, Q00 + Q22, zero},
      {Q01, Q01, zero, Q02, Q12, Q00 + Q11}};
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j <= i; ++j) {
      // v holds half of v_i: -2 (u_j . v_i + u_i . v_j) = -4 (u_j . v~_i + u_i . v~_j).
      const v4d cross_terms = column_dot(u[j], v[i]) + column_dot(u[i], v[j]);
      const v4d rot = column_dot(u[i], u[j]) * trQ - column_dot(u[i], Qu[j]);
      A[i][j] = p.volume * (A0[i][j] - 4.0 * cross_terms + 4.0 * rot) + at(i, j);
    }
}

// dx_k = w_k sqrt(V0) R (P - 2 [U]x) b_k, P the symmetric 3x3 of the increment y, U = sum_i y_i u_i
// (= w_k sqrt(V0) R sum_i y_i Y_ik).
inline void pack_corotated_corrections(const TetPack& p, const PackGeometry& g, const v4d u[6][3],
                                       const v4d y[6], v4d dx[4][3]) {
  v4d U[3];
  for (int c = 0; c < 3; ++c) {
    U[c] = y[0] * u[0][c];
    for (int i = 1; i < 6; ++i) U[c] += y[i] * u[i][c];
  }
  const v4d two = splat(2.0);
  const v4d P[3][3] = {{y[0], y[5] + two * U[2], y[4] - two * U[1]},
                       {y[5] - two * U[2], y[1], y[3] + two * U[0]},
                       {y[4] + two * U[1], y[3] - two * U[0], y[2]}};
  pack_move_corners(p, g.r, P, dx);
}

}  // namespace

int project_pack(const TetPack& p, std::vector<Vec3>& x, std::vector<Vec6>& lambda,
                 std::vector<Vec6>& dlambda, const BodyModel& model, const Mat6& at,
                 double lambda_scale, double inversion_floor, bool line_search) {
  const ElasticModel elastic = model.material.model;
  PackGeometry g;
  pack_geometry(p, x, g, elastic);
  v4d C[6], lam[6];
  pack_constraint(p, g, C);
  gather_lambda(p, lambda, lam);

  v4d A[6][6];
  v4d u[6][3];  // corotated only: the rotation axes of the rows
  if (elastic == ElasticModel::Corotated) {
    pack_corotated_system(p, g, at, A, u);
  } else {
    stvk_system(g.S, p.Q, p.volume, at, A);
  }
  v4d rhs[6];
  for (int r = 0; r < 6; ++r) {
    v4d s = -C[r];
    for (int c = 0; c < 6; ++c) s -= at(r, c) * lam[c];
    rhs[r] = s;
  }
  v4d D[6], y[6];
  ldlt_solve(A, rhs, lambda_scale, D, y);
  v4d dx[4][3];
  if (elastic == ElasticModel::Corotated) pack_corotated_corrections(p, g, u, y, dx);
  else pack_corrections(p, g, y, dx);
  v4d step = splat(1.0);
  if (line_search) step = residual_decreasing_step(elastic, p, g, C, lam, y, dx, at);
  const v4d det = pack_det(g.f);  // before the projection, for the inversion floor

  int floor_hits = 0;
  for (int l = 0; l < p.lanes; ++l) {
    bool ok = true;
    for (int r = 0; r < 6; ++r) ok &= std::isfinite(y[r][l]) && D[r][l] > 0;
    if (!ok) continue;  // not positive definite (cannot happen with alpha~ > 0): skip the tet
    const int32_t t = p.tet[l];
    const double a = step[l];
    Vec6& dl = dlambda[p.slot + l];
    for (int r = 0; r < 6; ++r) dl[r] = a * y[r][l];
    lambda[p.slot + l] += dl;
    for (int k = 0; k < 4; ++k) {
      Vec3& q = x[p.v[k][l]];
      q[0] += a * dx[k][0][l];
      q[1] += a * dx[k][1][l];
      q[2] += a * dx[k][2][l];
    }
    if (inversion_floor > 0 && det[l] < inversion_floor)
      floor_hits += enforce_volume_floor(model.tets[t], x, model.inv_mass, inversion_floor);
  }
  return floor_hits;
}

void pack_apply_increment(const TetPack& p, std::vector<Vec3>& x, const std::vector<Vec6>& dl,
                          ElasticModel model) {
  PackGeometry g;
  pack_geometry(p, x, g, model);
  v4d y[6];
  gather_lambda(p, dl, y);
  v4d dx[4][3];
  if (model == ElasticModel::Corotated) {
    v4d u[6][3];
    pack_corotated_axes(g, u);
    pack_corotated_corrections(p, g, u, y, dx);
  } else {
    pack_corrections(p, g, y, dx);
  }
  for (int l = 0; l < p.lanes; ++l)
    for (int k = 0; k < 4; ++k) {
      Vec3& q = x[p.v[k][l]];
      q[0] += dx[k][0][l];
      q[1] += dx[k][1][l];
      q[2] += dx[k][2][l];
    }
}

int pack_volume_floor(const TetPack& p, std::vector<Vec3>& x, const BodyModel& model, double floor,
                      std::vector<int32_t>* hit) {
  v4d f[3][3];
  pack_deformation(p, x, f);
  const v4d det = pack_det(f);
  int hits = 0;
  for (int l = 0; l < p.lanes; ++l)
    if (det[l] < floor && enforce_volume_floor(model.tets[p.tet[l]], x, model.inv_mass, floor)) {
      ++hits;
      if (hit) hit->push_back(int32_t(p.tet[l]));
    }
  return hits;
}

double pack_residual_squared(const TetPack& p, const std::vector<Vec3>& x,
                             const std::vector<Vec6>& lambda, const Mat6& at, ElasticModel model) {
  PackGeometry g;
  pack_geometry(p, x, g, model);
  v4d C[6], lam[6];
  pack_constraint(p, g, C);
  gather_lambda(p, lambda, lam);
  v4d sum = splat(0.0);
  for (int r = 0; r < 6; ++r) {
    v4d s = C[r];
    for (int c = 0; c < 6; ++c) s += at(r, c) * lam[c];
    sum += s * s;
  }
  double total = 0;
  for (int l = 0; l < p.lanes; ++l) total += sum[l];
  return total;
}

}  // namespace pliant::detail
