// SPDX-License-Identifier: Apache-2.0
#include "pliant/builtin_meshes.hpp"

#include <stdexcept>
#include <utility>

namespace pliant {

TetMesh make_beam(int nx, int ny, int nz, double cube) {
  if (nx < 2 || ny < 2 || nz < 2 || !(cube > 0))
    throw std::invalid_argument("beam needs at least 2 nodes per axis and a positive cube size");
  TetMesh mesh;
  auto id = [&](int i, int j, int k) { return static_cast<int32_t>((k * ny + j) * nx + i); };
  mesh.vertices.reserve(size_t(nx) * ny * nz);
  for (int k = 0; k < nz; ++k)
    for (int j = 0; j < ny; ++j)
      for (int i = 0; i < nx; ++i) mesh.vertices.emplace_back(i * cube, j * cube, k * cube);

  // Corner c of a cube has offsets (c&1, (c>>1)&1, (c>>2)&1). The "even" split uses the
  // tetrahedron (1,2,4,7) in the middle, the "odd" one its mirror (0,3,5,6); alternating them
  // in a checkerboard makes the face diagonals of neighbouring cubes agree.
  static constexpr int kEven[5][4] = {{0, 1, 2, 4}, {1, 3, 2, 7}, {1, 4, 5, 7}, {2, 4, 6, 7}, {1, 2, 4, 7}};
  static constexpr int kOdd[5][4] = {{1, 0, 3, 5}, {0, 2, 3, 6}, {0, 5, 4, 6}, {3, 6, 7, 5}, {0, 3, 5, 6}};
  mesh.tets.reserve(size_t(nx - 1) * (ny - 1) * (nz - 1) * 5);
  for (int k = 0; k + 1 < nz; ++k)
    for (int j = 0; j + 1 < ny; ++j)
      for (int i = 0; i + 1 < nx; ++i) {
        int32_t corner[8];
        for (int c = 0; c < 8; ++c) corner[c] = id(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
        const auto& split = ((i + j + k) % 2 == 0) ? kEven : kOdd;
        for (const auto& t : split) {
          Tet tet{corner[t[0]], corner[t[1]], corner[t[2]], corner[t[3]]};
          if (signed_tet_volume(mesh.vertices[tet[0]], mesh.vertices[tet[1]], mesh.vertices[tet[2]],
                                mesh.vertices[tet[3]]) < 0)
            std::swap(tet[2], tet[3]);
          mesh.tets.push_back(tet);
        }
      }
  return mesh;
}

std::optional<TetMesh> builtin_mesh(std::string_view name) {
  TetMesh mesh;
  if (name == "beam1") mesh = make_beam(24, 3, 3, 0.005);
  else if (name == "beam2") mesh = make_beam(32, 4, 4, 0.01 / 3.0);
  else if (name == "beam3") mesh = make_beam(40, 5, 5, 0.0025);
  else return std::nullopt;
  mesh.name = std::string(name);
  return mesh;
}

std::vector<std::string> builtin_mesh_names() { return {"beam1", "beam2", "beam3"}; }

}  // namespace pliant
