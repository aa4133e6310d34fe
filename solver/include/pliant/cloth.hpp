// SPDX-License-Identifier: Apache-2.0
// Cloth and ropes: bodies of particles held by XPBD constraints (Macklin et al. 2016) stepped
// with small substeps (Macklin et al. 2019): distance constraints (stretch, optional shear),
// bending (the dihedral angle of two triangles for cloth; Kelager's triangle bending of three
// consecutive particles for ropes), an optional volume (pressure) constraint for closed
// surfaces, pinned particles, grabs, collisions with the scene's colliders (friction) and cloth
// self-collision (particle against triangle). Compliances are in SI units (see each field).
// docs/cloth.md describes the method and the parameters.
#pragma once

#include "pliant/mesh.hpp"
#include "pliant/particle_body.hpp"

#include <array>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace pliant {

class ThreadPool;
namespace detail {
class ToolMeeting;
}

struct ConstraintBodySettings {
  // XPBD compliances (inverse stiffnesses); 0 = rigid.
  double stretch_compliance = 1e-9;  // m/N: distance constraints along the edges (C in m)
  double shear_compliance = 1e-6;    // m/N: the grid's second diagonals (cloth_grid with shear)
  double bend_compliance = 1e3;      // cloth: 1/(N m) (C = dihedral angle, rad; 1e3 drapes
                                     // like a light fabric); rope: m/N (C = triangle-bending
                                     // distance, m)
  bool bending = true;               // false: no bending constraints at all
  double volume_compliance = 0.0;    // m^5/N (C = V - pressure V0, m^3); used when volume is set
  bool volume = false;               // closed surfaces only: keep the enclosed volume
  double pressure = 1.0;             // target volume as a multiple of the rest volume
  double damping = 0.0;              // 1/s: velocity damping v <- v (1 - damping h) per substep
  Vec3 gravity{0.0, -9.81, 0.0};     // m/s^2
  int substeps = 16;                 // per step
  int iterations = 1;                // constraint sweeps per substep
  double thickness = 0.005;          // m: particle radius against colliders, and the distance
                                     // self-collision keeps between a particle and a triangle
  bool self_collision = true;        // cloth only (ropes have no triangles)
  int threads = 1;                   // the calling thread included; results do not depend on it
};

// A cloth grid of nx x ny particles spanning size_x x size_y metres in the plane through
// `origin` spanned by the unit vectors `u` and `v` (default: horizontal, x and z).
struct ClothGridSpec {
  int nx = 64;
  int ny = 64;
  double size_x = 1.0;        // m
  double size_y = 1.0;        // m
  double mass_per_area = 0.2; // kg/m^2
  Vec3 origin{-0.5, 0.0, -0.5};
  Vec3 u{1.0, 0.0, 0.0};
  Vec3 v{0.0, 0.0, 1.0};
  bool shear = true;          // the second diagonal of every quad as a shear constraint
};

class ConstraintBody : public ParticleBody {
 public:
  // Cloth from a triangle surface (vertices in metres, triangles indexing them): the mass of
  // every triangle (area x mass_per_area, kg/m^2) goes a third to each of its vertices.
  static std::unique_ptr<ConstraintBody> cloth(std::vector<Vec3> vertices, const std::vector<Triangle>& triangles,
                                               double mass_per_area, const ConstraintBodySettings& settings);
  static std::unique_ptr<ConstraintBody> cloth_grid(const ClothGridSpec& spec, const ConstraintBodySettings& settings);
  // A triangle surface file read with assimp (OBJ, STL, PLY, glTF, OFF, ...); scale: file units
  // to metres.
  static std::unique_ptr<ConstraintBody> cloth_from_file(const std::string& path, double scale, double mass_per_area,
                                                         const ConstraintBodySettings& settings);
  // A rope along `polyline` (at least two points) resampled into `segments` segments of equal
  // length; linear_density in kg/m.
  static std::unique_ptr<ConstraintBody> rope(const std::vector<Vec3>& polyline, int segments, double linear_density,
                                              const ConstraintBodySettings& settings);

  ~ConstraintBody() override;

  std::string kind() const override { return is_rope_ ? "rope" : "cloth"; }
  size_t size() const override { return state_.x.size(); }
  const ParticleState& state() const override { return state_; }
  void set_state(const ParticleState& state) override;
  std::span<const double> inverse_masses() const override { return w_; }
  double contact_radius() const override { return settings_.thickness; }
  std::span<const std::array<uint32_t, 3>> triangles() const override { return triangles_; }
  // The distance constraints' particle pairs, the grid's shear diagonals left out.
  std::span<const std::array<uint32_t, 2>> segments() const override { return segments_; }

  int substeps() const override;
  using ParticleBody::advance;
  ParticleStepReport advance(double dt, int substeps, std::span<const Collider> colliders, bool ends_step,
                             SurfaceBoundary* surface, ToolBoundary* tools) override;
  void set_gravity(const Vec3& gravity) override;

  // Pins particle i where it is (inverse mass 0) or frees it again with its mass.
  void pin(size_t i);
  void unpin(size_t i);
  // Moves a particle (a pinned one: a kinematic handle), zeroing its velocity.
  void set_position(size_t i, const Vec3& x);

  const ConstraintBodySettings& settings() const { return settings_; }
  // Changes the settings that can change between steps (compliances, damping, gravity,
  // budget, thickness, self-collision, threads); validated like the builders'.
  void set_settings(const ConstraintBodySettings& settings);
  std::span<const double> masses() const { return m_; }
  double total_mass() const;
  Vec3 linear_momentum() const;
  // Rest length of every distance constraint and its particles (stretch and shear, coloured
  // order), and the relative stretch |x_i - x_j| / rest - 1 of each.
  size_t distance_constraints() const { return dist_.size(); }
  size_t bending_constraints() const { return bend_.size() + rope_bend_.size(); }
  size_t constraint_count() const;  // = state().lambda.size()
  size_t colours() const;           // graph colours over all constraint groups
  double max_stretch() const;       // max over stretch constraints of | |x_i - x_j| / rest - 1 |
  double rest_volume() const { return rest_volume_; }
  double volume() const;  // enclosed volume of the triangles (closed surfaces), m^3
  // Self-collision contacts found in the last substep.
  size_t self_contacts() const { return last_self_contacts_; }

  struct Distance {
    uint32_t i, j;
    double rest;
    bool shear;
  };
  struct Bend {  // dihedral: edge (a, b), wings c (triangle a b c) and d (triangle b a d)
    uint32_t a, b, c, d;
    double rest_angle;
    double rest_cos = 1.0, rest_sin = 0.0;  // of rest_angle (set when the body is finished)
  };
  struct RopeBend {  // Kelager et al. 2010: |x_b - (x_a + x_b + x_c)/3| = rest
    uint32_t a, b, c;
    double rest;
  };

 private:
  ConstraintBody();
  void finish(const ConstraintBodySettings& settings);
  void solve_distance(size_t k, double h2);
  void solve_bend(size_t k, double h2);
  void solve_rope_bend(size_t k, double h2);
  void solve_volume(double h2);
  void solve_grabs(double h2);
  void build_self_hash(double dt);
  // The relative stretch |x_i - x_j| / rest - 1 of the stretch constraints (the grid's shear
  // diagonals left out): RMS and largest magnitude.
  struct Stretch {
    double rms, max;
  };
  Stretch stretch() const;
  void find_self_contacts();
  void solve_self_contacts();
  size_t solve_colliders(std::span<const Collider> colliders);
  double self_thickness() const;
  // The soft body's surface met inside a step: what each particle met in the substep.
  struct SurfaceContacts;
  void meet_surface(SurfaceContacts& sc);
  size_t leave_surface(SurfaceContacts& sc, double h);
  void meet_tools(detail::ToolMeeting& tm);
  template <class F>
  void for_colours(const std::vector<size_t>& starts, F&& f);

  bool is_rope_ = false;
  ConstraintBodySettings settings_;
  ParticleState state_;
  std::vector<double> m_, w_, w_free_;
  std::vector<Vec3> p_, x_prev_;
  std::vector<std::array<uint32_t, 3>> triangles_;
  std::vector<Distance> dist_;
  std::vector<std::array<uint32_t, 2>> segments_;
  std::vector<std::array<uint32_t, 3>> tool_faces_;  // the triangles, or a rope's links as (a, b, b)
  std::vector<Bend> bend_;
  std::vector<RopeBend> rope_bend_;
  // colour k of a group is [starts[k], starts[k+1])
  std::vector<size_t> dist_colours_, bend_colours_, rope_bend_colours_;
  double rest_volume_ = 0.0;
  double shortest_edge_ = 0.0;  // the shortest stretch constraint's rest length (self_thickness)
  bool self_thickness_said_ = false;  // logged that self-collision keeps less than the thickness
                                      // (finish runs twice for a grid with shear diagonals)
  std::unique_ptr<ThreadPool> pool_;

  // self-collision: triangle candidates by hashed cell, rebuilt every step
  double cell_ = 0.0;
  std::vector<uint32_t> bucket_start_, bucket_tris_;
  std::vector<std::pair<uint32_t, uint32_t>> candidates_;  // (particle, triangle) for this step
  std::vector<size_t> adjacency_start_;  // particles joined by a distance constraint (CSR)
  std::vector<uint32_t> adjacency_;
  struct SelfContact {
    uint32_t particle, tri;
    double b0, b1, b2;  // barycentric coordinates of the closest point
    double side;        // +1 / -1: the side of the triangle the particle keeps
  };
  std::vector<SelfContact> self_contacts_;
  std::vector<std::vector<SelfContact>> self_scratch_;
  size_t last_self_contacts_ = 0;
  bool stretch_warned_ = false;  // warned of an under-resolved budget; re-armed once it recovers
  double h_ = 0.0;
};

// Distance, dihedral and rope-bending constraints as functions, for tests (values, gradients).
namespace cloth_math {
double dihedral_angle(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);
// atan2(s, c) - theta0 wrapped into (-pi, pi], from the cosine and sine of theta0: the angle of
// the pair (s, c) turned back by theta0. Near theta0 (the turned pair within 14 degrees of its
// axis) a series replaces the libm call, to the last bit or so.
double angle_from_rest(double s, double c, double cos0, double sin0);
// Gradients of dihedral_angle with respect to a, b, c, d.
std::array<Vec3, 4> dihedral_gradient(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);
// |x_b - centroid(a, b, c)| and its gradient with respect to a, b, c.
double rope_bend_value(const Vec3& a, const Vec3& b, const Vec3& c);
std::array<Vec3, 3> rope_bend_gradient(const Vec3& a, const Vec3& b, const Vec3& c);
// Enclosed volume of a closed triangle surface and its gradient per vertex.
double enclosed_volume(std::span<const Vec3> x, std::span<const std::array<uint32_t, 3>> triangles);
void enclosed_volume_gradient(std::span<const Vec3> x, std::span<const std::array<uint32_t, 3>> triangles,
                              std::vector<Vec3>& grad);
// The catenary through two points at equal height `span` apart with length `length`:
// parameter a (m) with length = 2 a sinh(span / (2 a)), and the sag a (cosh(span/(2a)) - 1).
double catenary_parameter(double span, double length);
double catenary_sag(double span, double length);
}  // namespace cloth_math

}  // namespace pliant
