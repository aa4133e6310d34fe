// SPDX-License-Identifier: Apache-2.0
// A point inside a ball (a sphere collider, or a tool's core point swept by its radius): the
// contact that pushes it out along the radius through it.
#pragma once

#include <Eigen/Core>

namespace pliant::detail {

// False when p is at or beyond the radius. A point at the centre leaves upwards (+y).
inline bool ball_contact(const Eigen::Vector3d& centre, double radius, const Eigen::Vector3d& p,
                         Eigen::Vector3d& normal, Eigen::Vector3d& q, double& depth) {
  const Eigen::Vector3d r = p - centre;
  const double len = r.norm();
  if (len >= radius) return false;
  normal = len > 1e-12 ? Eigen::Vector3d(r / len) : Eigen::Vector3d(0, 1, 0);
  q = centre + radius * normal;
  depth = radius - len;
  return true;
}

}  // namespace pliant::detail
