// SPDX-License-Identifier: Apache-2.0
#include "pliant/interaction.hpp"

#include "pliant/model.hpp"
#include "step/ball_contact.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace pliant {

Attachment Attachment::vertex(int32_t v, const Eigen::Vector3d& target, double compliance) {
  Attachment a;
  a.vertices = {v, -1, -1, -1};
  a.weights = {1.0, 0.0, 0.0, 0.0};
  a.target = target;
  a.compliance = compliance;
  return a;
}

Attachment Attachment::in_tet(const Tet& tet, const std::array<double, 4>& barycentric,
                              const Eigen::Vector3d& target, double compliance) {
  Attachment a;
  a.vertices = tet;
  a.weights = barycentric;
  a.target = target;
  a.compliance = compliance;
  return a;
}

Eigen::Vector3d Attachment::point(const std::vector<Eigen::Vector3d>& x) const {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (int k = 0; k < 4; ++k)
    if (vertices[k] >= 0) p += weights[k] * x[vertices[k]];
  return p;
}

RigidTool RigidTool::sphere(const Eigen::Vector3d& centre, double radius) {
  RigidTool t;
  t.shape = Shape::Sphere;
  t.position = centre;
  t.radius = radius;
  return t;
}

RigidTool RigidTool::capsule(const Eigen::Vector3d& centre, const Eigen::Quaterniond& orientation,
                             double radius, double half_length) {
  RigidTool t;
  t.shape = Shape::Capsule;
  t.position = centre;
  t.orientation = orientation.normalized();
  t.radius = radius;
  t.half_length = half_length;
  return t;
}

RigidTool RigidTool::at(double offset) const {
  RigidTool t = *this;
  t.position += velocity * offset;
  const double rate = angular_velocity.norm();
  if (rate > 0 && offset != 0)
    t.orientation = (Eigen::Quaterniond(Eigen::AngleAxisd(rate * offset, angular_velocity / rate)) * orientation).normalized();
  return t;
}

bool tool_contact(const RigidTool& tool, const Eigen::Vector3d& p, Eigen::Vector3d& q,
                  Eigen::Vector3d& normal, double& depth) {
  // Both shapes are a point set swept by a ball: find the closest core point, then it is a sphere.
  Eigen::Vector3d core = tool.position;
  if (tool.shape == RigidTool::Shape::Capsule && tool.half_length > 0) {
    const Eigen::Vector3d axis = tool.orientation * Eigen::Vector3d::UnitZ();
    const double s = std::clamp((p - tool.position).dot(axis), -tool.half_length, tool.half_length);
    core = tool.position + s * axis;
  }
  return detail::ball_contact(core, tool.radius, p, normal, q, depth);
}

namespace {
bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }

using V3 = Eigen::Vector3d;

// Closest points between segments p1-q1 and p2-q2 (parameters s, t in [0, 1]).
void closest_segment_segment(const V3& p1, const V3& q1, const V3& p2, const V3& q2, double& s, double& t) {
  const V3 d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  constexpr double eps = 1e-30;
  if (a <= eps && e <= eps) {
    s = t = 0;
    return;
  }
  if (a <= eps) {
    s = 0;
    t = std::clamp(f / e, 0.0, 1.0);
    return;
  }
  const double c = d1.dot(r);
  if (e <= eps) {
    t = 0;
    s = std::clamp(-c / a, 0.0, 1.0);
    return;
  }
  const double b = d1.dot(d2), denom = a * e - b * b;
  s = denom > eps ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
  t = (b * s + f) / e;
  if (t < 0) {
    t = 0;
    s = std::clamp(-c / a, 0.0, 1.0);
  } else if (t > 1) {
    t = 1;
    s = std::clamp((b - c) / a, 0.0, 1.0);
  }
}

}  // namespace

void closest_core_triangle(const RigidTool& tool, const V3& a, const V3& b, const V3& c, V3& core_point,
                           V3& tri_point, std::array<double, 3>& bary) {
  if (tool.shape != RigidTool::Shape::Capsule || tool.half_length <= 0) {
    core_point = tool.position;
    tri_point = closest_point_on_triangle(core_point, a, b, c, bary);
    return;
  }
  const V3 axis = tool.orientation * V3::UnitZ();
  const V3 s0 = tool.position - tool.half_length * axis, s1 = tool.position + tool.half_length * axis;
  double best = std::numeric_limits<double>::infinity();
  auto consider = [&](const V3& on_core, const V3& on_tri, const std::array<double, 3>& w) {
    const double d = (on_tri - on_core).squaredNorm();
    if (d < best) {
      best = d;
      core_point = on_core;
      tri_point = on_tri;
      bary = w;
    }
  };
  std::array<double, 3> w{};
  for (const V3* end : {&s0, &s1}) {
    const V3 q = closest_point_on_triangle(*end, a, b, c, w);
    consider(*end, q, w);
  }
  const V3* corner[3] = {&a, &b, &c};
  for (int k = 0; k < 3; ++k) {
    const int l = (k + 1) % 3;
    double sp, tp;
    closest_segment_segment(s0, s1, *corner[k], *corner[l], sp, tp);
    std::array<double, 3> we{0, 0, 0};
    we[k] = 1 - tp;
    we[l] = tp;
    consider(s0 + sp * (s1 - s0), *corner[k] + tp * (*corner[l] - *corner[k]), we);
  }
  // The segment crossing the triangle's interior: distance 0 there.
  const V3 n = (b - a).cross(c - a);
  const double d0 = n.dot(s0 - a), d1 = n.dot(s1 - a);
  if ((d0 < 0) != (d1 < 0) && d0 != d1) {
    const V3 hit = s0 + (d0 / (d0 - d1)) * (s1 - s0);
    const V3 q = closest_point_on_triangle(hit, a, b, c, w);
    consider(hit, q, w);
  }
}

void closest_core_segment(const RigidTool& tool, const V3& a, const V3& b, V3& core_point, V3& segment_point,
                          double& u) {
  V3 s0 = tool.position, s1 = tool.position;
  if (tool.shape == RigidTool::Shape::Capsule && tool.half_length > 0) {
    const V3 axis = tool.orientation * V3::UnitZ();
    s0 -= tool.half_length * axis;
    s1 += tool.half_length * axis;
  }
  double s = 0;
  closest_segment_segment(s0, s1, a, b, s, u);
  core_point = s0 + s * (s1 - s0);
  segment_point = a + u * (b - a);
}

int project_tool_contacts(const BodyModel& m, std::vector<V3>& x, const std::vector<V3>& x_start,
                          const RigidTool& tool, double h,
                          const std::function<void(int32_t, const V3&, const V3&)>& record) {
  int n = 0;
  // Vertices inside the tool (remembered: the faces around them are theirs, below).
  std::vector<int32_t> touched;
  for (size_t i = 0; i < x.size(); ++i) {
    if (m.inv_mass[i] == 0) continue;
    V3 q, normal;
    double depth;
    if (!tool_contact(tool, x[i], q, normal, depth)) continue;
    const V3 before = x[i];
    x[i] += depth * normal;
    const V3 dx = x[i] - x_start[i] - tool.motion(x[i], h);  // relative to the tool's surface
    const V3 tangential = dx - dx.dot(normal) * normal;
    const double tn = tangential.norm();
    if (tn < tool.static_friction * depth) x[i] -= tangential;
    else if (tn > 0) x[i] -= tangential * std::min(tool.dynamic_friction * depth / tn, 1.0);
    record(int32_t(i), m.inertia[i] * (x[i] - before), normal);  // the impulse the contact gave (times h)
    touched.push_back(int32_t(i));
    ++n;
  }
  if (m.surface.empty()) return n;
  // Boundary triangles whose interior or edges are inside the tool. Cheap rejection first: the
  // tool's bounding sphere (core centre, radius + half length) against the triangle's.
  const double reach = tool.radius + (tool.shape == RigidTool::Shape::Capsule ? tool.half_length : 0.0);
  constexpr double kCorner = 1.0 - 1e-9;  // a weight this close to 1: the corner's own contact
  for (const Triangle& tri : m.surface) {
    const int32_t v[3] = {tri[0], tri[1], tri[2]};
    const double w[3] = {m.inv_mass[v[0]], m.inv_mass[v[1]], m.inv_mass[v[2]]};
    if (w[0] == 0 && w[1] == 0 && w[2] == 0) continue;
    // A face with a corner in vertex contact (projected by the vertex pass above) is that
    // vertex's: the face is a chord of the tool, and pushing it out as well pushes the corner
    // past the tool's surface (a polyhedral cup around the tool), which at 1-2 substeps crushed
    // and inverted the 50k-tet beam of pliant_tick_profile under a 1 cm sphere. (Testing
    // "on the surface" geometrically instead is not enough: friction leaves a projected vertex
    // slightly outside, and that variant exploded the same way.) Faces between the contacts (a
    // tool smaller than the faces, between vertices) are still caught.
    if (std::find(touched.begin(), touched.end(), v[0]) != touched.end() ||
        std::find(touched.begin(), touched.end(), v[1]) != touched.end() ||
        std::find(touched.begin(), touched.end(), v[2]) != touched.end())
      continue;
    const V3 centre = (x[v[0]] + x[v[1]] + x[v[2]]) / 3.0;
    const double tri_r = std::sqrt(std::max({(x[v[0]] - centre).squaredNorm(), (x[v[1]] - centre).squaredNorm(),
                                             (x[v[2]] - centre).squaredNorm()}));
    if ((centre - tool.position).norm() > reach + tri_r) continue;
    V3 core = V3::Zero(), p = V3::Zero();  // set by closest_core_triangle; zeroed for GCC 12 -Wmaybe-uninitialized
    std::array<double, 3> b{};
    closest_core_triangle(tool, x[v[0]], x[v[1]], x[v[2]], core, p, b);
    if (b[0] >= kCorner || b[1] >= kCorner || b[2] >= kCorner) continue;
    const V3 r = p - core;
    const double len = r.norm();
    if (len >= tool.radius) continue;
    V3 normal;
    if (len > 1e-12) normal = r / len;
    else {
      // The core touches the triangle: push it along its inward normal (the surface is wound
      // outward, so into the body is minus the face normal).
      const V3 fn = (x[v[1]] - x[v[0]]).cross(x[v[2]] - x[v[0]]);
      normal = fn.norm() > 0 ? V3(-fn.normalized()) : V3(0, 1, 0);
    }
    const double depth = tool.radius - len;
    double wsum = 0;
    for (int k = 0; k < 3; ++k) wsum += b[k] * b[k] * w[k];
    if (wsum <= 0) continue;  // the point sits on fixed corners only
    // The contact point's correction dp, moved onto the corners (x_k += w_k b_k dp / wsum:
    // p moves by exactly dp); the multiplier is dlambda = dp / wsum, corner k's share b_k
    // dlambda (= m_k * its correction for a free corner; a fixed corner passes its share to the
    // support, so the tool still feels the whole constraint force).
    V3 moved = V3::Zero();
    auto move_point = [&](const V3& dp) {
      for (int k = 0; k < 3; ++k) x[v[k]] += (w[k] * b[k] / wsum) * dp;
      moved += dp;
    };
    move_point(depth * normal);
    V3 dp = V3::Zero();
    for (int k = 0; k < 3; ++k) dp += b[k] * (x[v[k]] - x_start[v[k]]);
    dp -= tool.motion(p + moved, h);  // the point, now on the tool's surface
    const V3 tangential = dp - dp.dot(normal) * normal;
    const double tn = tangential.norm();
    if (tn < tool.static_friction * depth) move_point(-tangential);
    else if (tn > 0) move_point(-tangential * std::min(tool.dynamic_friction * depth / tn, 1.0));
    const V3 dlambda = moved / wsum;
    for (int k = 0; k < 3; ++k)
      if (b[k] > 0) record(v[k], b[k] * dlambda, normal);
    ++n;
  }
  return n;
}

std::string validate_interaction(const std::vector<Attachment>& attachments,
                                 const std::vector<RigidTool>& tools, const BodyModel& model) {
  std::ostringstream os;
  const auto nv = int64_t(model.vertex_count());
  for (size_t i = 0; i < attachments.size(); ++i) {
    const Attachment& a = attachments[i];
    int used = 0;
    double wsum = 0;
    for (int k = 0; k < 4; ++k) {
      if (a.vertices[k] < 0) continue;
      if (a.vertices[k] >= nv) {
        os << "attachments[" << i << "].vertices[" << k << "] = " << a.vertices[k]
           << " is out of range (model has " << nv << " vertices)";
        return os.str();
      }
      if (!std::isfinite(a.weights[k])) {
        os << "attachments[" << i << "].weights[" << k << "] = " << a.weights[k] << " is not finite";
        return os.str();
      }
      ++used;
      wsum += a.weights[k];
    }
    if (used == 0) {
      os << "attachments[" << i << "] has no vertex";
      return os.str();
    }
    if (std::abs(wsum - 1.0) > 1e-6) {
      os << "attachments[" << i << "].weights sum to " << wsum << ", expected 1";
      return os.str();
    }
    if (!finite(a.target)) {
      os << "attachments[" << i << "].target is not finite";
      return os.str();
    }
    if (!(a.compliance >= 0) || !std::isfinite(a.compliance)) {
      os << "attachments[" << i << "].compliance = " << a.compliance << " must be finite and >= 0";
      return os.str();
    }
  }
  for (size_t i = 0; i < tools.size(); ++i) {
    const RigidTool& t = tools[i];
    if (!finite(t.position)) {
      os << "tools[" << i << "].position is not finite";
      return os.str();
    }
    if (!t.orientation.coeffs().allFinite() || t.orientation.norm() < 1e-9) {
      os << "tools[" << i << "].orientation is not a rotation (norm " << t.orientation.norm() << ")";
      return os.str();
    }
    if (!finite(t.velocity)) {
      os << "tools[" << i << "].velocity is not finite";
      return os.str();
    }
    if (!finite(t.angular_velocity)) {
      os << "tools[" << i << "].angular_velocity is not finite";
      return os.str();
    }
    if (!(t.radius > 0) || !std::isfinite(t.radius)) {
      os << "tools[" << i << "].radius = " << t.radius << " must be > 0";
      return os.str();
    }
    if (!(t.half_length >= 0) || !std::isfinite(t.half_length)) {
      os << "tools[" << i << "].half_length = " << t.half_length << " must be >= 0";
      return os.str();
    }
    if (!(t.static_friction >= 0) || !(t.dynamic_friction >= 0)) {
      os << "tools[" << i << "] friction must be >= 0 (static " << t.static_friction << ", dynamic "
         << t.dynamic_friction << ")";
      return os.str();
    }
  }
  return {};
}

}  // namespace pliant
