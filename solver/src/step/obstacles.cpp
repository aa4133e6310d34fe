// SPDX-License-Identifier: Apache-2.0
#include "step/obstacles.hpp"

#include "pliant/interaction.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

namespace pliant::detail {

void ObstacleContacts::begin_step(const BodyModel& m, const std::vector<Vec3>& x_step_start,
                                  const std::vector<TriangleObstacle>& obstacles) {
  obstacles_.clear();
  grids_.clear();
  boxes_.clear();
  impulses_.assign(obstacles.size(), {});
  if (obstacles.empty()) return;
  for (size_t o = 0; o < obstacles.size(); ++o) {
    const TriangleObstacle& ob = obstacles[o];
    const std::string f = "obstacles[" + std::to_string(o) + "]";
    if (!(ob.radius > 0) || !std::isfinite(ob.radius))
      throw std::invalid_argument(f + ".radius must be > 0, got " + std::to_string(ob.radius));
    if (!(ob.friction >= 0) || !std::isfinite(ob.friction))
      throw std::invalid_argument(f + ".friction must be >= 0, got " + std::to_string(ob.friction));
    for (const Vec3& p : ob.x)
      if (!p.allFinite()) throw std::invalid_argument(f + ".x holds a non-finite position");
    for (const auto& t : ob.triangles)
      if (t[0] >= ob.x.size() || t[1] >= ob.x.size() || t[2] >= ob.x.size())
        throw std::invalid_argument(f + ".triangles index a corner beyond its " + std::to_string(ob.x.size()));
  }
  if (model_id_ != m.id || surface_.empty()) {
    model_id_ = m.id;
    std::vector<uint8_t> on(m.vertex_count(), 0);
    surface_.clear();
    for (const Triangle& t : m.surface)
      for (int32_t v : t)
        if (!on[size_t(v)]) {
          on[size_t(v)] = 1;
          surface_.push_back(v);
        }
  }
  step_start_.resize(surface_.size());
  for (size_t k = 0; k < surface_.size(); ++k) step_start_[k] = x_step_start[size_t(surface_[k])];
  for (size_t o = 0; o < obstacles.size(); ++o) {
    impulses_[o].assign(obstacles[o].x.size(), Vec3::Zero());
    obstacles_.push_back(&obstacles[o]);
    Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
    for (const Vec3& p : obstacles[o].x) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    boxes_.emplace_back(lo - Vec3::Constant(obstacles[o].radius), hi + Vec3::Constant(obstacles[o].radius));
    grids_.push_back(std::make_unique<TriangleGrid>(obstacles[o].triangles, std::span<const Vec3>(obstacles[o].x),
                                                    obstacles[o].radius));
  }
}

int ObstacleContacts::resolve(const BodyModel& m, std::vector<Vec3>& x, const std::vector<Vec3>& x_substep_start,
                              double h) {
  int contacts = 0;
  std::vector<int32_t> near;
  for (size_t o = 0; o < obstacles_.size(); ++o) {
    const TriangleObstacle& ob = *obstacles_[o];
    const TriangleGrid& grid = *grids_[o];
    const double r = ob.radius;
    for (size_t k = 0; k < surface_.size(); ++k) {
      const size_t v = size_t(surface_[k]);
      if (!(m.inv_mass[v] > 0)) continue;
      Vec3& xv = x[v];
      const Vec3& start = step_start_[k];
      if (!xv.allFinite()) continue;
      // Most vertices of a large body are nowhere near the cloth: its box first.
      if ((start.cwiseMax(xv).array() < boxes_[o].first.array()).any() ||
          (start.cwiseMin(xv).array() > boxes_[o].second.array()).any())
        continue;
      grid.near_segment(start, xv, 4096, near);
      if (near.empty()) {
        const auto cell = grid.near(xv);
        near.assign(cell.begin(), cell.end());
      }
      double deepest = 0;
      int32_t best = -1;
      std::array<double, 3> best_b{};
      Vec3 best_n = Vec3::Zero();
      for (int32_t t : near) {
        const auto& tri = ob.triangles[size_t(t)];
        const Vec3 &a = ob.x[tri[0]], &b = ob.x[tri[1]], &c = ob.x[tri[2]];
        const Vec3 face = (b - a).cross(c - a);
        if (!(face.squaredNorm() > 0)) continue;
        const Vec3 nf = face.normalized();
        // The vertex's side: where it started the step (the triangles do not move during it).
        std::array<double, 3> bs;
        const Vec3 qs = closest_point_on_triangle(start, a, b, c, bs);
        const Vec3 n_side = (start - qs).dot(nf) < 0 ? Vec3(-nf) : nf;
        std::array<double, 3> bw;
        const Vec3 q = closest_point_on_triangle(xv, a, b, c, bw);
        const Vec3 d = xv - q;
        const double along = d.dot(n_side);
        Vec3 n = n_side;
        double C;
        if (along >= 0) {
          const double len = d.norm();
          if (len >= r) continue;
          if (len > 1e-12 * r) n = d / len;
          C = len - r;
        } else {
          // Behind the plane: a contact only if the vertex's path since the step's start went
          // through this triangle (within the radius), else it is behind another part of it.
          const double s0 = (start - a).dot(n_side), s1 = along;
          if (!(s0 > 0) || s0 == s1) continue;
          const Vec3 pc = start + (s0 / (s0 - s1)) * (xv - start);
          std::array<double, 3> bc;
          if ((pc - closest_point_on_triangle(pc, a, b, c, bc)).norm() > r) continue;
          C = along - r;
        }
        if (C < deepest) {
          deepest = C;
          best = t;
          best_b = bw;
          best_n = n;
        }
      }
      if (best < 0) continue;
      ++contacts;
      const Vec3 before = xv;
      xv -= deepest * best_n;
      // Friction against the motion since the substep's start, across the normal: held while
      // it is below friction x the push, else shortened by that much.
      if (ob.friction > 0) {
        const Vec3 moved = xv - x_substep_start[v];
        const Vec3 slip = moved - moved.dot(best_n) * best_n;
        const double limit = ob.friction * (-deepest), len = slip.norm();
        if (len <= limit) xv -= slip;
        else if (len > 0) xv -= slip * (limit / len);
      }
      // The momentum this correction gives the body over the substep comes from the corners.
      const Vec3 impulse = (xv - before) / (m.inv_mass[v] * h);
      const auto& tri = ob.triangles[size_t(best)];
      for (int a = 0; a < 3; ++a) impulses_[o][tri[a]] -= best_b[a] * impulse;
    }
  }
  return contacts;
}

void ObstacleContacts::finish(StepReport& report) {
  if (!impulses_.empty()) report.obstacle_impulses = std::move(impulses_);
  impulses_.clear();
  obstacles_.clear();
  grids_.clear();
  boxes_.clear();
}

}  // namespace pliant::detail
