// SPDX-License-Identifier: Apache-2.0
// pliant_tick_profile: where the time of one server tick goes on a large mesh. Steps the 50k-tet
// beam of pliant_haptic_bench (0.25 x 0.1 x 0.05 m, E = 50 MPa, x <= 1 mm fixed, gravity off,
// damping 20/s, dt = 1/60 s, 1 substep x 1 iteration by default) with a sphere (r = 1 cm) lowered
// 4 mm into its top over 0.5 s and held (the bench's press), as the server's tick does (Stepper::step with the scene's settings), and prints the
// mean wall time per tick split as the solver reports it (projection sweep, residual passes,
// "other": prediction, tool contacts, inversion-floor passes, velocity update, damping), for
// solver variants that isolate each part (residuals off, inversion floor off, 2 threads), plus
// the server's own per-tick work outside the solver (the rollback copy of the state, the
// finiteness check, the frame's float positions). --time-budget gives every variant the
// solver's time budget per tick (iterations and the floor's later passes stop when it is spent).
//
// Usage: pliant_tick_profile [--ticks N] [--substeps S] [--iterations I] [--young E] [--gravity] [--mu MU]
//                            [--time-budget MS] [--method M] [--json]   (one JSON line per variant and one for the
//                            server's work; --method: the solver family or method of every variant, default xpbd)
// (--young 1e6 --gravity --iterations 4: the 50k scene of pliant_service_bench, which sags under
// its weight.)
#include "pliant/builtin_meshes.hpp"
#include "pliant/model.hpp"
#include "pliant/settings.hpp"
#include "pliant/state.hpp"
#include "pliant/stepper.hpp"
#include "pliant/version.hpp"

#include "cli.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

using namespace pliant;
using Clock = std::chrono::steady_clock;

namespace {

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

struct Variant {
  const char* name;
  bool residuals;
  double floor;
  int threads;
  bool tool = true;
};

}  // namespace

int main(int argc, char** argv) {
  int ticks = 60, substeps = 1, iterations = 1;
  double young = 5e7;
  bool gravity = false;
  double budget_ms = 0;  // --time-budget: SolverSettings::time_budget_ms of every variant
  double mu = -1;  // --mu: the sphere's static and dynamic friction (default: RigidTool's)
  bool json = false;
  std::string method_name = "xpbd";
  CLI::App app{"pliant_tick_profile: where the time of one server tick goes on the 50k-tet beam", "pliant_tick_profile"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.add_option("--ticks", ticks, "measured ticks per variant, after 30 (default 60)")->check(CLI::Range(1, 100000));
  app.add_option("--substeps", substeps, "substeps per tick (default 1)")->check(CLI::Range(1, 100000));
  app.add_option("--iterations", iterations, "iterations per substep (default 1)")->check(CLI::Range(1, 100000));
  app.add_option("--young", young, "Young's modulus, Pa (default 5e7)")->check(CLI::Range(1.0, 1e12));
  app.add_flag("--gravity", gravity, "-9.81 m/s^2 and the server's default damping (0.5/s), no tool");
  app.add_option("--mu", mu, "the sphere's static and dynamic friction (default: RigidTool's)")->check(CLI::Range(0.0, 10.0));
  app.add_option("--time-budget", budget_ms, "each variant's solver time budget per tick, ms (default 0: none)")
      ->check(CLI::Range(0.0, 1e6));
  app.add_option("--method", method_name, "every variant's method: " + std::string(method_names()) + " (default xpbd)");
  app.add_flag("--json", json, "one JSON line per variant and one for the server's work, instead of the table");
  if (auto rc = pliant::cli::parse_or_exit(app, argc, argv, "pliant_tick_profile")) return *rc;
  const std::optional<Method> method = parse_method(method_name);
  if (!method) {
    std::fprintf(stderr, "pliant_tick_profile: --method %s is not one of %s\n", method_name.c_str(),
                 std::string(method_names()).c_str());
    return 2;
  }
  const TetMesh mesh = make_beam(51, 21, 11, 0.005);
  Material mat;
  mat.young = young;
  FixedSelection fixed;
  fixed.boxes.push_back({Vec3(-1e9, -1e9, -1e9), Vec3(1e-3, 1e9, 1e9)});
  auto model = build_model(mesh, mat, fixed);
  const char* scene = gravity ? "gravity, damping 0.5/s, no tool" : "no gravity, damping 20/s, sphere pressed 4 mm";
  if (!json) {
    std::printf("50k beam: %zu vertices, %zu tets, %zu colours; E %g Pa, %s; method %s, %d substep(s) x %d iteration(s), "
                "%d ticks per variant after 30\n",
                model->vertex_count(), model->tet_count(), model->colours.size(), young, scene, method_name.c_str(),
                substeps, iterations, ticks);
    std::printf("| variant | tick ms | projection | residual | other | update | iterations / tick | volume corrections / tick | "
                "ticks with the floor cut by the budget | tets with det F < 0.2 / <= 0 / min det F at the end |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
  }
  const Variant variants[] = {
      {"server default (residuals on, floor 0.2, 1 thread)", true, 0.2, 1},
      {"residuals off", false, 0.2, 1},
      {"inversion floor off", true, 0.0, 1},
      {"residuals off, floor off", false, 0.0, 1},
      {"2 threads (residuals on, floor 0.2)", true, 0.2, 2},
      {"2 threads, residuals off, floor off", false, 0.0, 2},
      {"no tool: server default", true, 0.2, 1, false},
      {"no tool: 2 threads, residuals off, floor off", false, 0.0, 2, false},
  };
  for (const Variant& var : variants) {
    SolverSettings s;
    s.method = *method;
    s.dt = 1.0 / 60;
    s.substeps = substeps;
    s.iterations = iterations;
    if (!gravity) {
      s.damping_coefficient = 20;
      s.gravity = Eigen::Vector3d::Zero();
    }
    s.record_residuals = var.residuals;
    s.inversion_floor = var.floor;
    s.threads = var.threads;
    s.time_budget_ms = budget_ms;
    BodyState st = rest_state(*model);
    Stepper stepper;
    StepInputs in;
    // The sphere of pliant_haptic_bench's device (r = 1 cm at x = 0.2), lowered over the
    // first 30 ticks (0.5 s) to 4 mm below the top face (y = 0.1) and held, as its press does.
    RigidTool sphere = RigidTool::sphere(Eigen::Vector3d(0.2, 0.11, 0.025), 0.01);
    if (mu >= 0) sphere.static_friction = sphere.dynamic_friction = mu;
    PhaseTimes sum;
    double wall = 0, corrections = 0, iterations_done = 0, floor_passes = 0, floor_scans = 0;
    int floor_cut = 0;  // ticks whose later floor passes the budget cut
    const int warmup = 30;  // the press reaches its depth
    for (int k = 0; k < warmup + ticks; ++k) {
      in.tools.clear();
      if (var.tool && !gravity) {
        const double u = std::min(1.0, (k + 1) / 30.0);
        const double y = 0.11 - 0.004 * 0.5 * (1 - std::cos(M_PI * u));
        sphere.velocity = Eigen::Vector3d(0, y - sphere.position.y(), 0) / s.dt;
        sphere.position.y() = y;
        in.tools.push_back(sphere);
      }
      const auto t0 = Clock::now();
      StepReport r = stepper.step(*model, st, s, in);
      const double w = ms_since(t0);
      if (k < warmup) continue;
      wall += w;
      sum.projection_ms += r.times.projection_ms;
      sum.residual_ms += r.times.residual_ms;
      sum.other_ms += r.times.other_ms;
      sum.floor_ms += r.times.floor_ms;
      sum.floor_scan_ms += r.times.floor_scan_ms;
      floor_passes += r.floor_passes;
      floor_scans += r.floor_scan_passes;
      sum.update_ms += r.times.update_ms + r.times.anderson_ms;
      corrections += r.volume_corrections;
      iterations_done += r.iterations;
      floor_cut += r.floor_stopped_by_budget;
    }
    // Volume ratios det F after the last tick: how many tets sit under the floor.
    int under_floor = 0, inverted = 0;
    double min_det = 1e300;
    for (const TetRest& t : model->tets) {
      Mat3 ds;
      for (int c = 0; c < 3; ++c) ds.col(c) = st.x[t.v[c]] - st.x[t.v[3]];
      const double det = (ds * t.dm_inv).determinant();
      min_det = std::min(min_det, det);
      under_floor += det < 0.2;
      inverted += det <= 0;
    }
    if (json) {
      std::printf("%s\n", pliant::cli::json_line({{"variant", var.name},
                                                   {"vertices", model->vertex_count()},
                                                   {"tets", model->tet_count()},
                                                   {"young", young},
                                                   {"scene", scene},
                                                   {"substeps", substeps},
                                                   {"method", method_name},
                                                   {"iterations", iterations},
                                                   {"ticks", ticks},
                                                   {"tick_ms", wall / ticks},
                                                   {"projection_ms", sum.projection_ms / ticks},
                                                   {"residual_ms", sum.residual_ms / ticks},
                                                   {"other_ms", sum.other_ms / ticks},
                                                   {"floor_ms", sum.floor_ms / ticks},
                                                   {"floor_passes_per_tick", floor_passes / ticks},
                                                   {"floor_scan_passes_per_tick", floor_scans / ticks},
                                                   {"floor_scan_ms", sum.floor_scan_ms / ticks},
                                                   {"update_ms", sum.update_ms / ticks},
                                                   {"volume_corrections_per_tick", corrections / ticks},
                                                   {"time_budget_ms", budget_ms},
                                                   {"iterations_per_tick", iterations_done / ticks},
                                                   {"ticks_floor_cut_by_budget", floor_cut},
                                                   {"tets_below_floor", under_floor},
                                                   {"tets_inverted", inverted},
                                                   {"min_det_f", min_det}})
                                 .c_str());
    } else {
      std::printf("| %s | %.2f | %.2f | %.2f | %.2f | %.2f | %.1f | %.0f | %d | %d / %d / %.3f |\n", var.name, wall / ticks,
                  sum.projection_ms / ticks, sum.residual_ms / ticks, sum.other_ms / ticks, sum.update_ms / ticks,
                  iterations_done / ticks, corrections / ticks, floor_cut, under_floor, inverted, min_det);
    }
    std::fflush(stdout);
  }

  // The server's own work per tick (Scene::tick_once), outside Stepper::step.
  BodyState st = rest_state(*model), last_good;
  double copy_ms = 0, finite_ms = 0, frame_ms = 0;
  std::vector<float> positions;
  for (int k = 0; k < ticks; ++k) {
    auto t0 = Clock::now();
    last_good = st;
    copy_ms += ms_since(t0);
    t0 = Clock::now();
    volatile bool ok = is_finite(st);
    (void)ok;
    finite_ms += ms_since(t0);
    t0 = Clock::now();
    positions.resize(st.x.size() * 3);
    for (size_t i = 0; i < st.x.size(); ++i)
      for (int c = 0; c < 3; ++c) positions[3 * i + c] = static_cast<float>(st.x[i][c]);
    frame_ms += ms_since(t0);
  }
  if (json)
    std::printf("%s\n", pliant::cli::json_line({{"server_work", true},
                                                 {"rollback_copy_ms", copy_ms / ticks},
                                                 {"finiteness_check_ms", finite_ms / ticks},
                                                 {"frame_positions_ms", frame_ms / ticks}})
                               .c_str());
  else
    std::printf("server work outside the solver per tick: rollback copy of x, v, lambda %.3f ms; finiteness check "
                "%.3f ms; frame positions %.3f ms\n",
                copy_ms / ticks, finite_ms / ticks, frame_ms / ticks);
  return 0;
}
