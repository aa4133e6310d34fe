// SPDX-License-Identifier: Apache-2.0
// The constraint functions of cloth and ropes and their gradients (tested against finite
// differences), and the analytic catenary the rope is checked against.
#include "pliant/cloth.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace pliant::cloth_math {

// Edge (a, b) shared by triangles (a, b, c) and (b, a, d). With n1 = (b - a) x (c - a) and
// n2 = (a - b) x (d - b) (both point the same way on a consistently oriented flat sheet) the
// signed angle between them about the edge is atan2((n1 x n2).e, n1.n2): 0 when flat.
double dihedral_angle(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const Vec3 e = b - a;
  const Vec3 n1 = e.cross(c - a);
  const Vec3 n2 = (a - b).cross(d - b);
  const double el = e.norm();
  if (el == 0.0) return 0.0;
  return std::atan2(n1.cross(n2).dot(e) / el, n1.dot(n2));
}

// The pair turned back by theta0: (s', c') = rotation(-theta0) (s, c) in the (cos, sin) plane.
// Within |s'| <= c' / 4 the odd series of atan(t), t = s' / c', to t^23 leaves out less than
// 0.25^25 / 25 < 4e-17 rad, below the result's rounding.
double angle_from_rest(double s, double c, double cos0, double sin0) {
  const double sr = s * cos0 - c * sin0, cr = c * cos0 + s * sin0;
  if (cr > 0.0 && std::abs(sr) <= 0.25 * cr) {
    static constexpr double kCoef[12] = {1.0,        -1.0 / 3.0,  1.0 / 5.0,  -1.0 / 7.0,  1.0 / 9.0,  -1.0 / 11.0,
                                         1.0 / 13.0, -1.0 / 15.0, 1.0 / 17.0, -1.0 / 19.0, 1.0 / 21.0, -1.0 / 23.0};
    const double t = sr / cr, u = t * t, u2 = u * u, u4 = u2 * u2, u8 = u4 * u4;
    // Estrin's scheme: a short dependency chain (a Horner loop of 12 terms was as slow as atan2).
    const double p01 = kCoef[0] + kCoef[1] * u, p23 = kCoef[2] + kCoef[3] * u, p45 = kCoef[4] + kCoef[5] * u,
                 p67 = kCoef[6] + kCoef[7] * u, p89 = kCoef[8] + kCoef[9] * u, pab = kCoef[10] + kCoef[11] * u;
    const double p = (p01 + u2 * p23) + u4 * (p45 + u2 * p67) + u8 * (p89 + u2 * pab);
    return t * p;
  }
  return std::atan2(sr, cr);
}

// The wing's gradient is the normal over the wing's height (|n| / |e|); the edge vertices'
// follow from translation and rotation invariance (Bridson et al. 2003, the bending modes).
std::array<Vec3, 4> dihedral_gradient(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const Vec3 e = b - a;
  const double el = e.norm();
  const Vec3 n1 = e.cross(c - a);
  const Vec3 n2 = (a - b).cross(d - b);
  const double q1 = n1.squaredNorm(), q2 = n2.squaredNorm();
  std::array<Vec3, 4> g;
  if (el == 0.0 || q1 == 0.0 || q2 == 0.0) {
    g.fill(Vec3::Zero());
    return g;
  }
  const Vec3 m1 = n1 / q1, m2 = n2 / q2;
  const Vec3 eh = e / el;
  g[2] = -el * m1;
  g[3] = -el * m2;
  g[0] = -(((c - b).dot(eh)) * m1 + ((d - b).dot(eh)) * m2);
  g[1] = ((c - a).dot(eh)) * m1 + ((d - a).dot(eh)) * m2;
  return g;
}

double rope_bend_value(const Vec3& a, const Vec3& b, const Vec3& c) {
  return (b - (a + b + c) / 3.0).norm();
}

std::array<Vec3, 3> rope_bend_gradient(const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 r = b - (a + b + c) / 3.0;
  const double len = r.norm();
  std::array<Vec3, 3> g;
  if (len == 0.0) {
    g.fill(Vec3::Zero());
    return g;
  }
  const Vec3 n = r / len;
  g[0] = -n / 3.0;
  g[1] = 2.0 * n / 3.0;
  g[2] = -n / 3.0;
  return g;
}

double enclosed_volume(std::span<const Vec3> x, std::span<const std::array<uint32_t, 3>> triangles) {
  double v = 0.0;
  for (const auto& t : triangles) v += x[t[0]].cross(x[t[1]]).dot(x[t[2]]);
  return v / 6.0;
}

void enclosed_volume_gradient(std::span<const Vec3> x, std::span<const std::array<uint32_t, 3>> triangles,
                              std::vector<Vec3>& grad) {
  grad.assign(x.size(), Vec3::Zero());
  for (const auto& t : triangles) {
    const Vec3 &p0 = x[t[0]], &p1 = x[t[1]], &p2 = x[t[2]];
    grad[t[0]] += p1.cross(p2) / 6.0;
    grad[t[1]] += p2.cross(p0) / 6.0;
    grad[t[2]] += p0.cross(p1) / 6.0;
  }
}

double catenary_parameter(double span, double length) {
  if (!(span > 0.0) || !(length > span))
    throw std::invalid_argument("catenary: length must exceed span > 0 (span " + std::to_string(span) + " m, length " +
                                std::to_string(length) + " m)");
  // f(a) = 2 a sinh(span / 2a) - length decreases in a; bisection on a in log space.
  double lo = 1e-6 * span, hi = 1e6 * span;
  for (int i = 0; i < 200; ++i) {
    const double mid = std::sqrt(lo * hi);
    const double f = 2.0 * mid * std::sinh(span / (2.0 * mid)) - length;
    if (!std::isfinite(f) || f > 0.0)
      lo = mid;
    else
      hi = mid;
  }
  return std::sqrt(lo * hi);
}

double catenary_sag(double span, double length) {
  const double a = catenary_parameter(span, length);
  return a * (std::cosh(span / (2.0 * a)) - 1.0);
}

}  // namespace pliant::cloth_math
