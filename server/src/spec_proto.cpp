// SPDX-License-Identifier: Apache-2.0
// SceneSpec <-> SceneConfig, checked: the rules every way into a scene shares (create, update,
// snapshots), kept apart from the scene map so that each check is written once.
#include "pliant/server/spec_proto.hpp"

#include "pliant/server/edge.hpp"

#include "pliant/proto/enums.hpp"

#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/stepper.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

namespace pliant::server {

namespace {

Error invalid(std::string m) { return Error::invalid(std::move(m)); }

bool valid_name(const std::string& s) {
  if (s.empty() || s.size() > 64 || s == "." || s == "..") return false;
  return std::all_of(s.begin(), s.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == '-';
  });
}

}  // namespace

Error check_name(const std::string& field, const std::string& value) {
  if (valid_name(value)) return {};
  return invalid(fmt::format("{} {} is not a valid name: use 1 to 64 of A-Z a-z 0-9 _ . -",
                             field, echo(value)));
}

Vec3 from_proto(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

void to_proto(const Vec3& v, v1::Vec3* out) {
  out->set_x(v.x());
  out->set_y(v.y());
  out->set_z(v.z());
}

Error finite_from_proto(const v1::Vec3& v, const std::string& field, Vec3* out) {
  *out = from_proto(v);
  if (out->allFinite()) return {};
  return invalid(fmt::format("{} must be finite, got ({}, {}, {})", field, out->x(), out->y(), out->z()));
}

std::optional<TickMode> tick_mode_from(v1::TickMode m) {
  switch (m) {
    case v1::TICK_MODE_REALTIME: return TickMode::Realtime;
    case v1::TICK_MODE_LOCKSTEP: return TickMode::Lockstep;
    case v1::TICK_MODE_AS_FAST_AS_POSSIBLE: return TickMode::AsFastAsPossible;
    default: return std::nullopt;
  }
}

v1::TickMode tick_mode_to(TickMode m) {
  switch (m) {
    case TickMode::Realtime: return v1::TICK_MODE_REALTIME;
    case TickMode::Lockstep: return v1::TICK_MODE_LOCKSTEP;
    case TickMode::AsFastAsPossible: return v1::TICK_MODE_AS_FAST_AS_POSSIBLE;
  }
  return v1::TICK_MODE_UNSPECIFIED;
}

// Merges the set fields of `p` into `s`; `prefix` names the message in errors ("spec.solver").
Error merge_solver(const v1::SolverSettings& p, const std::string& prefix, int max_threads,
                   SolverSettings& s) {
  if (p.sweep() != v1::SWEEP_UNSPECIFIED) {
    auto sw = proto::sweep_from(p.sweep());
    if (!sw) return invalid(fmt::format("{}.sweep has unknown value {}", prefix, static_cast<int>(p.sweep())));
    s.sweep = *sw;
  }
  if (p.method() != v1::METHOD_UNSPECIFIED) {
    auto m = proto::method_from(p.method());
    if (!m) return invalid(fmt::format("{}.method has unknown value {}", prefix, static_cast<int>(p.method())));
    s.method = *m;
  }
  if (p.damping() != v1::DAMPING_UNSPECIFIED) {
    auto d = proto::damping_from(p.damping());
    if (!d) return invalid(fmt::format("{}.damping has unknown value {}", prefix, static_cast<int>(p.damping())));
    s.damping = *d;
  }
  if (p.newton_linear_solver() != v1::NEWTON_LINEAR_SOLVER_UNSPECIFIED) {
    auto l = proto::newton_linear_solver_from(p.newton_linear_solver());
    if (!l)
      return invalid(fmt::format("{}.newton_linear_solver has unknown value {}", prefix,
                                 static_cast<int>(p.newton_linear_solver())));
    s.newton_linear_solver = *l;
  }
  if (p.has_substeps()) s.substeps = p.substeps();
  if (p.has_target_wave_courant_number()) s.target_wave_courant_number = p.target_wave_courant_number();
  if (p.has_iterations()) s.iterations = p.iterations();
  if (p.has_window()) s.window = p.window();
  if (p.has_omega()) s.omega = p.omega();
  if (p.has_tolerance()) s.tolerance = p.tolerance();
  if (p.has_time_budget_ms()) s.time_budget_ms = p.time_budget_ms();
  if (p.has_damping_coefficient()) s.damping_coefficient = p.damping_coefficient();
  if (p.has_inversion_floor()) s.inversion_floor = p.inversion_floor();  // range: check_solver
  if (p.has_threads()) {
    if (p.threads() < 1)
      return invalid(fmt::format("{}.threads must be >= 1, got {}", prefix, p.threads()));
    s.threads = std::min(p.threads(), std::max(1, max_threads));
  }
  return {};
}

Error merge_tick(const v1::TickSettings& p, const std::string& prefix, SolverSettings& s,
                 TickMode& mode) {
  if (p.has_dt()) {
    if (!std::isfinite(p.dt()) || p.dt() <= 0 || p.dt() > 1)
      return invalid(fmt::format("{}.dt must be in (0, 1] s, got {}", prefix, p.dt()));
    s.dt = p.dt();
  }
  if (p.mode() != v1::TICK_MODE_UNSPECIFIED) {
    auto m = tick_mode_from(p.mode());
    if (!m) return invalid(fmt::format("{}.mode has unknown value {}", prefix, static_cast<int>(p.mode())));
    mode = *m;
  }
  return {};
}

Error merge_gravity(const v1::Vec3& g, const std::string& field, SolverSettings& s) {
  Vec3 v;
  if (Error e = finite_from_proto(g, field, &v); !e.ok()) return e;
  s.gravity = v;
  return {};
}

Error check_solver(const SolverSettings& s, const std::string& prefix) {
  std::string err = validate(s);
  if (err.empty()) return {};
  // The solver names its fields "solver.<name>"; say where they are in this request.
  if (err.rfind("solver.", 0) == 0) err = prefix + err.substr(6);
  return invalid(err);
}

bool pins_budget(const v1::SolverSettings& p) {
  return p.has_substeps() || p.has_iterations() || p.has_target_wave_courant_number();
}

Error merge_material(const v1::Material& p, const std::string& prefix, Material& m) {
  if (p.has_young_modulus()) m.young = p.young_modulus();
  if (p.has_poisson_ratio()) m.poisson = p.poisson_ratio();
  if (p.has_density()) m.density = p.density();
  if (p.has_inertia_floor()) m.inertia_floor = p.inertia_floor();
  if (p.has_support_inertia()) m.support_inertia = p.support_inertia();
  if (p.model() != v1::ELASTIC_MODEL_UNSPECIFIED) {
    auto em = proto::elastic_model_from(p.model());
    if (!em)
      return invalid(fmt::format("{}.model must be ELASTIC_MODEL_STVK or ELASTIC_MODEL_COROTATED, got {}", prefix,
                                 int(p.model())));
    m.model = *em;
  }
  if (!(std::isfinite(m.young) && m.young > 0))
    return invalid(fmt::format("{}.young_modulus must be a finite value > 0 Pa, got {}", prefix, m.young));
  if (!(m.poisson > -1 && m.poisson < 0.5))
    return invalid(fmt::format("{}.poisson_ratio must be in (-1, 0.5), got {}", prefix, m.poisson));
  if (!(std::isfinite(m.density) && m.density > 0))
    return invalid(fmt::format("{}.density must be a finite value > 0 kg/m^3, got {}", prefix, m.density));
  if (!(m.inertia_floor >= 0 && m.inertia_floor <= 1))
    return invalid(fmt::format("{}.inertia_floor must be in [0, 1] (a fraction of the mean vertex mass), got {}",
                               prefix, m.inertia_floor));
  if (!(m.support_inertia >= 0 && m.support_inertia <= 1))
    return invalid(fmt::format(
        "{}.support_inertia must be in [0, 1] (a fraction of the mass a vertex carries to the fixed vertices), got {}",
        prefix, m.support_inertia));
  return {};
}

Error check_work(const BodyModel& model, const SolverSettings& s, const std::string& prefix) {
  const int64_t substeps = effective_substeps(model, s);
  const int64_t iterations = std::max(1, s.iterations);
  if (substeps * iterations <= kMaxSweepsPerTick) return {};
  return invalid(fmt::format("{}.substeps x {}.iterations = {} x {} = {} sweeps per tick, more than this server's "
                             "limit of {} (lower either, or use time_budget_ms)",
                             prefix, prefix, substeps, iterations, substeps * iterations, kMaxSweepsPerTick));
}

Error config_from_spec(const v1::SceneSpec& spec, const std::string& prefix, int max_threads, SceneConfig* cfg,
                       Material* material) {
  if (Error e = merge_material(spec.material(), prefix + ".material", *material); !e.ok()) return e;
  if (Error e = merge_solver(spec.solver(), prefix + ".solver", max_threads, cfg->settings); !e.ok()) return e;
  if (Error e = merge_tick(spec.tick(), prefix + ".tick", cfg->settings, cfg->mode); !e.ok()) return e;
  if (spec.has_gravity())
    if (Error e = merge_gravity(spec.gravity(), prefix + ".gravity", cfg->settings); !e.ok()) return e;
  if (Error e = check_solver(cfg->settings, prefix + ".solver"); !e.ok()) return e;
  if (Error e = fixed_from(spec.fixed(), prefix + ".fixed", &cfg->fixed); !e.ok()) return e;
  cfg->fixed_groups.assign(spec.fixed().groups().begin(), spec.fixed().groups().end());
  return colliders_from(spec.colliders(), prefix + ".colliders", &cfg->colliders);
}

Error mesh_from_data(const v1::MeshData& d, const std::string& prefix, int64_t max_vertices,
                     TetMesh* out) {
  if (d.positions_size() % 3 != 0)
    return invalid(fmt::format("{}.positions has {} values, not a multiple of 3", prefix, d.positions_size()));
  if (d.tets_size() % 4 != 0)
    return invalid(fmt::format("{}.tets has {} values, not a multiple of 4", prefix, d.tets_size()));
  const int64_t nv = d.positions_size() / 3;
  if (nv == 0 || d.tets_size() == 0)
    return invalid(fmt::format("{} is empty ({} vertices, {} tets)", prefix, nv, d.tets_size() / 4));
  if (nv > max_vertices)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("{} has {} vertices, more than this server's --max-vertices {}",
                                   prefix, nv, max_vertices));
  out->vertices.resize(nv);
  for (int64_t i = 0; i < nv; ++i) {
    Vec3 p(d.positions(3 * i), d.positions(3 * i + 1), d.positions(3 * i + 2));
    if (!p.allFinite()) return invalid(fmt::format("{}.positions: vertex {} is not finite", prefix, i));
    out->vertices[i] = p;
  }
  out->tets.resize(d.tets_size() / 4);
  for (size_t t = 0; t < out->tets.size(); ++t)
    for (int k = 0; k < 4; ++k) {
      int32_t v = d.tets(4 * t + k);
      if (v < 0 || v >= nv)
        return invalid(fmt::format("{}.tets[{}]: vertex index {} out of range [0, {})", prefix, t, v, nv));
      out->tets[t][k] = v;
    }
  out->name = d.name().empty() ? "upload" : d.name();
  return {};
}

Error mesh_from_source(const v1::MeshSource& src, const std::vector<std::string>& model_path, int64_t max_vertices,
                       SceneConfig& cfg, TetMesh* mesh) {
  switch (src.source_case()) {
    case v1::MeshSource::kBuiltin: {
      auto m = builtin_mesh(src.builtin());
      if (!m) {
        std::string names;
        for (auto& n : builtin_mesh_names()) names += (names.empty() ? "" : ", ") + n;
        return invalid(fmt::format("spec.mesh.builtin {} is not a builtin mesh; choose one of {}",
                                   echo(src.builtin()), names));
      }
      *mesh = std::move(*m);
      cfg.mesh_kind = "builtin";
      cfg.mesh_name = src.builtin();
      break;
    }
    case v1::MeshSource::kModelPath: {
      // Builtin and model-set names first; anything else is a file inside --model-path.
      const std::string& name = src.model_path();
      const std::string field = "spec.mesh.model_path";
      if (name.find('\0') == std::string::npos)
        if (auto b = builtin_mesh(name)) {
          *mesh = std::move(*b);
          cfg.mesh_kind = "model_path";
          cfg.mesh_name = name;
          break;
        }
      const ModelEntry* model = name.find('\0') == std::string::npos ? find_model(name) : nullptr;
      std::string file;
      if (Error e = resolve_model_file(field, model ? model->file : name, model_path, &file); !e.ok()) {
        if (model) e.message = fmt::format("{} {}: {}", field, echo(name), e.message);
        return e;
      }
      try {
        MeshLoadOptions lo;
        if (model && model->scale > 0) lo.scale = model->scale;
        *mesh = load_mesh(file, lo);
        if (model) mesh->name = model->name;
      } catch (const std::exception& e) {
        // The loader's message may quote the file: it goes to the log, not to the client.
        spdlog::warn("{} {}: {} cannot be loaded: {}", field, echo(name), file, e.what());
        return invalid(fmt::format("{} {} is not a valid tet mesh (.node/.ele, .msh, .vtk or .vtu); the server log "
                                   "says why", field, echo(name)));
      }
      cfg.mesh_kind = "model_path";
      cfg.mesh_name = name;
      break;
    }
    case v1::MeshSource::kData: {
      if (Error e = mesh_from_data(src.data(), "spec.mesh.data", max_vertices, mesh); !e.ok()) return e;
      cfg.mesh_kind = "data";
      cfg.mesh_name = mesh->name;
      break;
    }
    default:
      return invalid("spec.mesh: no source set; set one of builtin, model_path, data");
  }
  if (src.has_scale()) {
    double s = src.scale();
    if (!std::isfinite(s) || s < 0)
      return invalid(fmt::format("spec.mesh.scale must be a finite value > 0, got {}", s));
    if (s > 0 && s != 1.0) scale_mesh(*mesh, s);
    cfg.mesh_scale = s > 0 ? s : 1.0;
  }
  if (static_cast<int64_t>(mesh->vertices.size()) > max_vertices)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("spec.mesh {} has {} vertices, more than this server's --max-vertices {}",
                                   echo(mesh->name), mesh->vertices.size(), max_vertices));
  return {};
}

Error fixed_from(const v1::FixedSelection& p, const std::string& prefix, FixedSelection* out) {
  out->indices.assign(p.indices().begin(), p.indices().end());
  for (int i = 0; i < p.boxes_size(); ++i) {
    Vec3 lo = from_proto(p.boxes(i).min()), hi = from_proto(p.boxes(i).max());
    if (!lo.allFinite() || !hi.allFinite() || (lo.array() > hi.array()).any())
      return invalid(fmt::format("{}.boxes[{}] must have finite min <= max, got min ({}, {}, {}) max ({}, {}, {})",
                                 prefix, i, lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z()));
    out->boxes.push_back({lo, hi});
  }
  return {};
}

namespace {

// Static colliders: every value range-checked, errors name the field and the value.
constexpr double kMaxColliderExtent = 1e6;  // metres: far beyond any scene, finite in float32
constexpr double kMaxFriction = 10.0;

}  // namespace

Error colliders_from(const google::protobuf::RepeatedPtrField<v1::Collider>& p, const std::string& prefix,
                     std::vector<Collider>* out) {
  out->clear();
  auto vec = [](const Vec3& v) { return fmt::format("({}, {}, {})", v.x(), v.y(), v.z()); };
  for (int i = 0; i < p.size(); ++i) {
    const v1::Collider& c = p.Get(i);
    const std::string f = fmt::format("{}[{}]", prefix, i);
    auto point_in_range = [&](const v1::Vec3& pv, const std::string& name, Vec3* v) -> Error {
      *v = from_proto(pv);
      if (!v->allFinite() || v->cwiseAbs().maxCoeff() > kMaxColliderExtent)
        return invalid(fmt::format("{}.{} must be finite and within {} m of the origin, got {}", f, name,
                                   kMaxColliderExtent, vec(*v)));
      return {};
    };
    Collider col;
    switch (c.shape_case()) {
      case v1::Collider::kPlane: {
        Vec3 point, normal;
        if (Error e = point_in_range(c.plane().point(), "plane.point", &point); !e.ok()) return e;
        normal = from_proto(c.plane().normal());
        if (!normal.allFinite() || !(normal.norm() > 1e-12))
          return invalid(fmt::format("{}.plane.normal must be a finite non-zero vector, got {}", f, vec(normal)));
        col = Collider::plane(point, normal);
        break;
      }
      case v1::Collider::kSphere: {
        Vec3 centre;
        if (Error e = point_in_range(c.sphere().center(), "sphere.center", &centre); !e.ok()) return e;
        const double r = c.sphere().radius();
        if (!std::isfinite(r) || r <= 0 || r > kMaxColliderExtent)
          return invalid(fmt::format("{}.sphere.radius must be in (0, {}] m, got {}", f, kMaxColliderExtent, r));
        col = Collider::sphere(centre, r);
        break;
      }
      case v1::Collider::kBox: {
        Vec3 centre, half;
        if (Error e = point_in_range(c.box().center(), "box.center", &centre); !e.ok()) return e;
        half = from_proto(c.box().half_extent());
        if (!half.allFinite() || (half.array() <= 0).any() || half.maxCoeff() > kMaxColliderExtent)
          return invalid(fmt::format("{}.box.half_extent must have each component in (0, {}] m, got {}", f,
                                     kMaxColliderExtent, vec(half)));
        col = Collider::box(centre, half);
        break;
      }
      default:
        return invalid(fmt::format("{}: no shape set; set one of plane, sphere, box", f));
    }
    if (c.has_static_friction()) {
      const double mu = c.static_friction();
      if (!std::isfinite(mu) || mu < 0 || mu > kMaxFriction)
        return invalid(fmt::format("{}.static_friction must be in [0, {}], got {}", f, kMaxFriction, mu));
      col.static_friction = mu;
    }
    if (c.has_dynamic_friction()) {
      const double mu = c.dynamic_friction();
      if (!std::isfinite(mu) || mu < 0 || mu > col.static_friction)
        return invalid(fmt::format("{}.dynamic_friction must be in [0, static_friction = {}], got {}", f,
                                   col.static_friction, mu));
      col.dynamic_friction = mu;
    } else {
      col.dynamic_friction = std::min(col.dynamic_friction, col.static_friction);
    }
    out->push_back(col);
  }
  return {};
}

namespace {

void colliders_to(const std::vector<Collider>& cs, v1::SceneSpec* spec) {
  for (const Collider& c : cs) {
    auto* pc = spec->add_colliders();
    switch (c.shape) {
      case Collider::Shape::Plane:
        to_proto(c.point, pc->mutable_plane()->mutable_point());
        to_proto(c.normal, pc->mutable_plane()->mutable_normal());
        break;
      case Collider::Shape::Sphere:
        to_proto(c.point, pc->mutable_sphere()->mutable_center());
        pc->mutable_sphere()->set_radius(c.radius);
        break;
      case Collider::Shape::Box:
        to_proto(c.point, pc->mutable_box()->mutable_center());
        to_proto(c.half_extent, pc->mutable_box()->mutable_half_extent());
        break;
    }
    pc->set_static_friction(c.static_friction);
    pc->set_dynamic_friction(c.dynamic_friction);
  }
}


}  // namespace

Error build_body(const TetMesh& mesh, const Material& material, const FixedSelection& fixed,
                 std::shared_ptr<const BodyModel>* out) {
  try {
    *out = build_model(mesh, material, fixed);
  } catch (const std::invalid_argument& e) {
    return invalid(std::string("spec.") + e.what());
  } catch (const std::exception& e) {
    return invalid(std::string("spec.mesh: ") + e.what());
  }
  return {};
}

void spec_to_proto(const SceneConfig& cfg, const BodyModel& model, v1::SceneSpec* spec) {
  auto* mesh = spec->mutable_mesh();
  if (cfg.mesh_kind == "model_path") mesh->set_model_path(cfg.mesh_name);
  else if (cfg.mesh_kind == "data") mesh->mutable_data()->set_name(cfg.mesh_name);
  else mesh->set_builtin(cfg.mesh_name);
  mesh->set_scale(cfg.mesh_scale);
  auto* m = spec->mutable_material();
  m->set_young_modulus(model.material.young);
  m->set_poisson_ratio(model.material.poisson);
  m->set_density(model.material.density);
  m->set_inertia_floor(model.material.inertia_floor);
  m->set_support_inertia(model.material.support_inertia);
  m->set_model(proto::elastic_model_to(model.material.model));
  auto* f = spec->mutable_fixed();
  for (int32_t i : cfg.fixed.indices) f->add_indices(i);
  for (const std::string& g : cfg.fixed_groups) f->add_groups(g);
  for (const auto& b : cfg.fixed.boxes) {
    auto* pb = f->add_boxes();
    to_proto(b.min, pb->mutable_min());
    to_proto(b.max, pb->mutable_max());
  }
  const SolverSettings& s = cfg.settings;
  to_proto(s.gravity, spec->mutable_gravity());
  auto* ps = spec->mutable_solver();
  ps->set_sweep(proto::sweep_to(s.sweep));
  ps->set_method(proto::method_to(s.method));
  ps->set_substeps(effective_substeps(model, s));
  ps->set_target_wave_courant_number(s.target_wave_courant_number);
  ps->set_iterations(s.iterations);
  ps->set_window(s.window);
  ps->set_omega(s.omega);
  ps->set_tolerance(s.tolerance);
  ps->set_time_budget_ms(s.time_budget_ms);
  ps->set_damping(proto::damping_to(s.damping));
  ps->set_damping_coefficient(s.damping_coefficient);
  ps->set_threads(s.threads);
  ps->set_inversion_floor(s.inversion_floor);
  ps->set_newton_linear_solver(proto::newton_linear_solver_to(s.newton_linear_solver));
  spec->mutable_tick()->set_dt(s.dt);
  spec->mutable_tick()->set_mode(tick_mode_to(cfg.mode));
  colliders_to(cfg.colliders, spec);
  bodies_to_spec(cfg.bodies, spec);
}

v1::SceneState scene_state_of(TickMode mode, bool running) {
  if (mode == TickMode::Lockstep) return v1::SCENE_STATE_LOCKSTEP;
  return running ? v1::SCENE_STATE_RUNNING : v1::SCENE_STATE_PAUSED;
}

void scene_to_proto(const Scene& scene, v1::Scene* out) {
  out->Clear();
  auto model = scene.model();
  SceneConfig cfg = scene.config();
  SceneStatus st = scene.status();
  out->set_scene_id(scene.id());
  spec_to_proto(cfg, *model, out->mutable_spec());
  out->mutable_spec()->set_start_paused(!st.running);
  out->set_state(scene_state_of(st.mode, st.running));
  out->set_tick(st.tick);
  out->set_sim_time(st.sim_time);
  out->set_vertex_count(static_cast<uint32_t>(model->vertex_count()));
  out->set_tet_count(static_cast<uint32_t>(model->tet_count()));
  out->set_surface_triangle_count(static_cast<uint32_t>(model->surface.size()));
  out->set_late_ticks(st.counters.late_ticks);
  out->set_skipped_ticks(st.counters.skipped_ticks);
  out->set_rollbacks(st.counters.rollbacks);
  out->set_ticks_per_second(st.running ? st.counters.ticks_per_second : 0.0);
  out->set_pause_reason(st.pause_reason);
  out->set_wave_courant_number(wave_courant_number(*model, cfg.settings.dt / effective_substeps(*model, cfg.settings)));
  out->set_floored_vertices(static_cast<uint32_t>(model->floored_vertices()));
  out->set_added_inertia(model->added_inertia());
  out->set_method_choice(cfg.method_choice);
  for (size_t i = 0; i < scene.bodies().size(); ++i) {
    const BodyInfo& b = scene.bodies()[i];
    auto* pb = out->add_bodies();
    pb->set_name(b.name);
    pb->set_kind(b.kind);
    pb->set_particle_count(static_cast<uint32_t>(i < st.body_particles.size() ? st.body_particles[i] : b.particles));
    pb->set_max_particle_count(static_cast<uint32_t>(b.capacity));
    pb->set_triangle_count(static_cast<uint32_t>(b.triangles.size()));
    pb->set_pinned_count(static_cast<uint32_t>(b.pinned.size()));
  }
}

}  // namespace pliant::server
