// SPDX-License-Identifier: Apache-2.0
// Render meshes: a high-resolution triangle surface (read through assimp: OBJ, STL, PLY, glTF/GLB,
// FBX, OFF, ...) embedded in a coarse tet mesh by barycentric coordinates, so a front end gets a
// smooth deformed surface while the solver runs on the tet mesh. Also the binding file written
// by `pliant-mesh embed`, and the surface side of `pliant-mesh tetrahedralize`.
#pragma once

#include "pliant/mesh.hpp"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace pliant {

struct SurfaceMesh {
  std::vector<Vec3> vertices;
  std::vector<Triangle> triangles;
  std::string name;
};

struct SurfaceLoadOptions {
  double scale = 1.0;        // file units -> metres
  bool weld = true;          // merge vertices with identical positions (STL, per-face normals)
};

// Loads every triangle of every mesh in the file (node transforms applied); MeshError on failure
// or when the file holds no triangles.
SurfaceMesh load_surface(const std::string& path, const SurfaceLoadOptions& options = {});
// The surface as an .off file (used as TetGen input) or .obj.
void write_surface(const SurfaceMesh& surface, const std::string& path);

// Each surface vertex bound to one tet by barycentric weights: x = sum_k w_k * X[tet[k]].
// Vertices inside the tet mesh get the tet containing them (all weights in [0,1] up to round-off);
// those outside get the nearest tet and (extrapolating) weights that still sum to 1 and still
// reproduce the rest position exactly.
struct SurfaceBinding {
  std::vector<int32_t> tet;                 // per surface vertex
  std::vector<Eigen::Vector4d> weights;     // per surface vertex, sum 1
  std::vector<Triangle> triangles;          // the surface's triangles (for normals)
  int64_t tet_vertex_count = 0;             // the tet mesh it was made for (checked on use)
  int64_t tet_count = 0;
  int64_t outside = 0;                      // vertices farther than 1e-6 x the mesh diagonal from every tet
  double max_outside_distance = 0;          // largest distance of those to their tet (m)
};

SurfaceBinding embed_surface(const TetMesh& tets, const SurfaceMesh& surface);

// Surface positions for tet-mesh positions `x` (the same vertex order as the embedding's mesh).
std::vector<Vec3> deform_surface(const SurfaceBinding& binding, const TetMesh& tets, const std::vector<Vec3>& x);
// Area-weighted unit vertex normals of a triangle surface (recomputed per frame).
std::vector<Vec3> vertex_normals(const std::vector<Vec3>& vertices, const std::vector<Triangle>& triangles);

// Binding file (text, "pliant-binding 1"): see the format description in render_mesh.cpp and
// README.md. MeshError on malformed files.
void write_binding(const SurfaceBinding& binding, const std::string& path, const std::string& tet_mesh_name = "",
                   const std::string& surface_name = "");
SurfaceBinding read_binding(const std::string& path);

// Runs Debian's `tetgen -pYq<ratio>` on a closed surface (written to a temporary .off in
// `work_dir`, or the source file itself, see below); the result is <work_dir>/surface.1.node/.ele. MeshError if tetgen is not installed or
// fails. `extra_switches` are appended (e.g. "a1e-6").
struct TetrahedralizeOptions {
  double quality_ratio = 1.5;      // -q<ratio>, radius-edge bound
  std::string extra_switches;
  std::string work_dir;            // empty: a fresh directory under the system temp dir
  std::string tetgen = "tetgen";   // program to run
  // The file the surface was loaded from. When TetGen reads its format itself (.ply, .off), the
  // file is handed to TetGen unchanged, so the result is exactly what `tetgen -pYq<r> file` gives
  // (assimp reorders vertices, and TetGen's output depends on the input order). Otherwise the
  // surface is written as .off. Either way the coordinates are the file's: scale the result.
  std::string source_file;
};
struct TetrahedralizeResult {
  std::string node_path;           // the .1.node written by tetgen (in work_dir)
  std::string command;
};
TetrahedralizeResult tetrahedralize_surface(const SurfaceMesh& surface, const TetrahedralizeOptions& options = {});
bool program_available(const std::string& program);

}  // namespace pliant
