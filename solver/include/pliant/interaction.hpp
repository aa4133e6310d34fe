// SPDX-License-Identifier: Apache-2.0
// Interaction inputs to a step: attachments (grab a vertex, or a point inside a tet by
// barycentric weights, and pull it to a moving target through a compliant constraint) and
// rigid tools (sphere, capsule) posed by the caller that the body's vertices collide with.
// The reactions come from the XPBD multipliers (f = lambda / h^2), not from a made-up spring.
#pragma once

#include "pliant/geometry.hpp"
#include "pliant/material.hpp"
#include "pliant/mesh.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <functional>
#include <string>
#include <vector>

namespace pliant {

struct BodyModel;

// C = sum_k b_k x_{v_k} - target (3 rows), compliance alpha (m/N; 0 = hard). A vertex grab uses
// one vertex with weight 1; a point inside a tet uses its four vertices and barycentric weights.
struct Attachment {
  std::array<int32_t, 4> vertices{-1, -1, -1, -1};  // -1: unused slot
  std::array<double, 4> weights{0, 0, 0, 0};
  Eigen::Vector3d target{0, 0, 0};
  double compliance = 0.0;

  static Attachment vertex(int32_t v, const Eigen::Vector3d& target, double compliance = 0.0);
  static Attachment in_tet(const Tet& tet, const std::array<double, 4>& barycentric,
                           const Eigen::Vector3d& target, double compliance = 0.0);
  // The attached point at positions x.
  Eigen::Vector3d point(const std::vector<Eigen::Vector3d>& x) const;
};

// Triangles the body must stay clear of during a step (a cloth's, at the start of the tick):
// every free surface vertex stays `radius` from them on the side it started the step on, pushed
// out inside the iterations like the static colliders (method newton: a penalty energy, like its
// colliders), with Coulomb friction `friction` (static and dynamic) against its motion; the step
// reports the impulse it put on each corner
// (StepReport::obstacle_impulses), which the obstacle's owner applies to it.
// With the corners' inverse masses a contact is one between two bodies (xpbd and vbd): the
// vertex makes w_v / (w_v + w_t) of the move a fixed triangle would ask of it (w_t: the
// triangle's inverse mass at the contact point, sum b_k^2 w_k), and the triangle takes the
// momentum of that move. A light cloth under a heavy body then yields to it instead of taking
// all of its momentum (docs/fluids.md, "The contact counted by both bodies' masses").
struct TriangleObstacle {
  std::vector<Eigen::Vector3d> x;                  // corners, m
  std::vector<std::array<uint32_t, 3>> triangles;  // indices into x
  double radius = 0.0;                             // m, > 0
  double friction = 0.0;                           // >= 0
  std::vector<double> inverse_mass;                // per corner, 1/kg (0: pinned); empty: all fixed
};

// A rigid tool driven by a pose. Sphere: centre = position. Capsule: the segment
// position +- half_length * (orientation * z) swept by radius.
struct RigidTool {
  enum class Shape { Sphere, Capsule };
  Shape shape = Shape::Sphere;
  Eigen::Vector3d position{0, 0, 0};
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  double radius = 0.01;
  double half_length = 0.0;  // capsule only
  double static_friction = 0.5;
  double dynamic_friction = 0.4;
  // Linear velocity (m/s). The pose is where the tool is at the END of the step; with a
  // velocity the step moves it there from position - velocity * dt over the substeps, and
  // friction acts on the vertices' motion relative to the tool's.
  Eigen::Vector3d velocity{0, 0, 0};
  // Angular velocity (rad/s, world axes, about `position`). Likewise the step turns the tool to
  // its orientation from that orientation turned back by angular_velocity * dt, and friction sees
  // the motion of the tool's surface where it touches.
  Eigen::Vector3d angular_velocity{0, 0, 0};

  // The tool `offset` seconds after the pose (offset <= 0: before the step's end), moved and
  // turned at its velocities.
  RigidTool at(double offset) const;
  // How far the tool's material point at p moves in a time h at its velocities.
  Eigen::Vector3d motion(const Eigen::Vector3d& p, double h) const {
    return h * (velocity + angular_velocity.cross(p - position));
  }

  static RigidTool sphere(const Eigen::Vector3d& centre, double radius);
  static RigidTool capsule(const Eigen::Vector3d& centre, const Eigen::Quaterniond& orientation,
                           double radius, double half_length);
};

// If p is inside the tool: the closest surface point q, the outward normal and the depth.
bool tool_contact(const RigidTool& tool, const Eigen::Vector3d& p, Eigen::Vector3d& q,
                  Eigen::Vector3d& normal, double& depth);

// One projection pass of a tool against the body (hard contact, tool of infinite mass,
// position-level Coulomb friction as for the static colliders), called by the stepper once per
// iteration after the strain sweep:
//  - every free vertex inside the tool is moved to its surface;
//  - then every boundary triangle (model.surface) whose closest point to the tool's core
//    (sphere centre; capsule segment) is inside the tool, and not at one of its corners (that
//    is the corner vertex's contact), is pushed out along the tool's normal there: the point
//    p = sum_k b_k x_k (barycentric b) is a generalized particle of inverse mass
//    sum_k b_k^2 w_k, and each corner moves by w_k b_k dlambda. So a small tool cannot pass
//    between the vertices of a coarse surface.
// Contacts are projected one after the other (Gauss-Seidel): a penetration resolved by one
// contact is not seen by the next, so an edge shared by two triangles, or a corner shared by a
// vertex contact, is not counted twice. Friction acts on the contact point's motion since
// x_start relative to the tool's surface there (tool.motion over the substep h).
// `record(vertex, dlambda, normal)` is called for every correction of a vertex: dlambda is the
// vector multiplier increment m_v * (correction of x_v) (force on the body = lambda / h^2, on
// the tool minus that), normal the tool's outward normal at the contact. Returns the number of
// contacts (vertices and triangles) projected.
int project_tool_contacts(const BodyModel& model, std::vector<Eigen::Vector3d>& x,
                          const std::vector<Eigen::Vector3d>& x_start, const RigidTool& tool, double h,
                          const std::function<void(int32_t vertex, const Eigen::Vector3d& dlambda,
                                                   const Eigen::Vector3d& normal)>& record);

// The closest points between a tool's core (its centre; a capsule's axis segment) and triangle
// (a, b, c): the point on the core, the point on the triangle and its barycentric weights.
void closest_core_triangle(const RigidTool& tool, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                           const Eigen::Vector3d& c, Eigen::Vector3d& core_point, Eigen::Vector3d& triangle_point,
                           std::array<double, 3>& barycentric);
// The same for segment (a, b): the point on the segment is a + u (b - a).
void closest_core_segment(const RigidTool& tool, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                          Eigen::Vector3d& core_point, Eigen::Vector3d& segment_point, double& u);

// One vertex in contact with a tool during the step.
struct ToolContact {
  int32_t vertex = -1;
  Eigen::Vector3d point{0, 0, 0};   // the vertex at the end of the step (on the tool's surface for a
                                    // vertex contact, a corner of the face for a triangle contact)
  Eigen::Vector3d normal{0, 0, 0};  // tool's outward normal there (last substep in contact)
  Eigen::Vector3d force{0, 0, 0};   // force ON THE TOOL from this contact, N (tick average)
};

// The reaction on one tool. force/torque are the averages over the substeps of the step, i.e.
// the impulse delivered during the tick divided by dt; torque is about the tool's position in
// each substep (tool.position at the end of the step for a tool without velocity).
// Normal and friction multipliers both count: f_tool = -sum over contacts of lambda / h^2.
struct ToolReaction {
  Eigen::Vector3d force{0, 0, 0};
  Eigen::Vector3d torque{0, 0, 0};
  std::vector<ToolContact> contacts;
};

// Empty when valid, else a message naming the bad field and its value (e.g.
// "attachments[2].vertices[0] = 99 is out of range (model has 50 vertices)").
std::string validate_interaction(const std::vector<Attachment>& attachments,
                                 const std::vector<RigidTool>& tools, const BodyModel& model);

}  // namespace pliant
