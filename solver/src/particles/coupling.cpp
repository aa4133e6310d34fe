// SPDX-License-Identifier: Apache-2.0
#include "pliant/coupling.hpp"

#include "pliant/interaction.hpp"
#include "particles/surface_contact.hpp"
#include "particles/triangle_grid.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <tuple>
#include <unordered_map>

namespace pliant {
using detail::closest_face;
using detail::FaceHit;
using detail::first_entered;
using detail::outward_at;
using detail::particle_contact;
using detail::TriangleGrid;
using detail::triangle_contact;
namespace {

// Whether segment a-b passes through triangle (p0, p1, p2), from either side (its edges
// included, with a margin of 1e-9 in the barycentric weights: a segment through the edge two
// triangles share pierces both).
bool pierces(const Vec3& a, const Vec3& b, const Vec3& p0, const Vec3& p1, const Vec3& p2) {
  constexpr double eps = 1e-9;
  const Vec3 e1 = p1 - p0, e2 = p2 - p0, d = b - a;
  const Vec3 pv = d.cross(e2);
  const double det = e1.dot(pv);
  if (!(std::abs(det) > 1e-300)) return false;
  const Vec3 tv = a - p0;
  const double u = tv.dot(pv) / det;
  if (u < -eps || u > 1 + eps) return false;
  const Vec3 qv = tv.cross(e1);
  const double v = d.dot(qv) / det;
  if (v < -eps || u + v > 1 + eps) return false;
  const double t = e2.dot(qv) / det;
  return t >= 0 && t <= 1;
}

// A point that keeps the contact radius from the body: a particle (j == i, s == 0) or a point
// s of the way along segment i-j.
struct Point {
  uint32_t i, j;
  double s;
  Vec3 at(std::span<const Vec3> x) const { return s == 0 ? x[i] : Vec3((1 - s) * x[i] + s * x[j]); }
};

// The points inside segment i-j of this length, no farther apart than the radius and at most
// 64: fn(point) for each (none for a segment no longer than the radius; 64 for one whose length
// overflowed, a blown-up body's, which the count must not convert from infinity).
template <class Fn>
void for_each_point_inside(uint32_t i, uint32_t j, double length, double radius, const Fn& fn) {
  const double spans = std::ceil(length / radius);
  const int inside = spans < 65 ? int(spans) - 1 : 64;
  for (int k = 1; k <= inside; ++k) fn(Point{i, j, double(k) / double(inside + 1)});
}

// The move of a segment's point (direction u) out of a contact of normal n and depth -C: across
// the segment only (a move along it slides the segment without changing its line), scaled so
// that its step along n is -C; a = |n across u| (kMinAcross bounds it away from 0).
Vec3 move_across(const Vec3& n, const Vec3& u, double C, double& a) {
  const Vec3 dir = n - n.dot(u) * u;
  a = dir.norm();
  return (-C / (a * a)) * dir;
}

struct PointContact {
  Point point;
  int32_t triangle;
  std::array<double, 3> b;  // barycentric weights of the surface point
  Vec3 n;                   // from the surface towards where the point belongs
};

// How much of a face normal lies across a segment of direction u (1 for a segment along the
// face, 0 for one piercing it head-on). A segment's point leaves the body by moving across the
// segment: a move along it slides the segment without changing its line.
double across(const Vec3& n, const Vec3& u) { return (n - n.dot(u) * u).norm(); }
constexpr double kMinAcross = 0.25;  // below (within 14 degrees of head-on), a face is not a segment's exit

// The contact of a point that moved from `start` to `now` with the body's surface, if any: a
// particle's as particle_contact finds it. A point inside a segment of direction `along` leaves
// through the near face it needs the least move across the segment to clear (the top of an edge
// the segment lies over, not the side face that only a slide along the segment would clear), and
// never through a face the segment pierces head-on.
bool find_contact(const BodyModel& m, const BodyState& body, const TriangleGrid& grid, const Point& pt,
                  const Vec3& start, const Vec3& now, const Vec3* along, double radius, std::vector<int32_t>& swept,
                  PointContact& out, double& depth) {
  const std::span<const Triangle> tris(m.surface);
  const std::span<const Vec3> x(body.x);
  FaceHit hit;
  if (!along) {
    if (!particle_contact(tris, x, grid, start, now, radius, swept, hit, depth)) return false;
    out = PointContact{pt, hit.triangle, hit.b, hit.n};
    return true;
  }
  auto normal_of = [&](const Triangle& t) {
    return Vec3((body.x[t[1]] - body.x[t[0]]).cross(body.x[t[2]] - body.x[t[0]]));
  };
  auto at = [&](const Triangle& t, const std::array<double, 3>& b) {
    return Vec3(b[0] * body.x[t[0]] + b[1] * body.x[t[1]] + b[2] * body.x[t[2]]);
  };
  if (start.allFinite()) grid.near_segment(start, now, 4096, swept);
  else swept.clear();
  if (first_entered(tris, x, grid, swept, start, now, [&](const Vec3& n) { return across(n, *along) < kMinAcross; },
                    hit)) {
    const Triangle& t = m.surface[hit.triangle];
    out = PointContact{pt, hit.triangle, hit.b, normal_of(t).normalized()};
    depth = radius - (now - at(t, hit.b)).dot(out.n);
    return true;
  }
  double distance;
  if (!closest_face(tris, x, grid, grid.near(now), now, hit, distance)) return false;
  const Triangle& t = m.surface[hit.triangle];
  const Vec3 face = normal_of(t);
  if (!(face.squaredNorm() > 0)) return false;
  const Vec3 d = now - at(t, hit.b);
  const bool outside = d.dot(outward_at(tris, x, grid, grid.near(now), now, hit, distance)) >= 0;
  if (outside && d.norm() >= radius) return false;  // outside and clear
  // Faces whose plane the point started outside of come first (it came from that side: a
  // segment swept over a body's edge goes back over it, not round the far one).
  double cheapest[2] = {INFINITY, INFINITY};
  PointContact pick[2];
  double picked_depth[2] = {0, 0};
  // The faces along the point's path (its cell included): the face it came over may be
  // farther than the reach by now.
  std::vector<int32_t>& candidates = swept;
  if (candidates.empty()) {
    const auto near = grid.near(now);
    candidates.assign(near.begin(), near.end());
  }
  for (int32_t k : candidates) {
    const Triangle& tk = m.surface[k];
    const Vec3 fk = normal_of(tk);
    if (!(fk.squaredNorm() > 0)) continue;
    const Vec3 nk = fk.normalized();
    const double a = across(nk, *along);
    if (a < kMinAcross) continue;
    std::array<double, 3> b;
    const Vec3 qk = closest_point_on_triangle(now, body.x[tk[0]], body.x[tk[1]], body.x[tk[2]], b);
    const double need = radius - (now - qk).dot(nk);  // how far along nk the point must go
    if (need <= 0) continue;
    const bool started_outside = start.allFinite() && (start - qk).dot(nk) >= 0;
    const int rank = started_outside ? 0 : 1;
    if (need / a >= cheapest[rank]) continue;
    cheapest[rank] = need / a;
    pick[rank] = PointContact{pt, k, b, nk};
    picked_depth[rank] = need;
  }
  const int use = cheapest[0] < INFINITY ? 0 : 1;
  if (!(cheapest[use] < INFINITY)) return false;
  out = pick[use];
  depth = picked_depth[use];
  return true;
}

}  // namespace

CouplingReport couple_particles_to_body(const BodyModel& m, BodyState& body, ParticleState& ps,
                                        std::span<const double> wp, const CouplingSettings& s, double dt,
                                        std::span<const Vec3> particle_start,
                                        std::span<const std::array<uint32_t, 2>> segments) {
  if (!(s.radius > 0) || !std::isfinite(s.radius))
    throw std::invalid_argument(fmt::format("coupling.radius must be > 0, got {}", s.radius));
  if (!(s.friction >= 0) || !std::isfinite(s.friction))
    throw std::invalid_argument(fmt::format("coupling.friction must be >= 0, got {}", s.friction));
  if (!(dt > 0)) throw std::invalid_argument(fmt::format("coupling dt must be > 0, got {}", dt));
  check_particle_counts(ps, wp.size(), "coupling");
  if (!particle_start.empty() && particle_start.size() != ps.x.size())
    throw std::invalid_argument(fmt::format("coupling: {} start positions for {} particles", particle_start.size(),
                                            ps.x.size()));
  if (body.x.size() != m.vertex_count() || body.v.size() != m.vertex_count())
    throw std::invalid_argument(fmt::format("coupling: the body state has {} positions and {} velocities, the model {} vertices",
                                            body.x.size(), body.v.size(), m.vertex_count()));
  for (size_t k = 0; k < segments.size(); ++k)
    if (segments[k][0] >= ps.x.size() || segments[k][1] >= ps.x.size() || segments[k][0] == segments[k][1])
      throw std::invalid_argument(fmt::format("coupling: segment {} joins particles {} and {} of {}", k, segments[k][0],
                                              segments[k][1], ps.x.size()));
  CouplingReport rep;
  if (m.surface.empty() || ps.x.empty()) return rep;

  // Where each particle started the step (from its velocity when the caller has no record).
  std::vector<Vec3> start_storage;
  std::span<const Vec3> start = particle_start;
  if (start.empty()) {
    start_storage.resize(ps.x.size());
    for (size_t p = 0; p < ps.x.size(); ++p) start_storage[p] = ps.x[p] - dt * ps.v[p];
    start = start_storage;
  }
  auto finite = [&](uint32_t p) { return ps.x[p].allFinite() && ps.v[p].allFinite(); };

  // Contacts at the positions the step reached: every particle (unless s.particles is off), then
  // the inside of every segment at points no farther apart than the radius (at most 64 a
  // segment), so that a segment longer than the contact's thickness cannot slide over an edge of
  // the body between its two particles.
  // The grid over the surface near the particles only: the box of every finite particle where
  // it started and ended (a segment's points lie inside it).
  std::pair<Vec3, Vec3> region{Vec3::Constant(INFINITY), Vec3::Constant(-INFINITY)};
  for (size_t p = 0; p < ps.x.size(); ++p) {
    if (!finite(uint32_t(p))) continue;
    region.first = region.first.cwiseMin(ps.x[p]);
    region.second = region.second.cwiseMax(ps.x[p]);
    if (start[p].allFinite()) {
      region.first = region.first.cwiseMin(start[p]);
      region.second = region.second.cwiseMax(start[p]);
    }
  }
  if (!(region.first.array() <= region.second.array()).all()) return rep;  // no finite particle
  const TriangleGrid grid(m.surface, std::span<const Vec3>(body.x), s.radius, {}, &region);
  if (grid.entries() == 0) return rep;  // no face within reach of the particles' region
  std::vector<PointContact> contacts;
  std::vector<int32_t> swept;
  const std::span<const Vec3> x(ps.x);
  for (size_t p = 0; p < ps.x.size() && s.particles; ++p) {
    if (!finite(uint32_t(p))) continue;  // a blown-up body: the caller rolls it back
    if (!(wp[p] > 0)) continue;           // a pinned particle stays where its pin holds it
    const Point pt{uint32_t(p), uint32_t(p), 0.0};
    PointContact c;
    double depth = 0;
    if (!find_contact(m, body, grid, pt, start[p], ps.x[p], nullptr, s.radius, swept, c, depth)) continue;
    rep.max_depth = std::max(rep.max_depth, depth);
    contacts.push_back(c);
  }
  const size_t particle_contacts = contacts.size();
  for (const auto& seg : segments) {
    const uint32_t i = seg[0], j = seg[1];
    if (!finite(i) || !finite(j) || !(wp[i] > 0 || wp[j] > 0)) continue;
    const double length = (ps.x[i] - ps.x[j]).norm();
    if (!(length > 0)) continue;
    const Vec3 u = (ps.x[j] - ps.x[i]) / length;
    for_each_point_inside(i, j, length, s.radius, [&](const Point& pt) {
      const Vec3 now = pt.at(x), from = pt.at(start);
      PointContact c;
      double depth = 0;
      if (!find_contact(m, body, grid, pt, from, now, &u, s.radius, swept, c, depth)) return;
      rep.max_depth = std::max(rep.max_depth, depth);
      contacts.push_back(c);
    });
  }
  rep.contacts = particle_contacts;
  rep.segment_contacts = contacts.size() - particle_contacts;
  if (contacts.empty()) return rep;

  // The particles take the whole position correction (a segment's point shares it between its
  // two particles by their inverse masses and its place along the segment, as a position-based
  // constraint on that point does); the body takes the momentum that the correction gave the
  // particles, as a change of its vertices' velocities (shared by the barycentric weights). The
  // body's positions stay: its own next step spreads the push through its elasticity, which a
  // position correction of a few light surface vertices would not (a heavy rope landing on a
  // light beam would dent it through). Momentum is exact at once: what the particles gain, the
  // body loses.
  const double inv_dt = 1.0 / dt;
  std::vector<Vec3> body_dv(body.v.size(), Vec3::Zero());  // applied after every contact's slip is measured
  for (const PointContact& c : contacts) {
    const Point& pt = c.point;
    const Triangle& t = m.surface[c.triangle];
    const double ai = 1 - pt.s, aj = pt.s;  // the point's weights on its particles
    const double wi = wp[pt.i], wj = pt.j == pt.i ? 0.0 : wp[pt.j];
    const double w = ai * ai * wi + aj * aj * wj;
    if (!(w > 0)) continue;
    const Vec3 before = pt.at(x);
    const Vec3 q = c.b[0] * body.x[t[0]] + c.b[1] * body.x[t[1]] + c.b[2] * body.x[t[2]];
    const double C = (before - q).dot(c.n) - s.radius;
    if (C >= 0) continue;  // cleared by an earlier correction
    Vec3 move = -C * c.n;
    if (pt.j != pt.i) {
      // A segment's point moves across the segment (see `across`): over a body's edge the part
      // of the face normal across the segment is the edge-edge contact's normal (edge x
      // segment); on a face it is the normal itself.
      double a;
      move = move_across(c.n, (ps.x[pt.j] - ps.x[pt.i]).normalized(), C, a);
    }
    if (s.friction > 0) {
      // The point's slip against the surface point over the step, tangential part, taken back
      // by at most friction x the normal correction.
      Vec3 q_start = Vec3::Zero();
      for (int a = 0; a < 3; ++a) q_start += c.b[a] * (body.x[t[a]] - dt * body.v[t[a]]);
      const Vec3 slip = (before + move - pt.at(start)) - (q - q_start);
      const Vec3 tangential = slip - slip.dot(c.n) * c.n;
      const double tn = tangential.norm();
      if (tn > 0) move -= std::min(tn, s.friction * -C) * (tangential / tn);
    }
    // Each particle moves by its share; the momentum they gain is move / w in all.
    Vec3 impulse = Vec3::Zero();
    for (const auto& [p, a, wk] : {std::tuple{pt.i, ai, wi}, std::tuple{pt.j, aj, wj}}) {
      if (!(wk > 0) || a == 0) continue;
      const Vec3 dx = (a * wk / w) * move;
      ps.x[p] += dx;
      ps.v[p] += dx * inv_dt;
      impulse += dx * inv_dt / wk;
    }
    for (int a = 0; a < 3; ++a) body_dv[t[a]] -= c.b[a] * m.inv_mass[t[a]] * impulse;
    for (int a = 0; a < 3; ++a)
      if (m.inv_mass[t[a]] > 0) rep.force_on_body -= c.b[a] * impulse * inv_dt;
  }
  for (size_t i = 0; i < body.v.size(); ++i) body.v[i] += body_dv[i];
  return rep;
}

Vec3 take_surface_impulse(const BodyModel& m, BodyState& body, const SurfaceBoundary& surface) {
  if (surface.impulse.size() != body.v.size() || body.v.size() != m.vertex_count())
    throw std::invalid_argument(fmt::format("surface impulse: {} impulses for {} velocities and {} vertices",
                                            surface.impulse.size(), body.v.size(), m.vertex_count()));
  Vec3 taken = Vec3::Zero();
  for (size_t k = 0; k < body.v.size(); ++k)
    if (m.inv_mass[k] > 0) {
      body.v[k] -= m.inv_mass[k] * surface.impulse[k];
      taken += surface.impulse[k];
    }
  return taken;
}

namespace {

// The checks the contacts between two particle bodies share: settings, counts and start positions
// (`body`: the other body's name in the messages).
void check_pair(const ParticleState& ps, std::span<const double> wp, std::span<const Vec3> particle_start,
                const ParticleState& other, std::span<const double> wo, std::span<const Vec3> other_start,
                const std::string& body, const CouplingSettings& s, double dt) {
  if (!(s.radius > 0) || !std::isfinite(s.radius))
    throw std::invalid_argument(fmt::format("contact radius must be > 0, got {}", s.radius));
  if (!(s.friction >= 0) || !std::isfinite(s.friction))
    throw std::invalid_argument(fmt::format("contact friction must be >= 0, got {}", s.friction));
  if (!(dt > 0) || !std::isfinite(dt)) throw std::invalid_argument(fmt::format("contact dt must be > 0, got {}", dt));
  check_particle_counts(ps, wp.size(), "particles");
  check_particle_counts(other, wo.size(), body);
  if (particle_start.size() != ps.x.size())
    throw std::invalid_argument(fmt::format("particle_start has {} positions for {} particles", particle_start.size(),
                                            ps.x.size()));
  if (other_start.size() != other.x.size())
    throw std::invalid_argument(fmt::format("{}_start has {} positions for {} particles", body, other_start.size(),
                                            other.x.size()));
}

// The contact of a point of the first body (a particle, or a point along one of its segments)
// with the point sum_k b_k x_k of `other` (corners idx, inverse masses wo), normal n towards the
// first body, depth -C, the point to go to `target`. Positions: only the first body moves (a
// particle to the target, a segment's point by its two particles' shares of the move, by their
// inverse masses and the point's place, as a position-based constraint on that point does; a
// pinned particle stays); the other body stays where its step put it (moving a light cloth's
// corners by a heavy particle's correction made it spring back through the particles within its
// next step). Velocities: a perfectly inelastic contact between the point (inverse mass w_p, or
// (1-s)^2 w_i + s^2 w_j along a segment) and the other point (inverse mass sum_k b_k^2 w_k), an
// impulse along the normal that leaves them no approaching speed, shared by the corners' weights,
// and Coulomb friction on their tangential speed up to friction x that impulse: momentum is exact,
// and neither side gets more than their relative speed (a heavy particle carries a light cloth
// along, a light one stops on a heavy cloth). Counts the contact in rep (a segment's among
// segment_contacts); nothing when both sides are pinned.
template <size_t N>
void exchange(ParticleState& ps, const Point& pt, std::span<const double> wp, ParticleState& other,
              const std::array<size_t, N>& idx, const std::array<double, N>& b, std::span<const double> wo,
              const Vec3& target, const Vec3& n, double C, double friction, double inv_dt, CouplingReport& rep) {
  const bool segment = pt.j != pt.i;
  const double ai = 1 - pt.s, aj = pt.s;  // the point's weights on its particles
  const double wi = wp[pt.i], wj = segment ? wp[pt.j] : 0.0;
  const double wpoint = segment ? ai * ai * wi + aj * aj * wj : wi;
  double wsum = wpoint;
  for (size_t k = 0; k < N; ++k) wsum += b[k] * b[k] * wo[idx[k]];
  if (!(wsum > 0)) return;  // a pinned particle on pinned corners
  rep.max_depth = std::max(rep.max_depth, -C);
  ++(segment ? rep.segment_contacts : rep.contacts);
  if (!segment) {
    if (wi > 0) ps.x[pt.i] = target;
  } else if (wpoint > 0) {
    const Vec3 move = target - pt.at(ps.x);
    ps.x[pt.i] += (ai * wi / wpoint) * move;
    ps.x[pt.j] += (aj * wj / wpoint) * move;
  }
  auto relative = [&] {
    Vec3 vq = Vec3::Zero();
    for (size_t k = 0; k < N; ++k) vq += b[k] * other.v[idx[k]];
    return Vec3(pt.at(ps.v) - vq);
  };
  auto apply = [&](const Vec3& impulse) {  // on the first body's point, momentum
    if (!segment) {
      ps.v[pt.i] += wi * impulse;
    } else {
      ps.v[pt.i] += (ai * wi) * impulse;
      ps.v[pt.j] += (aj * wj) * impulse;
    }
    for (size_t k = 0; k < N; ++k) other.v[idx[k]] -= wo[idx[k]] * b[k] * impulse;
    rep.force_on_body -= impulse * inv_dt;  // on the other body, its pins included
  };
  const double vn = relative().dot(n);
  if (vn >= 0) return;  // already separating
  const double jn = -vn / wsum;
  apply(jn * n);
  if (friction > 0) {
    const Vec3 vr = relative();
    const Vec3 vt = vr - vr.dot(n) * n;
    const double speed = vt.norm();
    if (speed > 0) apply(-std::min(speed / wsum, friction * jn) * (vt / speed));
  }
}

// The points of the first body that keep the radius from the other: every particle, then the
// inside of every segment at points no farther apart than the radius (at most 64 a segment, as
// against the soft body), so that a rope's link or a cloth's edge does not pass through the other
// body between its two particles. fn(point, start, now) for each whose path is finite; it
// returns whether the point touched. A segment one of whose particles touched is left to its
// particles: where a rope lies in a crumpled cloth, its links' points pushed its beads back
// into the triangles their own contacts had just cleared, and the rope stretched to many times
// its length within a second.
template <class Fn>
void for_each_contact_point(const ParticleState& ps, std::span<const Vec3> start,
                            std::span<const std::array<uint32_t, 2>> segments, double radius, const Fn& fn) {
  std::vector<char> touched(segments.empty() ? 0 : ps.x.size(), 0);
  for (size_t p = 0; p < ps.x.size(); ++p)
    if (ps.x[p].allFinite() && start[p].allFinite()) {
      const bool hit = fn(Point{uint32_t(p), uint32_t(p), 0.0}, start[p], ps.x[p]);
      if (!touched.empty()) touched[p] = hit;
    }
  for (const auto& seg : segments) {
    const uint32_t i = seg[0], j = seg[1];
    if (touched[i] || touched[j]) continue;
    if (!ps.x[i].allFinite() || !ps.x[j].allFinite() || !start[i].allFinite() || !start[j].allFinite()) continue;
    const double length = (ps.x[i] - ps.x[j]).norm();
    if (!(length > 0)) continue;
    for_each_point_inside(i, j, length, radius,
                          [&](const Point& pt) { fn(pt, pt.at(start), pt.at(std::span<const Vec3>(ps.x))); });
  }
}

// A segment's point moves across the segment (move_across, as against the soft body): the
// target `now - C n` becomes now + that move. False when the segment lies within 14 degrees of n,
// or when the move is longer than the segment (a steep link deep through a face near its edge:
// thrown sideways by more than its length, by each of its points in turn, a rope's link was
// flung 2 m in one contact pass); its particles' own contacts are the ones that hold it.
bool across_segment(const ParticleState& ps, const Point& pt, const Vec3& now, const Vec3& n, double C,
                    Vec3& target) {
  if (pt.j == pt.i) return true;
  double a;
  const Vec3 along = ps.x[pt.j] - ps.x[pt.i];
  const Vec3 move = move_across(n, along.normalized(), C, a);
  if (!(a >= kMinAcross) || move.squaredNorm() > along.squaredNorm()) return false;
  target = now + move;
  return true;
}

void check_segments(std::span<const std::array<uint32_t, 2>> segments, size_t particles) {
  for (size_t k = 0; k < segments.size(); ++k)
    if (segments[k][0] >= particles || segments[k][1] >= particles || segments[k][0] == segments[k][1])
      throw std::invalid_argument(fmt::format("segment {} joins particles {} and {} of {}", k, segments[k][0],
                                              segments[k][1], particles));
}

}  // namespace

CouplingReport couple_particles_to_cloth(ParticleState& ps, std::span<const double> wp,
                                         std::span<const Vec3> particle_start, ParticleState& cs,
                                         std::span<const double> wc,
                                         std::span<const std::array<uint32_t, 3>> triangles,
                                         std::span<const Vec3> cloth_start, const CouplingSettings& s, double dt,
                                         std::span<const std::array<uint32_t, 2>> segments) {
  check_pair(ps, wp, particle_start, cs, wc, cloth_start, "cloth", s, dt);
  check_segments(segments, ps.x.size());
  for (const auto& t : triangles)
    if (t[0] >= cs.x.size() || t[1] >= cs.x.size() || t[2] >= cs.x.size())
      throw std::invalid_argument(fmt::format("cloth triangle ({}, {}, {}) is out of range ({} particles)", t[0], t[1],
                                              t[2], cs.x.size()));
  CouplingReport rep;
  if (triangles.empty() || ps.x.empty()) return rep;
  for (const Vec3& x : cs.x)
    if (!x.allFinite()) return rep;  // a blown-up cloth: the caller rolls it back

  // Nothing to do when no particle's path comes within the radius of the cloth's swept box (two
  // bodies apart in the scene: no grid is built); a segment's points lie between its particles.
  Vec3 lo = cs.x[0], hi = cs.x[0];
  for (size_t i = 0; i < cs.x.size(); ++i) {
    lo = lo.cwiseMin(cs.x[i]).cwiseMin(cloth_start[i]);
    hi = hi.cwiseMax(cs.x[i]).cwiseMax(cloth_start[i]);
  }
  lo.array() -= s.radius;
  hi.array() += s.radius;
  auto box_near = [&](const Vec3& plo, const Vec3& phi) {
    return (plo.array() <= hi.array()).all() && (phi.array() >= lo.array()).all();
  };
  bool near_box = false;
  for (size_t p = 0; p < ps.x.size() && !near_box; ++p)
    near_box = box_near(ps.x[p].cwiseMin(particle_start[p]), ps.x[p].cwiseMax(particle_start[p]));
  for (size_t k = 0; k < segments.size() && !near_box; ++k) {
    const uint32_t i = segments[k][0], j = segments[k][1];
    near_box = box_near(ps.x[i].cwiseMin(particle_start[i]).cwiseMin(ps.x[j]).cwiseMin(particle_start[j]),
                        ps.x[i].cwiseMax(particle_start[i]).cwiseMax(ps.x[j]).cwiseMax(particle_start[j]));
  }
  if (!near_box) return rep;
  const TriangleGrid grid(triangles, std::span<const Vec3>(cs.x), s.radius, cloth_start);
  std::vector<int32_t> near;
  const double inv_dt = 1.0 / dt;
  for_each_contact_point(ps, particle_start, segments, s.radius, [&](const Point& pt, const Vec3& start, const Vec3& now) {
    grid.candidates_within(start, now, s.radius, near);
    double deepest = 0;  // C = distance along the contact normal - radius; a contact has C < 0
    int32_t best = -1;
    std::array<double, 3> best_b{};
    Vec3 best_n = Vec3::Zero();
    for (int32_t k : near) {
      const auto& t = triangles[size_t(k)];
      double C;
      Vec3 n;
      std::array<double, 3> bw;
      if (!triangle_contact(start, now, {cloth_start[t[0]], cloth_start[t[1]], cloth_start[t[2]]},
                            {cs.x[t[0]], cs.x[t[1]], cs.x[t[2]]}, s.radius, C, n, bw) ||
          !(C < deepest))
        continue;
      deepest = C;
      best = k;
      best_b = bw;
      best_n = n;
    }
    if (best < 0) return false;
    const auto& t = triangles[size_t(best)];
    // A segment through the cloth near its point at the start of the step as at its end is
    // threaded through it (its particles on either side, each held there by its own contact):
    // pushing its points out would drag the particles through the cloth every step. Left to its
    // particles.
    if (pt.j != pt.i) {
      const Vec3 &a0 = particle_start[pt.i], &b0 = particle_start[pt.j], &a1 = ps.x[pt.i], &b1 = ps.x[pt.j];
      for (int32_t k : near) {
        const auto& q = triangles[size_t(k)];
        if (pierces(a0, b0, cloth_start[q[0]], cloth_start[q[1]], cloth_start[q[2]]) &&
            pierces(a1, b1, cs.x[q[0]], cs.x[q[1]], cs.x[q[2]]))
          return false;
      }
    }
    Vec3 target = now - deepest * best_n;
    if (!across_segment(ps, pt, now, best_n, deepest, target)) return false;
    exchange<3>(ps, pt, wp, cs, {t[0], t[1], t[2]}, best_b, wc, target, best_n, deepest, s.friction, inv_dt, rep);
    return true;
  });
  return rep;
}

namespace {

// The closest point of segment a-b to p, at parameter s in [0, 1].
Vec3 closest_on_segment(const Vec3& p, const Vec3& a, const Vec3& b, double& s) {
  const Vec3 d = b - a;
  const double l2 = d.squaredNorm();
  s = l2 > 0 ? std::clamp((p - a).dot(d) / l2, 0.0, 1.0) : 0.0;
  return a + s * d;
}

}  // namespace

CouplingReport couple_particles_to_rope(ParticleState& ps, std::span<const double> wp,
                                        std::span<const Vec3> particle_start, ParticleState& rs,
                                        std::span<const double> wr, std::span<const Vec3> rope_start,
                                        const CouplingSettings& s, double dt,
                                        std::span<const std::array<uint32_t, 2>> segments) {
  check_pair(ps, wp, particle_start, rs, wr, rope_start, "rope", s, dt);
  check_segments(segments, ps.x.size());
  CouplingReport rep;
  if (rs.x.size() < 2 || ps.x.empty()) return rep;
  for (size_t i = 0; i < rs.x.size(); ++i)
    if (!rs.x[i].allFinite() || !rope_start[i].allFinite()) return rep;  // a blown-up rope: the caller rolls it back
  // The segments as degenerate triangles (k, k+1, k+1), binned by their swept boxes.
  std::vector<std::array<uint32_t, 3>> links(rs.x.size() - 1);
  for (size_t k = 0; k + 1 < rs.x.size(); ++k) links[k] = {uint32_t(k), uint32_t(k + 1), uint32_t(k + 1)};
  const TriangleGrid grid(links, std::span<const Vec3>(rs.x), s.radius, rope_start);
  std::vector<int32_t> near;
  const double inv_dt = 1.0 / dt;
  for_each_contact_point(ps, particle_start, segments, s.radius, [&](const Point& pt, const Vec3& start, const Vec3& xp) {
    grid.candidates_within(start, xp, s.radius, near);
    double deepest = 0;  // C = distance along the contact normal - radius; a contact has C < 0
    int32_t best = -1;
    double best_s = 0;
    Vec3 best_n = Vec3::Zero(), best_q = Vec3::Zero();
    for (int32_t k : near) {
      const Vec3 &a = rs.x[size_t(k)], &b = rs.x[size_t(k) + 1];
      const Vec3 &sa = rope_start[size_t(k)], &sb = rope_start[size_t(k) + 1];
      double s1;
      const Vec3 q1 = closest_on_segment(xp, a, b, s1);
      // The point's offset from the segment's point s1 at the start and at the end; both
      // moving linearly, the offset goes from r0 to r1.
      const Vec3 r1 = xp - q1, r0 = start - (sa + s1 * (sb - sa));
      Vec3 n;
      if (r0.norm() >= s.radius) {
        // Started clear: a contact if the offset came within the radius during the step; the
        // normal is the offset's direction when it first did (from the side it came from, so a
        // fast particle does not pass through, nor is it pushed out on the far side).
        const Vec3 dr = r1 - r0;
        const double A = dr.squaredNorm(), B = r0.dot(dr), Cq = r0.squaredNorm() - s.radius * s.radius;
        const double disc = B * B - A * Cq;
        if (!(A > 0) || disc < 0) continue;
        const double tau = (-B - std::sqrt(disc)) / A;
        if (tau < 0 || tau > 1) continue;
        n = (r0 + tau * dr).normalized();
      } else {
        // Started within it (resting on the rope): apart along the end offset, or along the
        // start's when the offset turned around.
        const Vec3 base = r1.dot(r0) >= 0 && r1.norm() > 1e-12 * s.radius ? r1 : r0;
        if (!(base.squaredNorm() > 0)) continue;
        n = base.normalized();
      }
      // Along the side of the capsule the normal is across the segment (its point is the closest
      // one); only at an end cap may it lean along it.
      if (s1 > 0 && s1 < 1) {
        const Vec3 axis = (b - a).normalized();
        const Vec3 across = n - n.dot(axis) * axis;
        if (!(across.squaredNorm() > 1e-24)) continue;
        n = across.normalized();
      }
      const double C = r1.dot(n) - s.radius;
      if (C < deepest) {
        deepest = C;
        best = k;
        best_s = s1;
        best_n = n;
        best_q = q1;
      }
    }
    if (best < 0) return false;
    // As against a cloth, at the radius where it first touched: a particle that hit the rope off
    // its top keeps its tangential speed and slides around it in the next steps.
    Vec3 target = best_q + s.radius * best_n;
    if (!across_segment(ps, pt, xp, best_n, deepest, target)) return false;
    const size_t ia = size_t(best);
    exchange<2>(ps, pt, wp, rs, {ia, ia + 1}, {1 - best_s, best_s}, wr, target, best_n, deepest, s.friction, inv_dt,
                rep);
    return true;
  });
  return rep;
}

size_t couple_particles_to_tool(ParticleState& ps, std::span<const double> wp, const RigidTool& tool, double radius,
                                double dt, std::span<const Vec3> particle_start, ToolReaction& reaction) {
  if (wp.size() != ps.x.size() || ps.v.size() != ps.x.size())
    throw std::invalid_argument(fmt::format("particles: {} positions, {} velocities and {} inverse masses differ",
                                            ps.x.size(), ps.v.size(), wp.size()));
  if (!particle_start.empty() && particle_start.size() != ps.x.size())
    throw std::invalid_argument(fmt::format("particle_start has {} positions for {} particles", particle_start.size(),
                                            ps.x.size()));
  if (!(dt > 0) || !std::isfinite(dt)) throw std::invalid_argument(fmt::format("dt must be > 0 s, got {}", dt));
  if (!(radius >= 0) || !std::isfinite(radius))
    throw std::invalid_argument(fmt::format("radius must be >= 0 m, got {}", radius));
  RigidTool grown = tool;
  grown.radius += radius;
  const double inv_dt = 1.0 / dt;
  size_t pushed = 0;
  Vec3 impulse_sum = Vec3::Zero(), angular_sum = Vec3::Zero();
  for (size_t i = 0; i < ps.x.size(); ++i) {
    if (!(wp[i] > 0)) continue;
    Vec3& xp = ps.x[i];
    if (!xp.allFinite()) continue;  // a blown-up particle is the caller's to report
    Vec3 q, n;
    double depth;
    if (!tool_contact(grown, xp, q, n, depth) || !(depth > 0)) continue;
    const Vec3 before = xp;
    xp += depth * n;
    const Vec3 start = particle_start.empty() ? Vec3(before - dt * ps.v[i]) : particle_start[i];
    const Vec3 slip = (xp - start) - tool.motion(xp, dt);
    const Vec3 tangential = slip - slip.dot(n) * n;
    const double tn = tangential.norm();
    if (tn < tool.static_friction * depth) xp -= tangential;
    else if (tn > 0) xp -= tangential * std::min(tool.dynamic_friction * depth / tn, 1.0);
    const Vec3 dv = (xp - before) * inv_dt;
    ps.v[i] += dv;
    const Vec3 impulse = dv / wp[i];  // the particle's momentum change
    impulse_sum += impulse;
    angular_sum += (xp - tool.position).cross(impulse);
    ++pushed;
  }
  reaction.force -= impulse_sum * inv_dt;
  reaction.torque -= angular_sum * inv_dt;
  return pushed;
}

CouplingReport step_with_cloth_contact(ParticleBody& particles, ParticleBody& cloth, const CouplingSettings& settings,
                                       double dt, std::span<const Collider> colliders, int parts) {
  const int substeps[] = {particles.substeps(), cloth.substeps()};
  const int k = parts > 0 ? parts : shared_step_parts(substeps);
  for (int n : substeps)
    if (k < 1 || n % k != 0)
      throw std::invalid_argument(fmt::format("step_with_cloth_contact: parts {} does not divide the bodies' substeps ({} and {})",
                                              parts, substeps[0], substeps[1]));
  CouplingReport total;
  for (int part = 0; part < k; ++part) {
    const std::vector<Vec3> particle_start = particles.state().x, cloth_start = cloth.state().x;
    particles.advance(dt / k, particles.substeps() / k, colliders, part + 1 == k);
    cloth.advance(dt / k, cloth.substeps() / k, colliders, part + 1 == k);
    ParticleState ps = particles.state(), cs = cloth.state();
    const CouplingReport r = couple_particles_to_cloth(ps, particles.inverse_masses(), particle_start, cs,
                                                       cloth.inverse_masses(), cloth.triangles(), cloth_start,
                                                       settings, dt / k, particles.segments());
    particles.set_state(ps);
    cloth.set_state(cs);
    total.contacts += r.contacts;
    total.segment_contacts += r.segment_contacts;
    total.max_depth = std::max(total.max_depth, r.max_depth);
    total.force_on_body += r.force_on_body / k;
  }
  return total;
}

}  // namespace pliant
