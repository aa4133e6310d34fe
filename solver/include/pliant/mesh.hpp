// SPDX-License-Identifier: Apache-2.0
// Tetrahedral meshes as plain data: vertex positions and tets (4 vertex indices each).
// This is what every loader produces and what a body model is built from; geometry helpers
// (volumes, boundary extraction, bounding box) live beside it.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace pliant {

using Vec3 = Eigen::Vector3d;
using Tet = std::array<int32_t, 4>;
using Triangle = std::array<int32_t, 3>;

// A set of vertices the mesh file names: a Gmsh physical group (the nodes of its elements).
struct VertexGroup {
  int dimension = 3;              // 0 points, 1 curves, 2 surfaces, 3 volumes
  int64_t tag = 0;                // the physical tag
  std::string name;               // from $PhysicalNames; empty when the file names none
  std::vector<int32_t> vertices;  // indices into TetMesh::vertices, ascending, unique
};

struct TetMesh {
  std::vector<Vec3> vertices;   // metres
  std::vector<Tet> tets;        // positive orientation: det[x1-x0, x2-x0, x3-x0] > 0
  std::string name;             // for messages and logs ("beam3", "armadillo.node", ...)
  std::vector<VertexGroup> groups;  // physical groups of a Gmsh file (empty for other formats)
};


struct Aabb {
  Vec3 min = Vec3::Constant(0.0);
  Vec3 max = Vec3::Constant(0.0);
  Vec3 extent() const { return max - min; }
};

// Signed volume of the tet (a, b, c, d): det[b-a, c-a, d-a] / 6.
double signed_tet_volume(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);
double tet_volume(const TetMesh& mesh, size_t tet);
double total_volume(const TetMesh& mesh);
Aabb bounding_box(const std::vector<Vec3>& points);

// Boundary faces (those owned by one tet), wound so that their normals point outward.
std::vector<Triangle> boundary_triangles(const std::vector<Tet>& tets);

// Uniform scale about the origin (file units to metres).
void scale_mesh(TetMesh& mesh, double factor);

}  // namespace pliant
