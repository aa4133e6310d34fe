// SPDX-License-Identifier: Apache-2.0
#include "pliant/coupling.hpp"

#include "pliant/interaction.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <unordered_map>

namespace pliant {
namespace {

// Surface triangles binned into a uniform grid by their boxes grown by the search reach: a
// particle looks in its own cell only.
class TriangleGrid {
 public:
  TriangleGrid(const BodyModel& m, const std::vector<Vec3>& x, double reach) {
    double edge = 0;
    for (const Triangle& t : m.surface) edge += (x[t[1]] - x[t[0]]).norm();
    edge = m.surface.empty() ? reach : edge / double(m.surface.size());
    cell_ = std::max(2 * reach, edge);
    std::vector<std::pair<uint64_t, int32_t>> entries;
    for (size_t k = 0; k < m.surface.size(); ++k) {
      const Triangle& t = m.surface[k];
      Vec3 lo = x[t[0]].cwiseMin(x[t[1]]).cwiseMin(x[t[2]]).array() - reach;
      Vec3 hi = x[t[0]].cwiseMax(x[t[1]]).cwiseMax(x[t[2]]).array() + reach;
      const auto a = cell_of(lo), b = cell_of(hi);
      for (int64_t i = a[0]; i <= b[0]; ++i)
        for (int64_t j = a[1]; j <= b[1]; ++j)
          for (int64_t l = a[2]; l <= b[2]; ++l) entries.emplace_back(key({i, j, l}), int32_t(k));
    }
    std::sort(entries.begin(), entries.end());
    triangles_.reserve(entries.size());
    for (size_t e = 0; e < entries.size(); ++e) {
      if (e == 0 || entries[e].first != entries[e - 1].first)
        ranges_[entries[e].first] = {uint32_t(e), uint32_t(e)};
      ranges_[entries[e].first].second = uint32_t(e + 1);
      triangles_.push_back(entries[e].second);
    }
  }

  std::span<const int32_t> near(const Vec3& p) const {
    const auto it = ranges_.find(key(cell_of(p)));
    if (it == ranges_.end()) return {};
    return {triangles_.data() + it->second.first, it->second.second - it->second.first};
  }

 private:
  std::array<int64_t, 3> cell_of(const Vec3& p) const {
    return {int64_t(std::floor(p.x() / cell_)), int64_t(std::floor(p.y() / cell_)), int64_t(std::floor(p.z() / cell_))};
  }
  static uint64_t key(const std::array<int64_t, 3>& c) {
    // 21 bits per axis (cells far outside +-2^20 wrap: only a slower search, never a missed one,
    // since every candidate is measured exactly).
    return (uint64_t(c[0]) & 0x1FFFFF) | ((uint64_t(c[1]) & 0x1FFFFF) << 21) | ((uint64_t(c[2]) & 0x1FFFFF) << 42);
  }

  double cell_ = 1;
  std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> ranges_;
  std::vector<int32_t> triangles_;
};

struct Contact {
  uint32_t particle;
  int32_t triangle;
  std::array<double, 3> b;  // barycentric weights of the closest point
  Vec3 n;                   // from the surface towards where the particle belongs
  double denominator;       // w_p + sum b_i^2 w_i
};

}  // namespace

CouplingReport couple_particles_to_body(const BodyModel& m, BodyState& body, ParticleState& ps,
                                        std::span<const double> wp, const CouplingSettings& s, double dt) {
  if (!(s.radius > 0) || !std::isfinite(s.radius))
    throw std::invalid_argument(fmt::format("coupling.radius must be > 0, got {}", s.radius));
  if (!(s.friction >= 0) || !std::isfinite(s.friction))
    throw std::invalid_argument(fmt::format("coupling.friction must be >= 0, got {}", s.friction));
  if (s.iterations < 1) throw std::invalid_argument(fmt::format("coupling.iterations must be >= 1, got {}", s.iterations));
  if (!(dt > 0)) throw std::invalid_argument(fmt::format("coupling dt must be > 0, got {}", dt));
  check_particle_counts(ps, wp.size(), "coupling");
  if (body.x.size() != m.vertex_count() || body.v.size() != m.vertex_count())
    throw std::invalid_argument(fmt::format("coupling: the body state has {} positions and {} velocities, the model {} vertices",
                                            body.x.size(), body.v.size(), m.vertex_count()));
  CouplingReport rep;
  if (m.surface.empty() || ps.x.empty()) return rep;

  // Contacts at the positions the step reached.
  const TriangleGrid grid(m, body.x, s.radius);
  std::vector<Contact> contacts;
  for (size_t p = 0; p < ps.x.size(); ++p) {
    const Vec3& xp = ps.x[p];
    double best = INFINITY;
    Contact c{};
    for (int32_t k : grid.near(xp)) {
      const Triangle& t = m.surface[k];
      std::array<double, 3> b;
      const Vec3 q = closest_point_on_triangle(xp, body.x[t[0]], body.x[t[1]], body.x[t[2]], b);
      const double d = (xp - q).norm();
      if (d < best) {
        best = d;
        c = Contact{uint32_t(p), k, b, Vec3::Zero(), 0.0};
      }
    }
    if (!(best < INFINITY)) continue;
    const Triangle& t = m.surface[c.triangle];
    const Vec3 face = (body.x[t[1]] - body.x[t[0]]).cross(body.x[t[2]] - body.x[t[0]]);
    if (!(face.squaredNorm() > 0)) continue;
    const Vec3 outward = face.normalized();
    const Vec3 q = c.b[0] * body.x[t[0]] + c.b[1] * body.x[t[1]] + c.b[2] * body.x[t[2]];
    const Vec3 d = xp - q;
    const double side = d.dot(outward);
    if (side >= 0 && d.norm() >= s.radius) continue;  // outside and clear
    // Outside: apart along the line to the closest point (the face normal when on it); inside:
    // back out through the closest face.
    c.n = side >= 0 && d.norm() > 1e-12 * s.radius ? Vec3(d.normalized()) : outward;
    c.denominator = wp[p];
    for (int a = 0; a < 3; ++a) c.denominator += c.b[a] * c.b[a] * m.inv_mass[t[a]];
    if (!(c.denominator > 0)) continue;  // a pinned particle on fixed vertices
    rep.max_depth = std::max(rep.max_depth, s.radius - d.dot(c.n));
    contacts.push_back(c);
  }
  rep.contacts = contacts.size();
  if (contacts.empty()) return rep;

  // Where each side was before the coupling, and where it came from over the step (for slip).
  std::vector<Vec3> body_before(body.x), particles_before(contacts.size());
  for (size_t k = 0; k < contacts.size(); ++k) particles_before[k] = ps.x[contacts[k].particle];
  // The surface point and the particle at the start of the step (velocities are the step's).
  auto start_point = [&](const Contact& c) {
    const Triangle& t = m.surface[c.triangle];
    Vec3 q = Vec3::Zero();
    for (int a = 0; a < 3; ++a) q += c.b[a] * (body_before[t[a]] - dt * body.v[t[a]]);
    return q;
  };
  for (int it = 0; it < s.iterations; ++it)
    for (size_t k = 0; k < contacts.size(); ++k) {
      const Contact& c = contacts[k];
      const Triangle& t = m.surface[c.triangle];
      Vec3& xp = ps.x[c.particle];
      const Vec3 q = c.b[0] * body.x[t[0]] + c.b[1] * body.x[t[1]] + c.b[2] * body.x[t[2]];
      const double C = (xp - q).dot(c.n) - s.radius;
      if (C >= 0) continue;
      const double dl = -C / c.denominator;
      xp += wp[c.particle] * dl * c.n;
      for (int a = 0; a < 3; ++a) body.x[t[a]] -= m.inv_mass[t[a]] * c.b[a] * dl * c.n;
      if (s.friction > 0) {
        // The particle's slip against the surface point over the step, tangential part, taken
        // back by at most friction x the normal correction.
        const Vec3 qn = c.b[0] * body.x[t[0]] + c.b[1] * body.x[t[1]] + c.b[2] * body.x[t[2]];
        const Vec3 slip = (xp - (particles_before[k] - dt * ps.v[c.particle])) - (qn - start_point(c));
        const Vec3 tangential = slip - slip.dot(c.n) * c.n;
        const double tn = tangential.norm();
        if (tn > 0) {
          const double dt_l = std::min(tn / c.denominator, s.friction * dl);
          const Vec3 dir = tangential / tn;
          xp -= wp[c.particle] * dt_l * dir;
          for (int a = 0; a < 3; ++a) body.x[t[a]] += m.inv_mass[t[a]] * c.b[a] * dt_l * dir;
        }
      }
    }
  // Velocities follow the corrections.
  const double inv_dt = 1.0 / dt;
  for (size_t i = 0; i < body.x.size(); ++i) {
    const Vec3 dx = body.x[i] - body_before[i];
    if (dx.isZero(0)) continue;
    body.v[i] += dx * inv_dt;
    if (m.inv_mass[i] > 0) rep.force_on_body += dx * (inv_dt * inv_dt / m.inv_mass[i]);
  }
  for (size_t k = 0; k < contacts.size(); ++k) {
    const uint32_t p = contacts[k].particle;
    ps.v[p] += (ps.x[p] - particles_before[k]) * inv_dt;
  }
  return rep;
}

}  // namespace pliant
