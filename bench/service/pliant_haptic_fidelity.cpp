// SPDX-License-Identifier: Apache-2.0
// pliant_haptic_fidelity: is the force the bridge's default scene feels the force of the model?
// Steps the scene `pliant-haptic` creates (beam1 with its bottom face fixed, or its end with
// --clamp end; gravity off, damping 20/s, 1 kHz ticks, the bridge's nu unless given) with the press the
// bridge's script makes (sphere r = 5 mm over the tip at x = 0.1 m, lowered 3 mm into the top
// face over 0.5 s with the server's swept-tool velocity, then held), and compares the force on
// the tool at rest (mean over the last 0.25 s of `--seconds`) at each solver budget with the
// same scene at a reference budget of many small substeps (converged: the two finest budgets
// are printed side by side). Also the wall time per 1 ms tick of each budget on this machine
// (1 thread, the server's default), so the budget that fits the tick can be chosen.
//
// Usage: pliant_haptic_fidelity [--young E1,E2,...] [--poisson NU] [--budgets 4x2,8x1,newton:1x2,...]
//                               [--reference SxI] [--seconds S] [--clamp bottom|end]
//                               [--support-inertia K]   (Material::support_inertia, default 0)
//                               [--pose-every K]   (the tool jumps K ticks of motion at once, default 1)
//                               [--json]   (one JSON line per row instead of the table)
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/haptic.hpp"
#include "pliant/model.hpp"
#include "pliant/proto/enums.hpp"
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
#include <sstream>
#include <string>
#include <vector>

using namespace pliant;

namespace {

struct Budget {
  int substeps = 1, iterations = 1;
  Method method = Method::Xpbd;
  std::string name() const {
    const std::string size = std::to_string(substeps) + " x " + std::to_string(iterations);
    return method == Method::Xpbd ? size : std::string(to_string(method)) + " " + size;
  }
};

struct Outcome {
  double force = 0;       // |F| on the tool at rest, N (mean over the last 0.25 s)
  double drift = 0;       // relative change of that mean between the last two 0.25 s windows
  double tick_ms = 0;     // mean wall time of a tick
  double tick_p99_ms = 0;
  double peak = 0;        // the largest |F| during the whole press, N (what a hand feels as a jolt)
  double lift_peak = 0;   // the largest |F| while the tool is lifted out again (0.5 s), N
  bool diverged = false;
};

// pose_every > 1: the tool's pose reaches the step only every pose_every ticks (a late or
// lossy device link), so the tool jumps that many ticks of motion at once.
Outcome press(const std::shared_ptr<const BodyModel>& model, const Budget& b, double hz, double seconds,
              int pose_every = 1) {
  SolverSettings s;
  s.dt = 1.0 / hz;
  s.substeps = b.substeps;
  s.iterations = b.iterations;
  s.method = b.method;
  s.damping_coefficient = 20;
  s.gravity = Eigen::Vector3d::Zero();
  BodyState st = rest_state(*model);
  Stepper stepper;
  const haptic::SimulatedDevice::Params dev;  // the bridge's press: over the tip, 3 mm deep
  const double top = dev.surface_y + dev.radius;  // centre height when the sphere touches
  const double lowered = top - dev.depth;
  const int ticks = static_cast<int>(std::lround(seconds * hz));
  const int window = static_cast<int>(std::lround(0.25 * hz));
  std::vector<double> forces, walls;
  forces.reserve(ticks);
  walls.reserve(ticks);
  Eigen::Vector3d previous(dev.start.x(), top, dev.start.z());
  Outcome out;
  for (int k = 1; k <= ticks; ++k) {
    const double t = (k - k % pose_every) / hz;
    const double u = std::min(t / 0.5, 1.0);
    const double y = top - (top - lowered) * 0.5 * (1 - std::cos(M_PI * u));
    StepInputs in;
    RigidTool tool = RigidTool::sphere(Eigen::Vector3d(dev.start.x(), y, dev.start.z()), dev.radius);
    tool.velocity = (tool.position - previous) * hz;  // as the server sweeps a posed tool
    previous = tool.position;
    in.tools.push_back(tool);
    const auto t0 = std::chrono::steady_clock::now();
    StepReport r = stepper.step(*model, st, s, in);
    walls.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    if (r.diverged) {
      out.diverged = true;
      return out;
    }
    forces.push_back(r.tools[0].force.norm());
    out.peak = std::max(out.peak, forces.back());
  }
  // Then the tool is lifted back to where it started (the same cosine ramp): the body springs
  // back after it; the force should fall to zero without a spike.
  for (int k = 1; k <= window * 2; ++k) {
    const double t = (k - k % pose_every) / hz;
    const double u = std::min(t / 0.5, 1.0);
    const double y = lowered + (top - lowered) * 0.5 * (1 - std::cos(M_PI * u));
    StepInputs in;
    RigidTool tool = RigidTool::sphere(Eigen::Vector3d(dev.start.x(), y, dev.start.z()), dev.radius);
    tool.velocity = (tool.position - previous) * hz;
    previous = tool.position;
    in.tools.push_back(tool);
    StepReport r = stepper.step(*model, st, s, in);
    if (r.diverged) {
      out.diverged = true;
      return out;
    }
    out.lift_peak = std::max(out.lift_peak, r.tools[0].force.norm());
  }
  auto mean = [&](size_t b0, size_t e0) {
    double sum = 0;
    for (size_t i = b0; i < e0; ++i) sum += forces[i];
    return sum / double(e0 - b0);
  };
  const size_t n = forces.size();
  out.force = mean(n - window, n);
  const double before = mean(n - 2 * window, n - window);
  out.drift = out.force > 0 ? std::abs(out.force - before) / out.force : 0;
  double sum = 0;
  for (double w : walls) sum += w;
  out.tick_ms = sum / double(walls.size());
  std::sort(walls.begin(), walls.end());
  out.tick_p99_ms = walls[std::min(walls.size() - 1, size_t(0.99 * double(walls.size())))];
  return out;
}

// "SxI" (the projection family's plain XPBD) or "METHOD:SxI" (any method but auto).
bool parse_budget(const std::string& s, Budget* b) {
  std::string size = s;
  if (const auto colon = s.find(':'); colon != std::string::npos) {
    const auto m = parse_method(s.substr(0, colon));
    if (!m || *m == Method::Auto) return false;
    b->method = *m;
    size = s.substr(colon + 1);
  }
  return std::sscanf(size.c_str(), "%dx%d", &b->substeps, &b->iterations) == 2 && b->substeps > 0 && b->iterations > 0;
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');) out.push_back(item);
  return out;
}

// "E1,E2,..": positive numbers; throws CLI::ValidationError naming the flag and the value.
std::vector<double> parse_youngs(const std::string& text) {
  std::vector<double> out;
  for (const auto& e : split(text)) {
    double v = 0;
    try {
      v = pliant::cli::parse_number("young", e);
    } catch (const std::exception&) {
      v = -1;
    }
    if (!(v > 0)) throw CLI::ValidationError("--young must be positive numbers E1,E2,..., got '" + text + "'");
    out.push_back(v);
  }
  if (out.empty()) throw CLI::ValidationError("--young needs at least one value, got '" + text + "'");
  return out;
}

std::vector<Budget> parse_budgets(const std::string& text) {
  std::vector<Budget> out;
  for (const auto& e : split(text)) {
    Budget b;
    if (!parse_budget(e, &b))
      throw CLI::ValidationError("--budgets: '" + e + "' is not SxI or METHOD:SxI (in '" + text + "')");
    out.push_back(b);
  }
  if (out.empty()) throw CLI::ValidationError("--budgets needs at least one budget, got '" + text + "'");
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const haptic::BridgeOptions defaults;
  std::vector<double> youngs{3e4, defaults.create_young, 3e5, 1e6, 5e6, 5e7};
  double poisson = defaults.create_poisson;
  const Budget bridge_default{defaults.create_substeps, defaults.create_iterations,
                              pliant::proto::method_from(defaults.create_method).value_or(Method::Xpbd)};
  std::vector<Budget> budgets{bridge_default, {8, 1}, {16, 1}};
  Budget reference{512, 1};
  double seconds = 3;
  double support_inertia = 0;
  std::string clamp = defaults.create_clamp == haptic::BridgeOptions::Clamp::End ? "end" : "bottom";
  bool json = false;
  int pose_every = 1;
  CLI::App app{"pliant_haptic_fidelity: the force the bridge's default scene feels against the converged force",
               "pliant_haptic_fidelity"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.add_option_function<std::string>("--young", [&](const std::string& v) { youngs = parse_youngs(v); },
                                       "Young's moduli E1,E2,... in Pa");
  app.add_option("--poisson", poisson, "Poisson's ratio")->check(CLI::Range(0.0, 0.499));
  app.add_option_function<std::string>("--budgets", [&](const std::string& v) { budgets = parse_budgets(v); },
                                       "budgets SxI or METHOD:SxI, comma separated (default: the bridge's, 8x1, 16x1)");
  app.add_option_function<std::string>(
      "--reference",
      [&](const std::string& v) {
        if (!parse_budget(v, &reference)) throw CLI::ValidationError("--reference must be SxI or METHOD:SxI, got '" + v + "'");
      },
      "the converged budget (default 512x1)");
  app.add_option("--seconds", seconds, "seconds per run, at least 0.75 (default 3)")->check(CLI::Range(0.75, 3600.0));
  app.add_option("--clamp", clamp, "bottom (the bridge's default) | end")->check(pliant::cli::one_of({"bottom", "end"}));
  app.add_option("--support-inertia", support_inertia, "Material::support_inertia (default 0)")
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--pose-every", pose_every,
                 "the tool's pose reaches the budgets' steps every K ticks: the tool jumps K ticks of motion at once, "
                 "as after late or skipped ticks (default 1)")
      ->check(CLI::Range(1, 1000));
  app.add_flag("--json", json, "one JSON line per row instead of the table");
  if (auto rc = pliant::cli::parse_or_exit(app, argc, argv, "pliant_haptic_fidelity")) return *rc;
  const TetMesh mesh = *builtin_mesh(defaults.create_builtin.empty() ? "beam1" : defaults.create_builtin);
  FixedSelection fixed;
  // As haptic::scene_request: the bottom face (y <= 1 mm) or the end x <= 1 mm fixed.
  if (clamp == "bottom") fixed.boxes.push_back({Vec3(-1e9, -1e9, -1e9), Vec3(1e9, 1e-3, 1e9)});
  else fixed.boxes.push_back({Vec3(-1e9, -1e9, -1e9), Vec3(1e-3, 1e9, 1e9)});
  const double hz = defaults.create_tick_hz;
  // --json: one line per row, each with the scene's settings, so that a line stands alone.
  auto row = [&](double e, const std::string& budget, const char* kind) {
    return nlohmann::ordered_json{{"mesh", mesh.name},   {"clamp", clamp},   {"poisson", poisson},
                                  {"tick_hz", hz},       {"seconds", seconds}, {"support_inertia", support_inertia},
                                  {"young", e},          {"row", kind},      {"budget", budget},
                                  {"reference", reference.name()}};
  };
  if (!json) {
  std::printf("scene: %s, %s fixed, nu = %g, %g Hz ticks, sphere r = 5 mm pressed 3 mm over the tip, "
              "%g s; bridge default budget %s; support inertia %g\n",
              mesh.name.c_str(), clamp == "end" ? "x <= 1 mm" : "bottom face y <= 1 mm", poisson, hz, seconds, bridge_default.name().c_str(), support_inertia);
  std::printf("| E | substeps x iterations | force at rest | reference (%s) | error | peak during the press | peak while lifting | tick ms mean / p99 |\n",
              reference.name().c_str());
  std::printf("|---|---|---|---|---|---|---|---|\n");
  }
  for (double e : youngs) {
    Material mat;
    mat.young = e;
    mat.poisson = poisson;
    mat.support_inertia = support_inertia;
    auto model = build_model(mesh, mat, fixed);
    const Outcome ref = press(model, reference, hz, seconds);
    // Is the reference converged? The same scene at half its substeps.
    const Budget half{std::max(1, reference.substeps / 2), reference.iterations};
    const Outcome ref_half = press(model, half, hz, seconds);
    if (json) {
      auto j = row(e, half.name(), "reference_check");
      j["force_n"] = ref_half.force;
      j["reference_force_n"] = ref.force;
      j["error"] = (ref_half.force - ref.force) / ref.force;
      std::printf("%s\n", pliant::cli::json_line(j).c_str());
    } else {
      std::printf("| %g Pa | reference check: %s | %.4g N | %.4g N | %+.1f%% | %.4g N | %.4g N | - |\n", e,
                  half.name().c_str(), ref_half.force, ref.force, 100 * (ref_half.force - ref.force) / ref.force,
                  ref_half.peak, ref_half.lift_peak);
    }
    for (const Budget& b : budgets) {
      const Outcome o = press(model, b, hz, seconds, pose_every);
      if (json) {
        auto j = row(e, b.name(), "budget");
        j["diverged"] = o.diverged;
        j["force_n"] = o.diverged ? nlohmann::ordered_json() : nlohmann::ordered_json(o.force);
        j["drift"] = o.diverged ? nlohmann::ordered_json() : nlohmann::ordered_json(o.drift);
        j["reference_force_n"] = ref.force;
        j["reference_drift"] = ref.drift;
        j["error"] = o.diverged ? nlohmann::ordered_json() : nlohmann::ordered_json((o.force - ref.force) / ref.force);
        j["peak_force_n"] = o.diverged ? nlohmann::ordered_json() : nlohmann::ordered_json(o.peak);
        j["lift_peak_force_n"] = o.diverged ? nlohmann::ordered_json() : nlohmann::ordered_json(o.lift_peak);
        j["pose_every"] = pose_every;
        j["tick_ms_mean"] = o.tick_ms;
        j["tick_ms_p99"] = o.tick_p99_ms;
        std::printf("%s\n", pliant::cli::json_line(j).c_str());
        std::fflush(stdout);
        continue;
      }
      if (o.diverged) {
        std::printf("| %g Pa | %s | diverged | %.4g N | - | - | - | - |\n", e, b.name().c_str(), ref.force);
        continue;
      }
      std::printf("| %g Pa | %s | %.4g N (drift %.1f%%) | %.4g N (drift %.1f%%) | %+.1f%% | %.4g N | %.4g N | %.3f / %.3f |\n",
                  e, b.name().c_str(), o.force, 100 * o.drift, ref.force, 100 * ref.drift,
                  100 * (o.force - ref.force) / ref.force, o.peak, o.lift_peak, o.tick_ms, o.tick_p99_ms);
      std::fflush(stdout);
    }
  }
  return 0;
}
