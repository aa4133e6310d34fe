// SPDX-License-Identifier: Apache-2.0
// Requests to scenes: validation with messages naming field and value, model building,
// limits, proto conversions, snapshots on disk.
#include "pliant/server/registry.hpp"

#include "pliant/server/edge.hpp"
#include "fixed_groups.hpp"

#include "pliant/proto/enums.hpp"

#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/method_choice.hpp"
#include "pliant/stepper.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <unistd.h>
#include <fstream>
#include <sstream>

namespace fs = std::filesystem;

namespace pliant::server {

using Clock = std::chrono::steady_clock;

namespace {

Error invalid(std::string m) { return Error::make(Code::InvalidArgument, std::move(m)); }

bool valid_name(const std::string& s) {
  if (s.empty() || s.size() > 64 || s == "." || s == "..") return false;
  return std::all_of(s.begin(), s.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '.' || c == '-';
  });
}

Error check_name(const std::string& field, const std::string& value) {
  if (valid_name(value)) return {};
  return invalid(fmt::format("{} {} is not a valid name: use 1 to 64 of A-Z a-z 0-9 _ . -",
                             field, echo(value)));
}

Error check_id_present(const std::string& id) {
  if (id.empty()) return invalid("scene_id is empty");
  return {};
}

Vec3 to_vec(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }
void to_proto(const Vec3& v, v1::Vec3* out) {
  out->set_x(v.x());
  out->set_y(v.y());
  out->set_z(v.z());
}

std::optional<Damping> damping_from(v1::Damping d) {
  switch (d) {
    case v1::DAMPING_NONE: return Damping::None;
    case v1::DAMPING_SIMPLE: return Damping::Simple;
    case v1::DAMPING_RIGID_PRESERVING: return Damping::RigidPreserving;
    default: return std::nullopt;
  }
}
v1::Damping damping_to(Damping d) {
  switch (d) {
    case Damping::None: return v1::DAMPING_NONE;
    case Damping::Simple: return v1::DAMPING_SIMPLE;
    case Damping::RigidPreserving: return v1::DAMPING_RIGID_PRESERVING;
  }
  return v1::DAMPING_UNSPECIFIED;
}
std::optional<TickMode> mode_from(v1::TickMode m) {
  switch (m) {
    case v1::TICK_MODE_REALTIME: return TickMode::Realtime;
    case v1::TICK_MODE_LOCKSTEP: return TickMode::Lockstep;
    case v1::TICK_MODE_AS_FAST_AS_POSSIBLE: return TickMode::AsFastAsPossible;
    default: return std::nullopt;
  }
}
v1::TickMode mode_to(TickMode m) {
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
    auto d = damping_from(p.damping());
    if (!d) return invalid(fmt::format("{}.damping has unknown value {}", prefix, static_cast<int>(p.damping())));
    s.damping = *d;
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
    auto m = mode_from(p.mode());
    if (!m) return invalid(fmt::format("{}.mode has unknown value {}", prefix, static_cast<int>(p.mode())));
    mode = *m;
  }
  return {};
}

Error merge_gravity(const v1::Vec3& g, const std::string& field, SolverSettings& s) {
  Vec3 v = to_vec(g);
  if (!v.allFinite())
    return invalid(fmt::format("{} must be finite, got ({}, {}, {})", field, v.x(), v.y(), v.z()));
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

// Whether solver settings name a budget in sweeps (then the server does not choose the method).
bool pins_budget(const v1::SolverSettings& p) {
  return p.has_substeps() || p.has_iterations() || p.has_target_wave_courant_number();
}

// Method auto: measures the candidates on the model (choose_method) and pins the winner in
// cfg.settings, keeping what was measured for GetScene and the log. The budget is the request's
// time_budget_ms, or kAutoBudgetFraction of the tick.
void resolve_auto_method(const std::string& id, const BodyModel& model, SceneConfig& cfg) {
  if (!cfg.method_auto) return;
  const MethodChoice choice = choose_method(model, cfg.settings, cfg.settings.time_budget_ms);
  cfg.settings = choice.settings;
  cfg.method_choice = choice.summary;
  spdlog::info("scene '{}': method auto chose {}", id, choice.summary);
}

Error merge_material(const v1::Material& p, const std::string& prefix, Material& m) {
  if (p.has_young_modulus()) m.young = p.young_modulus();
  if (p.has_poisson_ratio()) m.poisson = p.poisson_ratio();
  if (p.has_density()) m.density = p.density();
  if (p.has_inertia_floor()) m.inertia_floor = p.inertia_floor();
  if (p.has_support_inertia()) m.support_inertia = p.support_inertia();
  switch (p.model()) {
    case v1::ELASTIC_MODEL_UNSPECIFIED: break;
    case v1::ELASTIC_MODEL_STVK: m.model = ElasticModel::StVK; break;
    case v1::ELASTIC_MODEL_COROTATED: m.model = ElasticModel::Corotated; break;
    default:
      return invalid(fmt::format("{}.model must be ELASTIC_MODEL_STVK or ELASTIC_MODEL_COROTATED, got {}", prefix,
                                 int(p.model())));
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

Error resolve_source(const v1::MeshSource& src, const RegistryOptions& opt, SceneConfig& cfg,
                     TetMesh* mesh) {
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
      if (Error e = resolve_model_file(field, model ? model->file : name, opt.model_path, &file); !e.ok()) {
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
      if (Error e = mesh_from_data(src.data(), "spec.mesh.data", opt.max_vertices, mesh); !e.ok()) return e;
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
  if (static_cast<int64_t>(mesh->vertices.size()) > opt.max_vertices)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("spec.mesh {} has {} vertices, more than this server's --max-vertices {}",
                                   echo(mesh->name), mesh->vertices.size(), opt.max_vertices));
  return {};
}

Error fixed_from(const v1::FixedSelection& p, const std::string& prefix, FixedSelection* out) {
  out->indices.assign(p.indices().begin(), p.indices().end());
  for (int i = 0; i < p.boxes_size(); ++i) {
    Vec3 lo = to_vec(p.boxes(i).min()), hi = to_vec(p.boxes(i).max());
    if (!lo.allFinite() || !hi.allFinite() || (lo.array() > hi.array()).any())
      return invalid(fmt::format("{}.boxes[{}] must have finite min <= max, got min ({}, {}, {}) max ({}, {}, {})",
                                 prefix, i, lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z()));
    out->boxes.push_back({lo, hi});
  }
  return {};
}

// Static colliders: every value range-checked, errors name the field and the value.
constexpr double kMaxColliderExtent = 1e6;  // metres: far beyond any scene, finite in float32
constexpr double kMaxFriction = 10.0;

Error colliders_from(const google::protobuf::RepeatedPtrField<v1::Collider>& p, const std::string& prefix,
                     std::vector<Collider>* out) {
  out->clear();
  auto vec = [](const Vec3& v) { return fmt::format("({}, {}, {})", v.x(), v.y(), v.z()); };
  for (int i = 0; i < p.size(); ++i) {
    const v1::Collider& c = p.Get(i);
    const std::string f = fmt::format("{}[{}]", prefix, i);
    auto point_in_range = [&](const v1::Vec3& pv, const std::string& name, Vec3* v) -> Error {
      *v = to_vec(pv);
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
        normal = to_vec(c.plane().normal());
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
        half = to_vec(c.box().half_extent());
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

// Builds the model; std::invalid_argument from the solver becomes INVALID_ARGUMENT.
Error build(const TetMesh& mesh, const Material& material, const FixedSelection& fixed,
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

void fill_spec(const SceneConfig& cfg, const BodyModel& model, v1::SceneSpec* spec) {
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
  m->set_model(model.material.model == ElasticModel::Corotated ? v1::ELASTIC_MODEL_COROTATED : v1::ELASTIC_MODEL_STVK);
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
  ps->set_damping(damping_to(s.damping));
  ps->set_damping_coefficient(s.damping_coefficient);
  ps->set_threads(s.threads);
  ps->set_inversion_floor(s.inversion_floor);
  spec->mutable_tick()->set_dt(s.dt);
  spec->mutable_tick()->set_mode(mode_to(cfg.mode));
  colliders_to(cfg.colliders, spec);
}

v1::SceneState state_of(const SceneStatus& st) {
  if (st.mode == TickMode::Lockstep) return v1::SCENE_STATE_LOCKSTEP;
  return st.running ? v1::SCENE_STATE_RUNNING : v1::SCENE_STATE_PAUSED;
}

// Writes a temporary file next to `path`, fsyncs it, renames it over `path` and fsyncs the
// directory: after a crash the file is the old one or the new one, never a torn one.
Error write_file_atomically(const std::string& path, const std::string& bytes) {
  static std::atomic<uint64_t> counter{0};
  std::error_code ec;
  const fs::path dir = fs::path(path).parent_path();
  fs::create_directories(dir, ec);
  const std::string tmp = fmt::format("{}.tmp.{}.{}", path, ::getpid(), counter++);
  auto fail = [&](const char* what) {
    const int err = errno;
    ::unlink(tmp.c_str());
    return Error::make(Code::Internal, fmt::format("cannot {} '{}': {}", what, tmp, std::strerror(err)));
  };
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return fail("create");
  for (size_t done = 0; done < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      Error e = fail("write");
      ::close(fd);
      return e;
    }
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) {
    Error e = fail("fsync");
    ::close(fd);
    return e;
  }
  if (::close(fd) != 0) return fail("close");
  if (::rename(tmp.c_str(), path.c_str()) != 0) return fail("rename");
  if (const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dfd >= 0) {
    const int rc = ::fsync(dfd);
    ::close(dfd);
    if (rc != 0) return Error::make(Code::Internal, fmt::format("cannot fsync '{}': {}", dir.string(), std::strerror(errno)));
  }
  return {};
}

// Removes a file and makes the removal durable (fsync of its directory).
void remove_file_durably(const std::string& path) {
  if (::unlink(path.c_str()) != 0) return;
  const fs::path dir = fs::path(path).parent_path();
  if (const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

// A tick's work: substeps x iterations within kMaxSweepsPerTick (the substeps a target wave
// Courant number picks for this body included).
Error check_work(const BodyModel& model, const SolverSettings& s, const std::string& prefix) {
  const int64_t substeps = effective_substeps(model, s);
  const int64_t iterations = std::max(1, s.iterations);
  if (substeps * iterations <= kMaxSweepsPerTick) return {};
  return invalid(fmt::format("{}.substeps x {}.iterations = {} x {} = {} sweeps per tick, more than this server's "
                             "limit of {} (lower either, or use time_budget_ms)",
                             prefix, prefix, substeps, iterations, substeps * iterations, kMaxSweepsPerTick));
}

Error read_snapshot_file(const std::string& path, v1::Snapshot* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Error::make(Code::NotFound, fmt::format("snapshot file '{}' not found", path));
  std::stringstream ss;
  ss << f.rdbuf();
  if (!out->ParseFromString(ss.str()))
    return invalid(fmt::format("snapshot file '{}' is not a pliant.v1.Snapshot", path));
  return {};
}

}  // namespace

// ---------------------------------------------------------------------------------------

Error snapshot_to_proto(const SceneSnapshot& s, v1::Snapshot* out) {
  const BodyModel& m = *s.model;
  out->set_format_version(1);
  out->set_scene_id(s.id);
  fill_spec(s.config, m, out->mutable_spec());
  auto* mesh = out->mutable_mesh();
  mesh->set_name(m.name);
  mesh->mutable_positions()->Reserve(static_cast<int>(3 * m.vertex_count()));
  for (const auto& p : m.rest_positions)
    for (int k = 0; k < 3; ++k) mesh->add_positions(p[k]);
  for (const auto& t : m.tets)
    for (int k = 0; k < 4; ++k) mesh->add_tets(t.v[k]);
  for (size_t i = 0; i < m.fixed.size(); ++i)
    if (m.fixed[i]) out->add_fixed_vertices(static_cast<int32_t>(i));
  for (const auto& p : s.state.x)
    for (int k = 0; k < 3; ++k) out->add_x(p[k]);
  for (const auto& p : s.state.v)
    for (int k = 0; k < 3; ++k) out->add_v(p[k]);
  for (const auto& l : s.state.lambda)
    for (int k = 0; k < 6; ++k) out->add_lambda(l[k]);
  out->set_sim_time(s.state.time);
  out->set_tick(s.tick);
  out->set_paused(s.paused);
  for (const auto& [gid, a] : s.grabs) {
    auto* g = out->add_grabs();
    g->set_grab_id(gid);
    for (int k = 0; k < 4; ++k) {
      if (a.vertices[k] < 0) continue;
      g->add_vertices(a.vertices[k]);
      g->add_weights(a.weights[k]);
    }
    g->mutable_target()->set_x(a.target.x());
    g->mutable_target()->set_y(a.target.y());
    g->mutable_target()->set_z(a.target.z());
    g->set_compliance(a.compliance);
  }
  out->set_next_grab_id(s.next_grab_id);
  out->set_saved_unix_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(
                             std::chrono::system_clock::now().time_since_epoch())
                             .count());
  return {};
}

// Ticks and grab ids in a snapshot stay below 2^53: exact as doubles, far from wrapping.
constexpr uint64_t kMaxTick = uint64_t{1} << 53;

Error snapshot_from_proto(const v1::Snapshot& p, int max_threads, int64_t max_vertices,
                          SceneSnapshot* out) {
  if (p.format_version() != 1)
    return invalid(fmt::format("snapshot.format_version {} is not supported (this server reads 1)",
                               p.format_version()));
  TetMesh mesh;
  if (Error e = mesh_from_data(p.mesh(), "snapshot.mesh", max_vertices, &mesh); !e.ok()) return e;
  const size_t nv = mesh.vertices.size(), nt = mesh.tets.size();
  if (static_cast<size_t>(p.x_size()) != 3 * nv || static_cast<size_t>(p.v_size()) != 3 * nv)
    return invalid(fmt::format("snapshot.x/v have {}/{} values, expected {} (3 per vertex)",
                               p.x_size(), p.v_size(), 3 * nv));
  if (static_cast<size_t>(p.lambda_size()) != 6 * nt)
    return invalid(fmt::format("snapshot.lambda has {} values, expected {} (6 per tet)",
                               p.lambda_size(), 6 * nt));
  SceneConfig cfg;
  const auto& spec = p.spec();
  switch (spec.mesh().source_case()) {
    case v1::MeshSource::kModelPath: cfg.mesh_kind = "model_path"; cfg.mesh_name = spec.mesh().model_path(); break;
    case v1::MeshSource::kData: cfg.mesh_kind = "data"; cfg.mesh_name = spec.mesh().data().name(); break;
    default: cfg.mesh_kind = "builtin"; cfg.mesh_name = spec.mesh().builtin(); break;
  }
  cfg.mesh_scale = spec.mesh().has_scale() && spec.mesh().scale() > 0 ? spec.mesh().scale() : 1.0;
  Material material;
  if (Error e = merge_material(spec.material(), "snapshot.spec.material", material); !e.ok()) return e;
  if (Error e = merge_solver(spec.solver(), "snapshot.spec.solver", max_threads, cfg.settings); !e.ok()) return e;
  if (Error e = merge_tick(spec.tick(), "snapshot.spec.tick", cfg.settings, cfg.mode); !e.ok()) return e;
  if (spec.has_gravity())
    if (Error e = merge_gravity(spec.gravity(), "snapshot.spec.gravity", cfg.settings); !e.ok()) return e;
  if (Error e = check_solver(cfg.settings, "snapshot.spec.solver"); !e.ok()) return e;
  if (Error e = fixed_from(spec.fixed(), "snapshot.spec.fixed", &cfg.fixed); !e.ok()) return e;
  cfg.fixed_groups.assign(spec.fixed().groups().begin(), spec.fixed().groups().end());
  if (Error e = colliders_from(spec.colliders(), "snapshot.spec.colliders", &cfg.colliders); !e.ok()) return e;
  FixedSelection fixed;
  fixed.indices.assign(p.fixed_vertices().begin(), p.fixed_vertices().end());
  std::shared_ptr<const BodyModel> model;
  if (Error e = build(mesh, material, fixed, &model); !e.ok()) {
    e.message = "snapshot: " + e.message;
    return e;
  }
  BodyState st;
  st.x.resize(nv);
  st.v.resize(nv);
  st.lambda.resize(nt);
  for (size_t i = 0; i < nv; ++i) {
    st.x[i] = Vec3(p.x(3 * i), p.x(3 * i + 1), p.x(3 * i + 2));
    st.v[i] = Vec3(p.v(3 * i), p.v(3 * i + 1), p.v(3 * i + 2));
  }
  for (size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 6; ++k) st.lambda[t][k] = p.lambda(6 * t + k);
  st.time = p.sim_time();
  st.steps = p.tick();
  if (!is_finite(st)) return invalid("snapshot.x/v contain non-finite values");
  for (size_t t = 0; t < nt; ++t)
    if (!st.lambda[t].allFinite()) return invalid(fmt::format("snapshot.lambda: tet {} has a non-finite value", t));
  if (!std::isfinite(p.sim_time()) || p.sim_time() < 0)
    return invalid(fmt::format("snapshot.sim_time must be a finite value >= 0 s, got {}", p.sim_time()));
  if (p.tick() > kMaxTick)
    return invalid(fmt::format("snapshot.tick must be at most {}, got {}", kMaxTick, p.tick()));
  if (Error e = check_work(*model, cfg.settings, "snapshot.spec.solver"); !e.ok()) return e;
  // Grabs (absent from snapshots written before they were saved: none).
  std::map<uint64_t, Attachment> grabs;
  for (int i = 0; i < p.grabs_size(); ++i) {
    const auto& g = p.grabs(i);
    const std::string field = fmt::format("snapshot.grabs[{}]", i);
    if (g.grab_id() == 0) return invalid(field + ".grab_id = 0 is not a grab id (ids start at 1)");
    if (g.grab_id() > kMaxTick)
      return invalid(fmt::format("{}.grab_id = {} is larger than {}", field, g.grab_id(), kMaxTick));
    if (grabs.count(g.grab_id()))
      return invalid(fmt::format("{}.grab_id = {} appears twice", field, g.grab_id()));
    if (g.vertices_size() < 1 || g.vertices_size() > 4 || g.weights_size() != g.vertices_size())
      return invalid(fmt::format("{} has {} vertices and {} weights, expected 1 to 4 of each, as many weights as vertices",
                                 field, g.vertices_size(), g.weights_size()));
    Attachment a;
    for (int k = 0; k < g.vertices_size(); ++k) {
      a.vertices[k] = g.vertices(k);
      a.weights[k] = g.weights(k);
    }
    a.target = to_vec(g.target());
    a.compliance = g.compliance();
    if (std::string msg = validate_interaction({a}, {}, *model); !msg.empty()) {
      // validate_interaction names the field "attachments[0]": name the snapshot's instead.
      const std::string prefix = "attachments[0]";
      if (msg.rfind(prefix, 0) == 0) msg = field + msg.substr(prefix.size());
      return invalid(msg);
    }
    grabs.emplace(g.grab_id(), a);
  }
  if (p.next_grab_id() > kMaxTick)
    return invalid(fmt::format("snapshot.next_grab_id = {} is larger than {}", p.next_grab_id(), kMaxTick));
  uint64_t next_grab_id = std::max<uint64_t>(p.next_grab_id(), 1);
  for (const auto& [gid, a] : grabs) next_grab_id = std::max(next_grab_id, gid + 1);
  out->grabs = std::move(grabs);
  out->next_grab_id = next_grab_id;
  out->id = p.scene_id();
  out->config = std::move(cfg);
  out->model = std::move(model);
  out->state = std::move(st);
  out->tick = p.tick();
  out->paused = p.paused();
  return {};
}

// ---------------------------------------------------------------------------------------

SceneRegistry::SceneRegistry(RegistryOptions options) : options_(std::move(options)) {}

SceneRegistry::~SceneRegistry() {
  stop_background();
  std::map<std::string, std::shared_ptr<Scene>> scenes;
  {
    std::lock_guard lk(mu_);
    scenes.swap(scenes_);
  }
  for (auto& [id, s] : scenes) s->stop();
}

std::string SceneRegistry::scene_file(const std::string& id) const {
  return (fs::path(options_.data_dir) / "scenes" / (id + ".snapshot")).string();
}
std::string SceneRegistry::snapshot_file(const std::string& name) const {
  return (fs::path(options_.data_dir) / "snapshots" / (name + ".snapshot")).string();
}

namespace {

// A budget whose under_resolution (settings.hpp) is above 1 leaves the body clearly softer than
// its material (beam3: 17-30% near 1, 1.8-4.3x at 2-4). Says so, with the substeps that would
// bring the wave Courant number to 0.3 (within 2% on beam3 at 1 iteration).
void warn_if_under_resolved(const std::string& id, const BodyModel& model, const SolverSettings& s) {
  // Only constraint projection loses stiffness to an unconverged budget this way.
  if (family_of(s.method) != SolverFamilyKind::ConstraintProjection) return;
  const int substeps = effective_substeps(model, s);
  const double co = wave_courant_number(model, s.dt / substeps);
  if (under_resolution(co, s.iterations) <= 1.0) return;
  if (model.material.poisson > kUnderResolutionMaxPoisson) {
    spdlog::info("scene '{}': a pressure wave crosses {:.2g} elements per substep; not interpreted for nu {} "
                 "(calibrated up to {})", id, co, model.material.poisson, kUnderResolutionMaxPoisson);
    return;
  }
  SolverSettings resolved = s;
  resolved.target_wave_courant_number = 0.3;
  const int enough = effective_substeps(model, resolved);
  const bool fixed = std::find(model.fixed.begin(), model.fixed.end(), 1) != model.fixed.end();
  const char* support = model.material.support_inertia > 0
                            ? "; its support inertia holds its rest shape near the converged one, motion near the "
                              "fixed vertices is slower (docs/solver.md, \"Support inertia\")"
                        : fixed ? "; or material.support_inertia 1 holds it up near its converged rest shape at the "
                                  "price of slower motion near the fixed vertices (docs/solver.md, \"Support inertia\")"
                                : "";
  spdlog::warn("scene '{}': a pressure wave crosses {:.2g} elements per substep (E {:g} Pa, {} substeps x {} "
               "iterations per {:g} s tick): the body will be softer than its material; about {} substeps "
               "of 1 iteration would resolve it (wave_courant_number 0.3; docs/solver.md, \"Accuracy of a "
               "real-time budget\"){}",
               id, co, model.material.young, substeps, s.iterations, s.dt, enough, support);
}

}  // namespace

Error SceneRegistry::find(const std::string& id, std::shared_ptr<Scene>* out) const {
  if (Error e = check_id_present(id); !e.ok()) return e;
  std::lock_guard lk(mu_);
  auto it = scenes_.find(id);
  if (it == scenes_.end())
    return Error::make(Code::NotFound, fmt::format("scene_id {} not found", echo(id)));
  *out = it->second;
  return {};
}

Error SceneRegistry::open_stream(const std::string& scene_id, std::shared_ptr<void>* slot) {
  std::lock_guard lk(mu_);
  if (open_streams_ >= options_.max_streams)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("this server already has {} open streams (--max-streams {})", open_streams_,
                                   options_.max_streams));
  int& here = scene_streams_[scene_id];
  if (here >= options_.max_streams_per_scene)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("scene '{}' already has {} open streams (--max-streams-per-scene {})", scene_id,
                                   here, options_.max_streams_per_scene));
  ++open_streams_;
  ++here;
  *slot = std::shared_ptr<void>(nullptr, [this, scene_id](void*) {
    std::lock_guard lk(mu_);
    --open_streams_;
    if (--scene_streams_[scene_id] <= 0) scene_streams_.erase(scene_id);
  });
  return {};
}

std::vector<std::shared_ptr<Scene>> SceneRegistry::scenes() const {
  std::lock_guard lk(mu_);
  std::vector<std::shared_ptr<Scene>> out;
  out.reserve(scenes_.size());
  for (const auto& [id, scene] : scenes_) out.push_back(scene);
  return out;
}

std::map<std::string, int> SceneRegistry::stream_counts(int* total) const {
  std::lock_guard lk(mu_);
  *total = open_streams_;
  return scene_streams_;
}

Error SceneRegistry::describe(const Scene& scene, v1::Scene* out) const {
  out->Clear();
  auto model = scene.model();
  SceneConfig cfg = scene.config();
  SceneStatus st = scene.status();
  out->set_scene_id(scene.id());
  fill_spec(cfg, *model, out->mutable_spec());
  out->mutable_spec()->set_start_paused(!st.running);
  out->set_state(state_of(st));
  out->set_tick(st.tick);
  out->set_sim_time(st.sim_time);
  out->set_vertex_count(static_cast<uint32_t>(model->vertex_count()));
  out->set_tet_count(static_cast<uint32_t>(model->tet_count()));
  out->set_surface_triangle_count(static_cast<uint32_t>(model->surface.size()));
  out->set_late_ticks(st.late_ticks);
  out->set_skipped_ticks(st.skipped_ticks);
  out->set_rollbacks(st.rollbacks);
  out->set_ticks_per_second(st.running ? st.ticks_per_second : 0.0);
  out->set_pause_reason(st.pause_reason);
  out->set_wave_courant_number(wave_courant_number(*model, cfg.settings.dt / effective_substeps(*model, cfg.settings)));
  out->set_floored_vertices(static_cast<uint32_t>(model->floored_vertices()));
  out->set_added_inertia(model->added_inertia());
  out->set_method_choice(cfg.method_choice);
  return {};
}

Error SceneRegistry::add_scene(std::shared_ptr<Scene> scene, bool replace) {
  std::shared_ptr<Scene> old;
  {
    std::lock_guard lk(mu_);
    if (shutting_down_) return Error::make(Code::Unavailable, "the server is shutting down");
    auto it = scenes_.find(scene->id());
    if (it != scenes_.end() && !replace)
      return Error::make(Code::AlreadyExists, fmt::format("scene_id '{}' already exists", scene->id()));
    if (it == scenes_.end() && static_cast<int>(scenes_.size()) >= options_.max_scenes)
      return Error::make(Code::ResourceExhausted,
                         fmt::format("this server already hosts {} scenes (--max-scenes {}); delete one first",
                                     scenes_.size(), options_.max_scenes));
    if (it != scenes_.end()) old = it->second;
    scenes_[scene->id()] = scene;
    scene->start();
  }
  if (old) old->stop();
  return {};
}

Error SceneRegistry::create(const v1::CreateSceneRequest& req, v1::Scene* out) {
  std::string id = req.scene_id();
  if (!id.empty())
    if (Error e = check_name("scene_id", id); !e.ok()) return e;
  {
    std::lock_guard lk(mu_);
    if (shutting_down_) return Error::make(Code::Unavailable, "the server is shutting down");
    if (!id.empty() && scenes_.count(id))
      return Error::make(Code::AlreadyExists, fmt::format("scene_id '{}' already exists", id));
    if (static_cast<int>(scenes_.size()) >= options_.max_scenes)
      return Error::make(Code::ResourceExhausted,
                         fmt::format("this server already hosts {} scenes (--max-scenes {}); delete one first",
                                     scenes_.size(), options_.max_scenes));
    if (id.empty()) {
      do id = "scene-" + std::to_string(next_id_++);
      while (scenes_.count(id));
    }
  }
  const auto& spec = req.spec();
  SceneConfig cfg;
  Material material;
  TetMesh mesh;
  if (Error e = merge_material(spec.material(), "spec.material", material); !e.ok()) return e;
  if (Error e = merge_solver(spec.solver(), "spec.solver", options_.max_threads, cfg.settings); !e.ok()) return e;
  if (Error e = merge_tick(spec.tick(), "spec.tick", cfg.settings, cfg.mode); !e.ok()) return e;
  if (spec.has_gravity())
    if (Error e = merge_gravity(spec.gravity(), "spec.gravity", cfg.settings); !e.ok()) return e;
  if (Error e = check_solver(cfg.settings, "spec.solver"); !e.ok()) return e;
  if (Error e = fixed_from(spec.fixed(), "spec.fixed", &cfg.fixed); !e.ok()) return e;
  if (Error e = colliders_from(spec.colliders(), "spec.colliders", &cfg.colliders); !e.ok()) return e;
  if (Error e = resolve_source(spec.mesh(), options_, cfg, &mesh); !e.ok()) return e;
  FixedSelection fixed = cfg.fixed;
  if (Error e = add_fixed_groups(spec.fixed(), "spec.fixed", mesh, &fixed, &cfg.fixed_groups); !e.ok()) return e;
  std::shared_ptr<const BodyModel> model;
  if (Error e = build(mesh, material, fixed, &model); !e.ok()) return e;
  // A realtime scene whose request names neither a method nor a budget in sweeps gets the most
  // accurate method within its time budget (half the tick unless it names one).
  if (spec.solver().method() == v1::METHOD_UNSPECIFIED && !pins_budget(spec.solver()) && cfg.mode == TickMode::Realtime)
    cfg.settings.method = Method::Auto;
  cfg.method_auto = cfg.settings.method == Method::Auto;
  resolve_auto_method(id, *model, cfg);
  if (Error e = check_work(*model, cfg.settings, "spec.solver"); !e.ok()) return e;
  BodyState state = rest_state(*model);
  auto scene = std::make_shared<Scene>(id, cfg, model, std::move(state), 0, spec.start_paused());
  if (Error e = add_scene(scene, false); !e.ok()) return e;
  wake_checkpoint();
  spdlog::info("scene '{}' created: {} ({} vertices, {} tets), {} mode, dt {} s, {}", id,
               cfg.mesh_name, model->vertex_count(), model->tet_count(), to_string(cfg.mode),
               cfg.settings.dt, pliant::to_string(cfg.settings.method));
  warn_if_under_resolved(id, *model, cfg.settings);
  return describe(*scene, out);
}

Error SceneRegistry::list(v1::ListScenesResponse* out) const {
  std::vector<std::shared_ptr<Scene>> scenes;
  {
    std::lock_guard lk(mu_);
    for (auto& [id, s] : scenes_) scenes.push_back(s);
  }
  for (auto& s : scenes) describe(*s, out->add_scenes());
  return {};
}

Error SceneRegistry::get(const std::string& id, v1::Scene* out) const {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  return describe(*s, out);
}

Error SceneRegistry::update(const v1::UpdateSceneRequest& req, v1::Scene* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  std::lock_guard ulk(s->update_mutex());
  SceneConfig cfg = s->config();
  SceneUpdate up;
  SolverSettings settings = cfg.settings;
  TickMode mode = cfg.mode;
  if (req.has_solver())
    if (Error e = merge_solver(req.solver(), "solver", options_.max_threads, settings); !e.ok()) return e;
  if (req.has_tick())
    if (Error e = merge_tick(req.tick(), "tick", settings, mode); !e.ok()) return e;
  if (req.has_gravity())
    if (Error e = merge_gravity(req.gravity(), "gravity", settings); !e.ok()) return e;
  if (Error e = check_solver(settings, "solver"); !e.ok()) return e;
  // A request that names a method pins it, or asks for auto; one that names a budget in sweeps
  // (substeps, iterations, wave Courant number) pins the method in use with that budget; any
  // other keeps what was (auto chooses again for the new settings).
  bool method_auto = cfg.method_auto;
  if (req.has_solver() && req.solver().method() != v1::METHOD_UNSPECIFIED) method_auto = settings.method == Method::Auto;
  else if (req.has_solver() && pins_budget(req.solver())) method_auto = false;
  else if (method_auto) settings.method = Method::Auto;
  if (mode != cfg.mode) up.mode = mode;
  if (req.has_material()) {
    auto model = s->model();
    Material m = model->material;
    if (Error e = merge_material(req.material(), "material", m); !e.ok()) return e;
    try {
      up.model = with_material(*model, m);
    } catch (const std::exception& e) {
      return invalid(e.what());
    }
  }
  {
    SceneConfig resolved = cfg;
    resolved.settings = settings;
    resolved.method_auto = method_auto;
    resolved.method_choice.clear();
    resolve_auto_method(s->id(), up.model ? *up.model : *s->model(), resolved);
    up.settings = resolved.settings;
    up.method_auto = resolved.method_auto;
    up.method_choice = resolved.method_choice;
  }
  if (Error e = check_work(up.model ? *up.model : *s->model(), *up.settings, "solver"); !e.ok()) return e;
  if (Error e = s->update(up); !e.ok()) return e;
  spdlog::info("scene '{}' updated", s->id());
  warn_if_under_resolved(s->id(), up.model ? *up.model : *s->model(), *up.settings);
  return describe(*s, out);
}

Error SceneRegistry::remove(const std::string& id) {
  std::shared_ptr<Scene> s;
  {
    if (Error e = check_id_present(id); !e.ok()) return e;
    std::lock_guard lk(mu_);
    auto it = scenes_.find(id);
    if (it == scenes_.end()) return Error::make(Code::NotFound, fmt::format("scene_id {} not found", echo(id)));
    s = it->second;
    scenes_.erase(it);
  }
  s->stop();
  if (!options_.data_dir.empty()) {
    std::lock_guard files(files_mu_);
    remove_file_durably(scene_file(id));
    written_.erase(id);
  }
  spdlog::info("scene '{}' deleted", id);
  return {};
}

Error SceneRegistry::reset(const std::string& id, v1::Scene* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  if (Error e = s->reset(); !e.ok()) return e;
  return describe(*s, out);
}

Error SceneRegistry::pause(const std::string& id, v1::Scene* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  if (Error e = s->pause(); !e.ok()) return e;
  return describe(*s, out);
}

Error SceneRegistry::resume(const std::string& id, v1::Scene* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  if (Error e = s->resume(); !e.ok()) return e;
  return describe(*s, out);
}

Error SceneRegistry::step(const v1::StepRequest& req, Clock::time_point deadline, v1::StepResponse* out,
                          const std::function<bool()>& cancelled) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  uint32_t n = req.ticks() == 0 ? 1 : req.ticks();
  if (n > 100000) return invalid(fmt::format("ticks must be in [1, 100000], got {}", req.ticks()));
  StepResult r;
  if (Error e = s->step(n, deadline, &r, cancelled); !e.ok()) return e;
  out->set_tick(r.tick);
  out->set_sim_time(r.sim_time);
  out->set_rollbacks(r.rollbacks);
  return {};
}

Error SceneRegistry::apply_force(const v1::ApplyForceRequest& req, v1::ApplyForceResponse* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  const auto nv = static_cast<int64_t>(s->model()->vertex_count());
  if (req.vertices_size() == 0) return invalid("vertices is empty; list the vertex indices to push");
  for (int i = 0; i < req.vertices_size(); ++i)
    if (req.vertices(i) < 0 || req.vertices(i) >= nv)
      return invalid(fmt::format("vertices[{}] = {} is out of range [0, {})", i, req.vertices(i), nv));
  Vec3 f = to_vec(req.force());
  if (!f.allFinite()) return invalid(fmt::format("force must be finite, got ({}, {}, {})", f.x(), f.y(), f.z()));
  uint32_t ticks = req.ticks() == 0 ? 1 : req.ticks();
  if (ticks > 1000000) return invalid(fmt::format("ticks must be in [1, 1000000], got {}", req.ticks()));
  uint64_t first = 0;
  if (Error e = s->apply_force({req.vertices().begin(), req.vertices().end()}, f, ticks, &first); !e.ok())
    return e;
  out->set_first_tick(first);
  return {};
}

Error SceneRegistry::grab(const v1::GrabRequest& req, v1::GrabResponse* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  auto m = s->model();
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
    a.target = to_vec(req.target());
    if (!a.target.allFinite())
      return invalid(fmt::format("target must be finite, got ({}, {}, {})", a.target.x(), a.target.y(), a.target.z()));
  } else {
    // Hold the point where it is now: the latest frame, or before the first tick the positions
    // the scene started from (a restored snapshot's, not the rest shape).
    std::vector<Vec3> x = s->initial_positions().size() == m->vertex_count() ? s->initial_positions() : m->rest_positions;
    if (auto f = s->latest_frame(); f && f->positions.size() == 3 * x.size())
      for (size_t i = 0; i < x.size(); ++i) x[i] = Vec3(f->positions[3 * i], f->positions[3 * i + 1], f->positions[3 * i + 2]);
    a.target = a.point(x);
  }
  if (req.has_compliance()) {
    if (!std::isfinite(req.compliance()) || req.compliance() < 0)
      return invalid(fmt::format("compliance must be finite and >= 0, got {}", req.compliance()));
    a.compliance = req.compliance();
  }
  if (std::string msg = validate_interaction({a}, {}, *m); !msg.empty()) return invalid(msg);
  uint64_t id = 0, first = 0;
  if (Error e = s->grab(a, &id, &first, std::chrono::seconds(10), static_cast<size_t>(options_.max_grabs_per_scene));
      !e.ok())
    return e;
  out->set_grab_id(id);
  out->set_first_tick(first);
  return {};
}

Error SceneRegistry::move_grab(const v1::MoveGrabRequest& req, v1::MoveGrabResponse* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  if (!req.has_target()) return invalid("target is not set");
  const Vec3 t = to_vec(req.target());
  if (!t.allFinite()) return invalid(fmt::format("target must be finite, got ({}, {}, {})", t.x(), t.y(), t.z()));
  uint64_t first = 0;
  Vec3 force = Vec3::Zero();
  if (Error e = s->move_grab(req.grab_id(), t, &first, &force); !e.ok()) return e;
  out->set_first_tick(first);
  out->mutable_force()->set_x(force.x());
  out->mutable_force()->set_y(force.y());
  out->mutable_force()->set_z(force.z());
  return {};
}

Error SceneRegistry::release(const v1::ReleaseRequest& req) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  return s->release(req.grab_id());
}

Error SceneRegistry::parse_tool_pose(const v1::ToolPose& p, const RigidTool* previous, RigidTool* out) {
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
  t.position = to_vec(p.position());
  if (!t.position.allFinite())
    return invalid(fmt::format("position must be finite, got ({}, {}, {})", t.position.x(), t.position.y(), t.position.z()));
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

Error SceneRegistry::topology(const std::string& id, v1::Topology* out) const {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  auto m = s->model();
  out->set_vertex_count(static_cast<uint32_t>(m->vertex_count()));
  out->mutable_rest_positions()->Reserve(static_cast<int>(3 * m->vertex_count()));
  for (const auto& p : m->rest_positions)
    for (int k = 0; k < 3; ++k) out->add_rest_positions(static_cast<float>(p[k]));
  for (const auto& t : m->tets)
    for (int k = 0; k < 4; ++k) out->add_tets(t.v[k]);
  for (const auto& t : m->surface)
    for (int k = 0; k < 3; ++k) out->add_surface_triangles(t[k]);
  for (int32_t v : s->surface_vertices()) out->add_surface_vertices(v);
  for (size_t i = 0; i < m->fixed.size(); ++i)
    if (m->fixed[i]) out->add_fixed_vertices(static_cast<int32_t>(i));
  return {};
}

Error SceneRegistry::parse_stream_request(const v1::StreamFramesRequest& req, FrameSelection* out) {
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

void SceneRegistry::fill_frame(const Frame& f, const FrameSelection& sel,
                               const std::vector<int32_t>& surface, uint64_t skipped, v1::Frame* out) {
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
  }
  if (sel.residuals) out->mutable_residuals()->Add(f.residuals.begin(), f.residuals.end());
  auto* st = out->mutable_solver();
  st->set_iterations(f.iterations);
  st->set_residual_final(f.residual_final);
  st->set_relative_residual(f.residual_initial > 0 ? f.residual_final / f.residual_initial : 0.0);
  if (sel.solver_stats) {
    st->set_substeps(f.substeps);
    st->set_residual_initial(f.residual_initial);
    st->set_accelerations_tried(f.accelerations_tried);
    st->set_accelerations_accepted(f.accelerations_accepted);
    st->set_accelerations_rejected(f.accelerations_tried - f.accelerations_accepted);
    st->set_step_wall_ms(f.step_wall_ms);
    st->set_stopped_by_tolerance(f.stopped_by_tolerance);
    st->set_stopped_by_budget(f.stopped_by_budget);
    st->set_volume_corrections(f.volume_corrections);
  }
  out->set_late_ticks(f.late_ticks);
  out->set_skipped_ticks(f.skipped_ticks);
  out->set_lateness_ms(f.lateness_ms);
  out->set_ticks_per_second(f.ticks_per_second);
  out->set_rolled_back(f.rolled_back);
  out->set_rollbacks(f.rollbacks);
  out->set_rollback_reason(f.rollback_reason);
  out->set_published_unix_ns(f.published_unix_ns);
  out->set_state(f.mode == TickMode::Lockstep ? v1::SCENE_STATE_LOCKSTEP
                                              : (f.running ? v1::SCENE_STATE_RUNNING : v1::SCENE_STATE_PAUSED));
}

Error SceneRegistry::save_snapshot(const v1::SaveSnapshotRequest& req, v1::SaveSnapshotResponse* out) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  if (!req.name().empty()) {
    if (Error e = check_name("name", req.name()); !e.ok()) return e;
    if (options_.data_dir.empty())
      return Error::make(Code::FailedPrecondition,
                         fmt::format("name '{}': this server has no --data-dir to store snapshots in", req.name()));
  } else if (req.omit_snapshot()) {
    return invalid("omit_snapshot is set but name is empty: the snapshot would go nowhere");
  }
  SceneSnapshot snap;
  if (Error e = s->snapshot(&snap); !e.ok()) return e;
  v1::Snapshot proto;
  snapshot_to_proto(snap, &proto);
  if (!req.name().empty()) {
    std::string path = snapshot_file(req.name());
    if (Error e = write_file_atomically(path, proto.SerializeAsString()); !e.ok()) return e;
    out->set_path(path);
    spdlog::info("scene '{}': snapshot '{}' written to {}", s->id(), req.name(), path);
  }
  if (!req.omit_snapshot()) *out->mutable_snapshot() = std::move(proto);
  return {};
}

Error SceneRegistry::restore_snapshot(const v1::RestoreSnapshotRequest& req, v1::Scene* out) {
  v1::Snapshot from_file;
  const v1::Snapshot* proto = nullptr;
  switch (req.source_case()) {
    case v1::RestoreSnapshotRequest::kSnapshot: proto = &req.snapshot(); break;
    case v1::RestoreSnapshotRequest::kName: {
      if (Error e = check_name("name", req.name()); !e.ok()) return e;
      if (options_.data_dir.empty())
        return Error::make(Code::FailedPrecondition,
                           fmt::format("name '{}': this server has no --data-dir", req.name()));
      std::string path = snapshot_file(req.name());
      if (!fs::exists(path))
        return Error::make(Code::NotFound, fmt::format("snapshot name '{}' not found in the data directory", req.name()));
      if (Error e = read_snapshot_file(path, &from_file); !e.ok()) return e;
      proto = &from_file;
      break;
    }
    default: return invalid("source: set snapshot or name");
  }
  SceneSnapshot snap;
  if (Error e = snapshot_from_proto(*proto, options_.max_threads, options_.max_vertices, &snap); !e.ok())
    return e;
  std::string id = req.scene_id().empty() ? snap.id : req.scene_id();
  if (Error e = check_name("scene_id", id); !e.ok()) return e;
  const uint64_t tick = snap.tick;
  auto scene = std::make_shared<Scene>(std::move(snap), id);
  if (Error e = add_scene(scene, req.replace()); !e.ok()) return e;
  wake_checkpoint();
  spdlog::info("scene '{}' restored from a snapshot at tick {}", id, tick);
  return describe(*scene, out);
}

Error SceneRegistry::list_snapshots(v1::ListSnapshotsResponse* out) const {
  if (options_.data_dir.empty()) return {};
  std::vector<std::string> names;
  std::error_code ec;
  for (auto it = fs::directory_iterator(fs::path(options_.data_dir) / "snapshots", ec);
       !ec && it != fs::directory_iterator(); it.increment(ec))
    if (it->path().extension() == ".snapshot") names.push_back(it->path().stem().string());
  std::sort(names.begin(), names.end());
  for (auto& n : names) out->add_names(n);
  return {};
}

int SceneRegistry::restore_from_data_dir() {
  if (options_.data_dir.empty()) return 0;
  std::vector<fs::path> files;
  std::error_code ec;
  for (auto it = fs::directory_iterator(fs::path(options_.data_dir) / "scenes", ec);
       !ec && it != fs::directory_iterator(); it.increment(ec))
    if (it->path().extension() == ".snapshot") files.push_back(it->path());
  std::sort(files.begin(), files.end());
  int restored = 0;
  for (const auto& f : files) {
    v1::Snapshot proto;
    SceneSnapshot snap;
    Error e = read_snapshot_file(f.string(), &proto);
    if (e.ok()) e = snapshot_from_proto(proto, options_.max_threads, options_.max_vertices, &snap);
    if (e.ok()) e = check_name("scene_id", snap.id);
    if (e.ok()) {
      auto scene = std::make_shared<Scene>(snap);
      e = add_scene(scene, false);
      // The file holds this state already: no checkpoint until the scene changes.
      if (e.ok()) written_[snap.id] = {scene, scene->generation()};
    }
    if (!e.ok()) {
      spdlog::error("not restoring {}: {}", f.string(), e.message);
      continue;
    }
    spdlog::info("scene '{}' restored from {} (tick {}, t = {} s)", snap.id, f.string(), snap.tick,
                 proto.sim_time());
    ++restored;
  }
  return restored;
}

void SceneRegistry::start_background() {
  if (!options_.data_dir.empty()) {
    // Temporary files a crash left mid-write: never loaded, removed.
    std::error_code ec;
    for (const char* sub : {"scenes", "snapshots"})
      for (auto it = fs::directory_iterator(fs::path(options_.data_dir) / sub, ec);
           !ec && it != fs::directory_iterator(); it.increment(ec))
        if (it->path().filename().string().find(".snapshot.tmp.") != std::string::npos) {
          std::error_code removed;
          fs::remove(it->path(), removed);
        }
  }
  std::lock_guard lk(bg_mu_);
  if (bg_stop_ || watchdog_.joinable()) return;
  watchdog_ = std::thread([this] { watchdog_loop(); });
  if (!options_.data_dir.empty() && options_.checkpoint_ms > 0)
    checkpointer_ = std::thread([this] { checkpoint_loop(); });
}

void SceneRegistry::stop_background() {
  {
    std::lock_guard lk(bg_mu_);
    bg_stop_ = true;
  }
  bg_cv_.notify_all();
  if (watchdog_.joinable()) watchdog_.join();
  if (checkpointer_.joinable()) checkpointer_.join();
}

void SceneRegistry::wake_checkpoint() {
  {
    std::lock_guard lk(bg_mu_);
    checkpoint_requested_ = true;
  }
  bg_cv_.notify_all();
}

// Every 50 ms: stops ticks past max_tick_ms and reports ticks past stuck_tick_ms.
void SceneRegistry::watchdog_loop() {
  using namespace std::chrono;
  bool stuck_before = false;
  std::unique_lock lk(bg_mu_);
  while (!bg_stop_) {
    bg_cv_.wait_for(lk, milliseconds(50));
    if (bg_stop_) break;
    lk.unlock();
    std::vector<std::shared_ptr<Scene>> scenes;
    {
      std::lock_guard slk(mu_);
      for (auto& [id, s] : scenes_) scenes.push_back(s);
    }
    bool stuck = false;
    for (auto& s : scenes) {
      const auto running = s->tick_running_for();
      if (options_.max_tick_ms > 0 && running > milliseconds(options_.max_tick_ms))
        s->abort_tick(fmt::format("a tick ran longer than this server's --max-tick-ms {}", options_.max_tick_ms));
      if (options_.stuck_tick_ms > 0 && running > milliseconds(options_.stuck_tick_ms)) {
        if (!stuck_before) spdlog::error("scene '{}': a tick has been running for {} ms: NOT_SERVING until it ends",
                                         s->id(), duration_cast<milliseconds>(running).count());
        stuck = true;
      }
    }
    if (stuck != stuck_before) {
      if (!stuck) spdlog::info("no tick is stuck any more: SERVING");
      if (options_.on_health) options_.on_health(!stuck);
      stuck_before = stuck;
    }
    lk.lock();
  }
}

void SceneRegistry::checkpoint_loop() {
  std::unique_lock lk(bg_mu_);
  while (!bg_stop_) {
    bg_cv_.wait_for(lk, std::chrono::milliseconds(options_.checkpoint_ms),
                    [&] { return bg_stop_ || checkpoint_requested_; });
    if (bg_stop_) break;
    checkpoint_requested_ = false;
    lk.unlock();
    checkpoint();
    lk.lock();
  }
}

int SceneRegistry::checkpoint() {
  if (options_.data_dir.empty()) return 0;
  std::vector<std::shared_ptr<Scene>> scenes;
  {
    std::lock_guard lk(mu_);
    for (auto& [id, s] : scenes_) scenes.push_back(s);
  }
  int written = 0;
  for (auto& s : scenes) {
    const uint64_t generation = s->generation();
    {
      std::lock_guard files(files_mu_);
      auto it = written_.find(s->id());
      if (it != written_.end() && it->second.first.lock() == s && it->second.second == generation) continue;
    }
    // The state is copied on the tick thread at a tick boundary; serialised and written here.
    SceneSnapshot snap;
    if (Error e = s->snapshot(&snap, std::chrono::seconds(1)); !e.ok()) {
      spdlog::debug("scene '{}': checkpoint skipped: {}", s->id(), e.message);
      continue;
    }
    v1::Snapshot proto;
    snapshot_to_proto(snap, &proto);
    const std::string bytes = proto.SerializeAsString();
    std::lock_guard files(files_mu_);
    {
      std::lock_guard lk(mu_);  // deleted or replaced meanwhile: its file is not ours to write
      auto it = scenes_.find(s->id());
      if (it == scenes_.end() || it->second != s) continue;
    }
    if (Error e = write_file_atomically(scene_file(s->id()), bytes); !e.ok()) {
      spdlog::error("scene '{}': checkpoint failed: {}", s->id(), e.message);
      continue;
    }
    written_[s->id()] = {s, generation};
    ++written;
  }
  return written;
}

void SceneRegistry::begin_shutdown() {
  shutting_down_ = true;
  std::lock_guard lk(mu_);
  for (auto& [id, s] : scenes_) s->request_stop();
}

int SceneRegistry::shutdown() {
  shutting_down_ = true;
  stop_background();
  std::map<std::string, std::shared_ptr<Scene>> scenes;
  {
    std::lock_guard lk(mu_);
    scenes.swap(scenes_);
  }
  for (auto& [id, s] : scenes) s->stop();
  int written = 0;
  if (!options_.data_dir.empty()) {
    std::lock_guard files(files_mu_);
    for (auto& [id, s] : scenes) {
      v1::Snapshot proto;
      snapshot_to_proto(s->snapshot_stopped(), &proto);
      if (Error e = write_file_atomically(scene_file(id), proto.SerializeAsString()); !e.ok()) {
        spdlog::error("scene '{}': shutdown snapshot failed: {}", id, e.message);
        ++failed_saves_;
        continue;
      }
      ++written;
    }
    spdlog::info("wrote {} scene snapshot(s) to {}", written, (fs::path(options_.data_dir) / "scenes").string());
  }
  return written;
}

}  // namespace pliant::server
