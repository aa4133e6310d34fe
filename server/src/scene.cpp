// SPDX-License-Identifier: Apache-2.0
// The scene's tick thread: drains commands, steps on absolute deadlines, rolls back blow-ups,
// publishes frames.
#include "pliant/server/scene.hpp"

#include "pliant/coupling.hpp"
#include "pliant/stepper.hpp"

#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <future>
#include <map>
#include <numeric>
#include <optional>
#include <set>

namespace pliant::server {

using Clock = std::chrono::steady_clock;

std::string_view to_string(TickMode mode) {
  switch (mode) {
    case TickMode::Realtime: return "realtime";
    case TickMode::Lockstep: return "lockstep";
    case TickMode::AsFastAsPossible: return "as-fast-as-possible";
  }
  return "?";
}

namespace {
// A Step's tick stopped by the per-tick time limit.
struct TickAborted : std::runtime_error {
  using std::runtime_error::runtime_error;
};
}  // namespace

struct Scene::StepJob {
  uint32_t remaining;
  uint64_t rollbacks_before;
  std::shared_ptr<std::promise<StepResult>> done;
};

struct Scene::TickState {
  std::shared_ptr<const BodyModel> model;
  SolverSettings settings;
  TickMode mode = TickMode::Realtime;
  bool running = true;
  std::string pause_reason;
  BodyState state;
  BodyState last_good;
  Stepper stepper;
  uint64_t tick = 0;
  std::deque<StepJob> steps;
  std::vector<ActiveForce> forces;
  // Interaction, by id (ordered, so a tick's inputs are deterministic).
  std::map<uint64_t, Attachment> grabs;
  std::map<uint64_t, Vec3> grab_forces;  // last tick's force per grab
  uint64_t next_grab_id = 1;
  struct PosedTool {
    RigidTool tool;
    uint64_t seq = 0;
    int64_t client_ns = 0;
    // The pose the previous tick used: the tick sweeps and turns the tool from there (velocity =
    // displacement / dt, angular velocity = rotation / dt), so friction sees its motion and a
    // fast move is no teleport.
    Vec3 used_position = Vec3::Zero();
    Eigen::Quaterniond used_orientation = Eigen::Quaterniond::Identity();
    bool used = false;
  };
  std::map<uint64_t, PosedTool> tools;
  std::vector<Collider> colliders;  // static, from the scene's config
  // Particle bodies (config order), their states at the start of the tick in progress (for a
  // rollback) and as built (for a reset), and their grabs by id (ids shared with `grabs`).
  std::vector<std::unique_ptr<ParticleBody>> bodies;
  std::vector<ParticleState> bodies_last_good;
  std::vector<ParticleState> bodies_initial;
  std::map<uint64_t, ParticleGrab> body_grabs;
  // Each body's two-way contact with the tet body (nullopt: none).
  std::vector<std::optional<CouplingSettings>> body_contact;
  // Contacts between particle bodies: the particles of `particles` against the triangles of
  // `cloth` or the segments of a rope (`rope`), both with body_contact on.
  struct ClothPair {
    size_t particles, cloth;
    CouplingSettings settings;
    bool rope = false;
    int shared_substeps = 1;  // the largest factor of both bodies' substeps (Scene::body_parts)
  };
  std::vector<ClothPair> cloth_pairs;
  std::vector<uint8_t> in_cloth_pair;  // per body: in some ClothPair (its start positions are read)
  int body_parts = 1;  // the parts a tick of the bodies in some ClothPair is cut into (shared_step_parts)
  // Per body: it steps with the tet body in parts where their substeps allow (Scene::body_parts):
  // the fluids with soft_body_contact. Every body with soft_body_contact meets the tet body's
  // surface inside its own step, where the tet body's step (or part) left it; a cloth or a rope
  // steps once per tick after the tet body's whole step (the tet body's vertices meet a cloth's
  // triangles inside its step), and its segments meet the surface after its step.
  std::vector<uint8_t> tet_parts;
  bool surface_used = false;  // some body has soft_body_contact
  // The parts the substeps of those fluids and of the paired bodies share (shared_step_parts; 0:
  // no fluid touches the tet body): with the tet body's substeps, the parts of a tick.
  int tet_body_parts = 0;
  // The cloths with soft_body_contact: obstacles to the tet body's vertices in its step.
  std::vector<size_t> obstacle_bodies;
  std::vector<std::vector<Vec3>> body_start;  // scratch: each body's positions before its step
  std::vector<std::vector<Vec3>> body_part_start;  // scratch: before the part of the step (step_bodies)
  std::vector<size_t> part_contacts;              // scratch: each body's pair contacts at a cut of a part
  // Scratch per pair: its two bodies' positions where its span began (BodyParts::pair_calls),
  // where that is not the start of their own call.
  std::vector<std::array<std::vector<Vec3>, 2>> pair_start;
  // Scratch for the bodies that meet the tet body's surface inside their step: its vertices'
  // mean velocities over the part (or the tick) and its positions where the next part starts.
  std::vector<Vec3> surface_v, surface_part_start;
  std::vector<ParticleStepReport> body_reports;  // each body's step in the tick in progress
  // The momentum and angular momentum the particle bodies gained from each tool inside their
  // substeps over the tick in progress (the tools take minus them).
  std::vector<Vec3> tool_impulse, tool_angular_impulse;
  // Realtime schedule: tick k is due at anchor + k * period.
  bool schedule_valid = false;
  Clock::time_point anchor;
  uint64_t slot = 0;
  TickCounters counters;  // ticks_per_second: over the last second
  int consecutive_rollbacks = 0;
  // Solver wall time summed over the ticks run in this process (the metrics' mean step time).
  double step_wall_ms_sum = 0;
  uint64_t stepped_ticks = 0;
  // Tick rate over the last second.
  Clock::time_point rate_window_start = Clock::now();
  uint64_t rate_window_ticks = 0;
  Clock::time_point last_tick_end;
  struct TickProfile {
    uint64_t ticks = 0;
    double step_ms = 0, tick_ms = 0, gap_ms = 0, late_ms = 0;
    int64_t volume_corrections = 0;
    Clock::time_point window_start, last_start;
  } profile;

  Clock::duration period() const {
    return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(settings.dt));
  }
};

namespace {

// A body's start positions grown by the particles an emitter added since (they start where they
// are: no path to cross).
void add_emitted(std::vector<Vec3>& start, const std::vector<Vec3>& now) {
  for (size_t i = start.size(); i < now.size(); ++i) start.push_back(now[i]);
}

std::vector<int32_t> surface_vertices_of(const BodyModel& model) {
  std::vector<int32_t> out;
  out.reserve(model.surface.size());
  for (const auto& t : model.surface) out.insert(out.end(), t.begin(), t.end());
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

}  // namespace

Scene::Scene(std::string id, SceneConfig config, std::shared_ptr<const BodyModel> model,
             BodyState state, uint64_t tick, bool paused)
    : id_(std::move(id)), ts_(std::make_unique<TickState>()) {
  surface_vertices_ = surface_vertices_of(*model);
  initial_positions_ = state.x;
  ts_->model = model;
  ts_->settings = config.settings;
  ts_->mode = config.mode;
  ts_->colliders = config.colliders;
  ts_->running = !paused;
  ts_->state = std::move(state);
  ts_->last_good = ts_->state;
  ts_->tick = tick;
  for (size_t b = 0; b < config.bodies.size(); ++b) {
    const BodyConfig& bc = config.bodies[b];
    std::unique_ptr<ParticleBody> body;
    try {
      body = make_particle_body(bc, config.settings.gravity);
    } catch (const std::exception& e) {
      throw std::invalid_argument("bodies[" + std::to_string(b) + "] ('" + bc.name + "', " + bc.kind +
                                  "): " + e.what());
    }
    BodyInfo info;
    info.name = bc.name;
    info.kind = body->kind();
    info.particles = body->size();
    info.capacity = particle_capacity(bc, info.particles);
    const auto tris = body->triangles();
    info.triangles.assign(tris.begin(), tris.end());
    const auto w = body->inverse_masses();
    for (size_t i = 0; i < w.size(); ++i)
      if (w[i] == 0.0) info.pinned.push_back(static_cast<uint32_t>(i));
    info.rest = body->state().x;
    std::optional<CouplingSettings> contact;
    if (bc.soft_body_contact) {
      contact.emplace();
      contact->radius = contact_radius(bc);
      contact->friction = bc.soft_body_friction;
    }
    ts_->tet_parts.push_back(contact && body->kind() == "fluid");
    ts_->surface_used = ts_->surface_used || contact.has_value();
    ts_->body_contact.push_back(contact);
    ts_->bodies_initial.push_back(body->state());
    ts_->body_start.emplace_back();
    ts_->body_part_start.emplace_back();
    body->set_log_name(fmt::format("scene '{}' body '{}' ({})", id_, bc.name, bc.kind));
    ts_->bodies.push_back(std::move(body));
    bodies_info_.push_back(std::move(info));
  }
  ts_->bodies_last_good = ts_->bodies_initial;
  for (size_t c = 0; c < ts_->bodies.size(); ++c) {
    // Obstacles to the other bodies' particles: a cloth's triangles, a rope's segments.
    const bool rope = ts_->bodies[c]->kind() == "rope";
    if ((ts_->bodies[c]->triangles().empty() && !rope) || !config.bodies[c].body_contact) continue;
    for (size_t a = 0; a < ts_->bodies.size(); ++a) {
      if (a == c || !config.bodies[a].body_contact) continue;
      CouplingSettings cs;
      cs.radius = ts_->bodies[a]->contact_radius() + ts_->bodies[c]->contact_radius();
      cs.friction = std::max(config.bodies[a].body_friction, config.bodies[c].body_friction);
      ts_->cloth_pairs.push_back({a, c, cs, rope, std::gcd(ts_->bodies[a]->substeps(), ts_->bodies[c]->substeps())});
    }
  }
  for (size_t b = 0; b < ts_->bodies.size(); ++b)
    if (ts_->body_contact[b] && !ts_->bodies[b]->triangles().empty()) ts_->obstacle_bodies.push_back(b);
  ts_->in_cloth_pair.assign(ts_->bodies.size(), 0);
  for (const TickState::ClothPair& p : ts_->cloth_pairs) ts_->in_cloth_pair[p.particles] = ts_->in_cloth_pair[p.cloth] = 1;
  std::vector<int> paired_substeps, with_fluids;
  for (size_t b = 0; b < ts_->bodies.size(); ++b) {
    if (ts_->in_cloth_pair[b]) paired_substeps.push_back(ts_->bodies[b]->substeps());
    if (ts_->in_cloth_pair[b] || ts_->tet_parts[b]) with_fluids.push_back(ts_->bodies[b]->substeps());
  }
  ts_->body_parts = shared_step_parts(paired_substeps);
  if (std::any_of(ts_->tet_parts.begin(), ts_->tet_parts.end(), [](uint8_t f) { return f != 0; }))
    ts_->tet_body_parts = shared_step_parts(with_fluids);
  if (ts_->body_parts > 1)
    spdlog::debug("scene '{}': the bodies in contact step in {} parts a tick (substeps {})", id_, ts_->body_parts,
                  fmt::join(paired_substeps, ", "));
  std::set<std::pair<size_t, size_t>> told;  // a pair of bodies may be in contact both ways
  for (const TickState::ClothPair& p : ts_->cloth_pairs) {
    const int a = ts_->bodies[p.particles]->substeps(), c = ts_->bodies[p.cloth]->substeps();
    if (p.shared_substeps == 1 && std::max(a, c) > 1 &&
        told.emplace(std::min(p.particles, p.cloth), std::max(p.particles, p.cloth)).second)
      spdlog::info("scene '{}': the substeps of bodies '{}' ({}) and '{}' ({}) have no common factor, so their "
                   "contact comes once per tick; substeps with one (a fluid's 2 and a cloth's 16) let the scene "
                   "resolve it within the tick",
                   id_, config.bodies[p.particles].name, a, config.bodies[p.cloth].name, c);
  }
  if (ts_->tet_body_parts > 0 && !body_parts().with_tet)
    spdlog::info("scene '{}': the soft body's substeps ({}) share no factor with its fluids' and their partners', so "
                 "a fluid meets the soft body's surface where its whole step left it, not part by part (docs/fluids.md, "
                 "\"In parts with the soft body\")",
                 id_, effective_substeps(*ts_->model, ts_->settings));
  config_ = std::move(config);
  model_shared_ = std::move(model);
  publish_status();
}

Scene::Scene(SceneSnapshot snapshot, std::string id)
    : Scene(id.empty() ? snapshot.id : std::move(id), std::move(snapshot.config), snapshot.model,
            std::move(snapshot.state), snapshot.tick, snapshot.paused) {
  uint64_t next = std::max<uint64_t>(snapshot.next_grab_id, 1);
  for (const auto& [gid, a] : snapshot.grabs) next = std::max(next, gid + 1);
  ts_->grabs = std::move(snapshot.grabs);
  if (!snapshot.body_states.empty()) {
    if (snapshot.body_states.size() != ts_->bodies.size())
      throw std::invalid_argument("snapshot.bodies has " + std::to_string(snapshot.body_states.size()) +
                                  " states, snapshot.spec.bodies " + std::to_string(ts_->bodies.size()) + " bodies");
    for (size_t b = 0; b < ts_->bodies.size(); ++b) {
      try {
        ts_->bodies[b]->set_state(snapshot.body_states[b]);
      } catch (const std::exception& e) {
        throw std::invalid_argument("snapshot.bodies[" + std::to_string(b) + "] ('" + bodies_info_[b].name +
                                    "'): " + e.what());
      }
      ts_->bodies_last_good[b] = ts_->bodies[b]->state();
    }
  }
  for (const auto& [gid, g] : snapshot.body_grabs) {
    if (g.body >= ts_->bodies.size() || g.particle >= ts_->bodies[g.body]->size())
      throw std::invalid_argument("snapshot.bodies: grab " + std::to_string(gid) + " names particle " +
                                  std::to_string(g.particle) + " of a body that does not have it");
    ts_->bodies[g.body]->grab(gid, g.particle, g.target, g.compliance);
    next = std::max(next, gid + 1);
  }
  ts_->body_grabs = std::move(snapshot.body_grabs);
  ts_->next_grab_id = next;
  publish_status();  // the bodies' particle counts as restored
}

size_t Scene::particle_count() const {
  size_t n = 0;
  for (const BodyInfo& b : bodies_info_) n += b.capacity;
  return n;
}

void Scene::restore_bodies() {
  TickState& t = *ts_;
  for (size_t b = 0; b < t.bodies.size(); ++b) t.bodies[b]->set_state(t.bodies_last_good[b]);
  // A fluid back before some of its emitted layers no longer has their particles: their grabs go.
  for (auto it = t.body_grabs.begin(); it != t.body_grabs.end();)
    it = it->second.particle >= t.bodies[it->second.body]->size() ? t.body_grabs.erase(it) : std::next(it);
}

Scene::~Scene() { stop(); }

void Scene::start() {
  std::lock_guard lk(mu_);
  if (thread_.joinable() || stop_) return;
  thread_ = std::thread([this] { run(); });
}

void Scene::request_stop() {
  {
    std::lock_guard lk(mu_);
    stop_ = true;
    cancel_tick_ = true;
  }
  cv_.notify_all();
  {
    // Frame waiters see stop_ under frame_mu_ (wait_frame's predicate takes mu_ inside it).
    std::lock_guard lk(frame_mu_);
  }
  frame_cv_.notify_all();
  notify_listeners();
}

uint64_t Scene::add_frame_listener(std::function<void()> fn) {
  std::lock_guard lk(listeners_mu_);
  const uint64_t id = next_listener_++;
  listeners_.emplace(id, std::move(fn));
  return id;
}

void Scene::remove_frame_listener(uint64_t id) {
  std::lock_guard lk(listeners_mu_);
  listeners_.erase(id);
}

void Scene::notify_listeners() {
  std::lock_guard lk(listeners_mu_);
  for (auto& [id, fn] : listeners_) fn();
}

void Scene::stop() {
  request_stop();
  if (thread_.joinable() && thread_.get_id() != std::this_thread::get_id()) thread_.join();
  {
    std::lock_guard lk(mu_);
    commands_.clear();  // breaks the promises of calls still waiting: they answer Unavailable
  }
  if (ts_) {
    for (auto& job : ts_->steps)
      job.done->set_exception(std::make_exception_ptr(std::runtime_error("scene stopped")));
    ts_->steps.clear();
  }
  {
    std::lock_guard lk(frame_mu_);
  }
  frame_cv_.notify_all();
}

bool Scene::stopped() const {
  std::lock_guard lk(mu_);
  return stop_;
}

Clock::duration Scene::tick_running_for() const {
  const int64_t started = tick_started_ns_.load();
  if (started == 0) return Clock::duration::zero();
  return Clock::now().time_since_epoch() - std::chrono::nanoseconds(started);
}

void Scene::abort_tick(std::string reason) {
  std::lock_guard lk(abort_mu_);
  if (tick_started_ns_.load() == 0) return;  // the tick ended meanwhile
  abort_reason_ = std::move(reason);
  cancel_tick_ = true;
}

std::shared_ptr<const BodyModel> Scene::model() const {
  std::lock_guard lk(info_mu_);
  return model_shared_;
}

SceneConfig Scene::config() const {
  std::lock_guard lk(info_mu_);
  return config_;
}

SceneStatus Scene::status() const {
  std::lock_guard lk(info_mu_);
  return status_;
}

void Scene::publish_status() {
  SceneStatus s;
  s.running = ts_->running && ts_->mode != TickMode::Lockstep;
  s.mode = ts_->mode;
  s.tick = ts_->tick;
  s.sim_time = ts_->state.time;
  s.counters = ts_->counters;
  s.pause_reason = ts_->pause_reason;
  s.body_particles.reserve(ts_->bodies.size());
  for (const auto& b : ts_->bodies) s.body_particles.push_back(b->size());
  std::lock_guard lk(info_mu_);
  ++generation_;
  status_ = std::move(s);
  config_.settings = ts_->settings;
  config_.mode = ts_->mode;
  model_shared_ = ts_->model;
}

Error Scene::enqueue(Command fn, bool interrupt) {
  bool wake = false;
  {
    std::lock_guard lk(mu_);
    if (stop_) return Error::make(Code::Unavailable, "scene '" + id_ + "' is shutting down");
    commands_.push_back(std::move(fn));
    wake = waiting_for_commands_;
    if (interrupt) cancel_tick_ = true;
  }
  if (wake) cv_.notify_all();
  return {};
}

Error Scene::not_in_time() const {
  return Error::make(Code::DeadlineExceeded, "scene '" + id_ + "' did not reach a tick boundary in time");
}

Error Scene::stopped_before_running() const {
  return Error::make(Code::Unavailable, "scene '" + id_ + "' stopped before the command ran");
}

bool Scene::post(Command fn) {
  // Only a tick thread idle until the next command is woken: one waiting for its next
  // scheduled tick runs the command then anyway, and at 1 kHz of tool poses the wake-ups
  // would be 1000 useless context switches a second per stream.
  bool wake = false;
  {
    std::lock_guard lk(mu_);
    if (stop_) return false;
    commands_.push_back(std::move(fn));
    wake = waiting_for_commands_;
  }
  if (wake) cv_.notify_all();
  return true;
}

Error Scene::add_grab(std::function<Error(uint64_t id)> attach, uint64_t* grab_id, uint64_t* first_tick,
                      std::chrono::milliseconds timeout, size_t max_grabs) {
  struct Granted {
    uint64_t id = 0, first_tick = 0;
  } granted;
  Error e = call(
      [this, attach = std::move(attach), max_grabs](Granted& out) {
        const size_t held = ts_->grabs.size() + ts_->body_grabs.size();
        if (held >= max_grabs)
          return Error::make(Code::ResourceExhausted,
                             "scene '" + id_ + "' already has " + std::to_string(held) + " grabs (--max-grabs-per-scene " +
                                 std::to_string(max_grabs) + "); release one first");
        if (Error e = attach(ts_->next_grab_id); !e.ok()) return e;
        out.id = ts_->next_grab_id++;
        ++generation_;  // grabs are saved: a checkpoint is due
        out.first_tick = ts_->tick + 1;
        return Error{};
      },
      &granted, Clock::now() + timeout);
  if (e.ok()) {
    if (grab_id) *grab_id = granted.id;
    if (first_tick) *first_tick = granted.first_tick;
  }
  return e;
}

Error Scene::grab(const Attachment& attachment, uint64_t* grab_id, uint64_t* first_tick,
                  std::chrono::milliseconds timeout, size_t max_grabs) {
  return add_grab([this, attachment](uint64_t id) {
    ts_->grabs[id] = attachment;
    return Error{};
  }, grab_id, first_tick, timeout,
                  max_grabs);
}

Error Scene::grab_particle(size_t body, size_t particle, std::optional<Vec3> target, double compliance,
                          uint64_t* grab_id, uint64_t* first_tick, std::chrono::milliseconds timeout,
                          size_t max_grabs) {
  return add_grab(
      [this, body, particle, target, compliance](uint64_t id) {
        ParticleBody& b = *ts_->bodies.at(body);
        if (particle >= b.size())  // a fluid's emitters have not created it (yet)
          return Error::make(Code::InvalidArgument, "vertex " + std::to_string(particle) + " is out of range for body '" +
                                                        bodies_info_[body].name + "' (" + std::to_string(b.size()) +
                                                        " particles now)");
        const ParticleGrab g{body, particle, target.value_or(b.state().x.at(particle)), compliance};
        b.grab(id, g.particle, g.target, g.compliance);
        ts_->body_grabs[id] = g;
        return Error{};
      },
      grab_id, first_tick, timeout, max_grabs);
}

Error Scene::move_grab(uint64_t grab_id, const Vec3& target, uint64_t* first_tick, Vec3* last_force,
                       std::chrono::milliseconds timeout) {
  struct Moved {
    uint64_t first_tick = 0;
    Vec3 force = Vec3::Zero();
  } moved;
  Error e = call(
      [this, grab_id, target](Moved& out) {
        auto it = ts_->grabs.find(grab_id);
        auto bit = ts_->body_grabs.find(grab_id);
        if (it == ts_->grabs.end() && bit == ts_->body_grabs.end())
          return Error::make(Code::NotFound, "grab_id " + std::to_string(grab_id) + " is not a grab of scene '" + id_ + "'");
        if (it != ts_->grabs.end()) {
          it->second.target = target;
        } else {
          bit->second.target = target;
          ts_->bodies[bit->second.body]->move_grab(grab_id, target);
        }
        ++generation_;
        if (auto f = ts_->grab_forces.find(grab_id); f != ts_->grab_forces.end()) out.force = f->second;
        out.first_tick = ts_->tick + 1;
        return Error{};
      },
      &moved, Clock::now() + timeout);
  if (e.ok()) {
    if (first_tick) *first_tick = moved.first_tick;
    if (last_force) *last_force = moved.force;
  }
  return e;
}

Error Scene::release(uint64_t grab_id, std::chrono::milliseconds timeout) {
  return call(
      [this, grab_id] {
        if (auto bit = ts_->body_grabs.find(grab_id); bit != ts_->body_grabs.end()) {
          ts_->bodies[bit->second.body]->release(grab_id);
          ts_->body_grabs.erase(bit);
        } else if (ts_->grabs.erase(grab_id) == 0)
          return Error::make(Code::NotFound, "grab_id " + std::to_string(grab_id) + " is not a grab of scene '" + id_ + "'");
        ts_->grab_forces.erase(grab_id);
        ++generation_;
        return Error{};
      },
      Clock::now() + timeout);
}

uint64_t Scene::new_tool_id() {
  std::lock_guard lk(mu_);
  return next_tool_id_++;
}

bool Scene::set_tool(uint64_t tool_id, const RigidTool& tool, uint64_t pose_seq, int64_t pose_client_ns) {
  return post([this, tool_id, tool, pose_seq, pose_client_ns] {
    auto& pt = ts_->tools[tool_id];
    pt.tool = tool;
    pt.seq = pose_seq;
    pt.client_ns = pose_client_ns;
  });
}

void Scene::remove_tool(uint64_t tool_id) {
  post([this, tool_id] { ts_->tools.erase(tool_id); });
}

Error Scene::not_in_lockstep() const {
  if (ts_->mode != TickMode::Lockstep) return {};
  return Error::make(Code::FailedPrecondition, "scene '" + id_ + "' is in lockstep mode (it ticks only on Step)");
}

Error Scene::pause(std::chrono::milliseconds timeout) {
  return call(
      [this] {
        if (Error e = not_in_lockstep(); !e.ok()) return e;
        ts_->running = false;
        ts_->schedule_valid = false;
        publish_status();
        return Error{};
      },
      Clock::now() + timeout, /*interrupt=*/true);
}

Error Scene::resume(std::chrono::milliseconds timeout) {
  return call(
      [this] {
        if (Error e = not_in_lockstep(); !e.ok()) return e;
        ts_->running = true;
        ts_->pause_reason.clear();
        ts_->consecutive_rollbacks = 0;
        ts_->schedule_valid = false;
        publish_status();
        return Error{};
      },
      Clock::now() + timeout);
}

Error Scene::reset(std::chrono::milliseconds timeout) {
  return call(
      [this] {
        ts_->state = rest_state(*ts_->model);
        ts_->last_good = ts_->state;
        ts_->tick = 0;
        ts_->forces.clear();
        ts_->grabs.clear();
        ts_->grab_forces.clear();
        for (const auto& [gid, g] : ts_->body_grabs) ts_->bodies[g.body]->release(gid);
        ts_->body_grabs.clear();
        ts_->bodies_last_good = ts_->bodies_initial;
        restore_bodies();
        ts_->schedule_valid = false;
        ts_->consecutive_rollbacks = 0;
        publish_status();
        return Error{};
      },
      Clock::now() + timeout, /*interrupt=*/true);
}

Error Scene::update(const SceneUpdate& update, std::chrono::milliseconds timeout) {
  return call(
      [this, update] {
        if (update.settings) {
          if (update.settings->dt != ts_->settings.dt) ts_->schedule_valid = false;
          ts_->settings = *update.settings;
          // The particle bodies fall with the scene (their gravity is the scene's).
          for (auto& body : ts_->bodies) body->set_gravity(update.settings->gravity);
          std::lock_guard lk(info_mu_);
          config_.method_auto = update.method_auto;
          config_.method_choice = update.method_choice;
        }
        if (update.model) ts_->model = update.model;
        if (update.mode && *update.mode != ts_->mode) {
          ts_->mode = *update.mode;
          ts_->schedule_valid = false;
        }
        publish_status();
        return Error{};
      },
      Clock::now() + timeout, /*interrupt=*/true);
}

Error Scene::apply_force(std::vector<int32_t> vertices, const Vec3& force, uint32_t ticks,
                         uint64_t* first_tick, std::chrono::milliseconds timeout) {
  return call(
      [this, vertices = std::move(vertices), force, ticks](uint64_t& first) mutable {
        ts_->forces.push_back(ActiveForce{std::move(vertices), force, ticks});
        first = ts_->tick + 1;
        return Error{};
      },
      first_tick, Clock::now() + timeout);
}

Error Scene::step(uint32_t ticks, Clock::time_point deadline, StepResult* out,
                  const std::function<bool()>& cancelled) {
  auto done = std::make_shared<std::promise<StepResult>>();
  auto future = done->get_future();
  Error queued = call(
      [this, ticks, done] {
        if (ts_->running && ts_->mode != TickMode::Lockstep)
          return Error::make(Code::FailedPrecondition,
                             "scene '" + id_ + "' is running in " +
                                 std::string(to_string(ts_->mode)) +
                                 " mode; pause it or switch it to lockstep before stepping");
        ts_->steps.push_back(StepJob{ticks, ts_->counters.rollbacks, done});
        return Error{};
      },
      deadline);
  if (!queued.ok()) return queued;
  // Wait in slices so that a caller who went away is noticed.
  bool gave_up = false, was_cancelled = false;
  while (future.wait_until(std::min(deadline, Clock::now() + std::chrono::milliseconds(50))) !=
         std::future_status::ready) {
    if (cancelled && cancelled()) {
      gave_up = was_cancelled = true;
      break;
    }
    if (Clock::now() >= deadline) {
      gave_up = true;
      break;
    }
  }
  if (gave_up) {
    // Drop the ticks not run yet (the job may have finished meanwhile: then nothing to drop).
    call(
        [this, done] {
          for (auto it = ts_->steps.begin(); it != ts_->steps.end(); ++it)
            if (it->done == done) {
              ts_->steps.erase(it);
              break;
            }
          return Error{};
        },
        Clock::now() + std::chrono::seconds(10), /*interrupt=*/true);
    if (was_cancelled)
      return Error::make(Code::Cancelled, "scene '" + id_ + "': step cancelled by the caller");
    return Error::make(Code::DeadlineExceeded, "scene '" + id_ + "': step of " + std::to_string(ticks) +
                                                   " ticks did not finish before the deadline");
  }
  try {
    *out = future.get();
  } catch (const TickAborted& e) {
    return Error::make(Code::ResourceExhausted, "scene '" + id_ + "': " + e.what());
  } catch (const std::exception&) {
    return Error::make(Code::Unavailable, "scene '" + id_ + "' stopped during the step");
  }
  return {};
}

SceneSnapshot Scene::snapshot_now() const {
  SceneSnapshot out;
  out.id = id_;
  out.config = config();
  out.model = ts_->model;
  out.state = ts_->state;
  out.tick = ts_->tick;
  out.paused = !ts_->running;
  out.grabs = ts_->grabs;
  out.next_grab_id = ts_->next_grab_id;
  out.body_states.reserve(ts_->bodies.size());
  for (const auto& b : ts_->bodies) out.body_states.push_back(b->state());
  out.body_grabs = ts_->body_grabs;
  return out;
}

Error Scene::snapshot(SceneSnapshot* out, std::chrono::milliseconds timeout) {
  return call(
      [this](SceneSnapshot& snap) {
        snap = snapshot_now();
        return Error{};
      },
      out, Clock::now() + timeout);
}

SceneSnapshot Scene::snapshot_stopped() const { return snapshot_now(); }

std::shared_ptr<const Frame> Scene::latest_frame() const {
  std::lock_guard lk(frame_mu_);
  return latest_;
}

std::shared_ptr<const Frame> Scene::wait_frame(uint64_t after_seq, Clock::time_point deadline) const {
  std::unique_lock lk(frame_mu_);
  frame_cv_.wait_until(lk, deadline, [&] {
    if (latest_ && latest_->seq > after_seq) return true;
    std::lock_guard lk2(mu_);
    return stop_;
  });
  if (latest_ && latest_->seq > after_seq) return latest_;
  return nullptr;
}

void Scene::run() {
  spdlog::debug("scene '{}': tick thread started ({} mode, dt {} s)", id_, to_string(ts_->mode),
                ts_->settings.dt);
  std::unique_lock lk(mu_);
  while (true) {
    TickState& t = *ts_;
    const bool realtime = t.running && t.mode == TickMode::Realtime && t.steps.empty();
    const bool afap = t.running && t.mode == TickMode::AsFastAsPossible;
    Clock::time_point due{};
    if (realtime) {
      if (!t.schedule_valid) {
        t.schedule_valid = true;
        t.anchor = Clock::now();
        t.slot = 0;
      }
      due = t.anchor + t.period() * static_cast<int64_t>(t.slot);
      // Commands wait for the tick boundary; only stop wakes us early.
      cv_.wait_until(lk, due, [&] { return stop_; });
    } else if (!afap && t.steps.empty()) {
      waiting_for_commands_ = true;
      cv_.wait(lk, [&] { return stop_ || !commands_.empty(); });
      waiting_for_commands_ = false;
    }
    if (stop_) break;
    std::deque<Command> commands;
    commands.swap(commands_);
    cancel_tick_ = false;  // interrupting commands posted from here on cancel the next tick
    lk.unlock();
    for (auto& c : commands) {
      try {
        c();
      } catch (const std::exception& e) {  // a failing command must not take the tick down
        spdlog::error("scene '{}': command failed: {}", id_, e.what());
      }
    }

    const bool still_realtime = t.running && t.mode == TickMode::Realtime && t.steps.empty();
    if (!t.steps.empty()) {
      tick_once(false, {});
    } else if (t.running && t.mode == TickMode::AsFastAsPossible) {
      tick_once(false, {});
    } else if (still_realtime && realtime && t.schedule_valid && Clock::now() >= due) {
      tick_once(true, due);
    }
    lk.lock();
  }
  // Waiting calls and Steps answer Unavailable at once, not when stop() joins.
  commands_.clear();
  for (auto& job : ts_->steps)
    job.done->set_exception(std::make_exception_ptr(std::runtime_error("scene stopped")));
  ts_->steps.clear();
  spdlog::debug("scene '{}': tick thread stopped at tick {}", id_, ts_->tick);
}

void Scene::cancelled_tick(const std::string& abort_reason) {
  TickState& t = *ts_;
  t.state = t.last_good;  // as if the tick had not started
  restore_bodies();
  if (abort_reason.empty()) return;  // a command or stop interrupted it: they act next
  spdlog::error("scene '{}': tick {} stopped: {}", id_, t.tick + 1, abort_reason);
  if (t.mode != TickMode::Lockstep && t.running) {
    t.running = false;
    t.schedule_valid = false;
    t.pause_reason = "paused: " + abort_reason + "; lower substeps or iterations (or set a time budget) and resume";
  }
  if (!t.steps.empty()) {  // the Step that asked for the tick fails with the reason
    t.steps.front().done->set_exception(std::make_exception_ptr(TickAborted(abort_reason)));
    t.steps.pop_front();
  }
  publish_status();
}

// The one place the solver's report of a tick goes into its frame: the report as a whole, its
// per-tool reactions by tool id and its per-grab forces by grab id (none after a rollback: the
// tick's contacts were undone with it). The grab forces are kept for MoveGrab's answer.
void Scene::carry_report(StepReport&& report, bool rolled_back, Frame& frame) {
  TickState& t = *ts_;
  size_t k = 0;
  frame.tools.reserve(t.tools.size());
  for (const auto& [id, pt] : t.tools) {
    FrameTool ft{id, pt.seq, pt.client_ns, {}};
    if (!rolled_back && k < report.tools.size()) ft.reaction = std::move(report.tools[k]);
    frame.tools.push_back(std::move(ft));
    ++k;
  }
  k = 0;
  t.grab_forces.clear();
  frame.grab_forces.reserve(t.grabs.size());
  for (const auto& [id, a] : t.grabs) {
    const Vec3 f = !rolled_back && k < report.attachment_forces.size() ? report.attachment_forces[k] : Vec3::Zero();
    t.grab_forces[id] = f;
    frame.grab_forces.emplace_back(id, f);
    ++k;
  }
  report.tools.clear();
  report.attachment_forces.clear();
  frame.solver = std::move(report);
}

namespace {

double ms_since(Clock::time_point from) {
  return std::chrono::duration<double, std::milli>(Clock::now() - from).count();
}

// A body's share of the tick, unless the tick has failed already; a throw names the body in
// `failure` (the caller rolls the tick back).
template <class Fn>
void guard_body(const std::string& name, std::string& failure, Fn&& work) {
  if (!failure.empty()) return;
  try {
    work();
  } catch (const std::exception& e) {
    failure = "body '" + name + "': " + e.what();
  }
}

}  // namespace

// How a tick cuts the particle bodies' steps (shared_step_parts): the fluids in contact with the
// tet body step with it in parts of whole substeps of every body, the tet body's and the paired
// bodies' included, where their substeps share a factor; else the bodies in contact with each
// other step in parts among themselves (the tet body's whole step first), else every body in one
// piece. Within a part, a pair whose two bodies share a larger factor meets that many times a
// tick (a rope and a cloth of 16 substeps beside a fluid of 2: 16 times, the fluid's pairs
// twice), each body's step cut at every contact of its pairs.
Scene::BodyParts Scene::body_parts() const {
  const TickState& t = *ts_;
  BodyParts bp;
  bp.parts = t.body_parts;
  if (t.tet_body_parts > 0) {
    const int substeps[] = {t.tet_body_parts, effective_substeps(*t.model, t.settings)};
    const int with_tet = shared_step_parts(substeps);
    if (with_tet > 1) {
      bp.parts = with_tet;
      bp.with_tet = true;
    }
  }
  // Every paired body's substeps are a multiple of the parts; so is each pair's common factor.
  bp.body_calls.assign(t.bodies.size(), 1);
  bp.pair_calls.assign(t.cloth_pairs.size(), 1);
  constexpr int kMostCuts = 4096;  // beyond it (substeps with few common factors) one call a part
  for (size_t k = 0; k < t.cloth_pairs.size(); ++k) {
    const TickState::ClothPair& pair = t.cloth_pairs[k];
    bp.pair_calls[k] = std::max(pair.shared_substeps / bp.parts, 1);
    for (size_t b : {pair.particles, pair.cloth})
      bp.body_calls[b] = int(std::min<long>(std::lcm<long>(bp.body_calls[b], bp.pair_calls[k]), kMostCuts + 1));
  }
  long fine = 1;
  for (int c : bp.body_calls) fine = std::min<long>(std::lcm(fine, long(c)), kMostCuts + 1);
  if (fine > kMostCuts) {
    std::fill(bp.body_calls.begin(), bp.body_calls.end(), 1);
    std::fill(bp.pair_calls.begin(), bp.pair_calls.end(), 1);
    fine = 1;
  }
  bp.fine = int(fine);
  return bp;
}

// The particle bodies' share of a tick before its parts: their reports.
void Scene::begin_bodies() {
  TickState& t = *ts_;
  t.body_reports.assign(t.bodies.size(), ParticleStepReport{});
  t.tool_impulse.clear();
  t.tool_angular_impulse.clear();
}

// One part of the particle bodies' step (the whole step when parts is 1), after the tet body's
// (its part, with bp.with_tet): the soft body's push on the cloths it touched (`obstacle_impulses`,
// before they step), each body's step against the scene's colliders followed by its contact with
// the tet body (a fluid's after every part with bp.with_tet, else after its whole step), then the
// contacts between bodies (particles against cloths and ropes). Bodies in contact step in parts,
// whole substeps each, so that a contact is resolved within the step as the bodies' own
// constraints are; the others step in one piece, after the tet body's whole step. A cancelled
// tick stops between bodies (a body's own step is not interrupted); a throw or a blow-up names
// its body in `failure`.
void Scene::bodies_part(int part, const BodyParts& bp, const std::vector<std::vector<Vec3>>& obstacle_impulses,
                        std::span<const RigidTool> tools, bool& cancelled, std::string& failure) {
  TickState& t = *ts_;
  if (t.bodies.empty() || !failure.empty() || cancelled) return;
  const double dt = t.settings.dt;
  const int parts = bp.parts;
  auto guarded = [&](size_t b, auto&& work) { guard_body(bodies_info_[b].name, failure, work); };
  for (size_t k = 0; k < t.obstacle_bodies.size() && k < obstacle_impulses.size(); ++k) {
    const size_t b = t.obstacle_bodies[k];
    guarded(b, [&] {
      ParticleBody& cloth = *t.bodies[b];
      const auto& impulse = obstacle_impulses[k];
      const auto w = cloth.inverse_masses();
      ParticleState st = cloth.state();
      bool any = false;
      for (size_t i = 0; i < impulse.size() && i < st.v.size(); ++i)
        if (w[i] > 0 && !impulse[i].isZero()) {
          st.v[i] += w[i] * impulse[i];
          any = true;
        }
      if (any) cloth.set_state(st);
    });
  }
  // The tet body's surface for the bodies that meet it inside their step: where its step (or
  // part) left it, moving at its mean velocity over the step (or part): a solver's velocities
  // at its last substep are noisy, and friction would carry that noise into the particles. After
  // the tet body's whole step it is the same for every part.
  const bool surface_used = t.surface_used;
  if (surface_used && (bp.with_tet || part == 0)) {
    const std::vector<Vec3>& from = bp.with_tet && part > 0 ? t.surface_part_start : t.last_good.x;
    const double span = bp.with_tet ? dt / parts : dt;
    t.surface_v.resize(t.state.x.size());
    for (size_t k = 0; k < t.surface_v.size(); ++k) t.surface_v[k] = (t.state.x[k] - from[k]) / span;
  }
  // A part cut `bp.fine` times: at each cut the bodies whose next call starts there step it, then
  // the pairs whose contact ends at the next cut meet.
  if (t.pair_start.size() != t.cloth_pairs.size()) t.pair_start.resize(t.cloth_pairs.size());
  for (int f = 0; f < bp.fine && failure.empty(); ++f) {
    // A pair whose span begins here and is not its body's call keeps where the body is.
    for (size_t k = 0; k < t.cloth_pairs.size(); ++k) {
      const TickState::ClothPair& pair = t.cloth_pairs[k];
      if (f % (bp.fine / bp.pair_calls[k]) != 0) continue;
      if (bp.pair_calls[k] != bp.body_calls[pair.particles]) t.pair_start[k][0] = t.bodies[pair.particles]->state().x;
      if (bp.pair_calls[k] != bp.body_calls[pair.cloth]) t.pair_start[k][1] = t.bodies[pair.cloth]->state().x;
    }
    for (size_t b = 0; b < t.bodies.size() && failure.empty(); ++b) {
      const bool tet_parts = bp.with_tet && t.tet_parts[b];  // with the tet body, part by part
      const int calls = bp.body_calls[b];
      const bool in_parts = parts * calls > 1 && (t.in_cloth_pair[b] || tet_parts);
      // One piece: after the tet body's whole step (its last part, or before the first part here).
      if (!in_parts && (f > 0 || part != (bp.with_tet ? parts - 1 : 0))) continue;
      const int span = bp.fine / calls;  // the cuts one of its calls covers
      if (f % span != 0) continue;
      const int call = part * calls + f / span, total_calls = parts * calls;  // its call in the tick
      const bool first = !in_parts || call == 0;
      const bool last_call = !in_parts || call + 1 == total_calls;
      if (cancel_tick_.load()) {
        cancelled = true;
        return;
      }
      guarded(b, [&] {
        // The start positions, for the contacts that read them (none: no copy in the tick): the
        // tick's for the tools' contacts and the first call's, the call's for the later ones'.
        const bool starts = t.body_contact[b] || t.in_cloth_pair[b] || !tools.empty();
        const bool part_start = in_parts && call > 0;
        if (starts && first) t.body_start[b] = t.bodies[b]->state().x;
        if (part_start) t.body_part_start[b] = t.bodies[b]->state().x;
        const auto t_body = Clock::now();
        const int n = in_parts ? t.bodies[b]->substeps() / total_calls : t.bodies[b]->substeps();
        const double h = in_parts ? dt / total_calls : dt;
        // The soft body's surface where its step (or part) left it, met inside the body's own
        // substeps; its push goes to the soft body's velocities.
        const auto& contact = t.body_contact[b];
        std::optional<SurfaceBoundary> surface;
        if (contact) {
          surface.emplace();
          surface->triangles = t.model->surface;
          surface->x = t.state.x;
          surface->v = t.surface_v;
          surface->radius = contact->radius;
          surface->friction = contact->friction;
        }
        // The tools where they are at the end of this call, moving at their velocities over the tick.
        std::vector<RigidTool> posed;
        ToolBoundary on_tools;
        if (!tools.empty()) {
          const double before_end = in_parts ? dt - (call + 1) * h : 0.0;
          posed.assign(tools.begin(), tools.end());
          for (RigidTool& tool : posed) tool = tool.at(-before_end);
          on_tools.tools = posed;
        }
        const ParticleStepReport r = t.bodies[b]->advance(h, n, t.colliders, last_call, surface ? &*surface : nullptr,
                                                          tools.empty() ? nullptr : &on_tools);
        if (surface) take_surface_impulse(*t.model, t.state, *surface);
        if (!tools.empty()) {
          t.tool_impulse.resize(tools.size(), Vec3::Zero());
          t.tool_angular_impulse.resize(tools.size(), Vec3::Zero());
          for (size_t k = 0; k < tools.size() && k < on_tools.impulse.size(); ++k) {
            t.tool_impulse[k] += on_tools.impulse[k];
            t.tool_angular_impulse[k] += on_tools.angular_impulse[k];
          }
        }
        ParticleStepReport& rep = t.body_reports[b];
        if (first) {
          rep = r;
          rep.parts = in_parts ? total_calls : 1;
        } else {  // the step's substeps, the end of its last call
          rep.substeps += r.substeps;
          rep.constraint_error = r.constraint_error;
          rep.max_constraint_error = r.max_constraint_error;
          rep.contacts = r.contacts;
          rep.tool_contacts = std::max(rep.tool_contacts, r.tool_contacts);
          rep.self_collision_suspended = rep.self_collision_suspended || r.self_collision_suspended;
        }
        // Particles an emitter added during the step start where they are (no path to cross).
        const auto& now = t.bodies[b]->state().x;
        if (starts) add_emitted(t.body_start[b], now);
        if (part_start) add_emitted(t.body_part_start[b], now);
        // The particles met the surface inside the step (the report counts those it pushed in the
        // last substep; in parts, the most in one call).
        if (surface && !first) rep.soft_body_contacts = std::max(rep.soft_body_contacts, r.soft_body_contacts);
        if (surface && !t.bodies[b]->segments().empty() && (tet_parts || last_call)) {
          // A rope's links and a cloth's edges after the step, two-way: their inside points move
          // out, the tet body takes their momentum; over the call with the tet body's parts, else
          // over the whole tick.
          ParticleState ps = t.bodies[b]->state();
          CouplingSettings along = *contact;
          along.particles = false;
          const CouplingReport c = couple_particles_to_body(
              *t.model, t.state, ps, t.bodies[b]->inverse_masses(), along, tet_parts ? h : dt,
              tet_parts && part_start ? t.body_part_start[b] : t.body_start[b], t.bodies[b]->segments());
          rep.soft_body_contacts += c.segment_contacts;
          if (c.segment_contacts > 0) t.bodies[b]->set_state(ps);
        }
        // Its step and its contacts, below.
        rep.wall_ms = (first ? 0.0 : rep.wall_ms) + ms_since(t_body);
      });
    }
    // The pairs whose contact ends at the next cut, each over its own span of the part.
    t.part_contacts.assign(t.bodies.size(), 0);
    for (size_t k = 0; k < t.cloth_pairs.size() && failure.empty(); ++k) {
      const TickState::ClothPair& pair = t.cloth_pairs[k];
      const int span = bp.fine / bp.pair_calls[k];
      if ((f + 1) % span != 0) continue;
      const int contact = part * bp.pair_calls[k] + (f + 1) / span - 1;  // the pair's contact in the tick
      // Each body's positions where the pair's span began: its call's start where the two spans
      // are the same, else those kept at that cut (the top of the loop).
      auto start_of = [&](size_t b, int side) -> const std::vector<Vec3>& {
        if (bp.pair_calls[k] == bp.body_calls[b]) return contact == 0 ? t.body_start[b] : t.body_part_start[b];
        std::vector<Vec3>& kept = t.pair_start[k][size_t(side)];
        add_emitted(kept, t.bodies[b]->state().x);
        return kept;
      };
      guarded(pair.particles, [&] {
        const auto t_pair = Clock::now();
        ParticleBody& a = *t.bodies[pair.particles];
        ParticleBody& c = *t.bodies[pair.cloth];
        const std::vector<Vec3>& a_start = start_of(pair.particles, 0);
        const std::vector<Vec3>& c_start = start_of(pair.cloth, 1);
        const double h = dt / (parts * bp.pair_calls[k]);
        ParticleState ps = a.state(), cs = c.state();
        const CouplingReport r =
            pair.rope ? couple_particles_to_rope(ps, a.inverse_masses(), a_start, cs, c.inverse_masses(), c_start,
                                                 pair.settings, h, a.segments())
                      : couple_particles_to_cloth(ps, a.inverse_masses(), a_start, cs, c.inverse_masses(),
                                                  c.triangles(), c_start, pair.settings, h, a.segments());
        if (r.contacts + r.segment_contacts > 0) {
          a.set_state(ps);
          c.set_state(cs);
        }
        t.part_contacts[pair.particles] += r.contacts + r.segment_contacts;
        t.body_reports[pair.particles].wall_ms += ms_since(t_pair);
      });
    }
    // In parts: the most in one cut (a particle held through the step counts once).
    for (size_t b = 0; b < t.bodies.size(); ++b)
      if (t.in_cloth_pair[b])
        t.body_reports[b].body_contacts =
            std::max(part == 0 && f == 0 ? 0 : t.body_reports[b].body_contacts, t.part_contacts[b]);
  }
  if (surface_used && bp.with_tet && part + 1 < parts) t.surface_part_start = t.state.x;
}

// The particle bodies' share of a tick after its last part: the tools' reactions (the haptic
// stream's force) take the momentum the bodies gained from them inside their substeps, and a last
// contact catches what the contacts between bodies pushed into a tool after that; then a check
// that every body is finite.
void Scene::finish_bodies(const StepInputs& inputs, StepReport& report, std::string& failure) {
  TickState& t = *ts_;
  auto guarded = [&](size_t b, auto&& work) { guard_body(bodies_info_[b].name, failure, work); };
  const double dt = t.settings.dt;
  if (!t.bodies.empty() && !inputs.tools.empty() && report.tools.size() != inputs.tools.size())
    report.tools.resize(inputs.tools.size());
  for (size_t k = 0; k < t.tool_impulse.size() && k < report.tools.size(); ++k) {
    report.tools[k].force -= t.tool_impulse[k] / dt;
    report.tools[k].torque -= t.tool_angular_impulse[k] / dt;
  }
  for (size_t b = 0; b < t.bodies.size() && !inputs.tools.empty(); ++b)
    guarded(b, [&] {
      const auto t_tools = Clock::now();
      ParticleState ps = t.bodies[b]->state();
      size_t pushed = 0;
      for (size_t k = 0; k < inputs.tools.size(); ++k)
        pushed += couple_particles_to_tool(ps, t.bodies[b]->inverse_masses(), inputs.tools[k],
                                           t.bodies[b]->contact_radius(), dt, t.body_start[b], report.tools[k]);
      if (pushed > 0) t.bodies[b]->set_state(ps);
      t.body_reports[b].tool_contacts += pushed;
      t.body_reports[b].wall_ms += ms_since(t_tools);
    });
  for (size_t b = 0; b < t.bodies.size() && failure.empty(); ++b) {
    const ParticleState& st = t.bodies[b]->state();
    bool finite = true;
    for (size_t i = 0; i < st.x.size() && finite; ++i) finite = st.x[i].allFinite() && st.v[i].allFinite();
    if (!finite) failure = "body '" + bodies_info_[b].name + "': non-finite positions or velocities";
  }
}

namespace {

// The angular velocity (rad/s, world axes) that turns `from` into `to` in dt, the short way.
Vec3 turn_rate(const Eigen::Quaterniond& from, const Eigen::Quaterniond& to, double dt) {
  Eigen::Quaterniond q = to * from.conjugate();
  if (q.w() < 0) q.coeffs() = -q.coeffs();
  const Eigen::AngleAxisd turn(q.normalized());
  return turn.axis() * (turn.angle() / dt);
}

}  // namespace

void Scene::tick_once(bool scheduled, Clock::time_point due) {
  TickState& t = *ts_;
  const auto start = Clock::now();
  const double lateness_ms =
      scheduled ? std::chrono::duration<double, std::milli>(start - due).count() : 0.0;

  StepInputs inputs;
  inputs.colliders = t.colliders;
  if (!t.forces.empty()) {
    inputs.external_forces.assign(t.model->vertex_count(), Vec3::Zero());
    for (auto& f : t.forces)
      for (int32_t v : f.vertices) inputs.external_forces[v] += f.force;
  }
  inputs.attachments.reserve(t.grabs.size());
  for (const auto& [id, a] : t.grabs) inputs.attachments.push_back(a);
  inputs.tools.reserve(t.tools.size());
  for (auto& [id, pt] : t.tools) {
    RigidTool tool = pt.tool;
    tool.velocity = pt.used ? Vec3((tool.position - pt.used_position) / t.settings.dt) : Vec3::Zero();
    tool.angular_velocity = pt.used ? turn_rate(pt.used_orientation, tool.orientation, t.settings.dt) : Vec3::Zero();
    pt.used_position = tool.position;
    pt.used_orientation = tool.orientation;
    pt.used = true;
    inputs.tools.push_back(tool);
  }
  // The cloths in contact with the soft body, where they start the tick: obstacles to its
  // surface vertices inside its step (their reactions go to the cloths before they step).
  for (size_t b : t.obstacle_bodies) {
    const ParticleBody& cloth = *t.bodies[b];
    TriangleObstacle ob;
    ob.x = cloth.state().x;
    const auto tris = cloth.triangles();
    ob.triangles.assign(tris.begin(), tris.end());
    ob.radius = t.body_contact[b]->radius;
    ob.friction = t.body_contact[b]->friction;
    const auto w = cloth.inverse_masses();  // two bodies: a light cloth yields to a heavy body
    ob.inverse_mass.assign(w.begin(), w.end());
    inputs.obstacles.push_back(std::move(ob));
  }

  t.last_good = t.state;  // copy-assign reuses the buffers
  for (size_t b = 0; b < t.bodies.size(); ++b) t.bodies_last_good[b] = t.bodies[b]->state();
  StepReport report;
  std::string failure;
  inputs.cancel = &cancel_tick_;
  {
    std::lock_guard lk(abort_mu_);
    abort_reason_.clear();
    tick_started_ns_ = std::chrono::duration_cast<std::chrono::nanoseconds>(start.time_since_epoch()).count();
  }
  const BodyParts parts = body_parts();
  bool bodies_cancelled = false;
  begin_bodies();
  try {
    if (parts.with_tet) {
      // The bodies step with the tet body, part by part; the cloths it touches are its obstacles
      // where each part starts.
      report = t.stepper.step_in_parts(
          *t.model, t.state, t.settings, inputs, parts.parts,
          [&](int part, const StepReport& r, StepInputs& next) {
            bodies_part(part, parts, r.obstacle_impulses, inputs.tools, bodies_cancelled, failure);
            for (size_t k = 0; k < t.obstacle_bodies.size() && k < next.obstacles.size(); ++k)
              next.obstacles[k].x = t.bodies[t.obstacle_bodies[k]]->state().x;
          });
    } else {
      report = t.stepper.step(*t.model, t.state, t.settings, inputs);
    }
    if (report.diverged)
      failure = "solver diverged (residual " + std::to_string(report.residual_final) +
                " from " + std::to_string(report.residual_initial) + ")";
    else if (!is_finite(t.state))
      failure = "non-finite positions or velocities";
  } catch (const std::exception& e) {
    failure = std::string("solver error: ") + e.what();
  }
  if (!parts.with_tet)
    for (int part = 0; part < parts.parts && failure.empty() && !report.cancelled && !bodies_cancelled; ++part)
      bodies_part(part, parts, part == 0 ? report.obstacle_impulses : std::vector<std::vector<Vec3>>{},
                  inputs.tools, bodies_cancelled, failure);
  report.cancelled = report.cancelled || bodies_cancelled;
  if (failure.empty() && !report.cancelled) finish_bodies(inputs, report, failure);
  std::string abort_reason;
  {
    std::lock_guard lk(abort_mu_);
    tick_started_ns_ = 0;
    abort_reason.swap(abort_reason_);
  }
  if (report.cancelled) {
    cancelled_tick(abort_reason);
    return;
  }
  for (auto& f : t.forces) --f.remaining;
  std::erase_if(t.forces, [](const ActiveForce& f) { return f.remaining == 0; });
  ++t.tick;
  const bool rolled_back = !failure.empty();
  if (rolled_back) {
    t.state = t.last_good;
    restore_bodies();
    ++t.counters.rollbacks;
    ++t.consecutive_rollbacks;
    spdlog::warn("scene '{}': tick {}: {}; rolled back to the state of tick {}", id_, t.tick,
                 failure, t.tick - 1);
    if (t.consecutive_rollbacks >= kMaxConsecutiveRollbacks && t.mode != TickMode::Lockstep &&
        t.running) {
      t.running = false;
      t.schedule_valid = false;
      t.pause_reason = "paused after " + std::to_string(t.consecutive_rollbacks) +
                       " consecutive solver blow-ups (" + failure +
                       "); change the settings and resume";
      spdlog::error("scene '{}': {}", id_, t.pause_reason);
    }
  } else {
    t.consecutive_rollbacks = 0;
  }

  const auto end = Clock::now();
  if (scheduled) {
    // Absolute deadlines: the next tick is due one period after this one's slot, whatever
    // this tick cost. Ending past that deadline makes this tick late; falling a whole period
    // or more behind skips the missed slots (counted) instead of stretching the schedule.
    const auto period = t.period();
    ++t.slot;
    auto next_due = t.anchor + period * static_cast<int64_t>(t.slot);
    if (end > next_due) {
      ++t.counters.late_ticks;
      const auto behind = end - next_due;
      const auto missed = static_cast<uint64_t>(behind / period);
      if (missed > 0) {
        t.slot += missed;
        t.counters.skipped_ticks += missed;
      }
    }
  }
  ++t.rate_window_ticks;
  const double window_s = std::chrono::duration<double>(end - t.rate_window_start).count();
  if (window_s >= 1.0) {
    t.counters.ticks_per_second = t.rate_window_ticks / window_s;
    t.rate_window_ticks = 0;
    t.rate_window_start = end;
  } else if (t.counters.ticks_per_second == 0 && window_s > 0.1) {
    t.counters.ticks_per_second = t.rate_window_ticks / window_s;
  }
  t.last_tick_end = end;

  const double step_wall_ms = report.wall_ms;
  const int volume_corrections = report.volume_corrections, contacts = report.contacts;
  auto frame = std::make_shared<Frame>();
  frame->tick = t.tick;
  frame->sim_time = t.state.time;
  frame->positions.resize(t.state.x.size() * 3);
  for (size_t i = 0; i < t.state.x.size(); ++i)
    for (int k = 0; k < 3; ++k) frame->positions[3 * i + k] = static_cast<float>(t.state.x[i][k]);
  carry_report(std::move(report), rolled_back, *frame);
  for (const auto& [gid, g] : t.body_grabs)
    t.grab_forces[gid] = rolled_back ? Vec3(Vec3::Zero()) : t.bodies[g.body]->grab_force(gid);
  frame->bodies.resize(t.bodies.size());
  for (size_t b = 0; b < t.bodies.size(); ++b) {
    const auto& x = t.bodies[b]->state().x;
    frame->bodies[b].name = bodies_info_[b].name;
    frame->bodies[b].report = b < t.body_reports.size() ? t.body_reports[b] : ParticleStepReport{};
    auto& out = frame->bodies[b].positions;
    out.resize(x.size() * 3);
    for (size_t i = 0; i < x.size(); ++i)
      for (int k = 0; k < 3; ++k) out[3 * i + k] = static_cast<float>(x[i][k]);
  }
  t.step_wall_ms_sum += step_wall_ms;
  ++t.stepped_ticks;
  frame->step_wall_ms_sum = t.step_wall_ms_sum;
  frame->stepped_ticks = t.stepped_ticks;
  frame->counters = t.counters;
  frame->lateness_ms = lateness_ms;
  frame->rolled_back = rolled_back;
  frame->rollback_reason = failure;
  frame->running = t.running && t.mode != TickMode::Lockstep;
  frame->mode = t.mode;

  publish_status();
  // Where the tick time goes, logged at debug level every 10 s: the solver step, the tick's
  // own work around it (state copy, frame, status), the time between tick starts, lateness.
  {
    auto& p = t.profile;
    p.step_ms += step_wall_ms;
    p.tick_ms += std::chrono::duration<double, std::milli>(Clock::now() - start).count();
    if (p.ticks > 0) p.gap_ms += std::chrono::duration<double, std::milli>(start - p.last_start).count();
    p.late_ms += lateness_ms;
    p.volume_corrections += volume_corrections;
    p.last_start = start;
    if (++p.ticks == 1) p.window_start = start;
    if (start - p.window_start >= std::chrono::seconds(10)) {
      const double n = double(p.ticks);
      spdlog::debug("scene '{}': {} ticks, per tick: step {:.2f} ms, tick {:.2f} ms (outside the step {:.2f} ms), "
                    "{:.2f} ms between starts, late {:.2f} ms, {:.0f} volume corrections, {} contacts",
                    id_, p.ticks, p.step_ms / n, p.tick_ms / n, (p.tick_ms - p.step_ms) / n,
                    p.gap_ms / std::max(1.0, n - 1), p.late_ms / n, double(p.volume_corrections) / n, contacts);
      p = {};
    }
  }
  {
    std::lock_guard lk(frame_mu_);
    frame->seq = ++seq_;
    frame->published = Clock::now();
    frame->published_unix_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                                   std::chrono::system_clock::now().time_since_epoch())
                                   .count();
    latest_ = std::move(frame);
  }
  frame_cv_.notify_all();
  notify_listeners();
  // A Step completes after its last frame and status are visible to every reader.
  if (!t.steps.empty()) {
    auto& job = t.steps.front();
    if (--job.remaining == 0) {
      job.done->set_value(StepResult{t.tick, t.state.time, t.counters.rollbacks - job.rollbacks_before});
      t.steps.pop_front();
    }
  }
}

}  // namespace pliant::server
