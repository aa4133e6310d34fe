// SPDX-License-Identifier: Apache-2.0
// The body's surface vertices against the step's triangle obstacles (StepInputs::obstacles, a
// cloth's triangles): a stage of the iterations, like the static colliders, shared by the
// solver families that project contacts at position level (xpbd and vbd); newton asks it for
// the contacts and makes them a penalty energy.
#pragma once

#include "pliant/model.hpp"
#include "pliant/stepper.hpp"
#include "particles/triangle_grid.hpp"

#include <array>
#include <vector>

namespace pliant::detail {

class ObstacleContacts {
 public:
  // Before the step's first substep: the surface vertices, where they start the step (their
  // side of each triangle), and a grid over each obstacle. No obstacles: the stage does nothing.
  void begin_step(const BodyModel& model, const std::vector<Vec3>& x_step_start,
                  const std::vector<TriangleObstacle>& obstacles);
  // In an iteration: every free surface vertex too close to a triangle (or behind it, having
  // crossed it during the step) goes out to the radius on its side, with friction against its
  // motion since x_substep_start, or its share of that move by the inverse masses when the
  // obstacle has them; the momentum that gives the body over the substep (h) is taken from the
  // triangle's corners. Returns the vertices in contact.
  int resolve(const BodyModel& model, std::vector<Vec3>& x, const std::vector<Vec3>& x_substep_start, double h);
  // After the step: the impulse on each corner of each obstacle, N s; the stage is then idle
  // until the next begin_step.
  void finish(StepReport& report);
  bool active() const { return !obstacles_.empty(); }

  // The deepest contact of surface vertex k at x with obstacle o, if it has one (resolve()
  // projects it; newton makes it a penalty energy).
  struct Hit {
    int32_t triangle = -1;
    double C = 0;                  // < 0: the distance along n less the radius
    Vec3 n = Vec3::Zero();         // towards the side the vertex started the step on
    std::array<double, 3> b{};     // barycentric weights of the closest point
  };
  double friction(size_t o) const { return obstacles_[o]->friction; }
  bool deepest(size_t o, size_t k, const Vec3& x, Hit& hit) const;
  // fn(o, v, hit) for every free surface vertex v of x in contact with obstacle o.
  template <class Fn>
  void for_each_hit(const BodyModel& m, const std::vector<Vec3>& x, Fn&& fn) const {
    Hit hit;
    for (size_t o = 0; o < obstacles_.size(); ++o)
      for (size_t k = 0; k < surface_.size(); ++k) {
        const int32_t v = surface_[k];
        if (m.inv_mass[size_t(v)] > 0 && deepest(o, k, x[size_t(v)], hit)) fn(o, v, hit);
      }
  }
  // An impulse given to the body at the closest point of a hit: minus it on the triangle's corners.
  void add_impulse(size_t o, const Hit& hit, const Vec3& impulse_on_body);
  // The triangle's inverse mass at a hit's closest point (0 for an obstacle without masses).
  double inverse_mass_at(size_t o, const Hit& hit) const;

 private:
  uint64_t model_id_ = 0;
  std::vector<const TriangleObstacle*> obstacles_;
  std::vector<TriangleGrid> grids_;
  std::vector<std::pair<Vec3, Vec3>> boxes_;  // each obstacle's box grown by its radius
  std::vector<int32_t> surface_;    // surface vertices
  std::vector<Vec3> step_start_;    // their positions at the start of the step
  std::vector<std::vector<Vec3>> impulses_;
  mutable std::vector<int32_t> near_;  // scratch: a vertex's candidate triangles
};

}  // namespace pliant::detail
