// SPDX-License-Identifier: Apache-2.0
// pliant_service_bench: the service's timing figures.
//  1. Achieved tick rate and tick jitter (lateness of each tick's start against its absolute
//     deadline, p50/p99) for a 1 kHz realtime scene on beam1 and a 60 Hz realtime scene on a
//     50k-tet beam (uploaded as mesh data).
//     Then the 1 kHz scene again with a 60 Hz beam3 scene running beside it.
//  2. Stream latency from the end of a tick (frame publication) to a gRPC client's receipt on
//     loopback, p50/p99, with and without positions.
// Usage: pliant_service_bench [--seconds S] [--threads N] [--small SUBSTEPS,ITERATIONS]
//                             [--big SUBSTEPS,ITERATIONS] [--json]
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"

#include "cli.hpp"
#include "pliant/version.hpp"

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

using namespace pliant;
using Clock = std::chrono::steady_clock;

namespace {

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  size_t i = static_cast<size_t>(std::ceil(p * v.size()));
  return v[std::min(v.size() - 1, i == 0 ? 0 : i - 1)];
}

struct TickFigures {
  std::string name;
  double target_hz = 0;
  uint64_t ticks = 0;
  double seconds = 0;
  double achieved_hz = 0;
  double lateness_p50_ms = 0, lateness_p99_ms = 0, lateness_max_ms = 0;
  uint64_t late_ticks = 0, skipped_ticks = 0;
  double step_ms_p50 = 0;
  std::string settings;
};

v1::CreateSceneRequest scene_request(const std::string& id, double hz, int substeps, int iterations, int threads) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  client::clamp_below_x(*s, 1e-3);
  s->mutable_solver()->set_substeps(substeps);
  s->mutable_solver()->set_iterations(iterations);
  s->mutable_solver()->set_threads(threads);
  s->mutable_tick()->set_dt(1.0 / hz);
  s->mutable_tick()->set_mode(v1::TICK_MODE_REALTIME);
  s->set_start_paused(true);
  return r;
}

// Runs the scene for `seconds` and reads every frame in-process (a reader that keeps up).
TickFigures measure_ticks(server::SceneRegistry& reg, const v1::CreateSceneRequest& req, double seconds) {
  v1::Scene created;
  if (auto e = reg.create(req, &created); !e.ok()) {
    std::fprintf(stderr, "create %s: %s\n", req.scene_id().c_str(), e.message.c_str());
    std::exit(1);
  }
  std::shared_ptr<server::Scene> scene;
  reg.find(req.scene_id(), &scene);
  v1::Scene ignored;
  reg.resume(req.scene_id(), &ignored);
  std::vector<double> lateness, step_ms;
  uint64_t after = 0;
  std::shared_ptr<const server::Frame> first, last;
  const auto start = Clock::now();
  // Warm-up: skip the first 0.2 s (allocation, first touches).
  while (Clock::now() - start < std::chrono::duration<double>(seconds + 0.2)) {
    auto f = scene->wait_frame(after, Clock::now() + std::chrono::milliseconds(200));
    if (!f) continue;
    after = f->seq;
    if (Clock::now() - start < std::chrono::milliseconds(200)) continue;
    if (!first) first = f;
    last = f;
    lateness.push_back(f->lateness_ms);
    step_ms.push_back(f->solver.wall_ms);
  }
  reg.pause(req.scene_id(), &ignored);
  TickFigures t;
  t.name = req.scene_id();
  t.target_hz = 1.0 / req.spec().tick().dt();
  if (first && last && last != first) {
    t.ticks = last->tick - first->tick;
    t.seconds = std::chrono::duration<double>(last->published - first->published).count();
    t.achieved_hz = t.ticks / t.seconds;
    t.late_ticks = last->counters.late_ticks - first->counters.late_ticks;
    t.skipped_ticks = last->counters.skipped_ticks - first->counters.skipped_ticks;
  }
  t.lateness_p50_ms = percentile(lateness, 0.5);
  t.lateness_p99_ms = percentile(lateness, 0.99);
  t.lateness_max_ms = lateness.empty() ? NAN : *std::max_element(lateness.begin(), lateness.end());
  t.step_ms_p50 = percentile(step_ms, 0.5);
  char buf[256];
  std::snprintf(buf, sizeof buf, "%u vertices, %u tets, %d substeps x %d iterations, %d thread(s)",
                created.vertex_count(), created.tet_count(), req.spec().solver().substeps(),
                req.spec().solver().iterations(), created.spec().solver().threads());
  t.settings = buf;
  reg.remove(req.scene_id());
  return t;
}

struct LatencyFigures {
  std::string name;
  uint64_t frames = 0, skipped = 0;
  double p50_us = 0, p99_us = 0;
};

LatencyFigures measure_latency(client::Client& c, const std::string& id, bool positions, double seconds) {
  v1::StreamFramesRequest q;
  q.set_scene_id(id);
  if (!positions) q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  std::vector<double> us;
  uint64_t skipped = 0;
  const auto start = Clock::now();
  auto stream = c.stream_frames(q);
  v1::Frame f;
  bool first = true;
  while (Clock::now() - start < std::chrono::duration<double>(seconds) && stream->next(&f)) {
    const int64_t now = std::chrono::duration_cast<std::chrono::nanoseconds>(
                            std::chrono::system_clock::now().time_since_epoch())
                            .count();
    if (first) {  // the first frame is the latest at subscription time, not a fresh one
      first = false;
      continue;
    }
    us.push_back((now - f.published_unix_ns()) / 1000.0);
    skipped += f.skipped_frames();
  }
  stream->cancel();
  stream->finish();
  LatencyFigures l;
  l.name = positions ? "all fields (positions, residuals, stats)" : "header + solver stats only";
  l.frames = us.size();
  l.skipped = skipped;
  l.p50_us = percentile(us, 0.5);
  l.p99_us = percentile(us, 0.99);
  return l;
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 5;
  int threads = 1;
  bool json = false;
  int small_sub = 1, small_it = 4, big_sub = 1, big_it = 4;
  CLI::App app{"pliant_service_bench: tick rate, lateness and stream latency of an in-process server"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.add_option("--seconds", seconds, "seconds per measurement (default 5)")->check(CLI::Range(0.1, 3600.0));
  app.add_option("--threads", threads, "solver threads per scene (default 1)")->check(CLI::Range(1, 256));
  app.add_option_function<std::string>(
      "--small", [&](const std::string& v) { cli::parse_int_pair("--small", v, 1, &small_sub, &small_it); },
      "SUBSTEPS,ITERATIONS of the small scene (default 1,4)");
  app.add_option_function<std::string>(
      "--big", [&](const std::string& v) { cli::parse_int_pair("--big", v, 1, &big_sub, &big_it); },
      "SUBSTEPS,ITERATIONS of the big scene (default 1,4)");
  app.add_flag("--json", json, "one JSON line per figure");
  if (auto rc = cli::parse_or_exit(app, argc, argv, "pliant_service_bench")) return *rc;
  spdlog::set_level(spdlog::level::warn);

  server::ServerOptions so;
  so.listen = "127.0.0.1:0";
  so.threads = std::max(1, threads);
  server::PliantServer srv(so);
  if (auto e = srv.start(); !e.ok()) {
    std::fprintf(stderr, "%s\n", e.message.c_str());
    return 1;
  }
  auto& reg = srv.registry();

  std::vector<TickFigures> ticks;
  {
    auto r = scene_request("beam1-1kHz", 1000, small_sub, small_it, threads);
    r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
    ticks.push_back(measure_ticks(reg, r, seconds));
  }
  {
    auto r = scene_request("beam50k-60Hz", 60, big_sub, big_it, threads);
    TetMesh big = make_beam(51, 21, 11, 0.005);  // 50 x 20 x 10 cubes x 5 = 50,000 tets
    auto* d = r.mutable_spec()->mutable_mesh()->mutable_data();
    d->set_name("beam-50k");
    for (const auto& p : big.vertices)
      for (int k = 0; k < 3; ++k) d->add_positions(p[k]);
    for (const auto& t : big.tets)
      for (int k = 0; k < 4; ++k) d->add_tets(t[k]);
    ticks.push_back(measure_ticks(reg, r, seconds));
  }

  // Side by side: the 1 kHz beam1 scene again while a 60 Hz beam3 scene runs beside it.
  {
    auto bg = scene_request("beam3-60Hz-beside", 60, 2, 4, 1);
    bg.mutable_spec()->mutable_mesh()->set_builtin("beam3");
    bg.mutable_spec()->set_start_paused(false);
    v1::Scene s;
    if (auto e = reg.create(bg, &s); !e.ok()) {
      std::fprintf(stderr, "%s\n", e.message.c_str());
      return 1;
    }
    auto r = scene_request("beam1-1kHz-beside", 1000, small_sub, small_it, threads);
    r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
    ticks.push_back(measure_ticks(reg, r, seconds));
    v1::Scene beside;
    reg.get(bg.scene_id(), &beside);
    ticks.back().settings += "; beside it beam3 at 60 Hz (2 x 4) ran " + std::to_string(beside.tick()) +
                             " ticks, " + std::to_string(beside.late_ticks()) + " late";
    reg.remove(bg.scene_id());
  }

  // Stream latency: a 200 Hz beam1 scene, one gRPC subscriber on loopback.
  std::vector<LatencyFigures> latency;
  {
    auto r = scene_request("latency", 200, 2, 4, 1);
    r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
    r.mutable_spec()->set_start_paused(false);
    v1::Scene s;
    if (auto e = reg.create(r, &s); !e.ok()) {
      std::fprintf(stderr, "%s\n", e.message.c_str());
      return 1;
    }
    client::ConnectOptions co;
    co.address = "127.0.0.1:" + std::to_string(srv.port());
    client::Client c(co);
    latency.push_back(measure_latency(c, "latency", true, seconds));
    latency.push_back(measure_latency(c, "latency", false, seconds));
  }
  srv.shutdown();

  if (json) {
    // One JSON line per figure (nlohmann-json: strict JSON, NaN as null).
    for (auto& t : ticks) {
      nlohmann::ordered_json j;
      j["bench"] = "tick";
      j["scene"] = t.name;
      j["target_hz"] = t.target_hz;
      j["achieved_hz"] = t.achieved_hz;
      j["ticks"] = t.ticks;
      j["lateness_p50_ms"] = t.lateness_p50_ms;
      j["lateness_p99_ms"] = t.lateness_p99_ms;
      j["lateness_max_ms"] = t.lateness_max_ms;
      j["late_ticks"] = t.late_ticks;
      j["skipped_ticks"] = t.skipped_ticks;
      j["step_ms_p50"] = t.step_ms_p50;
      j["settings"] = t.settings;
      std::printf("%s\n", j.dump().c_str());
    }
    for (auto& l : latency) {
      nlohmann::ordered_json j;
      j["bench"] = "stream_latency";
      j["fields"] = l.name;
      j["frames"] = l.frames;
      j["skipped"] = l.skipped;
      j["p50_us"] = l.p50_us;
      j["p99_us"] = l.p99_us;
      std::printf("%s\n", j.dump().c_str());
    }
    return 0;
  }
  std::printf("Tick rate and jitter (%.0f s each, realtime mode, lateness = tick start - deadline)\n", seconds);
  for (auto& t : ticks) {
    std::printf("  %-16s target %7.1f Hz  achieved %8.2f Hz  lateness p50 %.3f ms  p99 %.3f ms  max %.3f ms\n",
                t.name.c_str(), t.target_hz, t.achieved_hz, t.lateness_p50_ms, t.lateness_p99_ms, t.lateness_max_ms);
    std::printf("  %-16s late ticks %llu, skipped deadlines %llu, step p50 %.3f ms; %s\n", "",
                static_cast<unsigned long long>(t.late_ticks), static_cast<unsigned long long>(t.skipped_ticks),
                t.step_ms_p50, t.settings.c_str());
  }
  std::printf("Stream latency, end of tick -> client receipt, loopback gRPC, 200 Hz beam1 scene\n");
  for (auto& l : latency)
    std::printf("  %-42s p50 %7.1f us  p99 %7.1f us  (%llu frames, %llu skipped)\n", l.name.c_str(), l.p50_us,
                l.p99_us, static_cast<unsigned long long>(l.frames), static_cast<unsigned long long>(l.skipped));
  return 0;
}
