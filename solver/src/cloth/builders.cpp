// SPDX-License-Identifier: Apache-2.0
// Cloth and rope builders: masses from area or length density, distance constraints along
// edges (and the grid's shear diagonals), dihedral bending across interior edges, Kelager's
// triangle bending along ropes.
#include "pliant/cloth.hpp"

#include "pliant/render_mesh.hpp"

#include <spdlog/fmt/fmt.h>
#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>
#include <string>

namespace pliant {

namespace {

}  // namespace

std::unique_ptr<ConstraintBody> ConstraintBody::cloth(std::vector<Vec3> vertices, const std::vector<Triangle>& triangles,
                                                      double mass_per_area, const ConstraintBodySettings& settings) {
  if (!std::isfinite(mass_per_area) || mass_per_area <= 0.0)
    throw std::invalid_argument("cloth: mass_per_area must be > 0 kg/m^2 (got " + fmt::format("{:g}", mass_per_area) + ")");
  if (vertices.size() < 3) throw std::invalid_argument("cloth: vertices: need at least 3 (got " +
                                                       std::to_string(vertices.size()) + ")");
  if (triangles.empty()) throw std::invalid_argument("cloth: triangles: none given");
  std::unique_ptr<ConstraintBody> body(new ConstraintBody());
  const size_t n = vertices.size();
  body->m_.assign(n, 0.0);
  std::map<std::pair<uint32_t, uint32_t>, std::vector<std::pair<uint32_t, uint32_t>>> edges;  // -> (tri, opposite)
  for (size_t t = 0; t < triangles.size(); ++t) {
    const Triangle& tri = triangles[t];
    for (int k = 0; k < 3; ++k)
      if (tri[k] < 0 || size_t(tri[k]) >= n)
        throw std::invalid_argument("cloth: triangles: triangle " + std::to_string(t) + " has vertex index " +
                                    std::to_string(tri[k]) + " outside [0, " + std::to_string(n) + ")");
    if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2])
      throw std::invalid_argument("cloth: triangles: triangle " + std::to_string(t) + " repeats a vertex");
    const Vec3 &a = vertices[tri[0]], &b = vertices[tri[1]], &c = vertices[tri[2]];
    const double area = 0.5 * (b - a).cross(c - a).norm();
    if (!(area > 0.0))
      throw std::invalid_argument("cloth: triangles: triangle " + std::to_string(t) + " has zero area");
    for (int k = 0; k < 3; ++k) body->m_[tri[k]] += area * mass_per_area / 3.0;
    body->triangles_.push_back({uint32_t(tri[0]), uint32_t(tri[1]), uint32_t(tri[2])});
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = tri[k], j = tri[(k + 1) % 3], o = tri[(k + 2) % 3];
      edges[{std::min(i, j), std::max(i, j)}].push_back({uint32_t(t), o});
    }
  }
  for (const auto& [key, wings] : edges) {
    const auto [i, j] = key;
    body->dist_.push_back(Distance{i, j, (vertices[i] - vertices[j]).norm(), false});
    if (wings.size() != 2) continue;  // boundary (1) or non-manifold (> 2): no bending
    // orient the edge as the first triangle runs it: (a, b, c)
    const auto& t1 = body->triangles_[wings[0].first];
    uint32_t a = i, b = j;
    for (int k = 0; k < 3; ++k)
      if (t1[k] == j && t1[(k + 1) % 3] == i) std::swap(a, b);
    Bend bend{a, b, wings[0].second, wings[1].second, 0.0};
    bend.rest_angle = cloth_math::dihedral_angle(vertices[a], vertices[b], vertices[bend.c], vertices[bend.d]);
    if (settings.bending) body->bend_.push_back(bend);
  }
  body->state_.x = std::move(vertices);
  body->finish(settings);
  return body;
}

std::unique_ptr<ConstraintBody> ConstraintBody::cloth_grid(const ClothGridSpec& spec,
                                                           const ConstraintBodySettings& settings) {
  if (spec.nx < 2 || spec.nx > 4096)
    throw std::invalid_argument("cloth grid: nx must be in [2, 4096] (got " + std::to_string(spec.nx) + ")");
  if (spec.ny < 2 || spec.ny > 4096)
    throw std::invalid_argument("cloth grid: ny must be in [2, 4096] (got " + std::to_string(spec.ny) + ")");
  if (!std::isfinite(spec.size_x) || spec.size_x <= 0.0)
    throw std::invalid_argument("cloth grid: size_x must be > 0 m (got " + fmt::format("{:g}", spec.size_x) + ")");
  if (!std::isfinite(spec.size_y) || spec.size_y <= 0.0)
    throw std::invalid_argument("cloth grid: size_y must be > 0 m (got " + fmt::format("{:g}", spec.size_y) + ")");
  if (!spec.origin.allFinite()) throw std::invalid_argument("cloth grid: origin must be finite");
  if (!spec.u.allFinite() || !spec.v.allFinite() || spec.u.cross(spec.v).norm() < 1e-9)
    throw std::invalid_argument("cloth grid: u and v must be finite and not parallel");
  const Vec3 u = spec.u.normalized(), v = spec.v.normalized();
  std::vector<Vec3> x;
  x.reserve(size_t(spec.nx) * spec.ny);
  for (int j = 0; j < spec.ny; ++j)
    for (int i = 0; i < spec.nx; ++i)
      x.push_back(spec.origin + u * (spec.size_x * i / (spec.nx - 1)) + v * (spec.size_y * j / (spec.ny - 1)));
  auto id = [&](int i, int j) { return int32_t(j * spec.nx + i); };
  std::vector<Triangle> tris;
  std::vector<std::pair<int32_t, int32_t>> shear;
  for (int j = 0; j + 1 < spec.ny; ++j)
    for (int i = 0; i + 1 < spec.nx; ++i) {
      const int32_t a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
      if ((i + j) % 2 == 0) {  // alternate the diagonal: no preferred direction
        tris.push_back({a, b, c});
        tris.push_back({a, c, d});
        shear.push_back({b, d});
      } else {
        tris.push_back({a, b, d});
        tris.push_back({b, c, d});
        shear.push_back({a, c});
      }
    }
  // Build through the general path, then add the shear diagonals and colour again.
  ConstraintBodySettings plain = settings;
  auto body = cloth(std::move(x), tris, spec.mass_per_area, plain);
  if (spec.shear) {
    for (const auto& [i, j] : shear)
      body->dist_.push_back(Distance{uint32_t(i), uint32_t(j), (body->state_.x[i] - body->state_.x[j]).norm(), true});
    body->finish(settings);
  }
  return body;
}

std::unique_ptr<ConstraintBody> ConstraintBody::cloth_from_file(const std::string& path, double scale,
                                                                double mass_per_area,
                                                                const ConstraintBodySettings& settings) {
  if (!std::isfinite(scale) || scale <= 0.0)
    throw std::invalid_argument("cloth file: scale must be > 0 (got " + fmt::format("{:g}", scale) + ")");
  SurfaceLoadOptions options;
  options.scale = scale;
  options.weld = true;
  SurfaceMesh surface = load_surface(path, options);
  return cloth(std::move(surface.vertices), surface.triangles, mass_per_area, settings);
}

std::unique_ptr<ConstraintBody> ConstraintBody::rope(const std::vector<Vec3>& polyline, int segments,
                                                     double linear_density, const ConstraintBodySettings& settings) {
  if (polyline.size() < 2)
    throw std::invalid_argument("rope: polyline needs at least 2 points (got " + std::to_string(polyline.size()) + ")");
  if (segments < 1 || segments > 1000000)
    throw std::invalid_argument("rope: segments must be in [1, 1000000] (got " + std::to_string(segments) + ")");
  if (!std::isfinite(linear_density) || linear_density <= 0.0)
    throw std::invalid_argument("rope: linear_density must be > 0 kg/m (got " + fmt::format("{:g}", linear_density) + ")");
  std::vector<double> s{0.0};
  for (size_t k = 0; k < polyline.size(); ++k) {
    if (!polyline[k].allFinite()) throw std::invalid_argument("rope: polyline point " + std::to_string(k) + " is not finite");
    if (k > 0) s.push_back(s.back() + (polyline[k] - polyline[k - 1]).norm());
  }
  const double length = s.back();
  if (!(length > 0.0)) throw std::invalid_argument("rope: polyline has zero length");
  std::unique_ptr<ConstraintBody> body(new ConstraintBody());
  body->is_rope_ = true;
  std::vector<Vec3> x;
  size_t seg = 0;
  for (int k = 0; k <= segments; ++k) {
    const double at = length * k / segments;
    while (seg + 2 < s.size() && s[seg + 1] < at) ++seg;
    const double span = s[seg + 1] - s[seg];
    const double t = span > 0.0 ? std::clamp((at - s[seg]) / span, 0.0, 1.0) : 0.0;
    x.push_back(polyline[seg] + t * (polyline[seg + 1] - polyline[seg]));
  }
  body->m_.assign(x.size(), 0.0);
  for (int k = 0; k < segments; ++k) {
    const double rest = (x[k + 1] - x[k]).norm();
    if (!(rest > 0.0)) throw std::invalid_argument("rope: polyline: segment " + std::to_string(k) + " has zero length");
    body->dist_.push_back(Distance{uint32_t(k), uint32_t(k + 1), rest, false});
    const double m = linear_density * rest / 2.0;
    body->m_[k] += m;
    body->m_[k + 1] += m;
  }
  if (settings.bending)
    for (int k = 1; k < segments; ++k)
      body->rope_bend_.push_back(
          RopeBend{uint32_t(k - 1), uint32_t(k), uint32_t(k + 1), cloth_math::rope_bend_value(x[k - 1], x[k], x[k + 1])});
  body->state_.x = std::move(x);
  body->finish(settings);
  return body;
}

}  // namespace pliant
