// SPDX-License-Identifier: Apache-2.0
// With F's columns F_0..F_2 and the vertex's row b (vbd_lanes.hpp), for an isotropic K:
//   StVK: S = K c (Voigt), dE/dx_i = V0 F S b^T; the Gauss-Newton block V0 M^T K M has the rows
//   m_0 = b_0 F_0, m_1 = b_1 F_1, m_2 = b_2 F_2, m_3 = b_2 F_1 + b_1 F_2, m_4 = b_2 F_0 + b_0 F_2,
//   m_5 = b_1 F_0 + b_0 F_1, so M^T K M = lambda t t^T + 2 mu sum_{r<3} m_r m_r^T +
//   mu sum_{r>=3} m_r m_r^T with t = m_0 + m_1 + m_2 = F b^T.
//   Corotated (R held fixed): dE/dx_i = V0 (2 mu (F b^T - q) + lambda tr(S - I) q), q = R b^T;
//   block V0 (2 mu |b|^2 I + lambda q q^T).
//   Energy: 1/2 V0 (lambda (sum_{r<3} c_r)^2 + 2 mu sum_{r<3} c_r^2 + mu sum_{r>=3} c_r^2).
#include "vbd/vbd_lanes.hpp"

#include "kernels/lane_geometry.hpp"

#include <algorithm>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wignored-attributes"

namespace pliant::detail {

namespace {

// D_m^-1 of the tet with its corner k moved to the origin: D_m = D'_m P, where column c of P
// is +1 at row slot(c) (c != k) and -1 at row slot(3) (the corner 3 among the others).
Mat3 reordered_inverse(const TetRest& t, int k, int others[3]) {
  int slot[4] = {-1, -1, -1, -1};
  for (int c = 0, j = 0; c < 4; ++c)
    if (c != k) {
      others[j] = c;
      slot[c] = j++;
    }
  if (k == 3) return t.dm_inv;
  Mat3 P = Mat3::Zero();
  for (int c = 0; c < 3; ++c) {
    if (c != k) P(slot[c], c) += 1.0;
    P(slot[3], c) -= 1.0;
  }
  return P * t.dm_inv;
}

template <class T>
void fill(VertexTetLanes<T>& p, int lane, const TetRest& t, int k, bool real) {
  int others[3];
  const Mat3 B = reordered_inverse(t, k, others);
  for (int r = 0; r < 3; ++r)
    for (int i = 0; i < 3; ++i) set_lane(p.B[3 * r + i], lane, B(r, i));
  for (int i = 0; i < 3; ++i) set_lane(p.b[i], lane, -(B(0, i) + B(1, i) + B(2, i)));
  set_lane(p.volume, lane, real ? t.volume : 0.0);
  for (int j = 0; j < 3; ++j) p.other[j][lane] = t.v[others[j]];
}

// F's columns with the vertex moved by d: F0 + d b.
template <class T>
inline void moved(const std::array<T, 9>& f0, const VertexTetLanes<T>& p, const Vec3& d, T f[3][3]) {
  for (int i = 0; i < 3; ++i)
    for (int c = 0; c < 3; ++c) f[i][c] = f0[3 * i + c] + d[c] * p.b[i];
}

template <class T>
inline double lane_sum(const T& a) {
  double s = 0;
  for (int l = 0; l < kLanes<T>; ++l) s += get_lane(a, l);
  return s;
}

}  // namespace

template <class T>
VertexPacks<T> compile_vertex_packs(const BodyModel& m) {
  constexpr int W = kLanes<T>;
  VertexPacks<T> out;
  out.begin.assign(m.vertex_count() + 1, 0);
  for (size_t i = 0; i < m.vertex_count(); ++i) {
    const int32_t a0 = m.vertex_tet_start[i], n = m.vertex_tet_start[i + 1] - a0;
    for (int32_t first = 0; first < n; first += W) {
      VertexTetLanes<T> p{};
      for (int l = 0; l < W; ++l) {
        const bool real = first + l < n;
        const int32_t entry = m.vertex_tet_entry[a0 + (real ? first + l : first)];
        fill(p, l, m.tets[entry >> 2], entry & 3, real);
      }
      out.packs.push_back(p);
    }
    out.begin[i + 1] = int32_t(out.packs.size());
  }
  return out;
}

template <class T>
void VertexTets<T>::gather(const VertexPacks<T>& vp, int32_t i, const std::vector<Vec3>& x) {
  constexpr int W = kLanes<T>;
  packs_ = vp.packs.data() + vp.begin[i];
  count_ = vp.begin[i + 1] - vp.begin[i];
  if (f_.size() < size_t(count_)) f_.resize(count_);
  const Vec3& xi = x[i];
  for (int k = 0; k < count_; ++k) {
    const VertexTetLanes<T>& p = packs_[k];
    T e[3][3];  // e[j][c]: component c of x_oj - x_i
    for (int j = 0; j < 3; ++j)
      for (int l = 0; l < W; ++l) {
        const Vec3& q = x[p.other[j][l]];
        for (int c = 0; c < 3; ++c) set_lane(e[j][c], l, q[c] - xi[c]);
      }
    for (int col = 0; col < 3; ++col)
      for (int c = 0; c < 3; ++c)
        f_[k][3 * col + c] = e[0][c] * p.B[col] + e[1][c] * p.B[3 + col] + e[2][c] * p.B[6 + col];
  }
}

template <class T>
void VertexTets<T>::derivatives(const Vec3& d, const Lame& lame, ElasticModel model, Vec3& g, Mat3* H) const {
  const T lambda = splat<T>(lame.lambda), mu = splat<T>(lame.mu), two_mu = splat<T>(2 * lame.mu);
  T gs[3] = {splat<T>(0.0), splat<T>(0.0), splat<T>(0.0)};
  T hs[6] = {splat<T>(0.0), splat<T>(0.0), splat<T>(0.0), splat<T>(0.0), splat<T>(0.0), splat<T>(0.0)};
  // hs += w u u^T (Voigt order 00 11 22 12 02 01)
  auto outer = [&hs](const T& w, const T u[3]) {
    const T wu0 = w * u[0], wu1 = w * u[1], wu2 = w * u[2];
    hs[0] += wu0 * u[0];
    hs[1] += wu1 * u[1];
    hs[2] += wu2 * u[2];
    hs[3] += wu1 * u[2];
    hs[4] += wu0 * u[2];
    hs[5] += wu0 * u[1];
  };
  for (int k = 0; k < count_; ++k) {
    const VertexTetLanes<T>& p = packs_[k];
    Geometry<T> geo;
    moved(f_[k], p, d, geo.f);
    const T* b = p.b;
    const T V = p.volume;
    T t[3];  // F b^T
    for (int c = 0; c < 3; ++c) t[c] = geo.f[0][c] * b[0] + geo.f[1][c] * b[1] + geo.f[2][c] * b[2];
    if (model == ElasticModel::Corotated) {
      corotated_strain(geo);
      T q[3];
      for (int c = 0; c < 3; ++c) q[c] = geo.r[0][c] * b[0] + geo.r[1][c] * b[1] + geo.r[2][c] * b[2];
      const T tr = geo.c[0] + geo.c[1] + geo.c[2];
      for (int c = 0; c < 3; ++c) gs[c] += V * (two_mu * (t[c] - q[c]) + lambda * tr * q[c]);
      if (H) {
        const T diag = V * two_mu * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
        hs[0] += diag;
        hs[1] += diag;
        hs[2] += diag;
        outer(V * lambda, q);
      }
      continue;
    }
    green_strain(geo);
    const T tr = geo.c[0] + geo.c[1] + geo.c[2];
    T s[6];
    for (int r = 0; r < 3; ++r) s[r] = lambda * tr + two_mu * geo.c[r];
    for (int r = 3; r < 6; ++r) s[r] = mu * geo.c[r];
    const T sb0 = s[0] * b[0] + s[5] * b[1] + s[4] * b[2];
    const T sb1 = s[5] * b[0] + s[1] * b[1] + s[3] * b[2];
    const T sb2 = s[4] * b[0] + s[3] * b[1] + s[2] * b[2];
    for (int c = 0; c < 3; ++c) gs[c] += V * (geo.f[0][c] * sb0 + geo.f[1][c] * sb1 + geo.f[2][c] * sb2);
    if (!H) continue;
    const T* F0 = geo.f[0];
    const T* F1 = geo.f[1];
    const T* F2 = geo.f[2];
    T m[3];
    const T v2mu = V * two_mu, vmu = V * mu;
    outer(V * lambda, t);
    for (int c = 0; c < 3; ++c) m[c] = b[0] * F0[c];
    outer(v2mu, m);
    for (int c = 0; c < 3; ++c) m[c] = b[1] * F1[c];
    outer(v2mu, m);
    for (int c = 0; c < 3; ++c) m[c] = b[2] * F2[c];
    outer(v2mu, m);
    for (int c = 0; c < 3; ++c) m[c] = b[2] * F1[c] + b[1] * F2[c];
    outer(vmu, m);
    for (int c = 0; c < 3; ++c) m[c] = b[2] * F0[c] + b[0] * F2[c];
    outer(vmu, m);
    for (int c = 0; c < 3; ++c) m[c] = b[1] * F0[c] + b[0] * F1[c];
    outer(vmu, m);
  }
  for (int c = 0; c < 3; ++c) g[c] = lane_sum(gs[c]);
  if (H) {
    const double h[6] = {lane_sum(hs[0]), lane_sum(hs[1]), lane_sum(hs[2]),
                         lane_sum(hs[3]), lane_sum(hs[4]), lane_sum(hs[5])};
    *H << h[0], h[5], h[4], h[5], h[1], h[3], h[4], h[3], h[2];
  }
}

template <class T>
bool VertexTets<T>::energy(const Vec3& d, const Lame& lame, ElasticModel model, double& e) const {
  const T lambda = splat<T>(lame.lambda), mu = splat<T>(lame.mu), two_mu = splat<T>(2 * lame.mu);
  T sum = splat<T>(0.0);
  for (int k = 0; k < count_; ++k) {
    const VertexTetLanes<T>& p = packs_[k];
    Geometry<T> geo;
    moved(f_[k], p, d, geo.f);
    const T det = det3(geo.f);
    for (int l = 0; l < kLanes<T>; ++l)
      if (!(get_lane(det, l) > 0)) return false;
    if (model == ElasticModel::Corotated) corotated_strain(geo);
    else green_strain(geo);
    const T tr = geo.c[0] + geo.c[1] + geo.c[2];
    const T normal = geo.c[0] * geo.c[0] + geo.c[1] * geo.c[1] + geo.c[2] * geo.c[2];
    const T shear = geo.c[3] * geo.c[3] + geo.c[4] * geo.c[4] + geo.c[5] * geo.c[5];
    sum += p.volume * (lambda * tr * tr + two_mu * normal + mu * shear);
  }
  e += 0.5 * lane_sum(sum);
  return true;
}

template VertexPacks<double> compile_vertex_packs<double>(const BodyModel&);
template VertexPacks<v4d> compile_vertex_packs<v4d>(const BodyModel&);
template class VertexTets<double>;
template class VertexTets<v4d>;

}  // namespace pliant::detail

#pragma GCC diagnostic pop
