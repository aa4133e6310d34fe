// SPDX-License-Identifier: Apache-2.0
// Meshes Pliant can build without a file: the thesis's cantilever beams. A beam is a grid of
// nx x ny x nz nodes spaced `cube` apart along +x, +y, +z from the origin, each cube split into
// 5 tets with alternating orientation so that neighbouring cubes share face diagonals
// (a conforming mesh). beam1/2/3 are the thesis's three resolutions (460/1395/3120 tets).
#pragma once

#include "pliant/mesh.hpp"

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace pliant {

TetMesh make_beam(int nx, int ny, int nz, double cube);

// "beam1" | "beam2" | "beam3"; nullopt for anything else.
std::optional<TetMesh> builtin_mesh(std::string_view name);
std::vector<std::string> builtin_mesh_names();

}  // namespace pliant
