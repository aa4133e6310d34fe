// SPDX-License-Identifier: Apache-2.0
// Render-mesh embedding, deformation and normals; the binding file; running TetGen.
//
// Binding file format ("pliant-binding 1"), text, '#' starts a comment:
//   pliant-binding 1
//   tet_mesh <vertex count> <tet count>        the tet mesh the binding was made for
//   vertices <N>                                then N lines: <tet> <w0> <w1> <w2> <w3>
//   triangles <F>                               then F lines: <a> <b> <c> (0-based surface vertices)
// Surface vertex i is at sum_k w_k * X[tets[tet][k]], with X the tet-mesh positions.
#include "pliant/render_mesh.hpp"

#include "mesh/mesh_parse.hpp"
#include "pliant/geometry.hpp"
#include "pliant/mesh_io.hpp"

#include <Eigen/Dense>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <unistd.h>

namespace pliant {

namespace fs = std::filesystem;

namespace {

Eigen::Vector4d barycentric(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  Eigen::Matrix3d m;
  m.col(0) = b - a;
  m.col(1) = c - a;
  m.col(2) = d - a;
  const Vec3 l = m.partialPivLu().solve(p - a);
  return {1.0 - l.sum(), l[0], l[1], l[2]};
}

struct TetGrid {
  Vec3 origin;
  double h = 1;
  Eigen::Vector3i dims;
  std::vector<int32_t> start;  // CSR: cell -> tets
  std::vector<int32_t> items;

  int cell_index(int i, int j, int k) const { return (k * dims[1] + j) * dims[0] + i; }
  Eigen::Vector3i cell_of(const Vec3& p) const {
    Eigen::Vector3i c;
    for (int a = 0; a < 3; ++a)
      c[a] = std::clamp(static_cast<int>(std::floor((p[a] - origin[a]) / h)), 0, dims[a] - 1);
    return c;
  }

  TetGrid(const TetMesh& mesh) {
    const Aabb box = bounding_box(mesh.vertices);
    const Vec3 ext = box.extent().cwiseMax(1e-12);
    const double cells = std::max<double>(1.0, static_cast<double>(mesh.tets.size()));
    h = std::cbrt(ext.prod() / cells) * 1.5;
    if (!(h > 0)) h = ext.maxCoeff();
    for (int a = 0; a < 3; ++a) dims[a] = std::clamp(static_cast<int>(std::ceil(ext[a] / h)), 1, 512);
    origin = box.min;
    const size_t n = static_cast<size_t>(dims.prod());
    std::vector<int32_t> count(n + 1, 0);
    auto for_cells = [&](const Tet& t, auto&& fn) {
      Vec3 lo = mesh.vertices[t[0]], hi = lo;
      for (int k = 1; k < 4; ++k) {
        lo = lo.cwiseMin(mesh.vertices[t[k]]);
        hi = hi.cwiseMax(mesh.vertices[t[k]]);
      }
      const Eigen::Vector3i a = cell_of(lo), b = cell_of(hi);
      for (int k = a[2]; k <= b[2]; ++k)
        for (int j = a[1]; j <= b[1]; ++j)
          for (int i = a[0]; i <= b[0]; ++i) fn(cell_index(i, j, k));
    };
    for (const Tet& t : mesh.tets) for_cells(t, [&](int c) { count[c + 1]++; });
    for (size_t c = 0; c < n; ++c) count[c + 1] += count[c];
    start = count;
    items.resize(static_cast<size_t>(count[n]));
    std::vector<int32_t> fill(count.begin(), count.end() - 1);
    for (size_t t = 0; t < mesh.tets.size(); ++t)
      for_cells(mesh.tets[t], [&](int c) { items[fill[c]++] = static_cast<int32_t>(t); });
  }
};

double distance_to_tet(const Vec3& p, const TetMesh& mesh, const Tet& t, const Eigen::Vector4d& w) {
  if (w.minCoeff() >= 0) return 0.0;
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  double best = std::numeric_limits<double>::infinity();
  for (const auto& f : kFaces) {
    std::array<double, 3> b;
    const Vec3 q = closest_point_on_triangle(p, mesh.vertices[t[f[0]]], mesh.vertices[t[f[1]]], mesh.vertices[t[f[2]]], b);
    best = std::min(best, (q - p).norm());
  }
  return best;
}

std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

}  // namespace

SurfaceBinding embed_surface(const TetMesh& mesh, const SurfaceMesh& surface) {
  if (mesh.tets.empty()) throw MeshError("embed: the tet mesh has no tets");
  if (surface.vertices.empty()) throw MeshError("embed: the surface has no vertices");
  SurfaceBinding out;
  out.tet_vertex_count = static_cast<int64_t>(mesh.vertices.size());
  out.tet_count = static_cast<int64_t>(mesh.tets.size());
  out.triangles = surface.triangles;
  out.tet.resize(surface.vertices.size());
  out.weights.resize(surface.vertices.size());
  const TetGrid grid(mesh);
  std::vector<int32_t> stamp(mesh.tets.size(), -1);
  // A point is inside when its smallest weight is above -kInside (round-off on shared faces).
  constexpr double kInside = 1e-10;
  // Vertices this close to the tet mesh count as on its boundary, not outside (a surface stored in
  // single precision, like most PLY/OBJ files, sits ~1e-8 of the size off the tets' faces).
  const double on_boundary = 1e-6 * bounding_box(mesh.vertices).extent().norm();

  for (size_t v = 0; v < surface.vertices.size(); ++v) {
    const Vec3& p = surface.vertices[v];
    const Eigen::Vector3i c = grid.cell_of(p);
    const auto stamp_id = static_cast<int32_t>(v);
    int32_t best_tet = -1;
    Eigen::Vector4d best_w;
    double best_score = -std::numeric_limits<double>::infinity();  // min weight: most inside wins
    double best_dist = std::numeric_limits<double>::infinity();
    const int max_r = grid.dims.maxCoeff();
    for (int r = 0; r <= max_r; ++r) {
      for (int k = std::max(0, c[2] - r); k <= std::min(grid.dims[2] - 1, c[2] + r); ++k)
        for (int j = std::max(0, c[1] - r); j <= std::min(grid.dims[1] - 1, c[1] + r); ++j) {
          // Only the shell at Chebyshev distance r: inside rows need just the two end cells.
          const bool full_row = std::abs(k - c[2]) == r || std::abs(j - c[1]) == r;
          const int step = full_row ? 1 : std::max(1, 2 * r);
          for (int i = c[0] - r; i <= c[0] + r; i += step) {
            if (i < 0 || i >= grid.dims[0]) continue;
            const int cell = grid.cell_index(i, j, k);
            for (int32_t s = grid.start[cell]; s < grid.start[cell + 1]; ++s) {
              const int32_t t = grid.items[s];
              if (stamp[t] == stamp_id) continue;
              stamp[t] = stamp_id;
              const Tet& tet = mesh.tets[t];
              const Eigen::Vector4d w = barycentric(p, mesh.vertices[tet[0]], mesh.vertices[tet[1]],
                                                    mesh.vertices[tet[2]], mesh.vertices[tet[3]]);
              if (!w.allFinite()) continue;
              const double score = w.minCoeff();
              if (score >= -kInside) {
                if (best_dist > 0 || score > best_score) {
                  best_tet = t, best_w = w, best_score = score, best_dist = 0;
                }
                continue;
              }
              if (best_dist == 0) continue;
              const double d = distance_to_tet(p, mesh, tet, w);
              if (d < best_dist) best_tet = t, best_w = w, best_dist = d, best_score = score;
            }
          }
        }
      // Tets not seen yet lie in cells at least r*h away.
      // Within the on-boundary tolerance counts as found (saves searching the next ring for every
      // vertex of a surface that is the tet mesh's own boundary).
      if (best_tet >= 0 && (best_dist <= r * grid.h || best_dist <= on_boundary)) break;
    }
    if (best_tet < 0) throw MeshError("embed: no tet found for surface vertex " + std::to_string(v));
    out.tet[v] = best_tet;
    out.weights[v] = best_w;
    if (best_dist > on_boundary) {
      ++out.outside;
      out.max_outside_distance = std::max(out.max_outside_distance, best_dist);
    }
  }
  if (out.outside)
    spdlog::info("embed: {} of {} surface vertices lie outside the tet mesh (max distance {:.3g}); bound to the nearest tet",
                 out.outside, surface.vertices.size(), out.max_outside_distance);
  return out;
}

std::vector<Vec3> deform_surface(const SurfaceBinding& b, const TetMesh& mesh, const std::vector<Vec3>& x) {
  if (static_cast<int64_t>(x.size()) != b.tet_vertex_count || static_cast<int64_t>(mesh.tets.size()) != b.tet_count)
    throw MeshError("deform_surface: the binding was made for a tet mesh with " + std::to_string(b.tet_vertex_count) +
                    " vertices / " + std::to_string(b.tet_count) + " tets, got " + std::to_string(x.size()) + " / " +
                    std::to_string(mesh.tets.size()));
  std::vector<Vec3> out(b.tet.size());
  for (size_t v = 0; v < b.tet.size(); ++v) {
    const Tet& t = mesh.tets[b.tet[v]];
    const Eigen::Vector4d& w = b.weights[v];
    out[v] = w[0] * x[t[0]] + w[1] * x[t[1]] + w[2] * x[t[2]] + w[3] * x[t[3]];
  }
  return out;
}

std::vector<Vec3> vertex_normals(const std::vector<Vec3>& vertices, const std::vector<Triangle>& triangles) {
  std::vector<Vec3> n(vertices.size(), Vec3::Zero());
  for (const Triangle& t : triangles) {
    // The cross product's length is twice the area: area weighting for free.
    const Vec3 fn = (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]);
    for (int32_t v : t) n[v] += fn;
  }
  for (Vec3& v : n) {
    const double len = v.norm();
    if (len > 0) v /= len;
  }
  return n;
}

void write_binding(const SurfaceBinding& b, const std::string& path, const std::string& tet_name, const std::string& surface_name) {
  std::string out = "pliant-binding 1\n";
  auto clean = [](std::string s) {
    for (char& c : s)
      if (c == '\n' || c == '\r') c = ' ';
    return s;
  };
  if (!tet_name.empty()) out += "# tet mesh: " + clean(tet_name) + "\n";
  if (!surface_name.empty()) out += "# surface: " + clean(surface_name) + "\n";
  out += "tet_mesh " + std::to_string(b.tet_vertex_count) + " " + std::to_string(b.tet_count) + "\n";
  out += "vertices " + std::to_string(b.tet.size()) + "\n";
  for (size_t v = 0; v < b.tet.size(); ++v) {
    detail::append_int(out, b.tet[v]);
    for (int k = 0; k < 4; ++k) {
      out += ' ';
      detail::append_double(out, b.weights[v][k]);
    }
    out += '\n';
  }
  out += "triangles " + std::to_string(b.triangles.size()) + "\n";
  for (const Triangle& t : b.triangles) {
    detail::append_int(out, t[0]);
    out += ' ';
    detail::append_int(out, t[1]);
    out += ' ';
    detail::append_int(out, t[2]);
    out += '\n';
  }
  detail::write_file_bytes(path, out);
}

SurfaceBinding read_binding(const std::string& path) {
  const std::string bytes = detail::read_file_bytes(path);
  detail::Cursor c(bytes, detail::base_name(path), '#');
  auto expect = [&](const char* word) {
    const std::string_view t = c.token(word);
    if (t != word) c.fail(std::string("expected '") + word + "', got '" + std::string(t.substr(0, 40)) + "'");
  };
  expect("pliant-binding");
  if (c.integer("the format version") != 1) c.fail("unsupported binding version");
  SurfaceBinding b;
  expect("tet_mesh");
  b.tet_vertex_count = c.integer("the tet-mesh vertex count");
  b.tet_count = c.integer("the tet count");
  if (b.tet_vertex_count < 4 || b.tet_count < 1) c.fail("bad tet-mesh counts");
  expect("vertices");
  const size_t n = c.checked_count(c.integer("the vertex count"), 10, "vertex count");
  b.tet.resize(n);
  b.weights.resize(n);
  for (size_t v = 0; v < n; ++v) {
    const int64_t t = c.integer("a tet index");
    if (t < 0 || t >= b.tet_count) c.fail("vertex " + std::to_string(v) + ": tet index " + std::to_string(t) + " out of range");
    b.tet[v] = static_cast<int32_t>(t);
    for (int k = 0; k < 4; ++k) b.weights[v][k] = c.real("a weight");
    if (!b.weights[v].allFinite() || std::abs(b.weights[v].sum() - 1.0) > 1e-6)
      c.fail("vertex " + std::to_string(v) + ": weights must be finite and sum to 1 (sum " + std::to_string(b.weights[v].sum()) + ")");
  }
  expect("triangles");
  const size_t f = c.checked_count(c.integer("the triangle count"), 6, "triangle count");
  b.triangles.resize(f);
  for (size_t i = 0; i < f; ++i)
    for (int k = 0; k < 3; ++k) {
      const int64_t v = c.integer("a triangle vertex");
      if (v < 0 || static_cast<size_t>(v) >= n) c.fail("triangle " + std::to_string(i) + ": vertex " + std::to_string(v) + " out of range");
      b.triangles[i][k] = static_cast<int32_t>(v);
    }
  if (c.skip_space()) c.fail("unexpected data after the triangles");
  return b;
}

bool program_available(const std::string& program) {
  if (program.find('/') != std::string::npos) return ::access(program.c_str(), X_OK) == 0;
  const char* path = std::getenv("PATH");
  if (!path) return false;
  std::string_view rest(path);
  while (true) {
    const size_t colon = rest.find(':');
    const std::string dir(rest.substr(0, colon));
    if (!dir.empty() && ::access((fs::path(dir) / program).c_str(), X_OK) == 0) return true;
    if (colon == std::string_view::npos) return false;
    rest.remove_prefix(colon + 1);
  }
}

TetrahedralizeResult tetrahedralize_surface(const SurfaceMesh& surface, const TetrahedralizeOptions& options) {
  if (!program_available(options.tetgen))
    throw MeshError("tetrahedralize: the '" + options.tetgen + "' program is not installed (Debian: apt-get install tetgen)");
  if (!(options.quality_ratio >= 1.0) || !std::isfinite(options.quality_ratio))
    throw MeshError("tetrahedralize: the quality ratio must be a number >= 1 (TetGen's -q radius-edge bound), got " +
                    std::to_string(options.quality_ratio));
  for (char ch : options.extra_switches)
    if (!std::isalnum(static_cast<unsigned char>(ch)) && ch != '.' && ch != '/' && ch != '-' && ch != '+')
      throw MeshError("tetrahedralize: bad character in extra TetGen switches '" + options.extra_switches + "'");
  const SurfaceStats stats = surface_stats(surface.vertices, surface.triangles);
  if (!stats.closed_manifold)
    throw MeshError("tetrahedralize: the surface " + surface.name + " is not closed (" + std::to_string(stats.boundary_edges) +
                    " open edges, " + std::to_string(stats.nonmanifold_edges) + " non-manifold edges)");
  std::string dir = options.work_dir;
  if (dir.empty()) {
    std::string templ = (fs::temp_directory_path() / "pliant-tetgen-XXXXXX").string();
    if (!::mkdtemp(templ.data())) throw MeshError("tetrahedralize: cannot create a temporary directory");
    dir = templ;
  } else {
    std::error_code ec;
    fs::create_directories(dir, ec);
  }
  const std::string source_ext = options.source_file.empty() ? "" : detail::lower_extension(options.source_file);
  const bool direct = source_ext == ".ply" || source_ext == ".off";
  const std::string input = (fs::path(dir) / ("surface" + (direct ? source_ext : std::string(".off")))).string();
  if (direct) {
    std::error_code ec;
    fs::copy_file(options.source_file, input, fs::copy_options::overwrite_existing, ec);
    if (ec) throw MeshError("tetrahedralize: cannot copy " + options.source_file + " to " + input + ": " + ec.message());
  } else {
    write_surface(surface, input);
  }
  char ratio[32];
  std::snprintf(ratio, sizeof ratio, "%g", options.quality_ratio);
  TetrahedralizeResult result;
  const std::string log = (fs::path(dir) / "tetgen.log").string();
  result.command = options.tetgen + " -pYq" + ratio + options.extra_switches + " " + input;
  const std::string cmd = shell_quote(options.tetgen) + " -pYq" + ratio + options.extra_switches + " " + shell_quote(input) +
                          " > " + shell_quote(log) + " 2>&1";
  spdlog::info("running: {}", result.command);
  const int rc = std::system(cmd.c_str());
  result.node_path = (fs::path(dir) / "surface.1.node").string();
  if (rc != 0 || !fs::exists(result.node_path)) {
    std::string tail;
    try {
      tail = detail::read_file_bytes(log);
      if (tail.size() > 600) tail = "..." + tail.substr(tail.size() - 600);
    } catch (const MeshError&) {
    }
    throw MeshError("tetrahedralize: tetgen failed (exit status " + std::to_string(rc) + "): " + tail);
  }
  return result;
}

}  // namespace pliant
