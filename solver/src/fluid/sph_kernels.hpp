// SPDX-License-Identifier: Apache-2.0
// The SPH kernels of position-based fluids: poly6 for densities, the spiky kernel's gradient
// for the density constraint's gradient; and the density constraint of one particle with its
// gradient, shared by the solver and the tests.
#pragma once

#include "pliant/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <span>

namespace pliant::fluid {

struct Kernels {
  double h = 1.0;
  double h2 = 1.0;
  double poly6_c = 0.0;  // 315 / (64 pi h^9)
  double spiky_c = 0.0;  // 15 / (pi h^6)
  double spiky_g = 0.0;  // -45 / (pi h^6)

  explicit Kernels(double support) : h(support), h2(support * support) {
    const double pi = std::numbers::pi;
    poly6_c = 315.0 / (64.0 * pi * std::pow(h, 9));
    spiky_c = 15.0 / (pi * std::pow(h, 6));
    spiky_g = -45.0 / (pi * std::pow(h, 6));
  }

  // poly6 W(r) = 315 / (64 pi h^9) (h^2 - r^2)^3 for r < h, from r^2.
  double poly6(double r2) const {
    if (r2 >= h2) return 0.0;
    const double t = h2 - r2;
    return poly6_c * t * t * t;
  }
  // spiky W(r) = 15 / (pi h^6) (h - r)^3 for r < h.
  double spiky(double r) const {
    if (r >= h) return 0.0;
    const double t = h - r;
    return spiky_c * t * t * t;
  }
  // grad_r of spiky W at r = p_i - p_j: -45 / (pi h^6) (h - |r|)^2 r / |r| (0 at r = 0 and
  // beyond h).
  Vec3 spiky_gradient(const Vec3& r) const {
    const double r2 = r.squaredNorm();
    if (r2 >= h2 || r2 <= 0.0) return Vec3::Zero();
    const double len = std::sqrt(r2);
    const double t = h - len;
    return (spiky_g * t * t / len) * r;
  }
};

// The fraction of poly6's mass beyond a plane at distance y from the kernel's centre (0.5 at
// y = 0, 0 from y = h): (pi c / 4) int_y^h (h^2 - z^2)^4 dz with c = 315 / (64 pi h^9), that is
// 1/2 - (pi c / 4) g(y) with g(z) = int_0^z (h^2 - s^2)^4 ds (g(h) = 128 h^9 / 315); and its
// derivative with respect to y.
inline double poly6_beyond(const Kernels& k, double y) {
  if (y >= k.h) return 0.0;
  y = std::max(y, 0.0);
  const double h2 = k.h2, y2 = y * y;
  const double g = y * (h2 * h2 * h2 * h2 + y2 * (-4.0 / 3.0 * h2 * h2 * h2 + y2 * (6.0 / 5.0 * h2 * h2 +
                                                                                   y2 * (-4.0 / 7.0 * h2 + y2 / 9.0))));
  return 0.5 - std::numbers::pi * k.poly6_c / 4.0 * g;
}
inline double poly6_beyond_slope(const Kernels& k, double y) {
  if (y >= k.h) return 0.0;
  y = std::max(y, 0.0);
  const double t = k.h2 - y * y;
  return -std::numbers::pi * k.poly6_c / 4.0 * t * t * t * t;
}

// grad W for the pair (i, j) at r = p_i - p_j: spiky_gradient, except for particles on the
// same point (a container's corner can put several there), where the direction is a fixed
// diagonal, signed by the index order so that the pair's gradients stay opposite, at the
// kernel's largest slope.
inline Vec3 pair_gradient(const Kernels& k, const Vec3& r, uint32_t i, uint32_t j) {
  if (r.squaredNorm() > 1e-18 * k.h2) return k.spiky_gradient(r);
  const double sign = i < j ? 1.0 : -1.0;
  return (sign * k.spiky_g * k.h2 / std::sqrt(3.0)) * Vec3(1.0, 1.0, 1.0);
}

// The density constraint C_i = rho_i / rho0 - 1 of particle i at p_i with neighbours p_j
// (rho_i = m sum_j W(p_i - p_j) + m W(0)), and its gradients: grad_i C_i = (m / rho0) sum_j
// grad W(p_i - p_j), grad_j C_i = -(m / rho0) grad W(p_i - p_j). Writes grad_i into *grad_i
// and the sum of |grad_j|^2 over the neighbours into *sum_sq_j.
inline double density_constraint(const Kernels& k, double mass, double rho0, const Vec3& pi,
                                 std::span<const Vec3> neighbours, Vec3* grad_i, double* sum_sq_j) {
  double rho = mass * k.poly6(0.0);
  const double s = mass / rho0;
  Vec3 gi = Vec3::Zero();
  double sq = 0.0;
  for (const Vec3& pj : neighbours) {
    const Vec3 r = pi - pj;
    rho += mass * k.poly6(r.squaredNorm());
    const Vec3 g = s * k.spiky_gradient(r);
    gi += g;
    sq += g.squaredNorm();
  }
  if (grad_i) *grad_i = gi;
  if (sum_sq_j) *sum_sq_j = sq;
  return rho / rho0 - 1.0;
}

}  // namespace pliant::fluid
