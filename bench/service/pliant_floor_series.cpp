// SPDX-License-Identifier: Apache-2.0
// pliant_floor_series: the inversion floor's robustness and cost on the service's armadillo scene
// (feet fixed below y = -0.040, E 1 MPa, nu 0.4, rho 1000, gravity, a floor plane under the feet,
// 1/60 s ticks, 1 substep x I iterations, one thread): steps it N ticks from rest and prints one
// line per tick (tick, inverted tets, floor corrections, CPU ms of the step) and a summary JSON
// line (over the ticks from --from: mean and last inverted tets, mean corrections, mean CPU ms per
// tick, and the solver's own wall-time split: the sweeps, and "other", where the floor passes
// are with the prediction, contacts and velocities). The scene is chaotic at this budget, so one tick's count is a sample: compare the means.
//
// Usage: pliant_floor_series [--ticks N] [--iterations I] [--from T] [--threads P] [--quiet]
#include "pliant/colliders.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/model.hpp"
#include "pliant/state.hpp"
#include "pliant/stepper.hpp"

#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

using namespace pliant;

namespace {

double cpu_ms() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return double(t.tv_sec) * 1e3 + double(t.tv_nsec) * 1e-6;
}

int int_flag(const char* name, const char* value) {
  char* end = nullptr;
  const long v = std::strtol(value, &end, 10);
  if (!end || *end != '\0' || v < 0 || v > 1000000) {
    std::fprintf(stderr, "pliant_floor_series: %s must be a non-negative integer, got '%s'\n", name, value);
    std::exit(2);
  }
  return int(v);
}

}  // namespace

int main(int argc, char** argv) {
  int ticks = 60, iterations = 1, from = 10, threads = 1;
  bool quiet = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--quiet") {
      quiet = true;
      continue;
    }
    if (i + 1 >= argc) {
      std::fprintf(stderr, "pliant_floor_series: %s needs a value (or unknown flag)\n", a.c_str());
      return 2;
    }
    const char* v = argv[++i];
    if (a == "--ticks") ticks = int_flag("--ticks", v);
    else if (a == "--iterations") iterations = int_flag("--iterations", v);
    else if (a == "--from") from = int_flag("--from", v);
    else if (a == "--threads") threads = int_flag("--threads", v);
    else {
      std::fprintf(stderr, "pliant_floor_series: unknown flag %s\n", a.c_str());
      return 2;
    }
  }
  const TetMesh mesh = resolve_mesh("armadillo");
  const auto box = bounding_box(mesh.vertices);
  FixedSelection fixed;
  fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(1, -0.040, 1)});  // the scene's --fix-box
  const auto model = build_model(mesh, Material{1e6, 0.4, 1000}, fixed);
  StepInputs inputs;
  inputs.colliders.push_back(Collider::plane(Vec3(0, box.min.y(), 0), Vec3(0, 1, 0)));
  BodyState state = rest_state(*model);
  SolverSettings s;
  s.substeps = 1;
  s.iterations = iterations;
  s.threads = threads;
  s.record_residuals = false;
  Stepper stepper;
  double inverted_sum = 0, ms_sum = 0, sweep_ms = 0, other_ms = 0;
  long corrections = 0;
  size_t inverted = 0;
  int counted = 0;
  for (int t = 0; t < ticks; ++t) {
    const double c0 = cpu_ms();
    const StepReport r = stepper.step(*model, state, s, inputs);
    const double ms = cpu_ms() - c0;
    inverted = count_inverted(*model, state.x);
    if (!quiet) std::printf("tick %d inverted %zu corrections %ld cpu_ms %.1f\n", t + 1, inverted, long(r.volume_corrections), ms);
    if (t + 1 >= from) {
      inverted_sum += double(inverted);
      ms_sum += ms;
      sweep_ms += r.times.projection_ms;
      other_ms += r.times.other_ms;
      corrections += r.volume_corrections;
      ++counted;
    }
  }
  const double n = counted > 0 ? counted : 1;
  std::printf("{\"iterations\":%d,\"ticks\":%d,\"from\":%d,\"mean_inverted\":%.1f,\"last_inverted\":%zu,"
              "\"mean_corrections\":%.0f,\"mean_cpu_ms\":%.1f,\"mean_sweep_ms\":%.1f,\"mean_other_ms\":%.1f}\n",
              iterations, ticks, from, inverted_sum / n, inverted, double(corrections) / n, ms_sum / n, sweep_ms / n,
              other_ms / n);
  return 0;
}
