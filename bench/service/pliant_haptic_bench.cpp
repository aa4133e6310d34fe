// SPDX-License-Identifier: Apache-2.0
// pliant_haptic_bench: the haptic bridge's figures on loopback, against an in-process server.
//  A. pliant-haptic's default scene (beam1 at 1 kHz, realtime), the bridge's simulated device
//     stroking it:
//     round-trip latency (pose sent -> force for that pose received) p50/p99/max, the device
//     loop's rate and period p99, the force felt.
//  B. a 50k-tet beam ticking at 60 Hz beside the bridge: the device loop must still hold
//     1 kHz (the force between ticks comes from the local extrapolation).
// Usage: pliant_haptic_bench [--seconds S] [--big SUBSTEPS,ITERATIONS] [--no-realtime] [--json] [--verbose]
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/haptic.hpp"
#include "pliant/server/server.hpp"

#include "cli.hpp"
#include "pliant/version.hpp"

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <cstring>
#include <string>
#include <thread>

using namespace pliant;
using namespace pliant::haptic;

namespace {

v1::CreateSceneRequest beam_scene(const std::string& id, double hz, int substeps, int iterations) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  client::clamp_below_x(*s, 1e-3);
  s->mutable_material()->set_young_modulus(5e7);
  s->mutable_gravity()->set_y(0);
  s->mutable_solver()->set_substeps(substeps);
  s->mutable_solver()->set_iterations(iterations);
  s->mutable_solver()->set_damping_coefficient(20);
  s->mutable_tick()->set_dt(1.0 / hz);
  s->mutable_tick()->set_mode(v1::TICK_MODE_REALTIME);
  return r;
}

struct Figures {
  std::string name;
  BridgeStats stats;
  uint64_t late_ticks = 0;
  double ticks_per_second = 0;
};

bool g_realtime = true;

std::string fmt_number(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

Figures run(const std::string& address, const std::string& scene, const SimulatedDevice::Params& dev,
            double seconds, const std::string& name) {
  BridgeOptions bo;
  bo.realtime_priority = g_realtime;
  bo.connect.address = address;
  bo.scene_id = scene;
  bo.create_builtin.clear();  // the bench creates its scenes
  bo.tool_radius = dev.radius;
  auto device = std::make_shared<SimulatedDevice>(dev);
  HapticBridge bridge(bo, device);
  bridge.start();
  // Warm up: connected and past the first press ramp.
  for (int i = 0; i < 500 && !bridge.connected(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  std::this_thread::sleep_for(std::chrono::seconds(1));
  client::ConnectOptions co;
  co.address = address;
  client::Client c(co);
  const auto before = c.get_scene(scene);
  bridge.reset_stats();
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
  Figures f;
  f.name = name;
  f.stats = bridge.stats();
  bridge.stop();
  const auto after = c.get_scene(scene);
  if (before.ok() && after.ok()) {
    f.late_ticks = after->late_ticks() - before->late_ticks();
    f.ticks_per_second = after->ticks_per_second();
  }
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 10;
  bool json = false, verbose = false;
  int big_sub = 1, big_it = 1;
  CLI::App app{"pliant_haptic_bench: the haptic stream's round trip and the bridge's loop rate"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.add_option("--seconds", seconds, "seconds per scene (default 10)")->check(CLI::Range(0.1, 3600.0));
  app.add_option_function<std::string>(
      "--big", [&](const std::string& v) { pliant::cli::parse_int_pair("--big", v, 1, &big_sub, &big_it); },
      "SUBSTEPS,ITERATIONS of the 50k-tet scene (default 1,1)");
  app.add_flag("--json", json, "one JSON line per scene");
  app.add_flag_callback("--no-realtime", [] { g_realtime = false; }, "no SCHED_FIFO for the device loop");
  app.add_flag("--verbose", verbose, "the server's debug log");
  if (auto rc = pliant::cli::parse_or_exit(app, argc, argv, "pliant_haptic_bench")) return *rc;
  // --verbose: the server's debug log, with each scene's tick profile every 10 s.
  spdlog::set_level(verbose ? spdlog::level::debug : spdlog::level::warn);
  server::ServerOptions so;
  so.listen = "127.0.0.1:0";
  so.restore = false;
  server::PliantServer srv(so);
  if (auto e = srv.start(); !e.ok()) {
    std::fprintf(stderr, "server: %s\n", e.message.c_str());
    return 1;
  }
  const std::string address = "127.0.0.1:" + std::to_string(srv.port());
  client::ConnectOptions co;
  co.address = address;
  client::Client c(co);

  std::vector<Figures> all;
  std::string scene_a;
  {
    // The scene pliant-haptic creates by default (beam1 lying on its bottom face, soft tissue,
    // 1 kHz, its default budget).
    BridgeOptions defaults;
    defaults.scene_id = "beam1-1kHz";
    const auto r = scene_request(defaults);
    scene_a = "beam1 @ 1 kHz, pliant-haptic's default scene (E " + fmt_number(defaults.create_young) + " Pa, " +
              std::to_string(defaults.create_substeps) + " substeps x " + std::to_string(defaults.create_iterations) +
              " iterations)";
    if (auto s = c.create_scene(r); !s.ok()) {
      std::fprintf(stderr, "create beam1: %s\n", s.status.to_string().c_str());
      return 1;
    }
    SimulatedDevice::Params dev;  // defaults: over beam1's tip, press 3 mm, 4 s cycle
    dev.script = SimulatedDevice::Script::Stroke;
    all.push_back(run(address, "beam1-1kHz", dev, seconds, scene_a));
    c.delete_scene("beam1-1kHz");
  }
  {
    auto r = beam_scene("beam50k-60Hz", 60, big_sub, big_it);
    TetMesh big = make_beam(51, 21, 11, 0.005);  // 0.25 x 0.1 x 0.05 m, 50,000 tets
    auto* d = r.mutable_spec()->mutable_mesh()->mutable_data();
    for (const auto& p : big.vertices)
      for (int k = 0; k < 3; ++k) d->add_positions(p[k]);
    for (const auto& t : big.tets)
      for (int k = 0; k < 4; ++k) d->add_tets(t[k]);
    d->set_name("beam50k");
    if (auto s = c.create_scene(r); !s.ok()) {
      std::fprintf(stderr, "create beam50k: %s\n", s.status.to_string().c_str());
      return 1;
    }
    SimulatedDevice::Params dev;
    dev.start = Vec3(0.2, 0.12, 0.025);
    dev.surface_y = 0.1;
    dev.radius = 0.01;
    dev.depth = 0.004;
    all.push_back(run(address, "beam50k-60Hz", dev, seconds,
                      "beam 50k tets @ 60 Hz (" + std::to_string(big_sub) + " substep(s) x " + std::to_string(big_it) +
                          " iteration(s))"));
  }
  srv.shutdown();

  for (const Figures& f : all) {
    const BridgeStats& s = f.stats;
    if (json) {
      // The bridge's figures and the server's, one strict JSON line (nlohmann-json).
      nlohmann::ordered_json j = nlohmann::ordered_json::parse(s.to_json());
      j["scene"] = f.name;
      j["server_ticks_per_second"] = f.ticks_per_second;
      j["server_late_ticks"] = f.late_ticks;
      std::printf("%s\n", j.dump().c_str());
    } else {
      std::printf("%s\n  device loop %.1f Hz, period p50 %.0f us / p99 %.0f us / max %.0f us (|error| p99 %.0f us)\n"
                  "  round trip pose -> force: p50 %.3f ms  p99 %.3f ms  max %.3f ms  (%llu feedback messages)\n"
                  "  force max %.3f N; server %.1f ticks/s, %llu late ticks\n",
                  f.name.c_str(), s.loop_hz, s.period_p50_us, s.period_p99_us, s.period_max_us, s.period_error_p99_us,
                  s.rtt_p50_ms, s.rtt_p99_ms, s.rtt_max_ms, static_cast<unsigned long long>(s.feedback), s.max_force_n,
                  f.ticks_per_second, static_cast<unsigned long long>(f.late_ticks));
    }
  }
  return 0;
}
