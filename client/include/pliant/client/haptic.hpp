// SPDX-License-Identifier: Apache-2.0
// The haptic bridge behind `pliant-haptic`: a device loop at 1 kHz on its own thread that never
// waits for the network, a network side that streams tool poses to a Pliant server and reads
// back the contact force after every tick, and between the two a force renderer that
// extrapolates the last server force locally (virtual coupling along the contact normal) and
// applies the safety limits (max force, max force rate, zero when the stream is lost).
#pragma once

#include "pliant/client/client.hpp"

#include <Eigen/Core>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace pliant::haptic {

using Vec3 = Eigen::Vector3d;
using Clock = std::chrono::steady_clock;

// A haptic device: where the handle is, and the force to render on it. A real driver
// implements this; the loop calls both from its own thread once per period.
class Device {
 public:
  virtual ~Device() = default;
  virtual std::string name() const = 0;
  // Handle position in scene coordinates (m) at time t (s since the loop started).
  virtual Vec3 position(double t) = 0;
  // The force to render (N). Called every period, after position().
  virtual void render(const Vec3& force) = 0;
};

// Scripted motion, so the bridge runs without hardware:
//  press:  from `start` straight down (-y) to `depth` below `surface_y` in ramp_s, hold, back up;
//  stroke: press, then slide along +x and back (amplitude stroke_x) while pressed.
class SimulatedDevice final : public Device {
 public:
  enum class Script { Press, Stroke };
  struct Params {
    Script script = Script::Press;
    Vec3 start{0.1, 0.025, 0.005};  // above beam1's top face near the tip
    double surface_y = 0.01;        // where contact begins (tool bottom touches)
    double radius = 0.005;          // tool radius (the script presses the tool's surface in)
    double depth = 0.003;           // m below the surface
    double ramp_s = 1.0;            // time to reach full depth
    double period_s = 4.0;          // one press / stroke cycle
    double stroke_x = 0.02;         // stroke half amplitude, m
  };
  explicit SimulatedDevice(Params p);
  std::string name() const override;
  Vec3 position(double t) override;
  void render(const Vec3& force) override;
  Vec3 last_force() const;

 private:
  Params p_;
  mutable std::mutex mu_;
  Vec3 last_force_ = Vec3::Zero();
};

struct SafetyLimits {
  double max_force = 8.0;          // N, magnitude clamp
  double max_force_rate = 2000.0;  // N/s, rising slew limit (cutting to zero is never limited)
  double stale_ms = 100.0;         // no feedback for this long: treat the stream as lost
  // The renderer follows the handle past the server's pose for at most this much of the pose's
  // age (see ForceRenderer); 0: no extrapolation at all.
  double extrapolate_ms = 10.0;
};

// The latest server answer, as the loop sees it.
struct ServerForce {
  bool valid = false;
  uint64_t tick = 0;
  Vec3 force = Vec3::Zero();  // on the tool, N
  Vec3 pose = Vec3::Zero();   // the tool position the tick used
  Clock::time_point received{};
  // When the device reported that pose (unset: treated as fresh).
  Clock::time_point pose_time{};
};

// Force between server updates. The server force F_s was computed for the pose p_s; for the
// current pose p the renderer adds k * ((p_s - p) . n) n along n = F_s / |F_s|, where k is a
// stiffness estimated from successive server updates (dF/dx along n, clamped to
// [0, max_stiffness]); with no contact it renders zero. So the device never sees a step when a
// tick is late: the force keeps following the handle with the local stiffness.
// The extrapolation is bounded by the pose's age a (now - pose_time): past
// limits.extrapolate_ms = e, the distance is scaled by e / a, so a handle moving steadily is
// followed over at most its last e milliseconds of motion. A server that falls behind (an old
// pose, a long way from the handle) then cannot make the renderer invent a large force from a
// stiffness estimated at a different depth; the force catches up as fresh answers arrive.
class ForceRenderer {
 public:
  explicit ForceRenderer(SafetyLimits limits, double max_stiffness = 5000.0);
  // One loop period: the handle position, the latest server force (or lost = true), dt (s),
  // and the loop's clock (for the pose's age).
  Vec3 update(const Vec3& position, const ServerForce& server, bool lost, double dt,
              Clock::time_point now = Clock::now());
  double stiffness() const { return k_; }
  const SafetyLimits& limits() const { return limits_; }

 private:
  SafetyLimits limits_;
  double max_k_;
  double k_ = 0;
  uint64_t last_tick_ = 0;
  double last_fn_ = 0;  // |F| along n at the previous update
  Vec3 last_pose_ = Vec3::Zero();
  bool have_last_ = false;
  Vec3 output_ = Vec3::Zero();
};

// Percentiles of a sample set (copies; p in [0, 100]).
double percentile(std::vector<double> samples, double p);

struct BridgeOptions {
  client::ConnectOptions connect;
  std::string scene_id = "haptic";
  // Create the scene when it does not exist (builtin mesh name; empty: never create).
  std::string create_builtin = "beam1";
  double create_tick_hz = 1000;     // tick rate of a created scene
  // How a created scene is held: Bottom fixes the beam's bottom face (y <= 1 mm: tissue
  // lying on a table, pressed from above, locally indented); End fixes x <= 1 mm (a
  // cantilever, which bends instead: soft materials then push back with millinewtons).
  enum class Clamp { Bottom, End };
  Clamp create_clamp = Clamp::Bottom;
  // Material of a created scene: soft tissue (E = 100 kPa, nearly incompressible). Gravity is
  // off so the scripted device finds the surface where it expects.
  double create_young = 1e5;
  double create_poisson = 0.49;
  // Solver of a created scene: one global Newton iteration per 1 kHz tick, which feels the
  // converged force at 100 kPa, 1 MPa and 10 MPa alike (docs/haptics.md: pliant_haptic_fidelity),
  // about 0.5-0.8 ms per tick for beam1 on the 2-core development machine. METHOD_XPBD with
  // 4 substeps x 2 iterations costs half that and is right up to about 100 kPa only.
  int create_substeps = 1;
  int create_iterations = 1;
  v1::Method create_method = v1::METHOD_NEWTON;
  double loop_hz = 1000;
  double tool_radius = 0.005;
  SafetyLimits limits;
  std::chrono::milliseconds reconnect_delay{200};
  bool realtime_priority = true;  // try SCHED_FIFO for the device loop (falls back quietly)
  // When set, one CSV row per server feedback is written here (docs/haptics.md "Trace").
  std::string trace_path;
};

// The CreateSceneRequest the bridge sends when its scene does not exist (create_builtin,
// create_clamp, create_young, create_poisson, create_substeps x create_iterations at
// create_tick_hz, realtime, gravity off, damping 20/s).
v1::CreateSceneRequest scene_request(const BridgeOptions& options);

struct BridgeStats {
  double loop_hz = 0;
  double period_p50_us = 0, period_p99_us = 0, period_max_us = 0;
  double period_error_p99_us = 0;  // |period - nominal|
  double rtt_p50_ms = 0, rtt_p99_ms = 0, rtt_max_ms = 0;
  double max_force_n = 0;
  double force_n = 0;              // current rendered magnitude
  uint64_t loops = 0, feedback = 0, reconnects = 0, stream_losses = 0;
  bool connected = false;
  std::string to_json() const;     // one line
};

// The bridge: the device loop thread plus the network threads.
class HapticBridge {
 public:
  HapticBridge(BridgeOptions options, std::shared_ptr<Device> device);
  ~HapticBridge();
  void start();
  void stop();
  BridgeStats stats() const;          // since start (or the last reset_stats)
  void reset_stats();
  bool connected() const { return connected_.load(); }
  // Loss bookkeeping for tests: the loop iteration at which the stream was flagged lost most
  // recently, and the first iteration after it that rendered exactly zero.
  uint64_t loss_flagged_at_loop() const { return loss_loop_.load(); }
  uint64_t zero_rendered_at_loop() const { return zero_loop_.load(); }

 private:
  void loop_thread();
  void network_thread();
  bool ensure_scene(client::Client& c);

  BridgeOptions opt_;
  std::shared_ptr<Device> device_;
  std::atomic<bool> running_{false};
  std::atomic<bool> connected_{false};
  std::atomic<uint64_t> loops_{0};
  std::atomic<uint64_t> loss_loop_{0}, zero_loop_{0};
  std::thread loop_, net_;

  // Latest pose from the loop to the sender (under pose_mu_).
  std::mutex pose_mu_;
  std::condition_variable pose_cv_;
  Vec3 pose_ = Vec3::Zero();
  uint64_t pose_seq_ = 0;

  // Latest feedback from the reader to the loop (under fb_mu_).
  mutable std::mutex fb_mu_;
  ServerForce server_;
  std::vector<Vec3> pose_history_;  // pose by seq % size, to know the pose a tick used

  // Stats (under stats_mu_).
  mutable std::mutex stats_mu_;
  std::vector<double> periods_us_, rtts_ms_;
  double max_force_ = 0, force_now_ = 0;
  uint64_t feedback_ = 0, reconnects_ = 0, losses_ = 0;
  Clock::time_point stats_start_;
  uint64_t stats_loops_start_ = 0;

  std::mutex stream_mu_;
  client::HapticStream* stream_ = nullptr;  // for stop() to cancel
};

}  // namespace pliant::haptic
