#include "pliant/mesh_io.hpp"

#include "pliant/builtin_meshes.hpp"

#include <cstdlib>
#include <sstream>

namespace pliant {

// Format loaders are being written (issue 3); until then only builtins resolve.
TetMesh load_mesh(const std::string& path, const MeshLoadOptions&) {
  throw MeshError(path + ": no mesh loader available for this file yet");
}

std::vector<std::string> default_model_path() {
  std::vector<std::string> out;
  if (const char* env = std::getenv("PLIANT_MODEL_PATH")) {
    std::stringstream ss(env);
    for (std::string item; std::getline(ss, item, ':');)
      if (!item.empty()) out.push_back(item);
  }
  out.push_back(PLIANT_MESH_DIR);
  return out;
}

TetMesh resolve_mesh(std::string_view spec, const std::vector<std::string>& search_path) {
  if (auto builtin = builtin_mesh(spec)) return *builtin;
  return load_mesh(std::string(spec));
}

}  // namespace pliant
