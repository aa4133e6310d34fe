// SPDX-License-Identifier: Apache-2.0
// Static collision geometry (planes, spheres, boxes) and the contact constraint
// C(p) = (p - q).n >= 0 projected against it, with Coulomb friction at position level.
#pragma once

#include <Eigen/Core>

#include <vector>

namespace pliant {

struct Collider {
  enum class Shape { Plane, Sphere, Box };
  Shape shape = Shape::Plane;
  Eigen::Vector3d point{0, 0, 0};    // plane: a point on it; sphere/box: centre
  Eigen::Vector3d normal{0, 1, 0};   // plane: outward normal (unit)
  double radius = 0.0;               // sphere
  Eigen::Vector3d half_extent{0, 0, 0};  // box (axis-aligned)
  double static_friction = 0.5;
  double dynamic_friction = 0.4;

  static Collider plane(const Eigen::Vector3d& point, const Eigen::Vector3d& normal);
  static Collider sphere(const Eigen::Vector3d& centre, double radius);
  static Collider box(const Eigen::Vector3d& centre, const Eigen::Vector3d& half_extent);
};

struct ContactPoint {
  Eigen::Vector3d q;       // closest surface point
  Eigen::Vector3d normal;  // outward from the collider
  double depth;            // penetration (> 0 inside)
};

// The contact for point p if p is inside (or on) the collider.
bool find_contact(const Collider& c, const Eigen::Vector3d& p, ContactPoint& out);

}  // namespace pliant
