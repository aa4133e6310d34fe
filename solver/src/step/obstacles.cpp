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
    if (!ob.inverse_mass.empty() && ob.inverse_mass.size() != ob.x.size())
      throw std::invalid_argument(f + ".inverse_mass has " + std::to_string(ob.inverse_mass.size()) +
                                  " values for " + std::to_string(ob.x.size()) + " corners");
    for (double w : ob.inverse_mass)
      if (!(w >= 0) || !std::isfinite(w))
        throw std::invalid_argument(f + ".inverse_mass must be finite and >= 0, got " + std::to_string(w));
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

bool ObstacleContacts::deepest(size_t o, size_t k, const Vec3& x, Hit& hit) const {
  const TriangleObstacle& ob = *obstacles_[o];
  const Vec3& start = step_start_[k];
  if (!x.allFinite()) return false;
  // Most vertices of a large body are nowhere near the cloth: its box first.
  if ((start.cwiseMax(x).array() < boxes_[o].first.array()).any() ||
      (start.cwiseMin(x).array() > boxes_[o].second.array()).any())
    return false;
  grids_[o].candidates(start, x, near_);
  hit = Hit{};
  for (int32_t t : near_) {
    const auto& tri = ob.triangles[size_t(t)];
    const std::array<Vec3, 3> corners{ob.x[tri[0]], ob.x[tri[1]], ob.x[tri[2]]};
    double C;
    Vec3 n;
    std::array<double, 3> bw;
    // The triangles do not move during the body's step: the same corners at both ends.
    if (!triangle_contact(start, x, corners, corners, ob.radius, C, n, bw) || !(C < hit.C)) continue;
    hit = Hit{t, C, n, bw};
  }
  return hit.triangle >= 0;
}

double ObstacleContacts::inverse_mass_at(size_t o, const Hit& hit) const {
  const std::vector<double>& w = obstacles_[o]->inverse_mass;
  if (w.empty()) return 0.0;
  const auto& tri = obstacles_[o]->triangles[size_t(hit.triangle)];
  return hit.b[0] * hit.b[0] * w[tri[0]] + hit.b[1] * hit.b[1] * w[tri[1]] + hit.b[2] * hit.b[2] * w[tri[2]];
}

void ObstacleContacts::add_impulse(size_t o, const Hit& hit, const Vec3& impulse_on_body) {
  const auto& tri = obstacles_[o]->triangles[size_t(hit.triangle)];
  for (int a = 0; a < 3; ++a) impulses_[o][tri[a]] -= hit.b[a] * impulse_on_body;
}

int ObstacleContacts::resolve(const BodyModel& m, std::vector<Vec3>& x, const std::vector<Vec3>& x_substep_start,
                              double h) {
  int contacts = 0;
  // for_each_hit reads x[v] just before handing its hit over, so a vertex pushed out by one
  // obstacle meets the next where the first left it.
  for_each_hit(m, x, [&](size_t o, int32_t vi, const Hit& hit) {
    const size_t v = size_t(vi);
    Vec3& xv = x[v];
    ++contacts;
    const Vec3 before = xv;
    Vec3 out = xv - hit.C * hit.n;
    // Friction against the motion since the substep's start, across the normal: held while it
    // is below friction x the push, else shortened by that much.
    if (const double mu = friction(o); mu > 0) {
      const Vec3 moved = out - x_substep_start[v];
      const Vec3 slip = moved - moved.dot(hit.n) * hit.n;
      const double limit = mu * (-hit.C), len = slip.norm();
      if (len <= limit) out -= slip;
      else if (len > 0) out -= slip * (limit / len);
    }
    // The vertex's share of that move against a triangle that moves too (all of it against a
    // fixed one); the momentum it gives the body over the substep comes from the corners.
    const double wv = m.inv_mass[v], wt = inverse_mass_at(o, hit);
    xv = wt > 0 ? before + (wv / (wv + wt)) * (out - before) : out;
    add_impulse(o, hit, (xv - before) / (wv * h));
  });
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
