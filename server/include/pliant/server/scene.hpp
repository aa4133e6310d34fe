// SPDX-License-Identifier: Apache-2.0
// One simulated scene and the thread that ticks it. Only the tick thread touches the body
// state: callers post commands that the tick drains at the start of a tick, and read the
// latest immutable Frame, published atomically after every tick. No gRPC in here.
#pragma once

#include "pliant/server/bodies.hpp"
#include "pliant/server/error.hpp"

#include "pliant/colliders.hpp"
#include "pliant/interaction.hpp"
#include "pliant/model.hpp"
#include "pliant/settings.hpp"
#include "pliant/state.hpp"
#include "pliant/stepper.hpp"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

namespace pliant::server {

enum class TickMode { Realtime, Lockstep, AsFastAsPossible };

std::string_view to_string(TickMode mode);

// How the scene was built (echoed back to clients; the model holds the geometry).
struct SceneConfig {
  std::string mesh_kind = "builtin";  // "builtin" | "model_path" | "data"
  std::string mesh_name;
  double mesh_scale = 1.0;
  FixedSelection fixed;               // as requested
  std::vector<std::string> fixed_groups;  // physical groups fixed as well (their vertices are in the model)
  std::vector<Collider> colliders;     // static obstacles, validated
  SolverSettings settings;            // dt is the tick length; gravity lives here too
  TickMode mode = TickMode::Realtime;
  // Method auto: settings.method is the chosen one; method_choice says what was measured.
  bool method_auto = false;
  std::string method_choice;
  // Particle bodies, stepped after the tet body in every tick (spec order).
  std::vector<BodyConfig> bodies;
};

// A tool's reaction in a tick, with the pose that produced it.
struct FrameTool {
  uint64_t tool_id = 0;
  uint64_t pose_seq = 0;        // the client's pose number the tick used
  int64_t pose_client_ns = 0;   // echoed client timestamp of that pose
  ToolReaction reaction;
};

// How the scene kept its schedule, counted since it was created or restored in this process.
// The same counters are in the status and in every frame.
struct TickCounters {
  uint64_t late_ticks = 0;
  uint64_t skipped_ticks = 0;  // missed slots of a realtime schedule, not run
  uint64_t rollbacks = 0;
  double ticks_per_second = 0;
};

// What a tick produced. Immutable once published; shared by every reader.
struct Frame {
  uint64_t seq = 0;        // publication number (monotonic for the scene's lifetime)
  uint64_t tick = 0;
  double sim_time = 0;
  std::vector<float> positions;  // all vertices, packed xyz
  // The solver's report of the tick as it came from the step (its per-tool reactions and
  // per-grab forces are in `tools` and `grab_forces`, by id).
  StepReport solver;
  double step_wall_ms_sum = 0;  // solver wall time over the ticks this scene ran in this process
  uint64_t stepped_ticks = 0;   // how many ticks that sum holds
  TickCounters counters;
  double lateness_ms = 0;
  bool rolled_back = false;
  std::string rollback_reason;
  int64_t published_unix_ns = 0;
  std::chrono::steady_clock::time_point published;  // for in-process latency figures
  bool running = false;
  TickMode mode = TickMode::Realtime;
  std::vector<FrameTool> tools;                        // every tool in the scene, by id
  std::vector<std::pair<uint64_t, Vec3>> grab_forces;  // force on the body per grab id
  // Each particle body's positions (float32, packed xyz), in the scene's body order.
  struct BodyPositions {
    std::string name;
    std::vector<float> positions;
    ParticleStepReport report;  // the body's step in this tick (wall_ms: with its contact)
  };
  std::vector<BodyPositions> bodies;
};

// residual_final / residual_initial of the tick's last substep; 0 when nothing was left to solve.
inline double relative_residual(const StepReport& r) {
  return r.residual_initial > 0 ? r.residual_final / r.residual_initial : 0.0;
}

struct SceneStatus {
  bool running = false;  // ticking on its own (realtime / as-fast-as-possible, not paused)
  TickMode mode = TickMode::Realtime;
  uint64_t tick = 0;
  double sim_time = 0;
  TickCounters counters;
  std::string pause_reason;
  std::vector<size_t> body_particles;  // each particle body's particles now
};

struct StepResult {
  uint64_t tick = 0;
  double sim_time = 0;
  uint64_t rollbacks = 0;
};

// A grab on a particle body (InteractionService.Grab with `body`).
struct ParticleGrab {
  size_t body = 0;      // index in SceneConfig::bodies
  size_t particle = 0;
  Vec3 target = Vec3::Zero();
  double compliance = 0.0;
};

// Everything needed to recreate the scene exactly.
struct SceneSnapshot {
  std::string id;
  SceneConfig config;
  std::shared_ptr<const BodyModel> model;
  BodyState state;
  uint64_t tick = 0;
  bool paused = false;
  // Grabs by id (tools are not saved: they live only while their stream is open).
  std::map<uint64_t, Attachment> grabs;
  uint64_t next_grab_id = 1;  // always > every id in grabs (and in body_grabs)
  // The particle bodies' states, in config.bodies order (empty: as built), and their grabs.
  std::vector<ParticleState> body_states;
  std::map<uint64_t, ParticleGrab> body_grabs;
};

// A live change of settings; unset parts are kept.
struct SceneUpdate {
  std::optional<SolverSettings> settings;             // already merged and validated
  std::shared_ptr<const BodyModel> model;             // new material (same geometry)
  std::optional<TickMode> mode;
  bool method_auto = false;                           // with settings: what the config says
  std::string method_choice;
};

class Scene {
 public:
  // Consecutive blow-ups after which the scene pauses itself instead of retrying forever.
  static constexpr int kMaxConsecutiveRollbacks = 20;

  // Builds the particle bodies of config.bodies: throws std::invalid_argument naming the body
  // when one cannot be built.
  Scene(std::string id, SceneConfig config, std::shared_ptr<const BodyModel> model,
        BodyState state, uint64_t tick, bool paused);
  // A scene recreated from a snapshot, its grabs included (same ids). Throws
  // std::invalid_argument naming snapshot.bodies[i] when a body's state does not fit it.
  explicit Scene(SceneSnapshot snapshot, std::string id = {});
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  void start();
  // Stops the tick thread (joins it). Pending calls fail with Unavailable; frame waiters wake.
  // A tick in progress stops at its next sweep and is undone.
  void stop();
  // Asks the tick thread to stop without waiting for it (stop() still joins it later).
  void request_stop();
  bool stopped() const;

  // How long the tick in progress has been running (zero when the thread is between ticks).
  std::chrono::steady_clock::duration tick_running_for() const;
  // Stops the tick in progress at its next sweep, undoes it and pauses the scene with `reason`
  // (a lockstep Step fails with it). For the registry's per-tick time limit.
  void abort_tick(std::string reason);

  const std::string& id() const { return id_; }
  std::shared_ptr<const BodyModel> model() const;
  SceneConfig config() const;
  SceneStatus status() const;
  // Surface vertices (ascending) of the fixed geometry.
  const std::vector<int32_t>& surface_vertices() const { return surface_vertices_; }
  // Positions the scene was created or restored with (what "where it is now" means before the
  // first tick publishes a frame).
  const std::vector<Vec3>& initial_positions() const { return initial_positions_; }
  // The particle bodies as built (fixed for the scene's lifetime), in config order.
  const std::vector<BodyInfo>& bodies() const { return bodies_info_; }
  size_t particle_count() const;

  // Commands, executed by the tick thread; each waits for it up to `timeout`.
  Error pause(std::chrono::milliseconds timeout = std::chrono::seconds(10));
  Error resume(std::chrono::milliseconds timeout = std::chrono::seconds(10));
  Error reset(std::chrono::milliseconds timeout = std::chrono::seconds(10));
  Error update(const SceneUpdate& update, std::chrono::milliseconds timeout = std::chrono::seconds(10));
  Error apply_force(std::vector<int32_t> vertices, const Vec3& force, uint32_t ticks,
                    uint64_t* first_tick, std::chrono::milliseconds timeout = std::chrono::seconds(10));
  // Advances `ticks` ticks (lockstep or paused only) and waits until they are done. When
  // `cancelled` turns true (the caller went away) or the deadline passes, the ticks not yet
  // run are dropped.
  Error step(uint32_t ticks, std::chrono::steady_clock::time_point deadline, StepResult* out,
             const std::function<bool()>& cancelled = {});
  // Interaction. Grabs are validated by the caller (validate_interaction) and wait for the
  // tick like the other commands; first_tick is the first tick they act in.
  // At most max_grabs at once (RESOURCE_EXHAUSTED).
  Error grab(const Attachment& attachment, uint64_t* grab_id, uint64_t* first_tick,
             std::chrono::milliseconds timeout = std::chrono::seconds(10), size_t max_grabs = SIZE_MAX);
  // A grab on particle `particle` of body `body` (an index in bodies(), validated by the
  // caller), held where the particle is when the grab starts unless `target` is given.
  Error grab_particle(size_t body, size_t particle, std::optional<Vec3> target, double compliance,
                      uint64_t* grab_id, uint64_t* first_tick,
                      std::chrono::milliseconds timeout = std::chrono::seconds(10), size_t max_grabs = SIZE_MAX);
  Error move_grab(uint64_t grab_id, const Vec3& target, uint64_t* first_tick, Vec3* last_force,
                  std::chrono::milliseconds timeout = std::chrono::seconds(10));
  Error release(uint64_t grab_id, std::chrono::milliseconds timeout = std::chrono::seconds(10));
  // Tools are posed at up to 1 kHz from a stream: these post the change and return at once
  // (the tick applies it at its next start). false when the scene is stopping.
  uint64_t new_tool_id();
  bool set_tool(uint64_t tool_id, const RigidTool& tool, uint64_t pose_seq, int64_t pose_client_ns);
  void remove_tool(uint64_t tool_id);

  // The full state at a tick boundary.
  Error snapshot(SceneSnapshot* out, std::chrono::milliseconds timeout = std::chrono::seconds(10));
  // Snapshot of a stopped scene (after stop(); no tick thread to ask).
  SceneSnapshot snapshot_stopped() const;

  // The latest frame (null before the first tick).
  std::shared_ptr<const Frame> latest_frame() const;
  // Waits for a frame with seq > after_seq; null on timeout or when the scene stopped.
  std::shared_ptr<const Frame> wait_frame(uint64_t after_seq,
                                          std::chrono::steady_clock::time_point deadline) const;

  // Frame listeners: `fn` runs on the tick thread after every published frame, and once when
  // the scene stops (stop / request_stop), so that a stream can notice both without a thread
  // of its own. It must return quickly and not call the listener functions. After
  // remove_frame_listener returns, the listener is not running and will not run again.
  uint64_t add_frame_listener(std::function<void()> fn);
  void remove_frame_listener(uint64_t id);

  // Bumped whenever the scene's state or settings change (every tick and command that
  // publishes status): a checkpoint is due when it moved.
  uint64_t generation() const { return generation_.load(); }

  // Serialises live updates (merge + validate + apply) from concurrent callers.
  std::mutex& update_mutex() { return update_mu_; }

 private:
  using Command = std::function<void()>;
  struct StepJob;
  struct ActiveForce {
    std::vector<int32_t> vertices;
    Vec3 force;
    uint32_t remaining;
  };

  // Runs `fn` on the tick thread at the next tick boundary and waits for it until `deadline`.
  // `fn(T& out)` returns an Error and fills `out`, which is handed to the caller (*out, when not
  // null) only once the tick thread is done with it: nothing the tick owns is shared with the
  // caller, and a caller that timed out leaves nothing behind that the command writes to.
  // `interrupt`: a tick in progress stops at its next sweep and is undone, so the command takes
  // effect at once.
  // Both kinds of grab: within the scene's limit, a new id handed to `attach` on the tick
  // thread, effective from the next tick.
  Error add_grab(std::function<Error(uint64_t id)> attach, uint64_t* grab_id, uint64_t* first_tick,
                 std::chrono::milliseconds timeout, size_t max_grabs);
  template <class T, class Fn>
  Error call(Fn fn, T* out, std::chrono::steady_clock::time_point deadline, bool interrupt = false);
  // A command that returns only its Error.
  template <class Fn>
  Error call(Fn fn, std::chrono::steady_clock::time_point deadline, bool interrupt = false) {
    struct Nothing {};
    return call<Nothing>([fn = std::move(fn)](Nothing&) mutable { return fn(); }, nullptr, deadline, interrupt);
  }
  // Queues a command for call(); Unavailable when the scene is stopping.
  Error enqueue(Command fn, bool interrupt);
  Error not_in_time() const;
  Error stopped_before_running() const;
  // FailedPrecondition for a scene in lockstep mode (pause and resume do not apply). Tick thread.
  Error not_in_lockstep() const;
  // The state at this tick boundary (tick thread, or a stopped scene).
  SceneSnapshot snapshot_now() const;
  // Queues a command without waiting for it; false when the scene is stopping.
  bool post(Command fn);
  void run();
  void tick_once(bool scheduled, std::chrono::steady_clock::time_point due);
  // The tick's particle bodies and their contacts (scene.cpp): their parts (with the tet body's
  // step or among themselves), the bodies' reports, each part of their step, then the tools'
  // contacts. `failure` names a body that threw or blew up; `report` gets the tools' share of the
  // bodies' pushes.
  struct BodyParts {
    int parts = 1;
    bool with_tet = false;  // the tet body steps in the same parts (Stepper::step_in_parts)
    // Within a part, each pair of bodies in contact meets as often as its two bodies' substeps
    // allow (their common factor over `parts`), and each body steps in as many calls as its
    // pairs need: `fine` cuts a part so that every call and every contact ends on a cut.
    int fine = 1;
    std::vector<int> body_calls;  // per body: its step's calls in a part
    std::vector<int> pair_calls;  // per pair (TickState::cloth_pairs): its contacts in a part
  };
  BodyParts body_parts() const;
  void begin_bodies();
  void bodies_part(int part, const BodyParts& parts, const std::vector<std::vector<Vec3>>& obstacle_impulses,
                   std::span<const RigidTool> tools, bool& cancelled, std::string& failure);
  void finish_bodies(const StepInputs& inputs, StepReport& report, std::string& failure);
  void carry_report(StepReport&& report, bool rolled_back, Frame& frame);
  // A tick the cancel flag stopped: undone; with a reason from abort_tick, also pauses.
  void cancelled_tick(const std::string& abort_reason);
  void publish_status();
  // Puts every particle body back to its state at the start of the tick.
  void restore_bodies();

  const std::string id_;
  std::vector<int32_t> surface_vertices_;
  std::vector<Vec3> initial_positions_;
  std::vector<BodyInfo> bodies_info_;

  // Shared with callers (under mu_).
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Command> commands_;
  bool stop_ = false;
  // The tick thread is idle until a command arrives (lockstep, paused): only then do new
  // commands notify cv_ (a realtime tick runs them at its next boundary without being woken).
  bool waiting_for_commands_ = false;
  uint64_t next_tool_id_ = 1;
  std::thread thread_;

  // Readable copies for other threads (under info_mu_).
  mutable std::mutex info_mu_;
  SceneConfig config_;
  std::shared_ptr<const BodyModel> model_shared_;
  SceneStatus status_;

  std::mutex update_mu_;

  // Latest frame (under frame_mu_).
  mutable std::mutex frame_mu_;
  mutable std::condition_variable frame_cv_;
  std::shared_ptr<const Frame> latest_;
  uint64_t seq_ = 0;

  // Frame listeners (under listeners_mu_, which is held while they run).
  void notify_listeners();
  std::mutex listeners_mu_;
  std::map<uint64_t, std::function<void()>> listeners_;
  uint64_t next_listener_ = 1;

  // Cancellation of the tick in progress (StepInputs::cancel): set by interrupting commands,
  // stop and abort_tick, cleared when the tick thread takes the next commands (under mu_).
  std::atomic<bool> cancel_tick_{false};
  std::atomic<uint64_t> generation_{0};
  std::atomic<int64_t> tick_started_ns_{0};  // steady clock of the tick in progress; 0: none
  std::mutex abort_mu_;
  std::string abort_reason_;  // why abort_tick stopped the tick (under abort_mu_)

  // Tick-thread-only state.
  struct TickState;
  std::unique_ptr<TickState> ts_;
};

template <class T, class Fn>
Error Scene::call(Fn fn, T* out, std::chrono::steady_clock::time_point deadline, bool interrupt) {
  struct Outcome {
    Error error;
    T value{};
  };
  // Only the command holds the promise: a command dropped unrun (the scene stopped) breaks it,
  // and the caller answers at once instead of at its deadline.
  auto done = std::make_shared<std::promise<Outcome>>();
  auto future = done->get_future();
  Error queued = enqueue(
      [done = std::move(done), fn = std::move(fn)]() mutable {
        Outcome o;
        o.error = fn(o.value);
        done->set_value(std::move(o));
      },
      interrupt);
  if (!queued.ok()) return queued;
  if (future.wait_until(deadline) != std::future_status::ready) return not_in_time();
  try {
    Outcome o = future.get();
    if (o.error.ok() && out) *out = std::move(o.value);
    return o.error;
  } catch (const std::future_error&) {  // the command was dropped (scene stopped) or threw
    return stopped_before_running();
  }
}

}  // namespace pliant::server
