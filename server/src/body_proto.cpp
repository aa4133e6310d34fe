// SPDX-License-Identifier: Apache-2.0
// SceneSpec.bodies <-> the scene's BodyConfigs, every field range-checked on the way in with the
// field path and the value in the error, and echoed back with the values in use.
#include "pliant/server/edge.hpp"
#include "pliant/server/spec_proto.hpp"

#include <spdlog/fmt/fmt.h>

#include <cmath>
#include <set>

namespace pliant::server {

namespace {

Error invalid(std::string m) { return Error::invalid(std::move(m)); }

// v in [lo, hi] (or (lo, hi] with lo_open); unit after the interval.
Error in_range(const std::string& field, double v, double lo, double hi, bool lo_open, const char* unit) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  if (ok) return {};
  return invalid(fmt::format("{} must be in {}{}, {}]{}{}, got {}", field, lo_open ? "(" : "[", lo, hi,
                             *unit ? " " : "", unit, v));
}

Error int_range(const std::string& field, int64_t v, int64_t lo, int64_t hi) {
  if (v >= lo && v <= hi) return {};
  return invalid(fmt::format("{} must be in [{}, {}], got {}", field, lo, hi, v));
}

// Points and extents of bodies: finite and within this distance of the origin (m).
constexpr double kMaxExtent = 1e4;

Error point(const v1::Vec3& p, const std::string& field, Vec3* out) {
  *out = from_proto(p);
  if (out->allFinite() && out->cwiseAbs().maxCoeff() <= kMaxExtent) return {};
  return invalid(fmt::format("{} must be finite and within {} m of the origin, got ({}, {}, {})", field, kMaxExtent,
                             out->x(), out->y(), out->z()));
}

Error unit_axis(const v1::Vec3& p, const std::string& field, Vec3* out) {
  const Vec3 a = from_proto(p);
  if (!a.allFinite() || !(a.norm() > 1e-12))
    return invalid(fmt::format("{} must be a finite non-zero vector, got ({}, {}, {})", field, a.x(), a.y(), a.z()));
  *out = a.normalized();
  return {};
}

#define PLIANT_OPT_DOUBLE(msg, name, dst, lo, hi, lo_open, unit)                                       \
  if ((msg).has_##name()) {                                                                           \
    if (Error e = in_range(p + "." #name, (msg).name(), lo, hi, lo_open, unit); !e.ok()) return e;    \
    dst = (msg).name();                                                                               \
  }
#define PLIANT_OPT_INT(msg, name, dst, lo, hi)                                            \
  if ((msg).has_##name()) {                                                              \
    if (Error e = int_range(p + "." #name, (msg).name(), lo, hi); !e.ok()) return e;     \
    dst = (msg).name();                                                                  \
  }

Error pins_from(const v1::ParticlePins& pins, const std::string& p, BodyConfig* c) {
  c->pin_indices.assign(pins.indices().begin(), pins.indices().end());
  for (int i = 0; i < pins.boxes_size(); ++i) {
    Vec3 lo, hi;
    const std::string f = fmt::format("{}.boxes[{}]", p, i);
    if (Error e = point(pins.boxes(i).min(), f + ".min", &lo); !e.ok()) return e;
    if (Error e = point(pins.boxes(i).max(), f + ".max", &hi); !e.ok()) return e;
    if ((lo.array() > hi.array()).any())
      return invalid(fmt::format("{} must have min <= max, got min ({}, {}, {}) max ({}, {}, {})", f, lo.x(), lo.y(),
                                 lo.z(), hi.x(), hi.y(), hi.z()));
    c->pin_boxes.emplace_back(lo, hi);
  }
  return {};
}

// An emitter; p names it (spec.bodies[i].fluid.emitters[k]). d: the fluid's spacing.
Error emitter_from(const v1::FluidEmitter& m, const std::string& p, double d, BodyConfig* c) {
  FluidEmitter e;
  if (Error err = point(m.center(), p + ".center", &e.centre); !err.ok()) return err;
  if (m.has_direction())
    if (Error err = unit_axis(m.direction(), p + ".direction", &e.direction); !err.ok()) return err;
  if (Error err = in_range(p + ".speed", m.speed(), 0.0, 100.0, true, "m/s"); !err.ok()) return err;
  e.speed = m.speed();
  e.max_particles = m.has_max_particles() ? m.max_particles() : kDefaultEmitterParticles;
  if (Error err = int_range(p + ".max_particles", static_cast<int64_t>(e.max_particles), 1,
                            static_cast<int64_t>(kMaxParticlesPerScene));
      !err.ok())
    return err;
  // Lattice points across the opening's bounding square: at least as many as a layer holds.
  auto across = [d](double half) { return 2.0 * std::floor(half / d + 1e-9) + 1.0; };
  double layer = 0;
  switch (m.opening_case()) {
    case v1::FluidEmitter::kRadius:
      e.shape = FluidEmitter::Shape::Disc;
      if (Error err = in_range(p + ".radius", m.radius(), 0.0, 10.0, true, "m"); !err.ok()) return err;
      e.radius = m.radius();
      layer = across(e.radius) * across(e.radius);
      break;
    case v1::FluidEmitter::kRectangle: {
      const auto& r = m.rectangle();
      e.shape = FluidEmitter::Shape::Rectangle;
      if (Error err = in_range(p + ".rectangle.half_u", r.half_u(), 0.0, 10.0, true, "m"); !err.ok()) return err;
      if (Error err = in_range(p + ".rectangle.half_v", r.half_v(), 0.0, 10.0, true, "m"); !err.ok()) return err;
      e.half_u = r.half_u();
      e.half_v = r.half_v();
      if (r.has_u_axis()) {
        e.u_axis = from_proto(r.u_axis());
        if (!e.u_axis.allFinite())
          return invalid(fmt::format("{}.rectangle.u_axis must be finite, got ({}, {}, {})", p, e.u_axis.x(),
                                     e.u_axis.y(), e.u_axis.z()));
      }
      layer = across(e.half_u) * across(e.half_v);
      break;
    }
    default:
      return invalid(p + ": no opening set; set one of radius, rectangle");
  }
  if (layer > static_cast<double>(e.max_particles))
    return invalid(fmt::format("{}: the opening spans up to {} lattice points per layer at spacing {} m, more than its "
                               "max_particles {}; make it smaller or raise max_particles",
                               p, layer, d, e.max_particles));
  c->emitters.push_back(e);
  return {};
}

Error fluid_from(const v1::FluidSpec& f, const std::string& p, BodyConfig* c, size_t* particles) {
  FluidSettings& s = c->fluid;
  PLIANT_OPT_DOUBLE(f, spacing, s.spacing, 1e-4, 10.0, false, "m")
  PLIANT_OPT_DOUBLE(f, rest_density, s.rest_density, 1.0, 1e5, false, "kg/m^3")
  PLIANT_OPT_INT(f, substeps, s.substeps, 1, 64)
  PLIANT_OPT_INT(f, iterations, s.iterations, 1, 100)
  PLIANT_OPT_DOUBLE(f, viscosity, s.xsph, 0.0, 1.0, false, "")
  PLIANT_OPT_DOUBLE(f, scorr_k, s.scorr_k, 0.0, 1.0, false, "")
  PLIANT_OPT_INT(f, scorr_n, s.scorr_n, 1, 8)
  if (f.has_scorr_dq()) {
    if (!(f.scorr_dq() > 0 && f.scorr_dq() < 1))
      return invalid(fmt::format("{}.scorr_dq must be in (0, 1), got {}", p, f.scorr_dq()));
    s.scorr_dq = f.scorr_dq();
  }
  PLIANT_OPT_DOUBLE(f, vorticity, s.vorticity, 0.0, 100.0, false, "m/s")
  PLIANT_OPT_DOUBLE(f, relaxation, s.relaxation, 0.0, 1.0, true, "")
  PLIANT_OPT_DOUBLE(f, support_ratio, s.support_ratio, 1.5, 4.0, false, "")
  PLIANT_OPT_DOUBLE(f, particle_radius, s.particle_radius, 0.0, 1.0, true, "")
  PLIANT_OPT_INT(f, sort_interval, s.sort_interval, 0, 1000)
  if (f.has_container_density()) s.container_density = f.container_density();
  if (f.has_surface_density()) s.surface_density = f.surface_density();
  if (f.has_container()) {
    google::protobuf::RepeatedPtrField<v1::Collider> one;
    *one.Add() = f.container();
    std::vector<Collider> cols;
    if (Error e = colliders_from(one, p + ".container", &cols); !e.ok()) {
      // colliders_from names the list's element: this is a single field.
      const std::string from = p + ".container[0]";
      if (auto at = e.message.find(from); at != std::string::npos) e.message.replace(at, from.size(), p + ".container");
      return e;
    }
    if (cols[0].shape != Collider::Shape::Box)
      return invalid(fmt::format("{}.container must be a box (its inside is the fluid's domain)", p));
    if (cols[0].half_extent.minCoeff() <= s.particle_radius * s.spacing)
      return invalid(fmt::format("{}.container.box.half_extent must exceed the particle radius {} m in every axis", p,
                                 s.particle_radius * s.spacing));
    s.container = cols[0];
  }
  if (f.blocks_size() == 0 && f.emitters_size() == 0)
    return invalid(p + ".blocks and " + p + ".emitters are empty; give at least one box of particles or an emitter");
  double total = 0;
  for (int i = 0; i < f.blocks_size(); ++i) {
    const std::string b = fmt::format("{}.blocks[{}]", p, i);
    FluidBlock block;
    if (Error e = point(f.blocks(i).min(), b + ".min", &block.min); !e.ok()) return e;
    if (Error e = point(f.blocks(i).max(), b + ".max", &block.max); !e.ok()) return e;
    if (Error e = point(f.blocks(i).velocity(), b + ".velocity", &block.velocity); !e.ok()) return e;
    const Vec3 ext = block.max - block.min;
    if (ext.minCoeff() < 0)
      return invalid(fmt::format("{}.max must not be below min in any axis, got extent ({}, {}, {}) m", b, ext.x(),
                                 ext.y(), ext.z()));
    double n = 1;
    for (int k = 0; k < 3; ++k) n *= std::floor(ext[k] / s.spacing + 1e-9);
    if (n < 1)
      return invalid(fmt::format("{} holds no particle: each side must be at least spacing = {} m, got extent ({}, {}, {}) m",
                                 b, s.spacing, ext.x(), ext.y(), ext.z()));
    total += n;
    c->blocks.push_back(block);
  }
  if (f.emitters_size() > static_cast<int>(kMaxEmittersPerFluid))
    return invalid(fmt::format("{}.emitters has {} emitters, at most {}", p, f.emitters_size(), kMaxEmittersPerFluid));
  for (int i = 0; i < f.emitters_size(); ++i)
    if (Error e = emitter_from(f.emitters(i), fmt::format("{}.emitters[{}]", p, i), s.spacing, c); !e.ok()) return e;
  // The capacity: what the blocks hold and what the emitters may add.
  for (const FluidEmitter& e : c->emitters) total += static_cast<double>(e.max_particles);
  *particles = total > 1e15 ? size_t(1e15) : static_cast<size_t>(total);
  return {};
}

// The settings cloth and ropes share.
template <class Msg>
Error constraint_common(const Msg& m, const std::string& p, ConstraintBodySettings& s) {
  PLIANT_OPT_DOUBLE(m, stretch_compliance, s.stretch_compliance, 0.0, 1.0, false, "m/N")
  PLIANT_OPT_DOUBLE(m, damping, s.damping, 0.0, 1000.0, false, "1/s")
  PLIANT_OPT_INT(m, substeps, s.substeps, 1, 256)
  PLIANT_OPT_INT(m, iterations, s.iterations, 1, 100)
  PLIANT_OPT_DOUBLE(m, thickness, s.thickness, 0.0, 1.0, true, "m")
  if (m.has_bending()) s.bending = m.bending();
  return {};
}

Error cloth_from(const v1::ClothSpec& cl, const std::string& p, const std::vector<std::string>& model_path,
                 BodyConfig* c, size_t* particles) {
  ConstraintBodySettings& s = c->constraint;
  if (Error e = constraint_common(cl, p, s); !e.ok()) return e;
  PLIANT_OPT_DOUBLE(cl, shear_compliance, s.shear_compliance, 0.0, 1.0, false, "m/N")
  PLIANT_OPT_DOUBLE(cl, bend_compliance, s.bend_compliance, 0.0, 1e9, false, "1/(N m)")
  if (cl.has_self_collision()) s.self_collision = cl.self_collision();
  PLIANT_OPT_DOUBLE(cl, mass_per_area, c->mass_per_area, 0.0, 1e4, true, "kg/m^2")
  c->grid.mass_per_area = c->mass_per_area;
  switch (cl.shape_case()) {
    case v1::ClothSpec::kGrid: {
      const auto& g = cl.grid();
      const std::string f = p + ".grid";
      if (Error e = int_range(f + ".resolution_x", g.resolution_x(), 2, 1024); !e.ok()) return e;
      if (Error e = int_range(f + ".resolution_y", g.resolution_y(), 2, 1024); !e.ok()) return e;
      if (Error e = in_range(f + ".size_x", g.size_x(), 0.0, kMaxExtent, true, "m"); !e.ok()) return e;
      if (Error e = in_range(f + ".size_y", g.size_y(), 0.0, kMaxExtent, true, "m"); !e.ok()) return e;
      c->grid.nx = static_cast<int>(g.resolution_x());
      c->grid.ny = static_cast<int>(g.resolution_y());
      c->grid.size_x = g.size_x();
      c->grid.size_y = g.size_y();
      if (Error e = point(g.origin(), f + ".origin", &c->grid.origin); !e.ok()) return e;
      if (g.has_u())
        if (Error e = unit_axis(g.u(), f + ".u", &c->grid.u); !e.ok()) return e;
      if (g.has_v())
        if (Error e = unit_axis(g.v(), f + ".v", &c->grid.v); !e.ok()) return e;
      if (std::abs(c->grid.u.dot(c->grid.v)) > 1.0 - 1e-9)
        return invalid(fmt::format("{}.u and {}.v must not be parallel", f, f));
      if (g.has_shear()) c->grid.shear = g.shear();
      *particles = size_t(c->grid.nx) * size_t(c->grid.ny);
      break;
    }
    case v1::ClothSpec::kModelPath: {
      const std::string f = p + ".model_path";
      c->mesh_name = cl.model_path();
      if (Error e = resolve_model_file(f, cl.model_path(), model_path, &c->mesh_file); !e.ok()) return e;
      if (cl.has_scale())
        if (Error e = in_range(p + ".scale", cl.scale(), 0.0, 1e6, true, ""); !e.ok()) return e;
      c->mesh_scale = cl.has_scale() ? cl.scale() : 1.0;
      *particles = 0;  // known once read
      break;
    }
    default:
      return invalid(p + ": no shape set; set one of grid, model_path");
  }
  return pins_from(cl.pins(), p + ".pins", c);
}

Error rope_from(const v1::RopeSpec& r, const std::string& p, BodyConfig* c, size_t* particles) {
  ConstraintBodySettings& s = c->constraint;
  if (Error e = constraint_common(r, p, s); !e.ok()) return e;
  PLIANT_OPT_DOUBLE(r, bend_compliance, s.bend_compliance, 0.0, 1e9, false, "m/N")
  PLIANT_OPT_DOUBLE(r, linear_density, c->linear_density, 0.0, 1e4, true, "kg/m")
  s.self_collision = false;
  if (r.points_size() < 2)
    return invalid(fmt::format("{}.points has {} points; a rope needs at least 2", p, r.points_size()));
  double length = 0;
  for (int i = 0; i < r.points_size(); ++i) {
    Vec3 x;
    if (Error e = point(r.points(i), fmt::format("{}.points[{}]", p, i), &x); !e.ok()) return e;
    if (i > 0) length += (x - c->rope_points.back()).norm();
    c->rope_points.push_back(x);
  }
  if (!(length > 1e-9)) return invalid(fmt::format("{}.points span no length (all at one point)", p));
  if (Error e = int_range(p + ".segments", r.segments(), 1, 100000); !e.ok()) return e;
  c->segments = static_cast<int>(r.segments());
  *particles = size_t(c->segments) + 1;
  return pins_from(r.pins(), p + ".pins", c);
}

#undef PLIANT_OPT_DOUBLE
#undef PLIANT_OPT_INT

}  // namespace

Error bodies_from_spec(const google::protobuf::RepeatedPtrField<v1::BodySpec>& bodies, const std::string& prefix,
                       const std::vector<std::string>& model_path, std::vector<BodyConfig>* out) {
  out->clear();
  if (bodies.size() > static_cast<int>(kMaxBodiesPerScene))
    return Error::make(Code::ResourceExhausted,
                       fmt::format("{} has {} bodies, more than the limit of {} bodies per scene", prefix,
                                   bodies.size(), kMaxBodiesPerScene));
  std::set<std::string> names;
  size_t total = 0;
  for (int i = 0; i < bodies.size(); ++i) {
    const v1::BodySpec& b = bodies.Get(i);
    const std::string p = fmt::format("{}[{}]", prefix, i);
    if (b.name().empty()) return invalid(p + ".name is empty; every body needs a name");
    if (Error e = check_name(p + ".name", b.name()); !e.ok()) return e;
    if (!names.insert(b.name()).second)
      return invalid(fmt::format("{}.name {} is already the name of another body in this scene", p, echo(b.name())));
    BodyConfig c;
    c.name = b.name();
    size_t particles = 0;
    Error e;
    switch (b.kind_case()) {
      case v1::BodySpec::kFluid: c.kind = "fluid"; e = fluid_from(b.fluid(), p + ".fluid", &c, &particles); break;
      case v1::BodySpec::kCloth: c.kind = "cloth"; e = cloth_from(b.cloth(), p + ".cloth", model_path, &c, &particles); break;
      case v1::BodySpec::kRope: c.kind = "rope"; e = rope_from(b.rope(), p + ".rope", &c, &particles); break;
      default: return invalid(p + ": no kind set; set one of fluid, cloth, rope");
    }
    if (!e.ok()) return e;
    if (b.has_soft_body_contact()) c.soft_body_contact = b.soft_body_contact();
    if (b.has_soft_body_friction()) {
      if (Error fe = in_range(p + ".soft_body_friction", b.soft_body_friction(), 0.0, 10.0, false, ""); !fe.ok())
        return fe;
      c.soft_body_friction = b.soft_body_friction();
    }
    if (b.has_body_contact()) c.body_contact = b.body_contact();
    if (b.has_body_friction()) {
      if (Error fe = in_range(p + ".body_friction", b.body_friction(), 0.0, 10.0, false, ""); !fe.ok()) return fe;
      c.body_friction = b.body_friction();
    }
    total += particles;
    if (total > kMaxParticlesPerScene)
      return Error::make(Code::ResourceExhausted,
                         fmt::format("{} brings the scene's particles to {} or more, beyond the limit of {} particles "
                                     "per scene", p, total, kMaxParticlesPerScene));
    out->push_back(std::move(c));
  }
  return {};
}

void bodies_to_spec(const std::vector<BodyConfig>& bodies, v1::SceneSpec* spec) {
  for (const BodyConfig& c : bodies) {
    auto* b = spec->add_bodies();
    b->set_name(c.name);
    b->set_soft_body_contact(c.soft_body_contact);
    b->set_soft_body_friction(c.soft_body_friction);
    b->set_body_contact(c.body_contact);
    b->set_body_friction(c.body_friction);
    if (c.kind == "fluid") {
      auto* f = b->mutable_fluid();
      const FluidSettings& s = c.fluid;
      f->set_spacing(s.spacing);
      f->set_rest_density(s.rest_density);
      for (const FluidBlock& blk : c.blocks) {
        auto* pb = f->add_blocks();
        to_proto(blk.min, pb->mutable_min());
        to_proto(blk.max, pb->mutable_max());
        to_proto(blk.velocity, pb->mutable_velocity());
      }
      if (s.container) {
        auto* pc = f->mutable_container();
        to_proto(s.container->point, pc->mutable_box()->mutable_center());
        to_proto(s.container->half_extent, pc->mutable_box()->mutable_half_extent());
        pc->set_static_friction(s.container->static_friction);
        pc->set_dynamic_friction(s.container->dynamic_friction);
      }
      f->set_substeps(s.substeps);
      f->set_iterations(s.iterations);
      f->set_viscosity(s.xsph);
      f->set_scorr_k(s.scorr_k);
      f->set_scorr_n(s.scorr_n);
      f->set_scorr_dq(s.scorr_dq);
      f->set_vorticity(s.vorticity);
      f->set_relaxation(s.relaxation);
      f->set_support_ratio(s.support_ratio);
      f->set_particle_radius(s.particle_radius);
      f->set_container_density(s.container_density);
      f->set_surface_density(s.surface_density);
      f->set_sort_interval(s.sort_interval);
      for (const FluidEmitter& e : c.emitters) {
        auto* pe = f->add_emitters();
        to_proto(e.centre, pe->mutable_center());
        to_proto(e.direction, pe->mutable_direction());
        pe->set_speed(e.speed);
        if (e.shape == FluidEmitter::Shape::Disc) {
          pe->set_radius(e.radius);
        } else {
          pe->mutable_rectangle()->set_half_u(e.half_u);
          pe->mutable_rectangle()->set_half_v(e.half_v);
          if (!e.u_axis.isZero()) to_proto(e.u_axis, pe->mutable_rectangle()->mutable_u_axis());
        }
        pe->set_max_particles(static_cast<uint32_t>(e.max_particles));
      }
      continue;
    }
    const ConstraintBodySettings& s = c.constraint;
    v1::ParticlePins* pins = nullptr;
    if (c.kind == "cloth") {
      auto* cl = b->mutable_cloth();
      if (!c.mesh_name.empty()) {
        cl->set_model_path(c.mesh_name);
        cl->set_scale(c.mesh_scale);
      } else {
        auto* g = cl->mutable_grid();
        g->set_resolution_x(static_cast<uint32_t>(c.grid.nx));
        g->set_resolution_y(static_cast<uint32_t>(c.grid.ny));
        g->set_size_x(c.grid.size_x);
        g->set_size_y(c.grid.size_y);
        to_proto(c.grid.origin, g->mutable_origin());
        to_proto(c.grid.u, g->mutable_u());
        to_proto(c.grid.v, g->mutable_v());
        g->set_shear(c.grid.shear);
      }
      cl->set_mass_per_area(c.mass_per_area);
      cl->set_stretch_compliance(s.stretch_compliance);
      cl->set_shear_compliance(s.shear_compliance);
      cl->set_bend_compliance(s.bend_compliance);
      cl->set_bending(s.bending);
      cl->set_damping(s.damping);
      cl->set_substeps(s.substeps);
      cl->set_iterations(s.iterations);
      cl->set_thickness(s.thickness);
      cl->set_self_collision(s.self_collision);
      pins = cl->mutable_pins();
    } else {
      auto* r = b->mutable_rope();
      for (const Vec3& x : c.rope_points) to_proto(x, r->add_points());
      r->set_segments(static_cast<uint32_t>(c.segments));
      r->set_linear_density(c.linear_density);
      r->set_stretch_compliance(s.stretch_compliance);
      r->set_bend_compliance(s.bend_compliance);
      r->set_bending(s.bending);
      r->set_damping(s.damping);
      r->set_substeps(s.substeps);
      r->set_iterations(s.iterations);
      r->set_thickness(s.thickness);
      pins = r->mutable_pins();
    }
    for (uint32_t i : c.pin_indices) pins->add_indices(i);
    for (const auto& [lo, hi] : c.pin_boxes) {
      auto* pb = pins->add_boxes();
      to_proto(lo, pb->mutable_min());
      to_proto(hi, pb->mutable_max());
    }
  }
}

}  // namespace pliant::server
