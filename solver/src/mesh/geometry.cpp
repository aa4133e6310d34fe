// SPDX-License-Identifier: Apache-2.0
#include "pliant/geometry.hpp"

namespace pliant {

Eigen::Vector3d closest_point_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                          const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                          std::array<double, 3>& w) {
  using V3 = Eigen::Vector3d;
  // Ericson, Real-Time Collision Detection 5.1.5.
  const V3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) {
    w = {1, 0, 0};
    return a;
  }
  const V3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) {
    w = {0, 1, 0};
    return b;
  }
  const double vc = d1 * d4 - d3 * d2;
  // The edges' regions: a zero-length edge (its two dot products equal) is left to the others.
  if (vc <= 0 && d1 >= 0 && d3 <= 0 && d1 - d3 > 0) {  // edge ab
    const double v = d1 / (d1 - d3);
    w = {1 - v, v, 0};
    return a + v * ab;
  }
  const V3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) {
    w = {0, 0, 1};
    return c;
  }
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0 && d2 - d6 > 0) {  // edge ac
    const double t = d2 / (d2 - d6);
    w = {1 - t, 0, t};
    return a + t * ac;
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0 && (d4 - d3) + (d5 - d6) > 0) {  // edge bc
    const double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    w = {0, 1 - t, t};
    return b + t * (c - b);
  }
  const double sum = va + vb + vc;
  if (!(sum > 0)) {  // a point (or not finite)
    w = {1, 0, 0};
    return a;
  }
  const double denom = 1.0 / sum;
  const double v = vb * denom, u = vc * denom;
  w = {1 - v - u, v, u};
  return a + v * ab + u * ac;
}

}  // namespace pliant
