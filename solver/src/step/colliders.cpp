// SPDX-License-Identifier: Apache-2.0
#include "pliant/colliders.hpp"

#include "step/ball_contact.hpp"

#include <cmath>

namespace pliant {

Collider Collider::plane(const Eigen::Vector3d& point, const Eigen::Vector3d& normal) {
  Collider c;
  c.shape = Shape::Plane;
  c.point = point;
  c.normal = normal.normalized();
  return c;
}

Collider Collider::sphere(const Eigen::Vector3d& centre, double radius) {
  Collider c;
  c.shape = Shape::Sphere;
  c.point = centre;
  c.radius = radius;
  return c;
}

Collider Collider::box(const Eigen::Vector3d& centre, const Eigen::Vector3d& half_extent) {
  Collider c;
  c.shape = Shape::Box;
  c.point = centre;
  c.half_extent = half_extent;
  return c;
}

bool find_contact(const Collider& c, const Eigen::Vector3d& p, ContactPoint& out) {
  switch (c.shape) {
    case Collider::Shape::Plane: {
      double d = (p - c.point).dot(c.normal);
      if (d > 0) return false;
      out.normal = c.normal;
      out.q = p - d * c.normal;
      out.depth = -d;
      return true;
    }
    case Collider::Shape::Sphere:
      return detail::ball_contact(c.point, c.radius, p, out.normal, out.q, out.depth);
    case Collider::Shape::Box: {
      Eigen::Vector3d local = p - c.point;
      Eigen::Vector3d gap = c.half_extent - local.cwiseAbs();  // > 0 inside along each axis
      if ((gap.array() < 0).any()) return false;
      int axis = 0;
      gap.minCoeff(&axis);  // leave through the nearest face
      out.normal = Eigen::Vector3d::Zero();
      out.normal[axis] = local[axis] >= 0 ? 1.0 : -1.0;
      out.q = p;
      out.q[axis] = c.point[axis] + out.normal[axis] * c.half_extent[axis];
      out.depth = gap[axis];
      return true;
    }
  }
  return false;
}

}  // namespace pliant
