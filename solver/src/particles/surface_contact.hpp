// SPDX-License-Identifier: Apache-2.0
// A point against a closed triangle surface (the soft body's, outward triangles): the face its
// path entered first, else the closest face. Shared by the contact after a particle body's step
// (couple_particles_to_body) and the surface a particle body meets inside its own substeps
// (SurfaceBoundary, held in place over the call).
#pragma once

#include "pliant/interaction.hpp"
#include "pliant/mesh.hpp"
#include "pliant/particle_body.hpp"
#include "particles/triangle_grid.hpp"

#include <array>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

namespace pliant::detail {

// Where segment a -> b enters triangle (p0, p1, p2) from its front (outward) side: the fraction
// along the segment, or -1.
double entering_fraction(const Vec3& a, const Vec3& b, const Vec3& p0, const Vec3& p1, const Vec3& p2,
                         std::array<double, 3>& bary);

// A point of a surface face: the triangle, the barycentric weights, the normal from the surface
// towards where the point belongs.
struct FaceHit {
  int32_t triangle = -1;
  std::array<double, 3> b{};
  Vec3 n = Vec3::Zero();
};

// The face among `candidates` (of `grid`, whose boxes rule out the faces the path's box misses)
// that the path start -> now entered first from outside, skipping those `skip(unit face normal)`
// rejects; false when none. out.n is left for the caller.
template <class Skip>
bool first_entered(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                   std::span<const int32_t> candidates, const Vec3& start, const Vec3& now, const Skip& skip,
                   FaceHit& out) {
  double first = INFINITY;
  const Vec3 lo = start.cwiseMin(now).array() - 1e-9, hi = start.cwiseMax(now).array() + 1e-9;  // rounding
  for (int32_t k : candidates) {
    const auto& [blo, bhi] = grid.box(k);
    if ((blo.array() > hi.array()).any() || (bhi.array() < lo.array()).any()) continue;
    const Triangle& t = tris[size_t(k)];
    std::array<double, 3> b;
    const double f = entering_fraction(start, now, x[t[0]], x[t[1]], x[t[2]], b);
    if (f >= 0 && f < first) {
      if (skip(Vec3((x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]).normalized()))) continue;
      first = f;
      out = FaceHit{k, b, Vec3::Zero()};
    }
  }
  return first < INFINITY;
}

// The face among `candidates` (of `grid`, whose boxes rule out the faces farther than the best so
// far) closest to p (the first of equals), its distance in `distance`; false when there is none.
bool closest_face(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                  std::span<const int32_t> candidates, const Vec3& p, FaceHit& out, double& distance);

// The surface's outward direction at the point of `hit` (closest_face's answer for p, at
// `distance`): the angle-weighted pseudo-normal of the faces as close to p as it (the face's
// normal inside a face, both faces' along an edge, each face's by its angle at a corner), whose
// side of p tells inside from outside wherever the closest point lies. One face's normal does
// not: beside an edge sharper than a right angle (a sagging beam's top meeting its clamped end),
// a point outside can lie behind the plane of one of the two faces, and when that face came
// first among the equally close ones the point read inside and was thrown the radius through
// it. Zero for a degenerate surface there.
Vec3 outward_at(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                std::span<const int32_t> candidates, const Vec3& p, const FaceHit& hit, double distance);

// A particle's contact with the surface after it moved from `start` (not finite: no path) to
// `now`: back out through the face its path entered first (however deep it got: the closest face
// of a thin body may be the far one), else away from the closest face when within `radius` of it
// or inside (out through it). out.n points where the particle belongs; depth is how far along it
// the particle must go to stand `radius` off. `swept`: scratch for the path's candidates.
bool particle_contact(std::span<const Triangle> tris, std::span<const Vec3> x, const TriangleGrid& grid,
                      const Vec3& start, const Vec3& now, double radius, std::vector<int32_t>& swept, FaceHit& out,
                      double& depth);

// The soft body's surface held in place over a particle body's call, met inside its substeps:
// the boundary's checks, a grid over the triangles near the particles, and the push of one point.
class SurfaceMeeting {
 public:
  // Checks the boundary (std::invalid_argument naming the field), sizes its impulses to zero and
  // bins the triangles that a point within `reach` of the particles' box can meet, for pushes
  // and for closest() up to `support` (at least the boundary's radius).
  SurfaceMeeting(SurfaceBoundary& boundary, std::span<const Vec3> particles, double reach, double support);

  // Moves p (which came from `from` over the substep) to the boundary's radius outside the
  // surface; returns how far it moved along hit.n (0: no contact). Safe from several threads.
  double push(const Vec3& from, Vec3& p, FaceHit& hit) const;
  // The face closest to p if within the support: its distance (0 inside the body) and hit.n, the
  // direction from the surface towards p (the outward face normal on it or inside).
  bool closest(const Vec3& p, FaceHit& hit, double& distance) const;
  // The surface's velocity at a hit.
  Vec3 velocity(const FaceHit& hit) const;
  // Adds the momentum a particle gained from the surface at `hit` to the corners' impulses.
  void give(const FaceHit& hit, const Vec3& momentum);
  double friction() const { return boundary_.friction; }

 private:
  SurfaceBoundary& boundary_;
  double support_;
  std::pair<Vec3, Vec3> region_;
  TriangleGrid grid_;
};

}  // namespace pliant::detail
