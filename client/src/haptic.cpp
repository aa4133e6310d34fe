// SPDX-License-Identifier: Apache-2.0
#include "pliant/client/haptic.hpp"

#include <pthread.h>
#include <sched.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>

namespace pliant::haptic {

namespace {
constexpr size_t kPoseHistory = 4096;  // poses by seq, enough for seconds of round trip at 1 kHz

int64_t steady_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch()).count();
}
}  // namespace

// ---------------------------------------------------------------------------------------
SimulatedDevice::SimulatedDevice(Params p) : p_(p) {}

std::string SimulatedDevice::name() const {
  return p_.script == Script::Press ? "simulated (press)" : "simulated (stroke)";
}

Vec3 SimulatedDevice::position(double t) {
  // Bottom of the tool from start height down to depth below the surface, as a smooth
  // (cosine) ramp so the script itself has no velocity steps.
  const double phase = std::fmod(t, p_.period_s);
  const double top = p_.start.y() - p_.radius;           // tool bottom at the start
  const double bottom = p_.surface_y - p_.depth;         // tool bottom at full depth
  auto ramp = [](double s) { s = std::clamp(s, 0.0, 1.0); return 0.5 - 0.5 * std::cos(M_PI * s); };
  const double down = ramp(phase / p_.ramp_s), up = ramp((phase - (p_.period_s - p_.ramp_s)) / p_.ramp_s);
  const double a = down - up;
  Vec3 x = p_.start;
  x.y() = top + a * (bottom - top) + p_.radius;
  if (p_.script == Script::Stroke) {
    const double hold = p_.period_s - 2 * p_.ramp_s;
    const double s = std::clamp((phase - p_.ramp_s) / std::max(hold, 1e-9), 0.0, 1.0);
    x.x() -= p_.stroke_x * std::sin(2 * M_PI * s);  // out towards the clamp and back
  }
  return x;
}

void SimulatedDevice::render(const Vec3& force) {
  std::lock_guard lk(mu_);
  last_force_ = force;
}

Vec3 SimulatedDevice::last_force() const {
  std::lock_guard lk(mu_);
  return last_force_;
}

// ---------------------------------------------------------------------------------------
ForceRenderer::ForceRenderer(SafetyLimits limits, double max_stiffness) : limits_(limits), max_k_(max_stiffness) {}

Vec3 ForceRenderer::update(const Vec3& position, const ServerForce& server, bool lost, double dt,
                           Clock::time_point now) {
  if (lost || !server.valid) {
    // Cut at once: the one change the rate limit never slows.
    k_ = 0;
    have_last_ = false;
    output_.setZero();
    return output_;
  }
  Vec3 target = Vec3::Zero();
  const double fn = server.force.norm();
  if (fn > 1e-9 && server.force.allFinite()) {
    const Vec3 n = server.force / fn;
    if (server.tick != last_tick_) {
      if (have_last_) {
        // Penetration grows when the pose moves against n (into the body).
        const double dx = (last_pose_ - server.pose).dot(n);
        if (std::abs(dx) > 1e-6) {
          const double k = (fn - last_fn_) / dx;
          if (std::isfinite(k) && k > 0) k_ = 0.8 * k_ + 0.2 * std::min(k, max_k_);
        }
      }
      last_tick_ = server.tick;
      last_fn_ = fn;
      last_pose_ = server.pose;
      have_last_ = true;
    }
    double deeper = limits_.extrapolate_ms > 0 ? (server.pose - position).dot(n) : 0.0;
    if (server.pose_time != Clock::time_point{}) {
      const double age_ms = std::chrono::duration<double, std::milli>(now - server.pose_time).count();
      if (age_ms > limits_.extrapolate_ms) deeper *= limits_.extrapolate_ms / age_ms;
    }
    target = std::max(0.0, fn + k_ * deeper) * n;
  } else {
    have_last_ = false;
    last_tick_ = server.tick;
  }
  const double mag = target.norm();
  if (mag > limits_.max_force) target *= limits_.max_force / mag;
  const Vec3 delta = target - output_;
  const double step = limits_.max_force_rate * dt;
  output_ = delta.norm() > step ? Vec3(output_ + delta * (step / delta.norm())) : target;
  return output_;
}

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(std::ceil(p / 100.0 * v.size())) - (p > 0 ? 1 : 0));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

std::string BridgeStats::to_json() const {
  // nlohmann-json: strict JSON (a figure that is NaN or infinite, e.g. before any feedback, is null).
  nlohmann::ordered_json j;
  j["loop_hz"] = loop_hz;
  j["period_p50_us"] = period_p50_us;
  j["period_p99_us"] = period_p99_us;
  j["period_max_us"] = period_max_us;
  j["period_error_p99_us"] = period_error_p99_us;
  j["rtt_p50_ms"] = rtt_p50_ms;
  j["rtt_p99_ms"] = rtt_p99_ms;
  j["rtt_max_ms"] = rtt_max_ms;
  j["max_force_n"] = max_force_n;
  j["loops"] = loops;
  j["feedback"] = feedback;
  j["reconnects"] = reconnects;
  j["stream_losses"] = stream_losses;
  j["connected"] = connected;
  return j.dump();
}

// ---------------------------------------------------------------------------------------
HapticBridge::HapticBridge(BridgeOptions options, std::shared_ptr<Device> device)
    : opt_(std::move(options)), device_(std::move(device)), pose_history_(kPoseHistory, Vec3::Zero()) {}

HapticBridge::~HapticBridge() { stop(); }

void HapticBridge::start() {
  if (running_.exchange(true)) return;
  reset_stats();
  loop_ = std::thread([this] { loop_thread(); });
  net_ = std::thread([this] { network_thread(); });
}

void HapticBridge::stop() {
  if (!running_.exchange(false)) return;
  pose_cv_.notify_all();
  {
    std::lock_guard lk(stream_mu_);
    if (stream_) stream_->cancel();
  }
  if (net_.joinable()) net_.join();
  if (loop_.joinable()) loop_.join();
  device_->render(Vec3::Zero());
}

void HapticBridge::reset_stats() {
  std::lock_guard lk(stats_mu_);
  periods_us_.clear();
  rtts_ms_.clear();
  max_force_ = 0;
  feedback_ = 0;
  stats_start_ = Clock::now();
  stats_loops_start_ = loops_.load();
}

BridgeStats HapticBridge::stats() const {
  BridgeStats s;
  std::lock_guard lk(stats_mu_);
  const double elapsed = std::chrono::duration<double>(Clock::now() - stats_start_).count();
  s.loops = loops_.load() - stats_loops_start_;
  s.loop_hz = elapsed > 0 ? s.loops / elapsed : 0;
  s.period_p50_us = percentile(periods_us_, 50);
  s.period_p99_us = percentile(periods_us_, 99);
  s.period_max_us = periods_us_.empty() ? 0 : *std::max_element(periods_us_.begin(), periods_us_.end());
  std::vector<double> err(periods_us_.size());
  const double nominal = 1e6 / opt_.loop_hz;
  for (size_t i = 0; i < err.size(); ++i) err[i] = std::abs(periods_us_[i] - nominal);
  s.period_error_p99_us = percentile(err, 99);
  s.rtt_p50_ms = percentile(rtts_ms_, 50);
  s.rtt_p99_ms = percentile(rtts_ms_, 99);
  s.rtt_max_ms = rtts_ms_.empty() ? 0 : *std::max_element(rtts_ms_.begin(), rtts_ms_.end());
  s.max_force_n = max_force_;
  s.force_n = force_now_;
  s.feedback = feedback_;
  s.reconnects = reconnects_;
  s.stream_losses = losses_;
  s.connected = connected_.load();
  return s;
}

void HapticBridge::loop_thread() {
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / opt_.loop_hz));
  const double dt = 1.0 / opt_.loop_hz;
  // The last stretch before a deadline is spun, not slept: sleeping alone wakes late by up to
  // scheduler granularity. The spin is short so the loop leaves the cores to the server.
  const auto spin = std::chrono::microseconds(100);
  if (opt_.realtime_priority) {
    // Best effort: a real-time priority keeps the server's tick thread (and everything else
    // on a small machine) from delaying a period. Needs CAP_SYS_NICE; without it the loop
    // runs at normal priority and says so once.
    sched_param sp{};
    sp.sched_priority = std::max(1, sched_get_priority_max(SCHED_FIFO) / 2);
    if (int e = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp); e != 0)
      spdlog::info("pliant-haptic: device loop at normal priority (SCHED_FIFO refused: {})", std::strerror(e));
  }
  ForceRenderer renderer(opt_.limits);
  const auto t0 = Clock::now();
  auto next = t0;
  auto prev = t0;
  while (running_.load()) {
    next += period;
    auto now = Clock::now();
    if (now > next + period) next = now;  // preempted for more than a period: no burst of catch-up loops
    if (next - now > spin) std::this_thread::sleep_until(next - spin);
    while ((now = Clock::now()) < next) {
    }
    const double period_us = std::chrono::duration<double, std::micro>(now - prev).count();
    prev = now;
    const uint64_t i = loops_.load();

    const Vec3 p = device_->position(std::chrono::duration<double>(now - t0).count());
    {
      std::lock_guard lk(pose_mu_);
      pose_ = p;
      ++pose_seq_;
    }
    pose_cv_.notify_one();

    ServerForce sf;
    {
      std::lock_guard lk(fb_mu_);
      sf = server_;
    }
    const bool stale = !sf.valid || now - sf.received > std::chrono::duration<double, std::milli>(opt_.limits.stale_ms);
    const bool lost = !connected_.load() || stale;
    const Vec3 f = renderer.update(p, sf, lost, dt, now);
    device_->render(f);
    if (f.isZero() && zero_loop_.load() < loss_loop_.load()) zero_loop_ = i;

    {
      std::lock_guard lk(stats_mu_);
      if (i > stats_loops_start_) periods_us_.push_back(period_us);
      force_now_ = f.norm();
      max_force_ = std::max(max_force_, force_now_);
    }
    loops_.fetch_add(1);
  }
}

v1::CreateSceneRequest scene_request(const BridgeOptions& o) {
  v1::CreateSceneRequest r;
  r.set_scene_id(o.scene_id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin(o.create_builtin);
  if (o.create_clamp == BridgeOptions::Clamp::End) {
    client::clamp_below_x(*s, 1e-3);  // the beams start at x = 0
  } else {
    auto* box = s->mutable_fixed()->add_boxes();  // the bottom face: the beams start at y = 0
    box->mutable_min()->set_x(-1e9);
    box->mutable_min()->set_y(-1e9);
    box->mutable_min()->set_z(-1e9);
    box->mutable_max()->set_x(1e9);
    box->mutable_max()->set_y(1e-3);
    box->mutable_max()->set_z(1e9);
  }
  s->mutable_material()->set_young_modulus(o.create_young);
  s->mutable_material()->set_poisson_ratio(o.create_poisson);
  s->mutable_gravity()->set_y(0);
  s->mutable_solver()->set_method(o.create_method);
  s->mutable_solver()->set_substeps(o.create_substeps);
  s->mutable_solver()->set_iterations(o.create_iterations);
  s->mutable_solver()->set_damping_coefficient(20);
  s->mutable_tick()->set_dt(1.0 / o.create_tick_hz);
  s->mutable_tick()->set_mode(v1::TICK_MODE_REALTIME);
  return r;
}

bool HapticBridge::ensure_scene(client::Client& c) {
  auto got = c.get_scene(opt_.scene_id);
  if (got.ok()) return true;
  if (got.status.code != 5 || opt_.create_builtin.empty()) {
    spdlog::warn("pliant-haptic: scene '{}': {}", opt_.scene_id, got.status.to_string());
    return false;
  }
  const v1::CreateSceneRequest r = scene_request(opt_);
  auto created = c.create_scene(r);
  if (!created.ok() && created.status.code != 6) {
    spdlog::warn("pliant-haptic: creating scene '{}': {}", opt_.scene_id, created.status.to_string());
    return false;
  }
  spdlog::info("pliant-haptic: created scene '{}' ({} at {} Hz)", opt_.scene_id, opt_.create_builtin, opt_.create_tick_hz);
  return true;
}

void HapticBridge::network_thread() {
  std::ofstream trace;
  if (!opt_.trace_path.empty()) {
    trace.open(opt_.trace_path, std::ios::trunc);
    if (!trace)
      spdlog::error("pliant-haptic: cannot write the trace '{}': {}", opt_.trace_path, std::strerror(errno));
    else
      trace << "t_ms,tick,skipped_ticks,pose_seq,pose_age_ms,pose_x,pose_y,pose_z,force_x,force_y,force_z,contacts\n";
  }
  const auto t_start = Clock::now();
  bool first_connect = true;
  while (running_.load()) {
    if (!first_connect) {
      std::this_thread::sleep_for(opt_.reconnect_delay);
      if (!running_.load()) break;
    }
    first_connect = false;
    client::Client c(opt_.connect);
    if (!c.wait_connected(std::chrono::milliseconds(500)) || !ensure_scene(c)) continue;
    std::unique_ptr<client::HapticStream> stream = c.haptic_stream();
    {
      std::lock_guard lk(stream_mu_);
      stream_ = stream.get();
    }
    std::atomic<bool> alive{true};
    std::thread sender([&] {
      uint64_t sent = 0;
      bool first = true;
      v1::ToolPose msg;
      while (running_.load() && alive.load()) {
        Vec3 p;
        uint64_t seq;
        {
          std::unique_lock lk(pose_mu_);
          pose_cv_.wait_for(lk, std::chrono::milliseconds(10),
                            [&] { return pose_seq_ != sent || !running_.load() || !alive.load(); });
          if (pose_seq_ == sent) continue;
          p = pose_;
          seq = pose_seq_;
        }
        {
          std::lock_guard lk(fb_mu_);
          pose_history_[seq % kPoseHistory] = p;
        }
        msg.Clear();
        if (first) {
          msg.set_scene_id(opt_.scene_id);
          msg.set_shape(v1::TOOL_SHAPE_SPHERE);
          msg.set_radius(opt_.tool_radius);
        }
        msg.set_seq(seq);
        msg.set_client_time_ns(steady_ns());
        msg.mutable_position()->set_x(p.x());
        msg.mutable_position()->set_y(p.y());
        msg.mutable_position()->set_z(p.z());
        if (!stream->send(msg)) break;
        first = false;
        sent = seq;
      }
    });

    v1::ToolFeedback fb;
    uint64_t last_seq = 0;
    while (stream->next(&fb)) {
      const auto now = Clock::now();
      {
        std::lock_guard lk(fb_mu_);
        server_.valid = true;
        server_.tick = fb.tick();
        server_.force = Vec3(fb.force().x(), fb.force().y(), fb.force().z());
        server_.pose = pose_history_[fb.pose_seq() % kPoseHistory];
        server_.received = now;
        // The echoed send time is this process's steady clock (steady_ns), so it is the pose's
        // time on the loop's clock.
        server_.pose_time = fb.pose_client_time_ns() > 0
                                ? Clock::time_point(std::chrono::duration_cast<Clock::duration>(
                                      std::chrono::nanoseconds(fb.pose_client_time_ns())))
                                : Clock::time_point{};
      }
      if (trace.is_open()) {
        const Vec3 pose = pose_history_[fb.pose_seq() % kPoseHistory];
        const double age_ms = fb.pose_client_time_ns() > 0 ? (steady_ns() - fb.pose_client_time_ns()) * 1e-6 : 0.0;
        trace << fmt::format("{:.3f},{},{},{},{:.3f},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{}\n",
                             std::chrono::duration<double, std::milli>(now - t_start).count(), fb.tick(),
                             fb.skipped_ticks(), fb.pose_seq(), age_ms, pose.x(), pose.y(), pose.z(),
                             fb.force().x(), fb.force().y(), fb.force().z(), fb.contacts_size());
      }
      if (!connected_.exchange(true)) spdlog::info("pliant-haptic: streaming with scene '{}'", opt_.scene_id);
      std::lock_guard lk(stats_mu_);
      ++feedback_;
      if (fb.pose_seq() != last_seq && fb.pose_client_time_ns() != 0) {
        rtts_ms_.push_back((steady_ns() - fb.pose_client_time_ns()) * 1e-6);
        last_seq = fb.pose_seq();
      }
    }
    // The stream ended: the loop renders zero from its next period on.
    const bool was_connected = connected_.exchange(false);
    loss_loop_ = loops_.load();
    {
      std::lock_guard lk(fb_mu_);
      server_.valid = false;
    }
    alive = false;
    pose_cv_.notify_all();
    sender.join();
    {
      std::lock_guard lk(stream_mu_);
      stream_ = nullptr;
    }
    stream->cancel();
    const auto status = stream->finish();
    if (running_.load()) {
      std::lock_guard lk(stats_mu_);
      ++losses_;
      ++reconnects_;
      if (was_connected) spdlog::warn("pliant-haptic: stream lost ({}); force cut, reconnecting", status.to_string());
    }
  }
  connected_ = false;
}

}  // namespace pliant::haptic
