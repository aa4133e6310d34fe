// SPDX-License-Identifier: Apache-2.0
// The scene map and what acts on it: each RPC's request checked (spec_proto, stream_proto),
// the scene found or created within the limits, the command handed to the scene's tick;
// the watchdog and the checkpoint writer.
#include "pliant/server/registry.hpp"

#include "pliant/server/edge.hpp"
#include "fixed_groups.hpp"
#include "pliant/server/spec_proto.hpp"
#include "pliant/server/stream_proto.hpp"

#include "pliant/method_choice.hpp"
#include "pliant/stepper.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>

namespace pliant::server {

using Clock = std::chrono::steady_clock;

namespace {

Error invalid(std::string m) { return Error::invalid(std::move(m)); }

Error check_id_present(const std::string& id) {
  if (id.empty()) return invalid("scene_id is empty");
  return {};
}

Error not_found(const std::string& id) {
  return Error::make(Code::NotFound, fmt::format("scene_id {} not found", echo(id)));
}

// The Scene message a call answers with.
Error answer(const Scene& scene, v1::Scene* out) {
  scene_to_proto(scene, out);
  return {};
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

SceneRegistry::SceneRegistry(RegistryOptions options)
    : options_(std::move(options)), store_(options_.data_dir) {}

SceneRegistry::~SceneRegistry() {
  stop_background();
  std::map<std::string, std::shared_ptr<Scene>> scenes;
  {
    std::lock_guard lk(mu_);
    scenes.swap(scenes_);
  }
  for (auto& [id, s] : scenes) s->stop();
}

Error SceneRegistry::find(const std::string& id, std::shared_ptr<Scene>* out) const {
  if (Error e = check_id_present(id); !e.ok()) return e;
  std::lock_guard lk(mu_);
  auto it = scenes_.find(id);
  if (it == scenes_.end()) return not_found(id);
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

Error SceneRegistry::check_room(const std::string& id, bool replacing) const {
  if (shutting_down_) return Error::make(Code::Unavailable, "the server is shutting down");
  const bool taken = !id.empty() && scenes_.count(id) > 0;
  if (taken && !replacing) return Error::make(Code::AlreadyExists, fmt::format("scene_id '{}' already exists", id));
  if (!taken && static_cast<int>(scenes_.size()) >= options_.max_scenes)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("this server already hosts {} scenes (--max-scenes {}); delete one first",
                                   scenes_.size(), options_.max_scenes));
  return {};
}

Error SceneRegistry::add_scene(std::shared_ptr<Scene> scene, bool replace) {
  std::shared_ptr<Scene> old;
  {
    std::lock_guard lk(mu_);
    if (Error e = check_room(scene->id(), replace); !e.ok()) return e;
    if (auto it = scenes_.find(scene->id()); it != scenes_.end()) old = it->second;
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
    if (Error e = check_room(id, false); !e.ok()) return e;
    if (id.empty()) {
      do id = "scene-" + std::to_string(next_id_++);
      while (scenes_.count(id));
    }
  }
  const auto& spec = req.spec();
  SceneConfig cfg;
  Material material;
  TetMesh mesh;
  if (Error e = config_from_spec(spec, "spec", options_.max_threads, &cfg, &material); !e.ok()) return e;
  if (Error e = mesh_from_source(spec.mesh(), options_.model_path, options_.max_vertices, cfg, &mesh); !e.ok())
    return e;
  FixedSelection fixed = cfg.fixed;
  if (Error e = add_fixed_groups(spec.fixed(), "spec.fixed", mesh, &fixed, &cfg.fixed_groups); !e.ok()) return e;
  std::shared_ptr<const BodyModel> model;
  if (Error e = build_body(mesh, material, fixed, &model); !e.ok()) return e;
  // A realtime scene whose request names neither a method nor a budget in sweeps gets the most
  // accurate method within its time budget (half the tick unless it names one).
  if (spec.solver().method() == v1::METHOD_UNSPECIFIED && !pins_budget(spec.solver()) && cfg.mode == TickMode::Realtime)
    cfg.settings.method = Method::Auto;
  cfg.method_auto = cfg.settings.method == Method::Auto;
  resolve_auto_method(id, *model, cfg);
  if (Error e = check_work(*model, cfg.settings, "spec.solver"); !e.ok()) return e;
  if (Error e = bodies_from_spec(spec.bodies(), "spec.bodies", options_.model_path, &cfg.bodies); !e.ok()) return e;
  BodyState state = rest_state(*model);
  std::shared_ptr<Scene> scene;
  try {
    scene = std::make_shared<Scene>(id, cfg, model, std::move(state), 0, spec.start_paused());
  } catch (const std::invalid_argument& e) {
    return invalid(std::string("spec.") + e.what());
  }
  if (scene->particle_count() > kMaxParticlesPerScene)
    return Error::make(Code::ResourceExhausted,
                       fmt::format("spec.bodies hold {} particles, beyond the limit of {} particles per scene",
                                   scene->particle_count(), kMaxParticlesPerScene));
  if (Error e = add_scene(scene, false); !e.ok()) return e;
  wake_checkpoint();
  spdlog::info("scene '{}' created: {} ({} vertices, {} tets), {} mode, dt {} s, {}", id,
               cfg.mesh_name, model->vertex_count(), model->tet_count(), to_string(cfg.mode),
               cfg.settings.dt, pliant::to_string(cfg.settings.method));
  warn_if_under_resolved(id, *model, cfg.settings);
  return answer(*scene, out);
}

Error SceneRegistry::list(v1::ListScenesResponse* out) const {
  for (auto& s : scenes()) scene_to_proto(*s, out->add_scenes());
  return {};
}

Error SceneRegistry::get(const std::string& id, v1::Scene* out) const {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  return answer(*s, out);
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
  return answer(*s, out);
}

Error SceneRegistry::remove(const std::string& id) {
  std::shared_ptr<Scene> s;
  {
    if (Error e = check_id_present(id); !e.ok()) return e;
    std::lock_guard lk(mu_);
    auto it = scenes_.find(id);
    if (it == scenes_.end()) return not_found(id);
    s = it->second;
    scenes_.erase(it);
  }
  s->stop();
  store_.remove_scene(id);
  spdlog::info("scene '{}' deleted", id);
  return {};
}

namespace {

// Pause, resume, reset: a command on the scene's tick (its default timeout), answered with the
// Scene message.
Error command_and_answer(const SceneRegistry& registry, const std::string& id,
                         Error (Scene::*command)(std::chrono::milliseconds), v1::Scene* out) {
  std::shared_ptr<Scene> s;
  if (Error e = registry.find(id, &s); !e.ok()) return e;
  if (Error e = ((*s).*command)(std::chrono::seconds(10)); !e.ok()) return e;
  return answer(*s, out);
}

}  // namespace

Error SceneRegistry::reset(const std::string& id, v1::Scene* out) {
  return command_and_answer(*this, id, &Scene::reset, out);
}

Error SceneRegistry::pause(const std::string& id, v1::Scene* out) {
  return command_and_answer(*this, id, &Scene::pause, out);
}

Error SceneRegistry::resume(const std::string& id, v1::Scene* out) {
  return command_and_answer(*this, id, &Scene::resume, out);
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
  Vec3 f;
  if (Error e = finite_from_proto(req.force(), "force", &f); !e.ok()) return e;
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
  uint64_t id = 0, first = 0;
  if (!req.body().empty()) {  // a particle of a particle body
    const auto& bodies = s->bodies();
    size_t b = 0;
    while (b < bodies.size() && bodies[b].name != req.body()) ++b;
    if (b == bodies.size())
      return Error::make(Code::NotFound, fmt::format("body {} is not a body of scene '{}'", echo(req.body()), s->id()));
    if (req.point_case() != v1::GrabRequest::kVertex)
      return invalid(fmt::format("body {}: set vertex to the particle index (tet_point is for the tet body)",
                                 echo(req.body())));
    if (req.vertex() < 0 || static_cast<size_t>(req.vertex()) >= bodies[b].capacity)
      return invalid(fmt::format("vertex {} is out of range for body {} ({} particles{})", req.vertex(),
                                 echo(req.body()), bodies[b].capacity,
                                 bodies[b].capacity > bodies[b].particles ? " at most" : ""));
    std::optional<Vec3> target;
    if (req.has_target()) {
      Vec3 t;
      if (Error e = finite_from_proto(req.target(), "target", &t); !e.ok()) return e;
      target = t;
    }
    double compliance = 0.0;
    if (req.has_compliance()) {
      if (!std::isfinite(req.compliance()) || req.compliance() < 0)
        return invalid(fmt::format("compliance must be finite and >= 0, got {}", req.compliance()));
      compliance = req.compliance();
    }
    if (Error e = s->grab_particle(b, static_cast<size_t>(req.vertex()), target, compliance, &id, &first,
                                   std::chrono::seconds(10), static_cast<size_t>(options_.max_grabs_per_scene));
        !e.ok())
      return e;
    out->set_grab_id(id);
    out->set_first_tick(first);
    return {};
  }
  Attachment a;
  if (Error e = grab_from_proto(req, *s, &a); !e.ok()) return e;
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
  Vec3 t;
  if (Error e = finite_from_proto(req.target(), "target", &t); !e.ok()) return e;
  uint64_t first = 0;
  Vec3 force = Vec3::Zero();
  if (Error e = s->move_grab(req.grab_id(), t, &first, &force); !e.ok()) return e;
  out->set_first_tick(first);
  to_proto(force, out->mutable_force());
  return {};
}

Error SceneRegistry::release(const v1::ReleaseRequest& req) {
  std::shared_ptr<Scene> s;
  if (Error e = find(req.scene_id(), &s); !e.ok()) return e;
  return s->release(req.grab_id());
}

Error SceneRegistry::topology(const std::string& id, v1::Topology* out) const {
  std::shared_ptr<Scene> s;
  if (Error e = find(id, &s); !e.ok()) return e;
  topology_to_proto(*s, out);
  return {};
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
    std::string path;
    if (Error e = store_.save_named(req.name(), proto, &path); !e.ok()) return e;
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
      if (Error e = store_.load_named(req.name(), &from_file); !e.ok()) return e;
      proto = &from_file;
      break;
    }
    default: return invalid("source: set snapshot or name");
  }
  SceneSnapshot snap;
  if (Error e = snapshot_from_proto(*proto, options_.max_threads, options_.max_vertices, options_.model_path, &snap); !e.ok())
    return e;
  std::string id = req.scene_id().empty() ? snap.id : req.scene_id();
  if (Error e = check_name("scene_id", id); !e.ok()) return e;
  const uint64_t tick = snap.tick;
  std::shared_ptr<Scene> scene;
  try {
    scene = std::make_shared<Scene>(std::move(snap), id);
  } catch (const std::invalid_argument& e) {
    return invalid(e.what());
  }
  if (Error e = add_scene(scene, req.replace()); !e.ok()) return e;
  wake_checkpoint();
  spdlog::info("scene '{}' restored from a snapshot at tick {}", id, tick);
  return answer(*scene, out);
}

Error SceneRegistry::list_snapshots(v1::ListSnapshotsResponse* out) const {
  for (auto& n : store_.names()) out->add_names(n);
  return {};
}

int SceneRegistry::restore_from_data_dir() {
  int restored = 0;
  for (const auto& f : store_.scene_files()) {
    v1::Snapshot proto;
    SceneSnapshot snap;
    Error e = SnapshotStore::read(f, &proto);
    if (e.ok()) e = snapshot_from_proto(proto, options_.max_threads, options_.max_vertices, options_.model_path, &snap);
    if (e.ok()) e = check_name("scene_id", snap.id);
    if (e.ok()) {
      std::shared_ptr<Scene> scene;
      try {
        scene = std::make_shared<Scene>(snap);
      } catch (const std::invalid_argument& ex) {
        e = invalid(ex.what());
      }
      if (e.ok()) e = add_scene(scene, false);
      // The file holds this state already: no checkpoint until the scene changes.
      if (e.ok()) store_.mark_written(scene, scene->generation());
    }
    if (!e.ok()) {
      spdlog::error("not restoring {}: {}", f, e.message);
      continue;
    }
    spdlog::info("scene '{}' restored from {} (tick {}, t = {} s)", snap.id, f, snap.tick, proto.sim_time());
    ++restored;
  }
  return restored;
}

void SceneRegistry::start_background() {
  store_.remove_temporaries();
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
    bool stuck = false;
    for (auto& s : scenes()) {
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
  if (!store_.enabled()) return 0;
  int written = 0;
  for (auto& s : scenes()) {
    const uint64_t generation = s->generation();
    if (store_.up_to_date(s, generation)) continue;
    // The state is copied on the tick thread at a tick boundary; serialised and written here.
    SceneSnapshot snap;
    if (Error e = s->snapshot(&snap, std::chrono::seconds(1)); !e.ok()) {
      spdlog::debug("scene '{}': checkpoint skipped: {}", s->id(), e.message);
      continue;
    }
    v1::Snapshot proto;
    snapshot_to_proto(snap, &proto);
    bool wrote = false;
    const auto still_hosted = [&] {
      std::lock_guard lk(mu_);
      auto it = scenes_.find(s->id());
      return it != scenes_.end() && it->second == s;
    };
    if (Error e = store_.write_checkpoint(s, generation, proto.SerializeAsString(), still_hosted, &wrote); !e.ok()) {
      spdlog::error("scene '{}': checkpoint failed: {}", s->id(), e.message);
      continue;
    }
    if (wrote) ++written;
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
  return store_.write_stopped(scenes, &failed_saves_);
}

}  // namespace pliant::server
