#include "pliant/interaction.hpp"

#include "pliant/model.hpp"

#include <algorithm>
#include <cmath>
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

bool tool_contact(const RigidTool& tool, const Eigen::Vector3d& p, Eigen::Vector3d& q,
                  Eigen::Vector3d& normal, double& depth) {
  // Both shapes are a point set swept by a ball: find the closest core point, then it is a sphere.
  Eigen::Vector3d core = tool.position;
  if (tool.shape == RigidTool::Shape::Capsule && tool.half_length > 0) {
    const Eigen::Vector3d axis = tool.orientation * Eigen::Vector3d::UnitZ();
    const double s = std::clamp((p - tool.position).dot(axis), -tool.half_length, tool.half_length);
    core = tool.position + s * axis;
  }
  const Eigen::Vector3d r = p - core;
  const double len = r.norm();
  if (len >= tool.radius) return false;
  normal = len > 1e-12 ? Eigen::Vector3d(r / len) : Eigen::Vector3d(0, 1, 0);
  q = core + tool.radius * normal;
  depth = tool.radius - len;
  return true;
}

namespace {
bool finite(const Eigen::Vector3d& v) { return v.allFinite(); }
}  // namespace

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
