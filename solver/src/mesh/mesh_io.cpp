// SPDX-License-Identifier: Apache-2.0
#include "pliant/mesh_io.hpp"

#include "mesh/mesh_parse.hpp"
#include "pliant/builtin_meshes.hpp"

#include <spdlog/spdlog.h>

#include <cstdlib>
#include <filesystem>
#include <sstream>

namespace pliant {

namespace fs = std::filesystem;

std::vector<std::string> tet_mesh_extensions() { return {".node", ".ele", ".msh", ".vtk", ".vtu"}; }

namespace {

enum class Format { TetGen, Gmsh, VtkLegacy, Vtu, Unknown };

Format sniff(const std::string& path) {
  const std::string ext = detail::lower_extension(path);
  if (ext == ".node" || ext == ".ele" || ext == ".face") return Format::TetGen;
  if (ext == ".msh") return Format::Gmsh;
  if (ext == ".vtk") return Format::VtkLegacy;
  if (ext == ".vtu") return Format::Vtu;
  // Unknown extension: look at the first bytes.
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) {
    char head[64] = {};
    if (FILE* f = std::fopen(path.c_str(), "rb")) {
      const size_t n = std::fread(head, 1, sizeof head - 1, f);
      std::fclose(f);
      const std::string_view h(head, n);
      if (h.starts_with("$MeshFormat") || h.starts_with("$NOD")) return Format::Gmsh;
      if (h.starts_with("# vtk")) return Format::VtkLegacy;
      if (h.find("<?xml") != std::string_view::npos || h.find("<VTKFile") != std::string_view::npos) return Format::Vtu;
    }
  }
  if (fs::exists(path + ".node", ec)) return Format::TetGen;
  return Format::Unknown;
}

void apply_scale(MeshLoadResult& result, const MeshLoadOptions& options) {
  if (!(options.scale > 0) || !std::isfinite(options.scale))
    throw MeshError("scale must be a positive number, got " + std::to_string(options.scale));
  if (options.fit_size < 0 || !std::isfinite(options.fit_size))
    throw MeshError("fit size must be positive, got " + std::to_string(options.fit_size));
  double factor = options.scale;
  if (options.fit_size > 0) {
    const double longest = bounding_box(result.mesh.vertices).extent().maxCoeff() * options.scale;
    if (!(longest > 0)) throw MeshError(result.mesh.name + ": cannot fit a mesh of zero extent");
    factor *= options.fit_size / longest;
  }
  if (factor != 1.0) scale_mesh(result.mesh, factor);
  result.applied_scale = factor;
}

MeshLoadResult finish(detail::RawTetMesh raw, const MeshLoadOptions& options) {
  MeshLoadResult result;
  result.mesh = std::move(raw.mesh);
  apply_scale(result, options);
  MeshValidationOptions v = options.validation;
  v.source = raw.file;
  v.origin_kind = raw.origin_kind;
  v.tet_origin = std::move(raw.tet_origin);
  result.report = validate_mesh(result.mesh, v);
  return result;
}

}  // namespace

MeshLoadResult load_mesh_with_report(const std::string& path, const MeshLoadOptions& options) {
  detail::RawTetMesh raw;
  switch (sniff(path)) {
    case Format::TetGen: raw = detail::read_tetgen(path); break;
    case Format::Gmsh: raw = detail::read_gmsh(path); break;
    case Format::VtkLegacy: raw = detail::read_vtk_legacy(path); break;
    case Format::Vtu: raw = detail::read_vtu(path); break;
    case Format::Unknown: {
      std::error_code ec;
      if (!fs::exists(path, ec)) throw MeshError(path + ": no such file");
      throw MeshError(path + ": unknown tet-mesh format (expected .node/.ele, .msh, .vtk or .vtu; surfaces such as .obj "
                             "or .stl are render meshes: see `pliant-mesh embed` and `pliant-mesh tetrahedralize`)");
    }
  }
  return finish(std::move(raw), options);
}

TetMesh load_mesh(const std::string& path, const MeshLoadOptions& options) {
  return load_mesh_with_report(path, options).mesh;
}

std::string bundled_model_dir() {
  std::error_code ec;
  // Installed: <prefix>/bin/<program> finds <prefix>/share/pliant/meshes wherever the prefix
  // was moved to.
  const fs::path exe = fs::canonical("/proc/self/exe", ec);
  if (!ec) {
    const fs::path installed = exe.parent_path() / PLIANT_DATA_FROM_BIN / "meshes";
    if (fs::is_directory(installed, ec)) return fs::weakly_canonical(installed, ec).string();
  }
  // A build tree: the source tree's meshes/ (or the directory given as PLIANT_MESH_DIR).
  if (fs::is_directory(PLIANT_MESH_DIR, ec)) return PLIANT_MESH_DIR;
  // A program outside the prefix linking the installed library: the prefix configured at build time.
  const fs::path configured = fs::path(PLIANT_INSTALL_FULL_DATADIR) / "meshes";
  if (fs::is_directory(configured, ec)) return configured.string();
  return PLIANT_MESH_DIR;
}

std::vector<std::string> default_model_path() {
  std::vector<std::string> out;
  if (const char* env = std::getenv("PLIANT_MODEL_PATH")) {
    std::stringstream ss(env);
    for (std::string item; std::getline(ss, item, ':');)
      if (!item.empty()) out.push_back(item);
  }
  out.push_back(bundled_model_dir());
  return out;
}

// The model set. Scales are fixed numbers (not fitted at load time) so that a model and its
// render surface always get the same transform; `size` is what they give. Fitted models divide
// the target longest side by the file's longest bounding-box side (measured with pliant-mesh).
const std::vector<ModelEntry>& model_registry() {
  static const std::vector<ModelEntry> models = {
      {"armadillo", "thesis/armadillo.node", 0.1, "13.5 x 8.6 x 10.4 cm",
       "the thesis armadillo, 14,779 V / 54,855 T (file unit 10 cm)",
       "AASolver (BSD-3, Bailin Deng); Stanford 3D Scanning Repository", ""},
      {"hippo", "thesis/hippo.node", 0.1, "17.3 x 9.0 x 5.8 cm", "the thesis hippo, 2,885 V / 10,361 T (file unit 10 cm)",
       "AASolver (BSD-3, Bailin Deng)", ""},
      {"armadillo-small", "armadillo/armadillo_4k_pbd.node", 0.135 / 3.02931, "longest side 13.5 cm",
       "small armadillo, 1,180 V / 3,717 T", "PositionBasedDynamics (MIT); Stanford 3D Scanning Repository", ""},
      {"armadillo-13k", "armadillo/armadillo_13k_ipc.msh", 0.135 / 151.36229, "longest side 13.5 cm",
       "IPC armadillo, 13,230 V / 54,985 T (best element quality)", "IPC (MIT); Stanford 3D Scanning Repository", ""},
      {"armadillo-tetgen", "armadillo/armadillo_tetgen_13867v_54990t.node", 0.135 / 0.9993882, "longest side 13.5 cm",
       "armadillo tetrahedralised from armadillo-surface (tetgen -pYq1.685), 13,867 V / 54,990 T",
       "Gaia (Apache-2.0) surface; Stanford 3D Scanning Repository", "armadillo/armadillo_10k_surface.ply"},
      {"liver", "liver/liver_sofa.msh", 0.20 / 6.48259, "longest side 20 cm", "SOFA liver, 181 V / 596 T", "SOFA (LGPL-2.1)", ""},
      {"liver2", "liver/liver2_sofa.msh", 0.20 / 2.144152921, "longest side 20 cm", "SOFA liver2, 507 V / 1,493 T", "SOFA (LGPL-2.1)", ""},
      {"bunny", "bunny/bunny_ipc.msh", 0.15 / 3.109975, "longest side 15 cm", "IPC bunny, 4,670 V / 19,379 T",
       "IPC (MIT); Stanford 3D Scanning Repository", ""},
  };
  return models;
}

const ModelEntry* find_model(std::string_view name) {
  for (const ModelEntry& m : model_registry())
    if (m.name == name) return &m;
  return nullptr;
}

std::vector<std::string> known_mesh_names() {
  std::vector<std::string> names = builtin_mesh_names();
  for (const ModelEntry& m : model_registry()) names.push_back(m.name);
  return names;
}

std::string find_in_model_path(const std::string& relative, const std::vector<std::string>& search_path) {
  const std::vector<std::string> dirs = search_path.empty() ? default_model_path() : search_path;
  std::error_code ec;
  for (const std::string& dir : dirs) {
    const fs::path p = fs::path(dir) / relative;
    if (fs::exists(p, ec)) return p.string();
  }
  std::string list;
  for (const std::string& d : dirs) list += (list.empty() ? "" : ":") + d;
  throw MeshError(relative + ": not found on the model path (" + list + "; set PLIANT_MODEL_PATH)");
}

MeshLoadResult resolve_mesh_with_report(std::string_view spec, const std::vector<std::string>& search_path,
                                        const MeshLoadOptions& options) {
  if (auto builtin = builtin_mesh(spec)) {
    MeshLoadResult result;
    result.mesh = std::move(*builtin);
    apply_scale(result, options);
    MeshValidationOptions v = options.validation;
    v.source = std::string(spec);
    result.report = validate_mesh(result.mesh, v);
    return result;
  }
  if (const ModelEntry* model = find_model(spec)) {
    const std::string path = find_in_model_path(model->file, search_path);
    MeshLoadOptions o = options;
    if (model->scale > 0) o.scale *= model->scale;
    MeshLoadResult result = load_mesh_with_report(path, o);
    result.mesh.name = model->name;
    return result;
  }
  const std::string path(spec);
  std::error_code ec;
  if (!fs::exists(path, ec) && !fs::exists(path + ".node", ec)) {
    std::string names;
    for (const std::string& n : known_mesh_names()) names += (names.empty() ? "" : ", ") + n;
    throw MeshError("'" + path + "' is neither a known mesh name nor an existing file (known names: " + names + ")");
  }
  return load_mesh_with_report(path, options);
}

TetMesh resolve_mesh(std::string_view spec, const std::vector<std::string>& search_path) {
  return resolve_mesh_with_report(spec, search_path).mesh;
}

}  // namespace pliant
