// Reading meshes: one entry point for every format, plus the resolver that turns what a user
// types (a builtin name like "beam3", a short model name like "armadillo", or a path) into a
// validated TetMesh. Errors are MeshError exceptions whose message names the file, the
// line/element and the value.
#pragma once

#include "pliant/mesh.hpp"

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
};

// Loads a tet mesh from a file, picking the format by extension (and content where needed).
TetMesh load_mesh(const std::string& path, const MeshLoadOptions& options = {});

// "beam1".."beam3" -> builtin; a short model name -> the model set on `search_path`
// (each entry a directory, e.g. the repo's meshes/); anything else -> a path.
TetMesh resolve_mesh(std::string_view spec, const std::vector<std::string>& search_path = {});

// The default model search path: $PLIANT_MODEL_PATH (colon-separated) then the compiled-in
// meshes/ directory of the source tree.
std::vector<std::string> default_model_path();

}  // namespace pliant
