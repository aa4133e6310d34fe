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
    grids_.emplace_back(obstacles[o].triangles, std::span<const Vec3>(obstacles[o].x), obstacles[o].radius);
  }
}

int ObstacleContacts::resolve(const BodyModel& m, std::vector<Vec3>& x, const std::vector<Vec3>& x_substep_start,
                              double h) {
  int contacts = 0;
  for (size_t o = 0; o < obstacles_.size(); ++o) {
    const TriangleObstacle& ob = *obstacles_[o];
    const TriangleGrid& grid = grids_[o];
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
      grid.candidates(start, xv, near_);
      double deepest = 0;
      int32_t best = -1;
      std::array<double, 3> best_b{};
      Vec3 best_n = Vec3::Zero();
      for (int32_t t : near_) {
        const auto& tri = ob.triangles[size_t(t)];
        const std::array<Vec3, 3> corners{ob.x[tri[0]], ob.x[tri[1]], ob.x[tri[2]]};
        double C;
        Vec3 n;
        std::array<double, 3> bw;
        // The triangles do not move during the body's step: the same corners at both ends.
        if (!triangle_contact(start, xv, corners, corners, r, C, n, bw) || !(C < deepest)) continue;
        deepest = C;
        best = t;
        best_b = bw;
        best_n = n;
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
