// SPDX-License-Identifier: Apache-2.0
#include "particles/surface_contact.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace pliant::detail {

double entering_fraction(const Vec3& a, const Vec3& b, const Vec3& p0, const Vec3& p1, const Vec3& p2,
                         std::array<double, 3>& bary) {
  const Vec3 e1 = p1 - p0, e2 = p2 - p0, d = b - a;
  const Vec3 n = e1.cross(e2);
  if (!(d.dot(n) < 0)) return -1;  // parallel, or leaving through the back
  const Vec3 pv = d.cross(e2);
  const double det = e1.dot(pv);
  if (std::abs(det) < 1e-300) return -1;
  const Vec3 tv = a - p0;
  const double u = tv.dot(pv) / det;
  if (u < 0 || u > 1) return -1;
  const Vec3 qv = tv.cross(e1);
  const double v = d.dot(qv) / det;
  if (v < 0 || u + v > 1) return -1;
  const double t = e2.dot(qv) / det;
  if (t < 0 || t > 1) return -1;
  bary = {1 - u - v, u, v};
  return t;
}

bool closest_face(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                  std::span<const int32_t> candidates, const Vec3& p, FaceHit& out, double& distance) {
  distance = INFINITY;
  for (int32_t k : candidates) {
    if (grid.box_distance2(k, p) > distance * distance * (1 + 1e-9)) continue;  // (rounding)
    const Triangle& t = tris[size_t(k)];
    std::array<double, 3> b;
    const double d = (p - closest_point_on_triangle(p, x[t[0]], x[t[1]], x[t[2]], b)).norm();
    if (d < distance) {
      distance = d;
      out = FaceHit{k, b, Vec3::Zero()};
    }
  }
  return distance < INFINITY;
}

Vec3 outward_at(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                std::span<const int32_t> candidates, const Vec3& p, const FaceHit& hit, double distance) {
  const Triangle& th = tris[size_t(hit.triangle)];
  if (hit.b[0] != 0 && hit.b[1] != 0 && hit.b[2] != 0) {  // inside the face: its own normal
    const Vec3 face = (x[th[1]] - x[th[0]]).cross(x[th[2]] - x[th[0]]);
    return face.squaredNorm() > 0 ? Vec3(face.normalized()) : Vec3::Zero();
  }
  const Vec3 q = hit.b[0] * x[th[0]] + hit.b[1] * x[th[1]] + hit.b[2] * x[th[2]];
  // The faces that reach q: as close to p as the closest (rounding aside), their closest point q.
  const double reach = distance * (1 + 1e-9) + 1e-12 * (std::abs(q[0]) + std::abs(q[1]) + std::abs(q[2]));
  Vec3 sum = Vec3::Zero();
  for (int32_t k : candidates) {
    if (grid.box_distance2(k, p) > reach * reach) continue;
    const Triangle& t = tris[size_t(k)];
    std::array<double, 3> b;
    const Vec3 qk = closest_point_on_triangle(p, x[t[0]], x[t[1]], x[t[2]], b);
    if ((p - qk).norm() > reach) continue;
    const Vec3 face = (x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]);
    if (!(face.squaredNorm() > 0)) continue;
    const int zeros = (b[0] == 0) + (b[1] == 0) + (b[2] == 0);
    double weight = 2 * M_PI;  // inside the face
    if (zeros == 1) {
      weight = M_PI;  // on an edge: half of the turn around it
    } else if (zeros == 2) {  // at a corner: the face's angle there
      const int c = b[0] != 0 ? 0 : (b[1] != 0 ? 1 : 2);
      const Vec3 u = x[t[(c + 1) % 3]] - x[t[c]], v = x[t[(c + 2) % 3]] - x[t[c]];
      weight = std::atan2(u.cross(v).norm(), u.dot(v));
    }
    sum += weight * face.normalized();
  }
  return sum.squaredNorm() > 0 ? Vec3(sum.normalized()) : Vec3::Zero();
}

bool particle_contact(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                      const Vec3& start, const Vec3& now, double radius, std::vector<int32_t>& swept, FaceHit& out,
                      double& depth) {
  auto at = [&](const FaceHit& h) {
    const Triangle& t = tris[size_t(h.triangle)];
    return Vec3(h.b[0] * x[t[0]] + h.b[1] * x[t[1]] + h.b[2] * x[t[2]]);
  };
  auto face_normal = [&](const FaceHit& h) {
    const Triangle& t = tris[size_t(h.triangle)];
    return Vec3((x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]));
  };
  if (start.allFinite()) grid.near_segment(start, now, 4096, swept);
  else swept.clear();
  if (first_entered(tris, x, grid, swept, start, now, [](const Vec3&) { return false; }, out)) {
    out.n = face_normal(out).normalized();
    depth = radius - (now - at(out)).dot(out.n);
    return true;
  }
  double distance;
  if (!closest_face(tris, x, grid, grid.near(now), now, out, distance)) return false;
  const Vec3 face = face_normal(out);
  if (!(face.squaredNorm() > 0)) return false;
  const Vec3 outward = face.normalized();
  const Vec3 d = now - at(out);
  const double side = d.dot(outward_at(tris, x, grid, grid.near(now), now, out, distance)), dn = d.norm();
  if (side >= 0 && dn >= radius) return false;  // outside and clear
  // Outside: apart along the line to the closest point (the face normal when on it); inside:
  // back out through the closest face.
  out.n = side >= 0 && dn > 1e-12 * radius ? Vec3(d / dn) : outward;
  depth = radius - d.dot(out.n);
  return true;
}

namespace {

// The box of the finite particles grown by `reach` (an empty box when none is finite).
std::pair<Vec3, Vec3> reach_box(std::span<const Vec3> particles, double reach) {
  std::pair<Vec3, Vec3> box{Vec3::Constant(INFINITY), Vec3::Constant(-INFINITY)};
  for (const Vec3& p : particles) {
    if (!p.allFinite()) continue;
    box.first = box.first.cwiseMin(p);
    box.second = box.second.cwiseMax(p);
  }
  box.first.array() -= reach;
  box.second.array() += reach;
  return box;
}

SurfaceBoundary& checked(SurfaceBoundary& s) {
  if (!(s.radius > 0) || !std::isfinite(s.radius))
    throw std::invalid_argument(fmt::format("surface boundary radius must be > 0, got {}", s.radius));
  if (!(s.friction >= 0) || !std::isfinite(s.friction))
    throw std::invalid_argument(fmt::format("surface boundary friction must be >= 0, got {}", s.friction));
  if (s.v.size() != s.x.size())
    throw std::invalid_argument(
        fmt::format("surface boundary: {} velocities for {} positions", s.v.size(), s.x.size()));
  for (size_t k = 0; k < s.triangles.size(); ++k)
    for (int32_t i : s.triangles[k])
      if (i < 0 || size_t(i) >= s.x.size())
        throw std::invalid_argument(
            fmt::format("surface boundary: triangle {} names vertex {} of {}", k, i, s.x.size()));
  s.impulse.assign(s.x.size(), Vec3::Zero());
  return s;
}

}  // namespace

SurfaceMeeting::SurfaceMeeting(SurfaceBoundary& boundary, std::span<const Vec3> particles, double reach,
                               double support)
    : boundary_(checked(boundary)),
      support_(std::max(support, boundary_.radius)),
      region_(reach_box(particles, reach)),
      grid_(boundary_.triangles, boundary_.x, support_, {}, &region_) {}

bool SurfaceMeeting::closest(const Vec3& p, FaceHit& hit, double& distance) const {
  if (!p.allFinite() || !closest_face(boundary_.triangles, boundary_.x, grid_, grid_.near(p), p, hit, distance) ||
      !(distance < support_))
    return false;
  const Triangle& t = boundary_.triangles[size_t(hit.triangle)];
  const std::span<const Vec3> x = boundary_.x;
  const Vec3 face = (x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]);
  if (!(face.squaredNorm() > 0)) return false;
  const Vec3 outward = face.normalized();
  const Vec3 d = p - (hit.b[0] * x[t[0]] + hit.b[1] * x[t[1]] + hit.b[2] * x[t[2]]);
  if (d.dot(outward_at(boundary_.triangles, x, grid_, grid_.near(p), p, hit, distance)) < 0) {
    distance = 0.0;  // inside: the whole half-space beyond
    hit.n = outward;
  } else {
    hit.n = distance > 1e-12 * support_ ? Vec3(d / distance) : outward;
  }
  return true;
}

double SurfaceMeeting::push(const Vec3& from, Vec3& p, FaceHit& hit) const {
  if (!p.allFinite()) return 0.0;
  thread_local std::vector<int32_t> swept;
  // A path within the radius ends within the radius of any face it entered: the closest face
  // is found from its end alone (the path's search costs several cells).
  const Vec3 start = (p - from).squaredNorm() > boundary_.radius * boundary_.radius ? from : Vec3::Constant(NAN);
  double depth = 0.0;
  if (!particle_contact(boundary_.triangles, boundary_.x, grid_, start, p, boundary_.radius, swept, hit, depth) ||
      !(depth > 0))
    return 0.0;
  p += depth * hit.n;
  return depth;
}

Vec3 SurfaceMeeting::velocity(const FaceHit& hit) const {
  const Triangle& t = boundary_.triangles[size_t(hit.triangle)];
  return hit.b[0] * boundary_.v[t[0]] + hit.b[1] * boundary_.v[t[1]] + hit.b[2] * boundary_.v[t[2]];
}

void SurfaceMeeting::give(const FaceHit& hit, const Vec3& momentum) {
  const Triangle& t = boundary_.triangles[size_t(hit.triangle)];
  for (int a = 0; a < 3; ++a) boundary_.impulse[t[a]] += hit.b[a] * momentum;
}

}  // namespace pliant::detail
