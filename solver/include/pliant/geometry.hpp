// SPDX-License-Identifier: Apache-2.0
// Geometric queries on plain points that every layer shares (the mesh embedding, the contacts,
// the cloth): written once here.
#pragma once

#include <Eigen/Core>

#include <array>

namespace pliant {

// Closest point to p on triangle (a, b, c) and its barycentric weights (sum 1, all >= 0), by the
// Voronoi regions of its corners, edges and face. A degenerate triangle (an edge or the whole of
// it of zero length) gives the closest point of what it is, a segment or a point, without
// dividing by zero.
Eigen::Vector3d closest_point_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                          const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                          std::array<double, 3>& barycentric);

}  // namespace pliant
