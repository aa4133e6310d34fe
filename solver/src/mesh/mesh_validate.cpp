// SPDX-License-Identifier: Apache-2.0
#include "pliant/mesh_validate.hpp"

#include "pliant/material.hpp"  // kDefaultInertiaFloor: which vertices the report calls light
#include "pliant/mesh_io.hpp"

#include <Eigen/Dense>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <sstream>

namespace pliant {
namespace {

constexpr double kPi = 3.14159265358979323846;
// Faces of a positively oriented tet, each wound outward (the same table as mesh.cpp).
constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

std::string fmt_g(double v) {
  std::ostringstream s;
  s.precision(3);
  s << v;
  return s.str();
}

class Locator {
 public:
  explicit Locator(const MeshValidationOptions& o) : o_(o) {}
  // "file.ele:14: " or "file.msh: element 12: " or "mesh: tet 3: "
  std::string operator()(size_t tet) const {
    const std::string src = o_.source.empty() ? std::string("mesh") : o_.source;
    if (tet < o_.tet_origin.size()) {
      if (o_.origin_kind == "line") return src + ":" + std::to_string(o_.tet_origin[tet]) + ": tet " + std::to_string(tet);
      return src + ": " + o_.origin_kind + " " + std::to_string(o_.tet_origin[tet]);
    }
    return src + ": tet " + std::to_string(tet);
  }

 private:
  const MeshValidationOptions& o_;
};

void warn(MeshReport& report, const MeshValidationOptions& o, const std::string& msg) {
  report.warnings.push_back(msg);
  if (o.log) spdlog::warn("{}", msg);
}

double max_edge(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const double e = std::max({(b - a).squaredNorm(), (c - a).squaredNorm(), (d - a).squaredNorm(), (c - b).squaredNorm(),
                             (d - b).squaredNorm(), (d - c).squaredNorm()});
  return std::sqrt(e);
}

}  // namespace

double tet_min_dihedral_deg(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const Vec3 p[4] = {a, b, c, d};
  Vec3 n[4];
  for (int f = 0; f < 4; ++f) {
    n[f] = (p[kFaces[f][1]] - p[kFaces[f][0]]).cross(p[kFaces[f][2]] - p[kFaces[f][0]]);
    const double len = n[f].norm();
    if (!(len > 0)) return 0.0;
    n[f] /= len;
  }
  double min_angle = kPi;
  for (int i = 0; i < 4; ++i)
    for (int j = i + 1; j < 4; ++j) {
      const double cosang = std::clamp(n[i].dot(n[j]), -1.0, 1.0);
      min_angle = std::min(min_angle, kPi - std::acos(cosang));
    }
  return min_angle * 180.0 / kPi;
}

double tet_aspect_ratio(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d) {
  const double v = std::abs(signed_tet_volume(a, b, c, d));
  const double area = 0.5 * ((c - b).cross(d - b).norm() + (d - a).cross(c - a).norm() + (b - a).cross(d - a).norm() +
                             (c - a).cross(b - a).norm());
  if (!(v > 0) || !(area > 0)) return std::numeric_limits<double>::infinity();
  const double r_in = 3.0 * v / area;
  return max_edge(a, b, c, d) / (2.0 * std::sqrt(6.0) * r_in);
}

std::vector<Triangle> boundary_faces(const std::vector<Tet>& tets, int64_t* overfull_faces) {
  struct FaceRef {
    std::array<int32_t, 3> key;
    int32_t tet;
    int8_t face;
  };
  std::vector<FaceRef> refs;
  refs.reserve(tets.size() * 4);
  for (size_t t = 0; t < tets.size(); ++t)
    for (int8_t f = 0; f < 4; ++f) {
      std::array<int32_t, 3> k{tets[t][kFaces[f][0]], tets[t][kFaces[f][1]], tets[t][kFaces[f][2]]};
      std::sort(k.begin(), k.end());
      refs.push_back({k, static_cast<int32_t>(t), f});
    }
  std::sort(refs.begin(), refs.end(), [](const FaceRef& x, const FaceRef& y) {
    return x.key != y.key ? x.key < y.key : x.tet < y.tet;
  });
  std::vector<Triangle> out;
  int64_t overfull = 0;
  for (size_t i = 0; i < refs.size();) {
    size_t j = i + 1;
    while (j < refs.size() && refs[j].key == refs[i].key) ++j;
    if (j - i == 1) {
      const Tet& t = tets[refs[i].tet];
      const int f = refs[i].face;
      out.push_back({t[kFaces[f][0]], t[kFaces[f][1]], t[kFaces[f][2]]});
    } else if (j - i > 2) {
      ++overfull;
    }
    i = j;
  }
  if (overfull_faces) *overfull_faces = overfull;
  return out;
}

SurfaceStats surface_stats(const std::vector<Vec3>& vertices, const std::vector<Triangle>& triangles) {
  SurfaceStats s;
  s.triangles = static_cast<int64_t>(triangles.size());
  struct Edge {
    int32_t a, b;
    bool forward;
  };
  std::vector<Edge> edges;
  edges.reserve(triangles.size() * 3);
  std::vector<int32_t> parent(vertices.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  std::vector<char> used(vertices.size(), 0);
  for (const Triangle& t : triangles) {
    for (int k = 0; k < 3; ++k) {
      const int32_t a = t[k], b = t[(k + 1) % 3];
      edges.push_back({std::min(a, b), std::max(a, b), a < b});
      used[a] = 1;
      const int32_t ra = find(a), rb = find(b);
      if (ra != rb) parent[ra] = rb;
    }
    s.area += 0.5 * (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]).norm();
  }
  std::sort(edges.begin(), edges.end(), [](const Edge& x, const Edge& y) { return x.a != y.a ? x.a < y.a : x.b < y.b; });
  for (size_t i = 0; i < edges.size();) {
    size_t j = i + 1;
    while (j < edges.size() && edges[j].a == edges[i].a && edges[j].b == edges[i].b) ++j;
    ++s.edges;
    if (j - i == 1) ++s.boundary_edges;
    else if (j - i > 2 || edges[i].forward == edges[i + 1].forward) ++s.nonmanifold_edges;
    i = j;
  }
  for (size_t v = 0; v < vertices.size(); ++v)
    if (used[v]) {
      ++s.vertices;
      if (find(static_cast<int32_t>(v)) == static_cast<int32_t>(v)) ++s.components;
    }
  // Pinched vertices: the triangles around a vertex must form one fan, i.e. the edges opposite
  // the vertex (its link) must be connected. Two tets touching at a single vertex fail this.
  {
    std::vector<int32_t> start(vertices.size() + 1, 0);
    for (const Triangle& t : triangles)
      for (int32_t v : t) start[v + 1]++;
    for (size_t v = 0; v < vertices.size(); ++v) start[v + 1] += start[v];
    std::vector<int32_t> fill(start.begin(), start.end() - 1), around(static_cast<size_t>(start.back()));
    for (size_t t = 0; t < triangles.size(); ++t)
      for (int32_t v : triangles[t]) around[fill[v]++] = static_cast<int32_t>(t);
    std::vector<int32_t> link, link_parent;
    for (size_t v = 0; v < vertices.size(); ++v) {
      if (start[v + 1] - start[v] < 2) continue;
      link.clear();
      auto local = [&](int32_t x) {
        for (size_t i = 0; i < link.size(); ++i)
          if (link[i] == x) return static_cast<int32_t>(i);
        link.push_back(x);
        link_parent.resize(link.size());
        link_parent.back() = static_cast<int32_t>(link.size() - 1);
        return static_cast<int32_t>(link.size() - 1);
      };
      auto root = [&](int32_t x) {
        while (link_parent[x] != x) x = link_parent[x] = link_parent[link_parent[x]];
        return x;
      };
      for (int32_t i = start[v]; i < start[v + 1]; ++i) {
        const Triangle& t = triangles[around[i]];
        const int k = t[0] == static_cast<int32_t>(v) ? 0 : t[1] == static_cast<int32_t>(v) ? 1 : 2;
        const int32_t a = local(t[(k + 1) % 3]), b = local(t[(k + 2) % 3]);
        link_parent[root(a)] = root(b);
      }
      int fans = 0;
      for (size_t i = 0; i < link.size(); ++i) fans += root(static_cast<int32_t>(i)) == static_cast<int32_t>(i);
      if (fans > 1) ++s.nonmanifold_vertices;
    }
  }
  s.euler_characteristic = static_cast<int>(s.vertices - s.edges + s.triangles);
  s.closed_manifold = s.triangles > 0 && s.boundary_edges == 0 && s.nonmanifold_edges == 0 && s.nonmanifold_vertices == 0;
  return s;
}

MeshReport validate_mesh(TetMesh& mesh, const MeshValidationOptions& o) {
  MeshReport report;
  report.source = o.source.empty() ? mesh.name : o.source;
  const Locator where(o);
  const std::string src = report.source.empty() ? std::string("mesh") : report.source;
  if (mesh.vertices.empty()) throw MeshError(src + ": the mesh has no vertices");
  if (mesh.tets.empty()) throw MeshError(src + ": the mesh has no tetrahedra");
  if (mesh.vertices.size() > static_cast<size_t>(std::numeric_limits<int32_t>::max()))
    throw MeshError(src + ": too many vertices");

  for (size_t i = 0; i < mesh.vertices.size(); ++i)
    if (!mesh.vertices[i].allFinite())
      throw MeshError(src + ": vertex " + std::to_string(i) + ": non-finite coordinate (" + fmt_g(mesh.vertices[i].x()) +
                      ", " + fmt_g(mesh.vertices[i].y()) + ", " + fmt_g(mesh.vertices[i].z()) + ")");

  const auto nv = static_cast<int64_t>(mesh.vertices.size());
  std::vector<char> keep(mesh.tets.size(), 1);
  int64_t dropped_degenerate = 0;
  std::string first_degenerate;
  auto degenerate = [&](size_t t, const std::string& why) {
    if (!o.drop_degenerate)
      throw MeshError(where(t) + ": " + why + " (zero volume; drop such tets with --drop-degenerate)");
    keep[t] = 0;
    if (dropped_degenerate++ == 0) first_degenerate = where(t) + ": " + why;
  };

  // Indices, then volume and orientation.
  std::vector<double> volume(mesh.tets.size(), 0.0);
  int64_t reoriented = 0;
  std::string first_inverted;
  for (size_t t = 0; t < mesh.tets.size(); ++t) {
    Tet& tet = mesh.tets[t];
    for (int k = 0; k < 4; ++k)
      if (tet[k] < 0 || tet[k] >= nv)
        throw MeshError(where(t) + ": vertex index " + std::to_string(tet[k]) + " out of range [0, " + std::to_string(nv - 1) + "]");
    bool repeated = false;
    for (int i = 0; i < 4 && !repeated; ++i)
      for (int j = i + 1; j < 4; ++j)
        if (tet[i] == tet[j]) {
          degenerate(t, "repeats vertex " + std::to_string(tet[i]));
          repeated = true;
          break;
        }
    if (repeated) continue;
    const Vec3 &a = mesh.vertices[tet[0]], &b = mesh.vertices[tet[1]], &c = mesh.vertices[tet[2]], &d = mesh.vertices[tet[3]];
    const double v = signed_tet_volume(a, b, c, d);
    const double l = max_edge(a, b, c, d);
    const double rel = 6.0 * v / (l * l * l);
    if (!(std::abs(rel) > o.degenerate_rel_volume)) {
      degenerate(t, "degenerate tet, volume " + fmt_g(v) + " (6V/Lmax^3 = " + fmt_g(rel) + ")");
      continue;
    }
    if (v < 0) {
      if (!o.reorient_inverted) throw MeshError(where(t) + ": inverted tet, volume " + fmt_g(v));
      std::swap(tet[2], tet[3]);
      if (reoriented++ == 0) first_inverted = where(t) + ", volume " + fmt_g(v);
    }
    volume[t] = std::abs(v);
  }
  if (reoriented)
    warn(report, o, src + ": " + std::to_string(reoriented) + " inverted tets re-oriented (first: " + first_inverted + ")");
  if (dropped_degenerate)
    warn(report, o, src + ": dropped " + std::to_string(dropped_degenerate) + " zero-volume tets (first: " + first_degenerate + ")");

  // Duplicate tets (the same four vertices): keep the first.
  {
    std::vector<std::pair<std::array<int32_t, 4>, int32_t>> keys;
    keys.reserve(mesh.tets.size());
    for (size_t t = 0; t < mesh.tets.size(); ++t) {
      if (!keep[t]) continue;
      std::array<int32_t, 4> k = mesh.tets[t];
      std::sort(k.begin(), k.end());
      keys.emplace_back(k, static_cast<int32_t>(t));
    }
    std::sort(keys.begin(), keys.end());
    int64_t dups = 0;
    std::string first;
    for (size_t i = 1; i < keys.size(); ++i)
      if (keys[i].first == keys[i - 1].first) {
        keep[keys[i].second] = 0;
        if (dups++ == 0) first = where(keys[i].second) + " repeats " + where(keys[i - 1].second);
      }
    if (dups) warn(report, o, src + ": dropped " + std::to_string(dups) + " duplicate tets (first: " + first + ")");
    report.dropped_duplicates = dups;
  }

  // Compact tets (keeping the origin list aligned for later messages).
  std::vector<int64_t> origin;
  const bool have_origin = o.tet_origin.size() == mesh.tets.size();
  {
    size_t w = 0;
    for (size_t t = 0; t < mesh.tets.size(); ++t) {
      if (!keep[t]) continue;
      mesh.tets[w] = mesh.tets[t];
      volume[w] = volume[t];
      origin.push_back(have_origin ? o.tet_origin[t] : static_cast<int64_t>(t));
      ++w;
    }
    mesh.tets.resize(w);
    volume.resize(w);
  }
  if (mesh.tets.empty()) throw MeshError(src + ": no tetrahedra left after dropping degenerate ones");
  MeshValidationOptions located = o;
  located.tet_origin = origin;
  if (!have_origin) located.origin_kind = "tet";
  const Locator where2(located);

  // Unreferenced vertices: drop and remap.
  {
    std::vector<int32_t> remap(mesh.vertices.size(), -1);
    for (const Tet& t : mesh.tets)
      for (int32_t v : t) remap[v] = 0;
    int32_t next = 0;
    for (size_t v = 0; v < remap.size(); ++v)
      if (remap[v] == 0) remap[v] = next++;
    const int64_t dropped = nv - next;
    if (dropped > 0) {
      std::vector<Vec3> kept;
      kept.reserve(static_cast<size_t>(next));
      for (size_t v = 0; v < remap.size(); ++v)
        if (remap[v] >= 0) kept.push_back(mesh.vertices[v]);
      mesh.vertices = std::move(kept);
      for (Tet& t : mesh.tets)
        for (int32_t& v : t) v = remap[v];
      // A group keeps the vertices that remain (a group of only dropped vertices stays, empty).
      for (VertexGroup& g : mesh.groups) {
        std::vector<int32_t> kept_group;
        for (int32_t v : g.vertices)
          if (v >= 0 && static_cast<size_t>(v) < remap.size() && remap[v] >= 0) kept_group.push_back(remap[v]);
        g.vertices = std::move(kept_group);
      }
      warn(report, o, src + ": dropped " + std::to_string(dropped) + " vertices no tet uses (indices remapped)");
    }
    report.dropped_vertices = dropped;
  }

  // Volumes and quality.
  const size_t nt = mesh.tets.size();
  double sum = 0, vmin = std::numeric_limits<double>::infinity(), vmax = 0;
  size_t vmin_at = 0;
  for (size_t t = 0; t < nt; ++t) {
    sum += volume[t];
    if (volume[t] < vmin) vmin = volume[t], vmin_at = t;
    vmax = std::max(vmax, volume[t]);
  }
  const double mean = sum / static_cast<double>(nt);
  int64_t tiny = 0;
  for (size_t t = 0; t < nt; ++t)
    if (volume[t] < o.tiny_volume_ratio * mean) ++tiny;
  if (tiny)
    warn(report, o, src + ": " + std::to_string(tiny) + " tiny tets (volume below " + fmt_g(o.tiny_volume_ratio) +
                        " x mean " + fmt_g(mean) + "); smallest: " + where2(vmin_at) + ", volume " + fmt_g(vmin) +
                        " (quality warning: they load, but may slow or destabilise the solver)");

  std::vector<double> dihedral(nt), aspect(nt);
  double aspect_sum = 0;
  for (size_t t = 0; t < nt; ++t) {
    const Tet& tet = mesh.tets[t];
    const Vec3 &a = mesh.vertices[tet[0]], &b = mesh.vertices[tet[1]], &c = mesh.vertices[tet[2]], &d = mesh.vertices[tet[3]];
    dihedral[t] = tet_min_dihedral_deg(a, b, c, d);
    aspect[t] = tet_aspect_ratio(a, b, c, d);
    aspect_sum += aspect[t];
    const auto& edges = QualityHistogram::kEdgesDeg;
    size_t bin = static_cast<size_t>(std::upper_bound(edges.begin(), edges.end(), dihedral[t]) - edges.begin());
    report.dihedral_histogram.counts[bin == 0 ? 0 : bin - 1]++;
  }
  std::vector<size_t> order(nt);
  std::iota(order.begin(), order.end(), size_t(0));
  const size_t k = std::min(nt, static_cast<size_t>(std::max(0, o.worst_listed)));
  std::partial_sort(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(k), order.end(),
                    [&](size_t x, size_t y) { return dihedral[x] < dihedral[y]; });
  for (size_t i = 0; i < k; ++i) {
    const size_t t = order[i];
    report.worst.push_back({static_cast<int64_t>(t), origin[t], dihedral[t], aspect[t], volume[t]});
  }
  int64_t poor = 0;
  for (size_t t = 0; t < nt; ++t)
    if (dihedral[t] < o.warn_min_dihedral_deg) ++poor;
  if (poor) {
    std::string list;
    for (const WorstTet& w : report.worst) {
      if (w.min_dihedral_deg >= o.warn_min_dihedral_deg) break;
      list += "\n  " + where2(static_cast<size_t>(w.tet)) + ": min dihedral " + fmt_g(w.min_dihedral_deg) + " deg, aspect " +
              fmt_g(w.aspect_ratio) + ", volume " + fmt_g(w.volume);
    }
    warn(report, o, src + ": " + std::to_string(poor) + " tets with a dihedral angle below " + fmt_g(o.warn_min_dihedral_deg) +
                        " deg (quality warning); worst:" + list);
  }

  // Boundary.
  int64_t overfull = 0;
  const std::vector<Triangle> boundary = boundary_faces(mesh.tets, &overfull);
  report.surface = surface_stats(mesh.vertices, boundary);
  report.surface.overfull_faces = overfull;
  if (overfull) report.surface.closed_manifold = false;
  if (!report.surface.closed_manifold)
    warn(report, o, src + ": the boundary is not a closed manifold (" + std::to_string(report.surface.boundary_edges) +
                        " open edges, " + std::to_string(report.surface.nonmanifold_edges) + " non-manifold edges, " +
                        std::to_string(report.surface.nonmanifold_vertices) + " pinched vertices, " +
                        std::to_string(overfull) + " faces shared by more than two tets)");

  report.origin_kind = have_origin ? o.origin_kind : std::string("tet");
  report.vertices = static_cast<int64_t>(mesh.vertices.size());
  report.tets = static_cast<int64_t>(nt);
  report.reoriented = reoriented;
  report.dropped_degenerate = dropped_degenerate;
  report.tiny_tets = tiny;
  report.poor_tets = poor;
  report.volume = sum;
  report.min_volume = vmin;
  report.max_volume = vmax;
  report.mean_volume = mean;
  report.min_dihedral_deg = *std::min_element(dihedral.begin(), dihedral.end());
  report.max_aspect_ratio = *std::max_element(aspect.begin(), aspect.end());
  report.mean_aspect_ratio = aspect_sum / static_cast<double>(nt);
  report.bbox = bounding_box(mesh.vertices);
  // Lumped vertex volumes (a quarter of each tet at each corner): how light the lightest
  // vertex is, and how many the default inertia floor raises (Material::inertia_floor).
  {
    std::vector<double> lumped(mesh.vertices.size(), 0.0);
    for (size_t t = 0; t < nt; ++t)
      for (int32_t v : mesh.tets[t]) lumped[v] += volume[t] / 4;
    const double mean_lumped = sum / static_cast<double>(mesh.vertices.size());
    report.min_vertex_mass_ratio = *std::min_element(lumped.begin(), lumped.end()) / mean_lumped;
    for (double l : lumped) report.light_vertices += l < kDefaultInertiaFloor * mean_lumped;
  }
  return report;
}

}  // namespace pliant
