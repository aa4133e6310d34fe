// SPDX-License-Identifier: Apache-2.0
// pliant-mesh: inspect, validate, convert, tetrahedralize and embed meshes.
// Output meant for the user goes to stdout; logs (warnings about quality, repairs) go to stderr.
#include "pliant/builtin_meshes.hpp"
#include "pliant/material.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/mesh_validate.hpp"
#include "pliant/render_mesh.hpp"
#include "pliant/version.hpp"
#include "cli.hpp"

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

using namespace pliant;

namespace {

constexpr const char* kUsage = R"(usage: pliant-mesh <command> [options]

commands:
  info <mesh>                      counts, bounding box, volume, mass, quality histogram, surface
  validate <mesh>                  check and report; exit 1 on errors (2 with --strict on warnings)
  convert <mesh> <out>             write .node/.ele (TetGen), .vtk, .vtu or .msh
  tetrahedralize <surface> <out>   run `tetgen -pYq<ratio>` on a closed surface, validate, write
  embed <mesh> <surface> <out>     bind a render surface to a tet mesh (binding file)
  models                           list the short model names

<mesh> is a builtin (beam1..beam3), a model name (armadillo, hippo, liver, ...) or a file.
<surface> is a file assimp reads (OBJ, STL, PLY, glTF/GLB, FBX, OFF, ...) or the name of a model
with a render surface (armadillo-tetgen).

options:
  --scale <s>            multiply coordinates (file units -> metres; models: times their own scale)
  --unit <mm|cm|m|in>    file unit (multiplies --scale; default m)
  --fit-size <m>         scale so the longest bounding-box side is <m> metres
  --density <kg/m^3>     info: report the mass
  --json                 info/validate: print one JSON object
  --drop-degenerate      drop zero-volume tets instead of rejecting the mesh
  --no-reorient          reject inverted tets instead of re-orienting them
  --strict               validate: exit 2 if there were warnings
  --binary               convert: binary VTK/VTU/Gmsh
  --gmsh-version <22|41> convert: Gmsh version (default 41)
  --index-base <0|1>     convert: TetGen index base (default 0)
  --ratio <q>            tetrahedralize: TetGen -q radius-edge ratio (default 1.5)
  --switches <s>         tetrahedralize: extra TetGen switches appended (e.g. a1e-7, in file units)
  --keep <dir>           tetrahedralize: keep TetGen's files in <dir>
  --surface-scale <s>    embed: scale of the surface file (default 1, or the model's scale)
  --model-path <dir>     search this directory for model names first (repeatable)
  -q, --quiet            only errors on stderr
  --version              print the version and exit
)";

struct Args {
  std::string command;
  std::vector<std::string> positional;
  std::map<std::string, std::string> values;
  std::set<std::string> flags;
  std::vector<std::string> model_path;
};

[[noreturn]] void bad_argument(const std::string& msg) {
  std::fprintf(stderr, "pliant-mesh: %s (see pliant-mesh --help)\n", msg.c_str());
  std::exit(2);
}

// Options may stand anywhere (before or after the command); the first word is the command,
// the words after it its arguments.
std::optional<int> parse_args(int argc, char** argv, Args* a) {
  static const std::set<std::string> kValued = {"scale", "unit", "fit-size", "density", "gmsh-version", "index-base",
                                                "ratio", "switches", "keep", "surface-scale"};
  static const std::set<std::string> kFlags = {"json", "drop-degenerate", "no-reorient", "strict", "binary"};
  CLI::App app{"pliant-mesh"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.formatter_fn([](const CLI::App*, std::string, CLI::AppFormatMode) { return std::string(kUsage); });
  std::map<std::string, std::string> values;
  cli::add_options(app, kValued, kFlags, &values);
  app.add_flag_callback("-q,--quiet", [a] { a->flags.insert("--quiet"); });
  app.add_option("--model-path", a->model_path)->allow_extra_args(false);
  std::vector<std::string> words;
  app.add_option("words", words);
  if (auto rc = cli::parse_or_exit(app, argc, argv, "pliant-mesh")) return rc;
  for (const auto& [name, value] : values) {
    if (kFlags.count(name)) a->flags.insert("--" + name);
    else a->values["--" + name] = value;
  }
  if (!words.empty()) {
    a->command = words[0];
    a->positional.assign(words.begin() + 1, words.end());
  }
  return std::nullopt;
}

double number_arg(const Args& a, const std::string& name, double fallback, double min_exclusive) {
  auto it = a.values.find(name);
  if (it == a.values.end()) return fallback;
  char* end = nullptr;
  const double v = std::strtod(it->second.c_str(), &end);
  if (it->second.empty() || *end != '\0' || !std::isfinite(v) || !(v > min_exclusive))
    bad_argument(name + " needs a number > " + std::to_string(min_exclusive).substr(0, 3) + ", got '" + it->second + "'");
  return v;
}

int int_arg(const Args& a, const std::string& name, int fallback, std::initializer_list<int> allowed) {
  auto it = a.values.find(name);
  if (it == a.values.end()) return fallback;
  for (int v : allowed)
    if (it->second == std::to_string(v)) return v;
  std::string list;
  for (int v : allowed) list += (list.empty() ? "" : " or ") + std::to_string(v);
  bad_argument(name + " must be " + list + ", got '" + it->second + "'");
}

void need_positional(const Args& a, size_t n, const char* what) {
  if (a.positional.size() < n) bad_argument(a.command + " needs " + what);
  if (a.positional.size() > n) bad_argument(a.command + ": unexpected argument '" + a.positional[n] + "'");
}

std::vector<std::string> search_path(const Args& a) {
  std::vector<std::string> p = a.model_path;
  for (const std::string& d : default_model_path()) p.push_back(d);
  return p;
}

double unit_arg(const Args& a) {
  auto it = a.values.find("--unit");
  if (it == a.values.end()) return 1.0;
  static const std::map<std::string, double> kUnits = {{"m", 1.0}, {"cm", 0.01}, {"mm", 0.001}, {"in", 0.0254}, {"dm", 0.1}};
  auto u = kUnits.find(it->second);
  if (u == kUnits.end()) bad_argument("--unit must be m, dm, cm, mm or in, got '" + it->second + "'");
  return u->second;
}

MeshLoadOptions load_options(const Args& a) {
  MeshLoadOptions o;
  o.scale = number_arg(a, "--scale", 1.0, 0.0) * unit_arg(a);
  o.fit_size = number_arg(a, "--fit-size", 0.0, -1.0);
  if (a.values.count("--fit-size") && !(o.fit_size > 0)) bad_argument("--fit-size needs a positive size in metres");
  o.validation.drop_degenerate = a.flags.count("--drop-degenerate") > 0;
  o.validation.reorient_inverted = a.flags.count("--no-reorient") == 0;
  return o;
}

using Json = nlohmann::ordered_json;
Json jvec(const Vec3& v) { return Json::array({v.x(), v.y(), v.z()}); }

// The report as one line of strict JSON (nlohmann-json: escaped strings, NaN as null).
std::string report_json(const MeshLoadResult& r, const std::optional<double>& density, double seconds) {
  const MeshReport& m = r.report;
  Json o;
  o["name"] = r.mesh.name;
  o["vertices"] = m.vertices;
  o["tets"] = m.tets;
  o["volume"] = m.volume;
  o["bbox"] = {{"min", jvec(m.bbox.min)}, {"max", jvec(m.bbox.max)}, {"extent", jvec(m.bbox.extent())}};
  if (density) {
    o["density"] = *density;
    o["mass"] = *density * m.volume;
  }
  o["scale"] = r.applied_scale;
  o["min_dihedral_deg"] = m.min_dihedral_deg;
  o["max_aspect_ratio"] = m.max_aspect_ratio;
  o["mean_aspect_ratio"] = m.mean_aspect_ratio;
  o["min_tet_volume"] = m.min_volume;
  o["mean_tet_volume"] = m.mean_volume;
  o["min_vertex_mass_ratio"] = m.min_vertex_mass_ratio;
  o["light_vertices"] = m.light_vertices;
  o["max_tet_volume"] = m.max_volume;
  Json histogram = Json::array();
  const auto& edges = QualityHistogram::kEdgesDeg;
  for (size_t i = 0; i < edges.size(); ++i)
    histogram.push_back({{"from_deg", edges[i]},
                         {"to_deg", i + 1 < edges.size() ? Json(edges[i + 1]) : Json(nullptr)},
                         {"count", m.dihedral_histogram.counts[i]}});
  o["dihedral_histogram"] = histogram;
  Json worst = Json::array();
  for (const WorstTet& w : m.worst)
    worst.push_back({{"tet", w.tet}, {"origin", w.origin}, {"origin_kind", m.origin_kind},
                     {"min_dihedral_deg", w.min_dihedral_deg}, {"aspect_ratio", w.aspect_ratio}, {"volume", w.volume}});
  o["worst_tets"] = worst;
  o["surface_triangles"] = m.surface.triangles;
  o["surface"] = {{"vertices", m.surface.vertices},
                  {"edges", m.surface.edges},
                  {"area", m.surface.area},
                  {"euler_characteristic", m.surface.euler_characteristic},
                  {"components", m.surface.components},
                  {"open_edges", m.surface.boundary_edges},
                  {"nonmanifold_edges", m.surface.nonmanifold_edges},
                  {"nonmanifold_vertices", m.surface.nonmanifold_vertices},
                  {"closed_manifold", m.surface.closed_manifold}};
  o["repairs"] = {{"reoriented", m.reoriented},
                  {"dropped_degenerate", m.dropped_degenerate},
                  {"dropped_duplicates", m.dropped_duplicates},
                  {"dropped_vertices", m.dropped_vertices}};
  o["tiny_tets"] = m.tiny_tets;
  o["poor_tets"] = m.poor_tets;
  o["warnings"] = m.warnings;
  o["load_seconds"] = seconds;
  return cli::json_line(o);
}

void print_text(const MeshLoadResult& r, const std::optional<double>& density, double seconds) {
  const MeshReport& m = r.report;
  const Vec3 e = m.bbox.extent();
  std::printf("mesh        %s (%s)\n", r.mesh.name.c_str(), m.source.c_str());
  std::printf("vertices    %lld\ntets        %lld\n", static_cast<long long>(m.vertices), static_cast<long long>(m.tets));
  std::printf("bbox        [%.6g, %.6g, %.6g] .. [%.6g, %.6g, %.6g]\n", m.bbox.min.x(), m.bbox.min.y(), m.bbox.min.z(),
              m.bbox.max.x(), m.bbox.max.y(), m.bbox.max.z());
  std::printf("extent      %.6g x %.6g x %.6g m (%.4g x %.4g x %.4g cm)\n", e.x(), e.y(), e.z(), e.x() * 100, e.y() * 100, e.z() * 100);
  std::printf("scale       %.6g (file units -> m)\n", r.applied_scale);
  std::printf("volume      %.6g m^3 (tets: min %.3g, mean %.3g, max %.3g)\n", m.volume, m.min_volume, m.mean_volume, m.max_volume);
  if (density) std::printf("mass        %.6g kg at %.6g kg/m^3\n", *density * m.volume, *density);
  std::printf("vertex mass lightest %.3g of the mean; %lld vertices under %g of the mean (their inertia is raised by the "
              "default inertia floor)\n", m.min_vertex_mass_ratio, static_cast<long long>(m.light_vertices), kDefaultInertiaFloor);
  std::printf("quality     min dihedral %.4g deg, aspect ratio mean %.3g max %.3g\n", m.min_dihedral_deg, m.mean_aspect_ratio,
              m.max_aspect_ratio);
  std::printf("min dihedral histogram (deg):\n");
  const auto& edges = QualityHistogram::kEdgesDeg;
  for (size_t i = 0; i < edges.size(); ++i) {
    if (i + 1 < edges.size()) std::printf("  [%4g, %4g)  %lld\n", edges[i], edges[i + 1], static_cast<long long>(m.dihedral_histogram.counts[i]));
    else std::printf("  [%4g, ...)  %lld\n", edges[i], static_cast<long long>(m.dihedral_histogram.counts[i]));
  }
  std::printf("worst tets:\n");
  for (const WorstTet& w : m.worst)
    std::printf("  tet %lld (%s %lld in the file): min dihedral %.4g deg, aspect %.4g, volume %.3g\n",
                static_cast<long long>(w.tet), m.origin_kind.c_str(), static_cast<long long>(w.origin), w.min_dihedral_deg,
                w.aspect_ratio, w.volume);
  const SurfaceStats& s = m.surface;
  std::printf("surface     %lld triangles, %lld vertices, %lld edges, area %.6g m^2, Euler %d, %d component(s), %s\n",
              static_cast<long long>(s.triangles), static_cast<long long>(s.vertices), static_cast<long long>(s.edges), s.area,
              s.euler_characteristic, s.components, s.closed_manifold ? "closed manifold" : "NOT a closed manifold");
  std::printf("repairs     %lld re-oriented, %lld degenerate dropped, %lld duplicates dropped, %lld unused vertices dropped\n",
              static_cast<long long>(m.reoriented), static_cast<long long>(m.dropped_degenerate),
              static_cast<long long>(m.dropped_duplicates), static_cast<long long>(m.dropped_vertices));
  std::printf("warnings    %zu\nload time   %.3f s\n", m.warnings.size(), seconds);
}

MeshLoadResult load(const Args& a, const std::string& spec, double* seconds = nullptr) {
  const auto t0 = std::chrono::steady_clock::now();
  MeshLoadResult r = resolve_mesh_with_report(spec, search_path(a), load_options(a));
  if (seconds) *seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

int cmd_info(const Args& a, bool validate_only) {
  need_positional(a, 1, "a mesh (name or file)");
  std::optional<double> density;
  if (a.values.count("--density")) density = number_arg(a, "--density", 0, 0.0);
  double seconds = 0;
  const MeshLoadResult r = load(a, a.positional[0], &seconds);
  if (a.flags.count("--json")) {
    std::printf("%s\n", report_json(r, density, seconds).c_str());
  } else if (validate_only) {
    std::printf("%s: ok, %lld vertices, %lld tets, volume %.6g m^3, min dihedral %.4g deg, %zu warning(s)\n",
                a.positional[0].c_str(), static_cast<long long>(r.report.vertices), static_cast<long long>(r.report.tets),
                r.report.volume, r.report.min_dihedral_deg, r.report.warnings.size());
  } else {
    print_text(r, density, seconds);
  }
  if (validate_only && a.flags.count("--strict") && !r.report.warnings.empty()) return 2;
  return 0;
}

int cmd_convert(const Args& a) {
  need_positional(a, 2, "an input mesh and an output file");
  const MeshLoadResult r = load(a, a.positional[0]);
  MeshWriteOptions w;
  w.binary = a.flags.count("--binary") > 0;
  w.gmsh_version = int_arg(a, "--gmsh-version", 41, {22, 41});
  w.tetgen_index_base = int_arg(a, "--index-base", 0, {0, 1});
  write_mesh(r.mesh, a.positional[1], w);
  std::printf("wrote %s: %lld vertices, %lld tets\n", a.positional[1].c_str(), static_cast<long long>(r.report.vertices),
              static_cast<long long>(r.report.tets));
  return 0;
}

// A surface given by model name (its render surface, at the model's scale) or by file.
SurfaceMesh load_surface_spec(const Args& a, const std::string& spec) {
  SurfaceLoadOptions so;
  std::string path = spec;
  if (const ModelEntry* m = find_model(spec)) {
    if (m->render_surface.empty()) bad_argument("model '" + spec + "' has no render surface");
    path = find_in_model_path(m->render_surface, search_path(a));
    so.scale = m->scale;
  }
  so.scale *= number_arg(a, "--surface-scale", 1.0, 0.0);
  return load_surface(path, so);
}

int cmd_tetrahedralize(const Args& a) {
  need_positional(a, 2, "a closed surface file and an output mesh file");
  // TetGen meshes the file's own coordinates (its -q bound is scale-free); the result is scaled.
  const SurfaceMesh surface = load_surface(a.positional[0]);
  TetrahedralizeOptions to;
  to.quality_ratio = number_arg(a, "--ratio", 1.5, 0.0);
  if (to.quality_ratio < 1.0) bad_argument("--ratio must be >= 1 (TetGen's radius-edge bound)");
  if (a.values.count("--switches")) to.extra_switches = a.values.at("--switches");
  if (a.values.count("--keep")) to.work_dir = a.values.at("--keep");
  to.source_file = a.positional[0];
  const TetrahedralizeResult t = tetrahedralize_surface(surface, to);
  const MeshLoadOptions lo = load_options(a);
  MeshLoadResult r = load_mesh_with_report(t.node_path, lo);
  MeshWriteOptions w;
  w.binary = a.flags.count("--binary") > 0;
  w.gmsh_version = int_arg(a, "--gmsh-version", 41, {22, 41});
  w.tetgen_index_base = int_arg(a, "--index-base", 0, {0, 1});
  r.mesh.name = surface.name;
  write_mesh(r.mesh, a.positional[1], w);
  if (!a.values.count("--keep")) {
    std::error_code ec;
    std::filesystem::remove_all(std::filesystem::path(t.node_path).parent_path(), ec);
  }
  std::printf("%s -> %s: %lld vertices, %lld tets, volume %.6g, min dihedral %.4g deg (%s)\n", a.positional[0].c_str(),
              a.positional[1].c_str(), static_cast<long long>(r.report.vertices), static_cast<long long>(r.report.tets),
              r.report.volume, r.report.min_dihedral_deg, t.command.c_str());
  return 0;
}

int cmd_embed(const Args& a) {
  need_positional(a, 3, "a tet mesh, a surface and an output binding file");
  const MeshLoadResult r = load(a, a.positional[0]);
  const SurfaceMesh surface = load_surface_spec(a, a.positional[1]);
  const SurfaceBinding b = embed_surface(r.mesh, surface);
  write_binding(b, a.positional[2], a.positional[0], a.positional[1]);
  double worst = 0;
  for (const auto& w : b.weights) worst = std::max(worst, std::abs(w.sum() - 1.0));
  std::printf("bound %zu surface vertices (%zu triangles) to %lld tets: %lld outside (max distance %.3g m), max |sum w - 1| %.2g\n",
              b.tet.size(), b.triangles.size(), static_cast<long long>(b.tet_count), static_cast<long long>(b.outside),
              b.max_outside_distance, worst);
  return 0;
}

int cmd_models(const Args& a) {
  for (const std::string& n : builtin_mesh_names()) std::printf("%-18s builtin thesis beam\n", n.c_str());
  for (const ModelEntry& m : model_registry()) {
    std::string where;
    try {
      where = find_in_model_path(m.file, search_path(a));
    } catch (const MeshError&) {
      where = "(not found: " + m.file + ")";
    }
    std::printf("%-18s %s; %s; %s\n%-18s   %s%s\n", m.name.c_str(), m.description.c_str(), m.size.c_str(), m.credit.c_str(), "",
                where.c_str(), m.render_surface.empty() ? "" : (" + render surface " + m.render_surface).c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  auto logger = spdlog::stderr_color_mt("pliant-mesh");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("[%l] %v");
  Args a;
  if (auto rc = parse_args(argc, argv, &a)) return *rc;
  if (a.flags.count("--quiet")) spdlog::set_level(spdlog::level::err);
  if (a.command.empty()) {
    std::fputs(kUsage, stderr);
    return 2;
  }
  try {
    if (a.command == "info") return cmd_info(a, false);
    if (a.command == "validate") return cmd_info(a, true);
    if (a.command == "convert") return cmd_convert(a);
    if (a.command == "tetrahedralize") return cmd_tetrahedralize(a);
    if (a.command == "embed") return cmd_embed(a);
    if (a.command == "models") return cmd_models(a);
    bad_argument("unknown command '" + a.command + "'");
  } catch (const MeshError& e) {
    std::fprintf(stderr, "pliant-mesh: error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pliant-mesh: error: %s\n", e.what());
    return 1;
  }
}
