// SPDX-License-Identifier: Apache-2.0
// A tet's deformation written once for a lane type T (strain_kernel.hpp): F's columns, the Green
// and corotated strains, the polar rotation of every lane at once, det F. The strain kernel and
// the vertex block descent kernel both build on these.
#pragma once

#include "kernels/strain_kernel.hpp"

#include "pliant/strain_constraint.hpp"

#include <cmath>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wignored-attributes"

namespace pliant::detail {

template <class T>
struct Geometry {
  T f[3][3];  // f[i][c]: component c of column i of F
  T r[3][3];  // Corotated: R's columns, same layout
  T S[6];  // StVK: F^T F (what its 6x6 system is built from)
  T stretch[6];  // Corotated: S = sym(R^T F) (what its system is built from)
  T c[6];  // strain vector (no sqrt(V0))
};

template <class T>
inline T column_dot(const T a[3], const T b[3]) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// Green strain from g.f (StVK): S = F^T F, c = ((S_ii - 1) / 2, S_12, S_02, S_01).
template <class T>
inline void green_strain(Geometry<T>& g) {
  g.S[0] = column_dot(g.f[0], g.f[0]);
  g.S[1] = column_dot(g.f[1], g.f[1]);
  g.S[2] = column_dot(g.f[2], g.f[2]);
  g.S[3] = column_dot(g.f[1], g.f[2]);
  g.S[4] = column_dot(g.f[0], g.f[2]);
  g.S[5] = column_dot(g.f[0], g.f[1]);
  g.c[0] = 0.5 * g.S[0] - 0.5;
  g.c[1] = 0.5 * g.S[1] - 0.5;
  g.c[2] = 0.5 * g.S[2] - 0.5;
  g.c[3] = g.S[3];
  g.c[4] = g.S[4];
  g.c[5] = g.S[5];
}

template <class T>
inline T det3(const T f[3][3]) {
  return f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1]) - f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0]) +
         f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0]);
}

template <class T>
inline void cross(const T a[3], const T b[3], T out[3]) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

// The rotation of F = R S for every lane at once: the scaled Newton iteration of polar_rotation
// (strain_constraint.cpp), same steps and stopping test per lane, iterated until every lane has
// converged (a converged lane stays put). Lanes with det F <= 0 or that do not converge take the
// scalar polar_rotation (SVD); they are rare (inverted or degenerate tets).
template <class T>
inline void rotation(const T f[3][3], T r[3][3]) {
  constexpr int W = kLanes<T>;
  T X[3][3];
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) X[i][c] = f[i][c];
  int pending = (1 << W) - 1, failed = 0;
  for (int it = 0; it < kMaxPolarIterations && pending; ++it) {
    T cof[3][3];
    cross(X[1], X[2], cof[0]);
    cross(X[2], X[0], cof[1]);
    cross(X[0], X[1], cof[2]);
    const T det = column_dot(X[0], cof[0]);
    T nx = splat<T>(0.0), nc = splat<T>(0.0);
    PLIANT_UNROLL
    for (int i = 0; i < 3; ++i)
      PLIANT_UNROLL
      for (int c = 0; c < 3; ++c) {
        nx += X[i][c] * X[i][c];
        nc += cof[i][c] * cof[i][c];
      }
    T g, inv;  // g and 1 / (g det) per lane
    PLIANT_UNROLL
    for (int l = 0; l < W; ++l) {
      const double d = get_lane(det, l);
      if (!(d > 0)) {  // inverted or degenerate: the SVD handles this lane
        failed |= pending & (1 << l);
        pending &= ~(1 << l);
        set_lane(g, l, 1.0);
        set_lane(inv, l, 0.0);
        continue;
      }
      const double x2 = get_lane(nx, l);
      const double gl = std::abs(x2 - 3.0) > kPolarScalingBand ? std::sqrt(std::sqrt(get_lane(nc, l) / (d * d) / x2)) : 1.0;
      set_lane(g, l, gl);
      set_lane(inv, l, 1.0 / (gl * d));
    }
    T change = splat<T>(0.0);
    PLIANT_UNROLL
    for (int i = 0; i < 3; ++i)
      PLIANT_UNROLL
      for (int c = 0; c < 3; ++c) {
        const T next = 0.5 * (g * X[i][c] + inv * cof[i][c]);
        const T d = next - X[i][c];
        change += d * d;
        X[i][c] = next;
      }
    PLIANT_UNROLL
    for (int l = 0; l < W; ++l)
      if ((pending & (1 << l)) && get_lane(change, l) < kPolarConverged) pending &= ~(1 << l);
  }
  failed |= pending;
  PLIANT_UNROLL
  for (int l = 0; l < W; ++l) {
    if (failed & (1 << l)) {
      Mat3 F;
      PLIANT_UNROLL
      for (int i = 0; i < 3; ++i)
        PLIANT_UNROLL
        for (int c = 0; c < 3; ++c) F(c, i) = get_lane(f[i][c], l);
      const Mat3 R = polar_rotation(F);
      PLIANT_UNROLL
      for (int i = 0; i < 3; ++i)
        PLIANT_UNROLL
        for (int c = 0; c < 3; ++c) set_lane(X[i][c], l, R(c, i));
    }
  }
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i)
    PLIANT_UNROLL
    for (int c = 0; c < 3; ++c) r[i][c] = X[i][c];
}

// Corotated strain from g.f: R's columns in g.r, the stretch S = sym(R^T F) in g.stretch, and
// c = (S_ii - 1, 2 S_ac).
template <class T>
inline void corotated_strain(Geometry<T>& g) {
  rotation(g.f, g.r);
  T* S = g.stretch;
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i) S[i] = column_dot(g.r[i], g.f[i]);
  S[3] = 0.5 * (column_dot(g.r[1], g.f[2]) + column_dot(g.r[2], g.f[1]));
  S[4] = 0.5 * (column_dot(g.r[0], g.f[2]) + column_dot(g.r[2], g.f[0]));
  S[5] = 0.5 * (column_dot(g.r[0], g.f[1]) + column_dot(g.r[1], g.f[0]));
  PLIANT_UNROLL
  for (int i = 0; i < 3; ++i) g.c[i] = S[i] - 1.0;
  PLIANT_UNROLL
  for (int i = 3; i < 6; ++i) g.c[i] = 2.0 * S[i];
}

template <class T>
inline void strain(Geometry<T>& g, ElasticModel model) {
  if (model == ElasticModel::Corotated) corotated_strain(g);
  else green_strain(g);
}

}  // namespace pliant::detail

#pragma GCC diagnostic pop
