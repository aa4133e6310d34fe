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
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/haptic.hpp"
#include "pliant/model.hpp"
#include "pliant/state.hpp"
#include "pliant/stepper.hpp"

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
  bool diverged = false;
};

Outcome press(const std::shared_ptr<const BodyModel>& model, const Budget& b, double hz, double seconds) {
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
    const double t = k / hz;
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

int usage() {
  std::fprintf(stderr,
               "usage: pliant_haptic_fidelity [--young E1,E2,...] [--poisson NU] [--budgets 4x2,8x1,newton:1x2,...] "
               "[--reference SxI] [--seconds S] [--clamp bottom|end] [--support-inertia K]\n");
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  const haptic::BridgeOptions defaults;
  std::vector<double> youngs{3e4, defaults.create_young, 3e5, 1e6, 5e6, 5e7};
  double poisson = defaults.create_poisson;
  std::vector<Budget> budgets{{defaults.create_substeps, defaults.create_iterations}, {8, 1}, {16, 1}};
  Budget reference{512, 1};
  double seconds = 3;
  double support_inertia = 0;
  std::string clamp = defaults.create_clamp == haptic::BridgeOptions::Clamp::End ? "end" : "bottom";
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) return usage();
    const std::string v = argv[++i];
    if (a == "--young") {
      youngs.clear();
      for (const auto& e : split(v)) youngs.push_back(std::atof(e.c_str()));
    } else if (a == "--poisson") poisson = std::atof(v.c_str());
    else if (a == "--budgets") {
      budgets.clear();
      for (const auto& e : split(v)) {
        Budget b;
        if (!parse_budget(e, &b)) return usage();
        budgets.push_back(b);
      }
    } else if (a == "--reference") {
      if (!parse_budget(v, &reference)) return usage();
    } else if (a == "--seconds") seconds = std::atof(v.c_str());
    else if (a == "--clamp") clamp = v;
    else if (a == "--support-inertia") support_inertia = std::atof(v.c_str());
    else return usage();
  }
  if (seconds < 0.75) seconds = 0.75;
  const TetMesh mesh = *builtin_mesh(defaults.create_builtin.empty() ? "beam1" : defaults.create_builtin);
  FixedSelection fixed;
  // As haptic::scene_request: the bottom face (y <= 1 mm) or the end x <= 1 mm fixed.
  if (clamp == "bottom") fixed.boxes.push_back({Vec3(-1e9, -1e9, -1e9), Vec3(1e9, 1e-3, 1e9)});
  else if (clamp == "end") fixed.boxes.push_back({Vec3(-1e9, -1e9, -1e9), Vec3(1e-3, 1e9, 1e9)});
  else return usage();
  const double hz = defaults.create_tick_hz;
  std::printf("scene: %s, %s fixed, nu = %g, %g Hz ticks, sphere r = 5 mm pressed 3 mm over the tip, "
              "%g s; bridge default budget %d x %d; support inertia %g\n",
              mesh.name.c_str(), clamp == "end" ? "x <= 1 mm" : "bottom face y <= 1 mm", poisson, hz, seconds, defaults.create_substeps, defaults.create_iterations, support_inertia);
  std::printf("| E | substeps x iterations | force at rest | reference (%s) | error | tick ms mean / p99 |\n",
              reference.name().c_str());
  std::printf("|---|---|---|---|---|---|\n");
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
    std::printf("| %g Pa | reference check: %s | %.4g N | %.4g N | %+.1f%% | - |\n", e, half.name().c_str(),
                ref_half.force, ref.force, 100 * (ref_half.force - ref.force) / ref.force);
    for (const Budget& b : budgets) {
      const Outcome o = press(model, b, hz, seconds);
      if (o.diverged) {
        std::printf("| %g Pa | %s | diverged | %.4g N | - | - |\n", e, b.name().c_str(), ref.force);
        continue;
      }
      std::printf("| %g Pa | %s | %.4g N (drift %.1f%%) | %.4g N (drift %.1f%%) | %+.1f%% | %.3f / %.3f |\n", e,
                  b.name().c_str(), o.force, 100 * o.drift, ref.force, 100 * ref.drift,
                  100 * (o.force - ref.force) / ref.force, o.tick_ms, o.tick_p99_ms);
      std::fflush(stdout);
    }
  }
  return 0;
}
