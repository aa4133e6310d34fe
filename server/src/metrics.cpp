// SPDX-License-Identifier: Apache-2.0
#include "pliant/server/metrics.hpp"

#include "pliant/version.hpp"

#include <civetweb.h>
#include <spdlog/fmt/fmt.h>

#include <cmath>
#include <vector>

namespace pliant::server {

namespace {

// A label value: backslash, double quote and line feed escaped (exposition format 0.0.4).
std::string label(const std::string& v) {
  std::string out;
  for (char c : v) {
    if (c == '\\') out += "\\\\";
    else if (c == '"') out += "\\\"";
    else if (c == '\n') out += "\\n";
    else out += c;
  }
  return out;
}

// A sample value: Prometheus spells the non-finite ones NaN, +Inf, -Inf.
std::string value(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "+Inf" : "-Inf";
  return fmt::format("{}", v);
}

struct Family {
  const char* name;
  const char* type;  // counter | gauge
  const char* help;
  std::vector<std::pair<std::string, double>> samples;  // (scene id, value)
};

}  // namespace

std::string render_metrics(const SceneRegistry& registry) {
  const auto scenes = registry.scenes();
  int open_streams = 0;
  const std::map<std::string, int> streams = registry.stream_counts(&open_streams);

  Family ticks{"pliant_scene_ticks_total", "counter", "Ticks the scene has run (restored scenes count on).", {}};
  Family late{"pliant_scene_late_ticks_total", "counter", "Realtime ticks that started after their slot.", {}};
  Family skipped{"pliant_scene_skipped_ticks_total", "counter", "Realtime tick slots skipped to catch up.", {}};
  Family rollbacks{"pliant_scene_rollbacks_total", "counter", "Ticks undone after a solver failure or a time limit.", {}};
  Family running{"pliant_scene_running", "gauge", "1 while the scene ticks on its own, 0 when paused or lockstep.", {}};
  Family rate{"pliant_scene_ticks_per_second", "gauge", "Ticks per second over the last second.", {}};
  Family step_last{"pliant_scene_step_seconds", "gauge", "Solver wall time of the last tick, seconds.", {}};
  Family step_mean{"pliant_scene_step_seconds_mean", "gauge",
                   "Mean solver wall time per tick since the scene started in this process, seconds.", {}};
  Family residual{"pliant_scene_residual", "gauge", "Constraint residual ||r|| at the end of the last tick.", {}};
  Family relative{"pliant_scene_relative_residual", "gauge",
                  "Last tick's final residual over its initial residual (last substep).", {}};
  Family iterations{"pliant_scene_iterations", "gauge", "Solver iterations in the last tick (all substeps).", {}};
  Family substeps{"pliant_scene_substeps", "gauge", "Substeps in the last tick.", {}};
  Family grabs{"pliant_scene_grabs", "gauge", "Grabs held on the scene at the last tick.", {}};
  Family scene_streams{"pliant_scene_open_streams", "gauge", "Open StreamFrames and HapticStream calls on the scene.", {}};

  for (const auto& scene : scenes) {
    const std::string& id = scene->id();
    const SceneStatus st = scene->status();
    ticks.samples.emplace_back(id, double(st.tick));
    late.samples.emplace_back(id, double(st.counters.late_ticks));
    skipped.samples.emplace_back(id, double(st.counters.skipped_ticks));
    rollbacks.samples.emplace_back(id, double(st.counters.rollbacks));
    running.samples.emplace_back(id, st.running ? 1.0 : 0.0);
    rate.samples.emplace_back(id, st.running ? st.counters.ticks_per_second : 0.0);
    auto s = streams.find(id);
    scene_streams.samples.emplace_back(id, s == streams.end() ? 0.0 : double(s->second));
    // Before its first tick a scene has no frame: the per-tick gauges are left out for it.
    if (const auto f = scene->latest_frame()) {
      step_last.samples.emplace_back(id, f->solver.wall_ms * 1e-3);
      step_mean.samples.emplace_back(id, f->stepped_ticks > 0 ? f->step_wall_ms_sum * 1e-3 / double(f->stepped_ticks)
                                                              : std::nan(""));
      residual.samples.emplace_back(id, f->solver.residual_final);
      relative.samples.emplace_back(id, f->solver.residual_initial > 0 ? relative_residual(f->solver)
                                                                : std::nan(""));
      iterations.samples.emplace_back(id, double(f->solver.iterations));
      substeps.samples.emplace_back(id, double(f->solver.substeps));
      grabs.samples.emplace_back(id, double(f->grab_forces.size()));
    }
  }

  std::string out;
  out += "# HELP pliant_build_info The pliant-server version.\n# TYPE pliant_build_info gauge\n";
  out += fmt::format("pliant_build_info{{version=\"{}\"}} 1\n", label(kVersion));
  out += "# HELP pliant_scenes Scenes hosted.\n# TYPE pliant_scenes gauge\n";
  out += fmt::format("pliant_scenes {}\n", scenes.size());
  out += "# HELP pliant_open_streams Open StreamFrames and HapticStream calls, all scenes.\n"
         "# TYPE pliant_open_streams gauge\n";
  out += fmt::format("pliant_open_streams {}\n", open_streams);
  for (const Family* f : {&ticks, &late, &skipped, &rollbacks, &running, &rate, &step_last, &step_mean, &residual,
                          &relative, &iterations, &substeps, &grabs, &scene_streams}) {
    out += fmt::format("# HELP {} {}\n# TYPE {} {}\n", f->name, f->help, f->name, f->type);
    for (const auto& [id, v] : f->samples) out += fmt::format("{}{{scene=\"{}\"}} {}\n", f->name, label(id), value(v));
  }
  return out;
}

namespace {

int serve_metrics(mg_connection* conn, void* data) {
  const auto* registry = static_cast<const SceneRegistry*>(data);
  const mg_request_info* info = mg_get_request_info(conn);
  if (std::string(info->request_method) != "GET" && std::string(info->request_method) != "HEAD") {
    mg_printf(conn, "HTTP/1.1 405 Method Not Allowed\r\nAllow: GET, HEAD\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
    return 405;
  }
  const std::string body = render_metrics(*registry);
  mg_printf(conn,
            "HTTP/1.1 200 OK\r\nContent-Type: text/plain; version=0.0.4; charset=utf-8\r\n"
            "Content-Length: %zu\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
            body.size());
  if (std::string(info->request_method) == "GET") mg_write(conn, body.data(), body.size());
  return 200;
}

}  // namespace

Error MetricsEndpoint::start(const std::string& listen, const SceneRegistry* registry,
                             std::unique_ptr<MetricsEndpoint>* out) {
  // civetweb listens on numeric addresses: localhost is spelled 127.0.0.1.
  std::string ports = listen;
  if (ports.rfind("localhost:", 0) == 0) ports = "127.0.0.1:" + ports.substr(10);
  const char* options[] = {"listening_ports", ports.c_str(), "num_threads", "2", nullptr};
  mg_callbacks callbacks{};
  std::unique_ptr<MetricsEndpoint> m(new MetricsEndpoint());
  m->registry_ = registry;
  m->ctx_ = mg_start(&callbacks, nullptr, options);
  if (!m->ctx_)
    return Error::make(Code::InvalidArgument,
                       fmt::format("--metrics-listen '{}': cannot listen (address in use or not a numeric "
                                   "HOST:PORT)",
                                   listen));
  mg_set_request_handler(m->ctx_, "/metrics$", serve_metrics, const_cast<SceneRegistry*>(registry));
  mg_server_port sp[4];
  const int n = mg_get_server_ports(m->ctx_, 4, sp);
  m->port_ = n > 0 ? sp[0].port : 0;
  *out = std::move(m);
  return {};
}

MetricsEndpoint::~MetricsEndpoint() {
  if (ctx_) mg_stop(ctx_);
}

}  // namespace pliant::server
