// SPDX-License-Identifier: Apache-2.0
#include "pliant/mesh.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <limits>
#include <map>

namespace pliant {

double signed_tet_volume(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  return (b - a).dot((c - a).cross(d - a)) / 6.0;
}

double tet_volume(const TetMesh& mesh, size_t t) {
  const Tet& v = mesh.tets[t];
  return signed_tet_volume(mesh.vertices[v[0]], mesh.vertices[v[1]], mesh.vertices[v[2]],
                           mesh.vertices[v[3]]);
}

double total_volume(const TetMesh& mesh) {
  double sum = 0;
  for (size_t t = 0; t < mesh.tets.size(); ++t) sum += tet_volume(mesh, t);
  return sum;
}

Aabb bounding_box(const std::vector<Vec3>& points) {
  Aabb box;
  if (points.empty()) return box;
  box.min = Vec3::Constant(std::numeric_limits<double>::infinity());
  box.max = -box.min;
  for (const Vec3& p : points) {
    box.min = box.min.cwiseMin(p);
    box.max = box.max.cwiseMax(p);
  }
  return box;
}

std::vector<Triangle> boundary_triangles(const std::vector<Tet>& tets) {
  // Faces of a positively oriented tet (0,1,2,3), each wound so its normal points away from
  // the opposite vertex.
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  struct Entry {
    Triangle tri;
    int count;
  };
  std::map<std::array<int32_t, 3>, Entry> faces;
  for (const Tet& t : tets) {
    for (const auto& f : kFaces) {
      Triangle tri{t[f[0]], t[f[1]], t[f[2]]};
      std::array<int32_t, 3> key = tri;
      std::sort(key.begin(), key.end());
      auto [it, inserted] = faces.try_emplace(key, Entry{tri, 0});
      it->second.count++;
    }
  }
  std::vector<Triangle> out;
  for (const auto& [key, e] : faces)
    if (e.count == 1) out.push_back(e.tri);
  return out;
}

void scale_mesh(TetMesh& mesh, double factor) {
  for (Vec3& p : mesh.vertices) p *= factor;
}

}  // namespace pliant
