// SPDX-License-Identifier: Apache-2.0
// Frames, tool poses and feedback, grab points and topology in the API's messages: what the
// streams and the interaction calls exchange, built or checked in one place for every handler.
#include "pliant/server/stream_proto.hpp"

#include "pliant/server/spec_proto.hpp"

#include <spdlog/fmt/fmt.h>

#include <array>
#include <chrono>
#include <cmath>

namespace pliant::server {

namespace {

Error invalid(std::string m) { return Error::invalid(std::move(m)); }

}  // namespace

Error parse_stream_request(const v1::StreamFramesRequest& req, FrameSelection* out) {
  if (req.fields_size() > 0) {
    out->positions = out->residuals = out->solver_stats = false;
    for (int i = 0; i < req.fields_size(); ++i) {
      switch (req.fields(i)) {
        case v1::FRAME_FIELD_POSITIONS: out->positions = true; break;
        case v1::FRAME_FIELD_RESIDUALS: out->residuals = true; break;
        case v1::FRAME_FIELD_SOLVER_STATS: out->solver_stats = true; break;
        default:
          return invalid(fmt::format("fields[{}] has unknown value {}", i, static_cast<int>(req.fields(i))));
      }
    }
  }
  out->surface_only = req.surface_only();
  if (!std::isfinite(req.max_rate_hz()) || req.max_rate_hz() < 0 ||
      (req.max_rate_hz() > 0 && (req.max_rate_hz() < kMinRateHz || req.max_rate_hz() > kMaxRateHz)))
    return invalid(fmt::format("max_rate_hz must be 0 (no limit) or in [{}, {}] Hz, got {}", kMinRateHz, kMaxRateHz,
                               req.max_rate_hz()));
  return {};
}

void solver_stats_to_proto(const StepReport& r, bool all, v1::SolverStats* out) {
  out->set_iterations(r.iterations);
  out->set_residual_final(r.residual_final);
  out->set_relative_residual(relative_residual(r));
  if (!all) return;
  out->set_substeps(r.substeps);
  out->set_residual_initial(r.residual_initial);
  out->set_accelerations_tried(r.accelerations_tried);
  out->set_accelerations_accepted(r.accelerations_accepted);
  out->set_accelerations_rejected(r.accelerations_tried - r.accelerations_accepted);
  out->set_step_wall_ms(r.wall_ms);
  out->set_stopped_by_tolerance(r.stopped_by_tolerance);
  out->set_stopped_by_budget(r.stopped_by_budget);
  out->set_floor_stopped_by_budget(r.floor_stopped_by_budget);
  out->set_volume_corrections(r.volume_corrections);
}

void frame_to_proto(const Frame& f, const FrameSelection& sel, const std::vector<int32_t>& surface, uint64_t skipped,
                    v1::Frame* out) {
  out->set_tick(f.tick);
  out->set_sim_time(f.sim_time);
  out->set_skipped_frames(skipped);
  if (sel.positions) {
    auto* pos = out->mutable_positions();
    if (sel.surface_only) {
      pos->Resize(static_cast<int>(3 * surface.size()), 0.0f);
      float* dst = pos->mutable_data();
      for (size_t i = 0; i < surface.size(); ++i)
        for (int k = 0; k < 3; ++k) dst[3 * i + k] = f.positions[3 * surface[i] + k];
    } else {
      pos->Add(f.positions.begin(), f.positions.end());
    }
    out->set_surface_only(sel.surface_only);
    for (const auto& b : f.bodies) {
      auto* pb = out->add_bodies();
      pb->set_name(b.name);
      pb->mutable_positions()->Add(b.positions.begin(), b.positions.end());
    }
  }
  if (sel.residuals) out->mutable_residuals()->Add(f.solver.residuals.begin(), f.solver.residuals.end());
  solver_stats_to_proto(f.solver, sel.solver_stats, out->mutable_solver());
  if (sel.solver_stats)
    for (const auto& b : f.bodies) {
      auto* bs = out->mutable_solver()->add_bodies();
      bs->set_name(b.name);
      bs->set_step_wall_ms(b.report.wall_ms);
      bs->set_substeps(b.report.substeps);
      bs->set_iterations(b.report.iterations);
      bs->set_constraint_error(b.report.constraint_error);
      bs->set_max_constraint_error(b.report.max_constraint_error);
      bs->set_contacts(static_cast<uint32_t>(b.report.contacts));
      bs->set_tool_contacts(static_cast<uint32_t>(b.report.tool_contacts));
      bs->set_body_contacts(static_cast<uint32_t>(b.report.body_contacts));
      bs->set_soft_body_contacts(static_cast<uint32_t>(b.report.soft_body_contacts));
      bs->set_self_collision_suspended(b.report.self_collision_suspended);
      bs->set_step_parts(static_cast<uint32_t>(b.report.parts));
    }
  out->set_late_ticks(f.counters.late_ticks);
  out->set_skipped_ticks(f.counters.skipped_ticks);
  out->set_lateness_ms(f.lateness_ms);
  out->set_ticks_per_second(f.counters.ticks_per_second);
  out->set_rolled_back(f.rolled_back);
  out->set_rollbacks(f.counters.rollbacks);
  out->set_rollback_reason(f.rollback_reason);
  out->set_published_unix_ns(f.published_unix_ns);
  out->set_state(scene_state_of(f.mode, f.running));
}

Error parse_tool_pose(const v1::ToolPose& p, const RigidTool* previous, RigidTool* out) {
  RigidTool t;
  if (previous) t = *previous;
  else {
    t.radius = 0.005;
    t.half_length = 0.02;
  }
  switch (p.shape()) {
    case v1::TOOL_SHAPE_CAPSULE: t.shape = RigidTool::Shape::Capsule; break;
    case v1::TOOL_SHAPE_SPHERE: t.shape = RigidTool::Shape::Sphere; break;
    case v1::TOOL_SHAPE_UNSPECIFIED: if (!previous) t.shape = RigidTool::Shape::Sphere; break;
    default: return invalid(fmt::format("shape = {} is not a ToolShape", static_cast<int>(p.shape())));
  }
  if (!p.has_position()) return invalid(fmt::format("pose seq {}: position is not set", p.seq()));
  if (Error e = finite_from_proto(p.position(), "position", &t.position); !e.ok()) return e;
  if (p.has_orientation()) {
    const auto& q = p.orientation();
    Eigen::Quaterniond o(q.w(), q.x(), q.y(), q.z());
    const double n = o.norm();
    if (!std::isfinite(n) || n < 1e-6)
      return invalid(fmt::format("orientation ({}, {}, {}, {}) is not a rotation (norm {})", q.w(), q.x(), q.y(), q.z(), n));
    t.orientation = o.normalized();
  }
  if (p.has_radius()) {
    if (!std::isfinite(p.radius()) || p.radius() <= 0) return invalid(fmt::format("radius must be > 0, got {}", p.radius()));
    t.radius = p.radius();
  }
  if (p.has_half_length()) {
    if (!std::isfinite(p.half_length()) || p.half_length() < 0)
      return invalid(fmt::format("half_length must be >= 0, got {}", p.half_length()));
    t.half_length = p.half_length();
  }
  if (p.has_static_friction()) {
    if (!std::isfinite(p.static_friction()) || p.static_friction() < 0)
      return invalid(fmt::format("static_friction must be >= 0, got {}", p.static_friction()));
    t.static_friction = p.static_friction();
  }
  if (p.has_dynamic_friction()) {
    if (!std::isfinite(p.dynamic_friction()) || p.dynamic_friction() < 0)
      return invalid(fmt::format("dynamic_friction must be >= 0, got {}", p.dynamic_friction()));
    t.dynamic_friction = p.dynamic_friction();
  }
  *out = t;
  return {};
}

bool tool_feedback_to_proto(const Frame& frame, uint64_t tool_id, uint64_t skipped, v1::ToolFeedback* out) {
  const FrameTool* ft = nullptr;
  for (const FrameTool& t : frame.tools)
    if (t.tool_id == tool_id) ft = &t;
  if (!ft) return false;
  out->Clear();
  out->set_tick(frame.tick);
  out->set_sim_time(frame.sim_time);
  out->set_pose_seq(ft->pose_seq);
  out->set_pose_client_time_ns(ft->pose_client_ns);
  to_proto(ft->reaction.force, out->mutable_force());
  to_proto(ft->reaction.torque, out->mutable_torque());
  for (const ToolContact& tc : ft->reaction.contacts) {
    auto* cp = out->add_contacts();
    cp->set_vertex(tc.vertex);
    to_proto(tc.point, cp->mutable_point());
    to_proto(tc.normal, cp->mutable_normal());
    to_proto(tc.force, cp->mutable_force());
  }
  out->set_skipped_ticks(skipped);
  out->set_server_time_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(
                              std::chrono::system_clock::now().time_since_epoch())
                              .count());
  return true;
}

Error grab_from_proto(const v1::GrabRequest& req, const Scene& scene, Attachment* out) {
  auto m = scene.model();
  const auto nv = static_cast<int64_t>(m->vertex_count());
  const auto nt = static_cast<int64_t>(m->tet_count());
  Attachment a;
  switch (req.point_case()) {
    case v1::GrabRequest::kVertex:
      if (req.vertex() < 0 || req.vertex() >= nv)
        return invalid(fmt::format("vertex = {} is out of range [0, {})", req.vertex(), nv));
      a = Attachment::vertex(req.vertex(), Vec3::Zero());
      break;
    case v1::GrabRequest::kTetPoint: {
      const auto& tp = req.tet_point();
      if (tp.tet() < 0 || tp.tet() >= nt)
        return invalid(fmt::format("tet_point.tet = {} is out of range [0, {})", tp.tet(), nt));
      if (tp.barycentric_size() != 4)
        return invalid(fmt::format("tet_point.barycentric must hold 4 values, got {}", tp.barycentric_size()));
      std::array<double, 4> b{};
      double sum = 0;
      for (int k = 0; k < 4; ++k) {
        b[k] = tp.barycentric(k);
        if (!std::isfinite(b[k]) || b[k] < -1e-9 || b[k] > 1 + 1e-9)
          return invalid(fmt::format("tet_point.barycentric[{}] = {} must be in [0, 1]", k, b[k]));
        sum += b[k];
      }
      if (std::abs(sum - 1) > 1e-6)
        return invalid(fmt::format("tet_point.barycentric must sum to 1, got {}", sum));
      a = Attachment::in_tet(m->tets[tp.tet()].v, b, Vec3::Zero());
      break;
    }
    default:
      return invalid("point is not set: give vertex or tet_point");
  }
  if (req.has_target()) {
    if (Error e = finite_from_proto(req.target(), "target", &a.target); !e.ok()) return e;
  } else {
    // Hold the point where it is now: the latest frame, or before the first tick the positions
    // the scene started from (a restored snapshot's, not the rest shape).
    std::vector<Vec3> x = scene.initial_positions().size() == m->vertex_count() ? scene.initial_positions() : m->rest_positions;
    if (auto f = scene.latest_frame(); f && f->positions.size() == 3 * x.size())
      for (size_t i = 0; i < x.size(); ++i) x[i] = Vec3(f->positions[3 * i], f->positions[3 * i + 1], f->positions[3 * i + 2]);
    a.target = a.point(x);
  }
  if (req.has_compliance()) {
    if (!std::isfinite(req.compliance()) || req.compliance() < 0)
      return invalid(fmt::format("compliance must be finite and >= 0, got {}", req.compliance()));
    a.compliance = req.compliance();
  }
  if (std::string msg = validate_interaction({a}, {}, *m); !msg.empty()) return invalid(msg);
  *out = a;
  return {};
}

void topology_to_proto(const Scene& scene, v1::Topology* out) {
  auto m = scene.model();
  out->set_vertex_count(static_cast<uint32_t>(m->vertex_count()));
  out->mutable_rest_positions()->Reserve(static_cast<int>(3 * m->vertex_count()));
  for (const auto& p : m->rest_positions)
    for (int k = 0; k < 3; ++k) out->add_rest_positions(static_cast<float>(p[k]));
  for (const auto& t : m->tets)
    for (int k = 0; k < 4; ++k) out->add_tets(t.v[k]);
  for (const auto& t : m->surface)
    for (int k = 0; k < 3; ++k) out->add_surface_triangles(t[k]);
  for (int32_t v : scene.surface_vertices()) out->add_surface_vertices(v);
  for (size_t i = 0; i < m->fixed.size(); ++i)
    if (m->fixed[i]) out->add_fixed_vertices(static_cast<int32_t>(i));
  for (const BodyInfo& b : scene.bodies()) {
    auto* pb = out->add_bodies();
    pb->set_name(b.name);
    pb->set_kind(b.kind);
    pb->set_particle_count(static_cast<uint32_t>(b.particles));
    pb->set_max_particle_count(static_cast<uint32_t>(b.capacity));
    pb->mutable_rest_positions()->Reserve(static_cast<int>(3 * b.rest.size()));
    for (const auto& x : b.rest)
      for (int k = 0; k < 3; ++k) pb->add_rest_positions(static_cast<float>(x[k]));
    for (const auto& t : b.triangles)
      for (int k = 0; k < 3; ++k) pb->add_triangles(t[k]);
    pb->mutable_pinned()->Add(b.pinned.begin(), b.pinned.end());
  }
}

}  // namespace pliant::server
