// SPDX-License-Identifier: Apache-2.0
// pliant-haptic: the haptic-device bridge. Runs the device loop at 1 kHz on its own thread,
// streams tool poses to a Pliant scene and renders the contact force it gets back, with local
// force extrapolation between server updates and safety limits. Uses a scripted simulated
// device by default. Prints a live statistics line every second; with --json it ends with
// one JSON line (loop_hz, period_p99_us, rtt_p50_ms, rtt_p99_ms, rtt_max_ms, max_force_n, ...).
// Exit codes: 0 ok; 2 usage error; 3 never connected to the server.
#include "pliant/client/haptic.hpp"
#include "pliant/proto/enums.hpp"
#include "pliant/version.hpp"
#include "cli.hpp"

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <iostream>
#include <string>
#include <thread>

namespace {

const char* kUsage = R"(usage: pliant-haptic [flags]

  --address HOST:PORT    server (default $PLIANT_ADDRESS or localhost:50051)
  --token TOKEN          access token (default $PLIANT_TOKEN)
  --scene ID             scene to touch (default "haptic")
  --create MESH          create the scene from this builtin mesh when it does not exist
                         (default beam1, clamped at x = 0; "" never creates)
  --tick-hz HZ           tick rate of a scene it creates (default 1000)
  --clamp bottom|end     how a scene it creates is held: bottom face fixed (default; tissue on
                         a table) or x <= 1 mm fixed (a cantilever)
  --young PA             Young's modulus of a scene it creates (default 1e5: soft tissue;
                         gravity off)
  --poisson NU           Poisson's ratio of a scene it creates (default 0.49)
  --substeps N --iterations N   solver of a scene it creates (default 1 x 1)
  --method M             its method (default newton: the converged force at every stiffness;
                         xpbd with 4 x 2 costs half and is right up to about 100 kPa,
                         docs/haptics.md; any name `pliant --help` lists)
  --rate HZ              device loop rate (default 1000)
  --script press|stroke  simulated device motion (default press)
  --start X,Y,Z          simulated handle start, m (default 0.1,0.025,0.005: over beam1's tip)
  --surface-y Y          height where contact starts, m (default 0.01: beam1's top)
  --depth M              press depth below the surface, m (default 0.003)
  --radius M             tool sphere radius, m (default 0.005)
  --max-force N          force clamp, N (default 8)
  --max-force-rate N/S   force slew limit, N/s (default 2000)
  --stale-ms MS          no feedback for this long cuts the force (default 100)
  --extrapolate-ms MS    follow the handle past the server's pose for at most this much of the
                         pose's age (default 10; 0: never)
  --duration S           stop after S seconds (default: until Ctrl-C)
  --json                 end with one JSON line of statistics on stdout
  --trace FILE           write one CSV row per server feedback (tick, pose, pose age, force)
  --quiet                no live statistics line
  --no-realtime          do not ask for SCHED_FIFO for the device loop
  --version              print the version and exit
)";

std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }

bool parse_vec(const std::string& s, pliant::haptic::Vec3* out) {
  double x, y, z;
  if (std::sscanf(s.c_str(), "%lf,%lf,%lf", &x, &y, &z) != 3) return false;
  *out = pliant::haptic::Vec3(x, y, z);
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace pliant::haptic;
  BridgeOptions opt;
  opt.connect.address = std::getenv("PLIANT_ADDRESS") ? std::getenv("PLIANT_ADDRESS") : "localhost:50051";
  if (const char* t = std::getenv("PLIANT_TOKEN")) opt.connect.token = t;
  opt.connect.timeout = std::chrono::seconds(5);
  SimulatedDevice::Params dev;
  double duration = 0;
  bool json = false, quiet = false;
  CLI::App app{"pliant-haptic"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.formatter_fn([](const CLI::App*, std::string, CLI::AppFormatMode) { return std::string(kUsage); });
  // Every valued flag: the last one given wins; its check fails the parse with one line.
  auto text = [&app](const std::string& name, std::function<void(const std::string&)> set) {
    app.add_option_function<std::string>(name, std::move(set))->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  };
  auto number = [&text](const std::string& name, double lo, double hi, std::function<void(double)> set) {
    text(name, [name, lo, hi, set](const std::string& v) {
      char* end = nullptr;
      const double d = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0' || !(d >= lo && d <= hi))
        throw CLI::ValidationError(fmt::format("{} must be a number in [{}, {}], got '{}'", name, lo, hi, v));
      set(d);
    });
  };
  text("--address", [&](const std::string& v) { opt.connect.address = v; });
  text("--token", [&](const std::string& v) { opt.connect.token = v; });
  text("--scene", [&](const std::string& v) { opt.scene_id = v; });
  text("--create", [&](const std::string& v) { opt.create_builtin = v; });
  number("--tick-hz", 1, 10000, [&](double d) { opt.create_tick_hz = d; });
  number("--young", 1, 1e12, [&](double d) { opt.create_young = d; });
  number("--poisson", -0.99, 0.499, [&](double d) { opt.create_poisson = d; });
  text("--clamp", [&](const std::string& s) {
    if (s == "bottom") opt.create_clamp = BridgeOptions::Clamp::Bottom;
    else if (s == "end") opt.create_clamp = BridgeOptions::Clamp::End;
    else throw CLI::ValidationError("--clamp must be bottom or end, got '" + s + "'");
  });
  text("--method", [&](const std::string& v) {
    const auto m = pliant::parse_method(v);
    if (!m) throw CLI::ValidationError(fmt::format("--method must be one of {}, got '{}'", pliant::method_names(), v));
    opt.create_method = pliant::proto::method_to(*m);
  });
  number("--substeps", 1, 10000, [&](double d) { opt.create_substeps = static_cast<int>(d); });
  number("--iterations", 1, 10000, [&](double d) { opt.create_iterations = static_cast<int>(d); });
  number("--rate", 10, 10000, [&](double d) { opt.loop_hz = d; });
  text("--script", [&](const std::string& s) {
    if (s == "press") dev.script = SimulatedDevice::Script::Press;
    else if (s == "stroke") dev.script = SimulatedDevice::Script::Stroke;
    else throw CLI::ValidationError("--script must be press or stroke, got '" + s + "'");
  });
  text("--start", [&](const std::string& s) {
    if (!parse_vec(s, &dev.start)) throw CLI::ValidationError("--start must be X,Y,Z, got '" + s + "'");
  });
  number("--surface-y", -1e3, 1e3, [&](double d) { dev.surface_y = d; });
  number("--depth", 0, 1, [&](double d) { dev.depth = d; });
  number("--radius", 1e-5, 1, [&](double d) { dev.radius = opt.tool_radius = d; });
  number("--max-force", 0, 1e4, [&](double d) { opt.limits.max_force = d; });
  number("--max-force-rate", 0, 1e7, [&](double d) { opt.limits.max_force_rate = d; });
  number("--stale-ms", 1, 1e5, [&](double d) { opt.limits.stale_ms = d; });
  number("--extrapolate-ms", 0, 1e4, [&](double d) { opt.limits.extrapolate_ms = d; });
  number("--duration", 0, 1e7, [&](double d) { duration = d; });
  text("--trace", [&](const std::string& v) {
    if (v.empty()) throw CLI::ValidationError("--trace must name a file, got ''");
    opt.trace_path = v;
  });
  app.add_flag("--json", json);
  app.add_flag("--quiet", quiet);
  app.add_flag_callback("--no-realtime", [&] { opt.realtime_priority = false; });
  if (auto rc = pliant::cli::parse_or_exit(app, argc, argv, "pliant-haptic")) return *rc;
  // Logs go to stderr so that stdout holds only the JSON line.
  spdlog::set_default_logger(spdlog::stderr_color_mt("pliant-haptic"));
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);

  auto device = std::make_shared<SimulatedDevice>(dev);
  HapticBridge bridge(opt, device);
  spdlog::info("device {}, loop {} Hz, server {}, scene '{}'", device->name(), opt.loop_hz, opt.connect.address,
               opt.scene_id);
  bridge.start();
  const auto t0 = std::chrono::steady_clock::now();
  auto next_print = t0 + std::chrono::seconds(1);
  bool ever_connected = false;
  while (!g_stop.load()) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    const auto now = std::chrono::steady_clock::now();
    ever_connected |= bridge.connected();
    if (duration > 0 && now - t0 >= std::chrono::duration<double>(duration)) break;
    if (!quiet && now >= next_print) {
      next_print += std::chrono::seconds(1);
      const BridgeStats s = bridge.stats();
      spdlog::info("loop {:.0f} Hz  period p99 {:.0f} us  rtt p50 {:.2f} / p99 {:.2f} / max {:.2f} ms  force {:.3f} N (max {:.3f})  {}",
                   s.loop_hz, s.period_p99_us, s.rtt_p50_ms, s.rtt_p99_ms, s.rtt_max_ms, s.force_n, s.max_force_n,
                   s.connected ? "connected" : "NOT CONNECTED");
    }
  }
  const BridgeStats s = bridge.stats();
  bridge.stop();
  if (json) std::cout << s.to_json() << std::endl;
  return ever_connected ? 0 : 3;
}
