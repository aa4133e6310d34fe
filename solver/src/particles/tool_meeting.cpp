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
    if (!t.position.allFinite() || !t.velocity.allFinite() || !std::isfinite(t.radius) ||
        !std::isfinite(t.half_length) || !t.orientation.coeffs().allFinite())
      throw std::invalid_argument(fmt::format("tools[{}]: pose or velocity is not finite", k));
  }
  tools_.assign(boundary.tools.begin(), boundary.tools.end());
  for (RigidTool& t : tools_) t.radius += radius_;
  boundary_.impulse.assign(tools_.size(), Vec3::Zero());
  boundary_.angular_impulse.assign(tools_.size(), Vec3::Zero());
  boundary_.pushed = 0;
}

void ToolMeeting::begin_substep(int s, size_t particles) {
  const double before_end = dt_ - (s + 1) * h_;  // how long before the call's end the substep ends
  lo_ = Vec3::Constant(INFINITY);
  hi_ = Vec3::Constant(-INFINITY);
  for (size_t k = 0; k < tools_.size(); ++k) {
    RigidTool& t = tools_[k];
    t.position = boundary_.tools[k].position - boundary_.tools[k].velocity * before_end;
    const double reach = t.radius + (t.shape == RigidTool::Shape::Capsule ? std::abs(t.half_length) : 0.0);
    lo_ = lo_.cwiseMin(t.position - Vec3::Constant(reach));
    hi_ = hi_.cwiseMax(t.position + Vec3::Constant(reach));
  }
  moved_.assign(particles * tools_.size(), Vec3::Zero());
  touched_.assign(particles, 0);
}

ToolMeeting::Push ToolMeeting::push_near(size_t i, Vec3& p) {
  Push out;
  for (size_t k = 0; k < tools_.size(); ++k) {
    Vec3 q, n;
    double depth;
    if (!tool_contact(tools_[k], p, q, n, depth) || !(depth > 0)) continue;
    const Vec3 d = depth * n;
    p += d;
    moved_[i * tools_.size() + k] += d;
    out.depth += depth;
    out.normal = n;
    out.tool = int(k);
  }
  if (out.tool >= 0) touched_[i] = 1;
  return out;
}

void ToolMeeting::friction(size_t i, int k, const Vec3& normal, double depth, const Vec3& moved, Vec3& p) {
  const RigidTool& t = tools_[size_t(k)];
  const Vec3 slip = moved - h_ * t.velocity;
  const Vec3 tang = slip - slip.dot(normal) * normal;
  const double tl = tang.norm();
  if (!(tl > 0)) return;
  const Vec3 back = tl < t.static_friction * depth ? tang : Vec3(tang * std::min(t.dynamic_friction * depth / tl, 1.0));
  p -= back;
  moved_[i * tools_.size() + size_t(k)] -= back;
}

}  // namespace pliant::detail
