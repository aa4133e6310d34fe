// SPDX-License-Identifier: Apache-2.0
#include "particles/tool_meeting.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace pliant::detail {

ToolMeeting::ToolMeeting(ToolBoundary& boundary, double radius, double dt, int substeps)
    : boundary_(boundary), radius_(radius), dt_(dt), h_(dt / substeps) {
  if (!(radius >= 0) || !std::isfinite(radius))
    throw std::invalid_argument(fmt::format("tools: radius must be >= 0 m, got {}", radius));
  for (size_t k = 0; k < boundary.tools.size(); ++k) {
    const RigidTool& t = boundary.tools[k];
    if (!t.position.allFinite() || !t.velocity.allFinite() || !t.angular_velocity.allFinite() ||
        !std::isfinite(t.radius) || !std::isfinite(t.half_length) || !t.orientation.coeffs().allFinite())
      throw std::invalid_argument(fmt::format("tools[{}]: pose or velocity is not finite", k));
  }
  tools_.assign(boundary.tools.begin(), boundary.tools.end());
  for (RigidTool& t : tools_) t.radius += radius_;
  near_ = tools_;
  for (RigidTool& t : near_) t.radius += radius_;
  boundary_.impulse.assign(tools_.size(), Vec3::Zero());
  boundary_.angular_impulse.assign(tools_.size(), Vec3::Zero());
  boundary_.pushed = 0;
}

bool ToolMeeting::swept_tools_meet(Vec3 lo, Vec3 hi, double reach) const {
  lo.array() -= reach;
  hi.array() += reach;
  for (const RigidTool& t : near_) {
    const double r = t.radius + (t.shape == RigidTool::Shape::Capsule ? std::abs(t.half_length) : 0.0);
    const Vec3 start = t.position - dt_ * t.velocity;
    const Vec3 tlo = t.position.cwiseMin(start).array() - r, thi = t.position.cwiseMax(start).array() + r;
    if (!((tlo.array() > hi.array()).any() || (thi.array() < lo.array()).any())) return true;
  }
  return false;
}

bool ToolMeeting::within_reach(std::span<const Vec3> x, double speed, double gravity) const {
  const double reach = dt_ * (speed + gravity * dt_);
  if (x.empty() || !std::isfinite(reach)) return !x.empty();
  Vec3 lo = x[0], hi = x[0];
  for (const Vec3& p : x) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  return swept_tools_meet(lo, hi, reach);
}

void ToolMeeting::select_faces(std::span<const std::array<uint32_t, 3>> faces, std::span<const Vec3> x, double speed,
                               double gravity) {
  faces_near_.clear();
  const double reach = dt_ * (speed + gravity * dt_);
  for (size_t f = 0; f < faces.size(); ++f) {
    const auto& face = faces[f];
    const Vec3 lo = x[face[0]].cwiseMin(x[face[1]]).cwiseMin(x[face[2]]);
    const Vec3 hi = x[face[0]].cwiseMax(x[face[1]]).cwiseMax(x[face[2]]);
    if (!std::isfinite(reach) || swept_tools_meet(lo, hi, reach)) faces_near_.push_back(uint32_t(f));
  }
}

void ToolMeeting::begin_substep(int s, size_t particles) {
  const double before_end = dt_ - (s + 1) * h_;  // how long before the call's end the substep ends
  lo_ = Vec3::Constant(INFINITY);
  hi_ = Vec3::Constant(-INFINITY);
  for (size_t k = 0; k < tools_.size(); ++k) {
    RigidTool& t = tools_[k];
    t = boundary_.tools[k].at(-before_end);
    t.radius += radius_;
    near_[k] = t;
    near_[k].radius += radius_;
    const double reach = near_[k].radius + (t.shape == RigidTool::Shape::Capsule ? std::abs(t.half_length) : 0.0);
    lo_ = lo_.cwiseMin(t.position - Vec3::Constant(reach));
    hi_ = hi_.cwiseMax(t.position + Vec3::Constant(reach));
  }
  // give() leaves the moves and marks zero, so only a new particle count clears them here (near_in_
  // holds pass numbers, which never repeat within the call).
  if (touched_.size() != particles) {
    moved_.assign(particles * tools_.size(), Vec3::Zero());
    moment_.assign(particles * tools_.size(), Vec3::Zero());
    touched_.assign(particles, 0);
    near_in_.resize(particles, 0);
  }
  pinned_impulse_.assign(tools_.size(), Vec3::Zero());
  pinned_angular_.assign(tools_.size(), Vec3::Zero());
}

ToolMeeting::Push ToolMeeting::push_near(size_t i, Vec3& p) {
  Push out;
  for (size_t k = 0; k < tools_.size(); ++k) {
    Vec3 q, n;
    double depth;
    if (!tool_contact(near_[k], p, q, n, depth) || !(depth > 0)) continue;
    near_in_[i] = pass_;
    depth -= radius_;
    if (!(depth > 0)) continue;
    const Vec3 d = depth * n;
    p += d;
    moved_[i * tools_.size() + k] += d;
    moment_[i * tools_.size() + k] += (p - near_[k].position).cross(d);
    out.depth += depth;
    out.normal = n;
    out.tool = int(k);
  }
  if (out.tool >= 0) touched_[i] = 1;
  return out;
}

size_t ToolMeeting::push_faces(std::span<const std::array<uint32_t, 3>> faces, std::span<Vec3> p,
                               std::span<const Vec3> x_prev, std::span<const double> w) {
  constexpr double kCorner = 1.0 - 1e-9;  // a weight this close to 1: the corner's own contact
  const size_t nt = tools_.size();
  size_t pushed = 0;
  for (uint32_t f : faces_near_) {
    const auto& face = faces[f];
    // A rope's link comes as (a, b, b): one corner b.
    const size_t corners = face[2] == face[1] ? 2 : 3;
    bool skip = false;
    Vec3 lo = p[face[0]], hi = p[face[0]];
    for (size_t c = 0; c < corners; ++c) {
      skip = skip || near_in_[face[c]] == pass_;
      lo = lo.cwiseMin(p[face[c]]);
      hi = hi.cwiseMax(p[face[c]]);
    }
    if (skip || (lo.array() > hi_.array()).any() || (hi.array() < lo_.array()).any()) continue;
    if (w[face[0]] == 0 && w[face[1]] == 0 && w[face[2]] == 0) continue;
    for (size_t k = 0; k < nt; ++k) {
      const RigidTool& t = tools_[k];
      Vec3 core = Vec3::Zero(), q = Vec3::Zero();
      std::array<double, 3> b{};
      if (corners == 2) {
        double u = 0;
        closest_core_segment(t, p[face[0]], p[face[1]], core, q, u);
        b = {1 - u, u, 0};
      } else {
        closest_core_triangle(t, p[face[0]], p[face[1]], p[face[2]], core, q, b);
      }
      if (b[0] >= kCorner || b[1] >= kCorner || b[2] >= kCorner) continue;
      const Vec3 r = q - core;
      const double len = r.norm();
      if (!(len < t.radius)) continue;
      double wsum = 0;
      for (size_t c = 0; c < corners; ++c) wsum += b[c] * b[c] * w[face[c]];
      if (!(wsum > 0)) continue;
      // Out along the direction from the core to the face, else (the core on the face) to the
      // side the face's point was on when the substep started.
      Vec3 normal = r / len;
      if (!(len > 1e-12 * t.radius)) {
        Vec3 before = Vec3::Zero();
        for (size_t c = 0; c < corners; ++c) before += b[c] * x_prev[face[c]];
        const Vec3 d = before - core;
        normal = d.norm() > 0 ? Vec3(d.normalized()) : Vec3(0, 1, 0);
      }
      // The point moves by dp; corner c by w_c b_c dp / wsum.
      Vec3 point_moved = Vec3::Zero();
      auto move_point = [&](const Vec3& dp) {
        point_moved += dp;
        for (size_t c = 0; c < corners; ++c) {
          const Vec3 d = (w[face[c]] * b[c] / wsum) * dp;
          p[face[c]] += d;
          moved_[face[c] * nt + k] += d;
          moment_[face[c] * nt + k] += (p[face[c]] - t.position).cross(d);
        }
      };
      const double depth = t.radius - len;
      move_point(depth * normal);
      Vec3 slip = -t.motion(q + point_moved, h_);  // the tool's surface where the point now is
      for (size_t c = 0; c < corners; ++c) slip += b[c] * (p[face[c]] - x_prev[face[c]]);
      const Vec3 tang = slip - slip.dot(normal) * normal;
      const double tl = tang.norm();
      if (tl > 0)
        move_point(tl < t.static_friction * depth ? Vec3(-tang)
                                                  : Vec3(-tang * std::min(t.dynamic_friction * depth / tl, 1.0)));
      // Corner c's share of the point's momentum is b_c dp / (wsum h) (for a free corner, its
      // mass times its move over h); a pinned corner's goes to its pin.
      for (size_t c = 0; c < corners; ++c) {
        if (!(b[c] > 0)) continue;
        if (w[face[c]] > 0) {
          touched_[face[c]] = 1;
        } else {
          const Vec3 share = (b[c] / (wsum * h_)) * point_moved;
          pinned_impulse_[k] += share;
          pinned_angular_[k] += (p[face[c]] - t.position).cross(share);
        }
      }
      ++pushed;
    }
  }
  return pushed;
}

void ToolMeeting::friction(size_t i, int k, const Vec3& normal, double depth, const Vec3& moved, Vec3& p) {
  const RigidTool& t = tools_[size_t(k)];
  const Vec3 slip = moved - t.motion(p, h_);
  const Vec3 tang = slip - slip.dot(normal) * normal;
  const double tl = tang.norm();
  if (!(tl > 0)) return;
  const Vec3 back = tl < t.static_friction * depth ? tang : Vec3(tang * std::min(t.dynamic_friction * depth / tl, 1.0));
  p -= back;
  moved_[i * tools_.size() + size_t(k)] -= back;
  moment_[i * tools_.size() + size_t(k)] -= (p - t.position).cross(back);
}

}  // namespace pliant::detail
