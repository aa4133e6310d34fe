// SPDX-License-Identifier: Apache-2.0
// TetGen .node/.ele reader. The index base (0 or 1) is the first node's index, as TetGen itself
// decides; attributes and boundary markers are read and ignored; a .face file is not needed.
#include "mesh/mesh_parse.hpp"

#include <spdlog/spdlog.h>

#include <cmath>
#include <filesystem>

namespace pliant::detail {

static std::string tetgen_stem(const std::string& path) {
  const std::string ext = lower_extension(path);
  if (ext == ".node" || ext == ".ele" || ext == ".face" || ext == ".edge" || ext == ".neigh")
    return path.substr(0, path.size() - ext.size());
  return path;
}

RawTetMesh read_tetgen(const std::string& path) {
  const std::string stem = tetgen_stem(path);
  const std::string node_path = stem + ".node";
  const std::string ele_path = stem + ".ele";
  if (!std::filesystem::exists(node_path)) throw MeshError(node_path + ": cannot open file (TetGen mesh needs .node and .ele)");
  if (!std::filesystem::exists(ele_path)) throw MeshError(ele_path + ": cannot open file (TetGen mesh needs .node and .ele)");

  RawTetMesh raw;
  raw.mesh.name = base_name(stem);
  raw.origin_kind = "line";
  raw.file = base_name(ele_path);

  // --- .node
  const std::string node_bytes = read_file_bytes(node_path);
  Cursor nc(node_bytes, base_name(node_path), '#');
  const int64_t n_raw = nc.integer("the number of points");
  const size_t header_line = nc.line();
  const int64_t dim = nc.integer("the dimension");
  int64_t n_attr = 0, n_marker = 0;
  if (nc.token_on_line(header_line)) n_attr = nc.integer("the number of attributes");
  if (nc.token_on_line(header_line)) n_marker = nc.integer("the number of boundary markers");
  if (n_raw == 0) nc.fail("the .node file lists 0 points (points in a .poly file are not supported)");
  if (dim != 3) nc.fail("dimension must be 3, got " + std::to_string(dim));
  if (n_attr < 0 || n_attr > 1000) nc.fail("bad number of attributes: " + std::to_string(n_attr));
  if (n_marker != 0 && n_marker != 1) nc.fail("number of boundary markers must be 0 or 1, got " + std::to_string(n_marker));
  // Each point line holds at least 4 tokens of 2 bytes.
  const size_t n = nc.checked_count(n_raw, 8, "number of points");
  raw.mesh.vertices.resize(n);
  int64_t base = 0;
  for (size_t i = 0; i < n; ++i) {
    const int64_t idx = nc.integer("a point index");
    if (i == 0) {
      if (idx != 0 && idx != 1) nc.fail("the first point index must be 0 or 1, got " + std::to_string(idx));
      base = idx;
    } else if (idx != base + static_cast<int64_t>(i)) {
      nc.fail("point indices must be consecutive: expected " + std::to_string(base + int64_t(i)) + ", got " +
              std::to_string(idx));
    }
    Vec3& p = raw.mesh.vertices[i];
    for (int k = 0; k < 3; ++k) {
      p[k] = nc.real("a coordinate");
      if (!std::isfinite(p[k])) nc.fail("point " + std::to_string(idx) + ": non-finite coordinate " + std::to_string(p[k]));
    }
    for (int64_t a = 0; a < n_attr + n_marker; ++a) nc.real("a point attribute or marker");
  }

  if (nc.skip_space())
    nc.fail("more data after the " + std::to_string(n) + " points the header announces (bad count?)");

  // --- .ele
  const std::string ele_bytes = read_file_bytes(ele_path);
  Cursor ec(ele_bytes, base_name(ele_path), '#');
  const int64_t t_raw = ec.integer("the number of tetrahedra");
  const size_t ele_header = ec.line();
  const int64_t npe = ec.integer("the number of nodes per tetrahedron");
  int64_t t_attr = 0;
  if (ec.token_on_line(ele_header)) t_attr = ec.integer("the number of attributes");
  if (npe != 4 && npe != 10) ec.fail("nodes per tetrahedron must be 4 or 10, got " + std::to_string(npe));
  if (t_attr < 0 || t_attr > 1000) ec.fail("bad number of attributes: " + std::to_string(t_attr));
  const size_t t = ec.checked_count(t_raw, 10, "number of tetrahedra");
  raw.mesh.tets.resize(t);
  raw.tet_origin.resize(t);
  const int64_t hi = base + static_cast<int64_t>(n) - 1;
  for (size_t i = 0; i < t; ++i) {
    const int64_t id = ec.integer("a tetrahedron index");
    raw.tet_origin[i] = static_cast<int64_t>(ec.line());
    for (int64_t k = 0; k < npe; ++k) {
      const int64_t v = ec.integer("a vertex index");
      if (k >= 4) continue;  // quadratic tets: the corners come first
      if (v < base || v > hi)
        ec.fail("tet " + std::to_string(id) + ": vertex index " + std::to_string(v) + " out of range [" +
                std::to_string(base) + ", " + std::to_string(hi) + "]");
      raw.mesh.tets[i][k] = static_cast<int32_t>(v - base);
    }
    for (int64_t a = 0; a < t_attr; ++a) ec.real("a tetrahedron attribute");
  }
  if (ec.skip_space())
    ec.fail("more data after the " + std::to_string(t) + " tetrahedra the header announces (bad count?)");
  spdlog::debug("{}: TetGen mesh, {}-based, {} points, {} tets", stem, base, n, t);
  return raw;
}

}  // namespace pliant::detail
