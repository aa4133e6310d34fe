// SPDX-License-Identifier: Apache-2.0
// Reading meshes: one entry point for every format, plus the resolver that turns what a user
// types (a builtin name like "beam3", a short model name like "armadillo", or a path) into a
// validated TetMesh. Errors are MeshError exceptions whose message names the file, the
// line/element and the value.
//
// Formats read: TetGen .node/.ele (0- or 1-based, detected from the first node index), Gmsh .msh
// v1, v2.2 and v4.1 (ASCII and binary), VTK legacy UNSTRUCTURED_GRID (.vtk, ASCII and binary)
// and VTK XML .vtu (ASCII, inline base64 binary and raw appended, uncompressed or zlib). Written: TetGen, VTK legacy, VTU, Gmsh.
#pragma once

#include "pliant/mesh.hpp"
#include "pliant/mesh_validate.hpp"

#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace pliant {

class MeshError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct MeshLoadOptions {
  double scale = 1.0;  // multiply coordinates (file units -> metres)
  // If > 0: after `scale`, scale uniformly about the origin so that the longest side of the
  // bounding box is fit_size metres.
  double fit_size = 0.0;
  MeshValidationOptions validation;  // source/origin fields are filled in by the loader
};

struct MeshLoadResult {
  TetMesh mesh;
  MeshReport report;
  double applied_scale = 1.0;  // the total factor applied to the file's coordinates
};

// Loads a tet mesh from a file, picking the format by extension (and content where needed).
TetMesh load_mesh(const std::string& path, const MeshLoadOptions& options = {});
// The same, with the validation report (counts, repairs, quality, surface).
MeshLoadResult load_mesh_with_report(const std::string& path, const MeshLoadOptions& options = {});

// The vertices of the physical group called `group` (Gmsh files), or, when no group has that
// name and `group` is a number, of the groups with that physical tag (every dimension). Throws
// MeshError naming the group and listing the mesh's groups when there is none.
std::vector<int32_t> group_vertices(const TetMesh& mesh, const std::string& group);
// The mesh's groups for messages: `1 "clamp" (surface, 42 vertices), 7 (volume, 216 vertices)`.
std::string describe_groups(const TetMesh& mesh);

// "beam1".."beam3" -> builtin; a short model name -> the model set on `search_path`
// (each entry a directory, e.g. the repo's meshes/); anything else -> a path.
TetMesh resolve_mesh(std::string_view spec, const std::vector<std::string>& search_path = {});
// The same with options (the model's own scale is multiplied by options.scale) and the report.
MeshLoadResult resolve_mesh_with_report(std::string_view spec, const std::vector<std::string>& search_path,
                                        const MeshLoadOptions& options = {});

// The default model search path: $PLIANT_MODEL_PATH (colon-separated) then bundled_model_dir().
std::vector<std::string> default_model_path();
// The model set that comes with Pliant: the installed one next to the running program
// (<bin>/../share/pliant/meshes), else the build's PLIANT_MESH_DIR (the source tree's meshes/),
// else the install prefix's share/pliant/meshes as configured at build time.
std::string bundled_model_dir();

// The short-name registry of the model set in meshes/ (see meshes/SOURCES.md).
struct ModelEntry {
  std::string name;            // "armadillo"
  std::string file;            // relative to a search-path directory
  double scale = 1.0;          // file units -> metres
  std::string size;            // resulting physical size, for listings ("13.5 x 8.6 x 10.4 cm")
  std::string description;
  std::string credit;          // origin and licence, short
  std::string render_surface;  // optional surface mesh (same frame, same scale), relative path
};
const std::vector<ModelEntry>& model_registry();
const ModelEntry* find_model(std::string_view name);
// Every name resolve_mesh knows without a path: builtins then models.
std::vector<std::string> known_mesh_names();
// First existing `relative` under the search path (empty search path: default); MeshError if none.
std::string find_in_model_path(const std::string& relative, const std::vector<std::string>& search_path);

// Writers. The format follows the extension: .node or .ele (TetGen, writes both files),
// .vtk (legacy), .vtu (XML), .msh (Gmsh). `binary` selects binary/base64 where the format has it.
struct MeshWriteOptions {
  bool binary = false;
  int gmsh_version = 41;  // 22 or 41
  int tetgen_index_base = 0;
};
void write_mesh(const TetMesh& mesh, const std::string& path, const MeshWriteOptions& options = {});
void write_tetgen(const TetMesh& mesh, const std::string& path_without_extension, int index_base = 0);
void write_vtk_legacy(const TetMesh& mesh, const std::string& path, bool binary = false);
void write_vtu(const TetMesh& mesh, const std::string& path, bool binary = false);
void write_gmsh(const TetMesh& mesh, const std::string& path, int version = 41, bool binary = false);

// Formats load_mesh accepts, by extension (for usage messages).
std::vector<std::string> tet_mesh_extensions();

}  // namespace pliant
