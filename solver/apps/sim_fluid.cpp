// SPDX-License-Identifier: Apache-2.0
#include "sim_fluid.hpp"

#include "pliant/fluid.hpp"

#include <spdlog/fmt/fmt.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <map>
#include <iostream>
#include <numeric>
#include <vector>

namespace pliant::sim {

const std::set<std::string> kFluidValued = {"scene", "particles", "substeps", "iterations", "seconds", "threads",
                                            "dt", "spacing", "relaxation", "scorr-k", "xsph", "vorticity",
                                            "settled-after", "friction", "sort-interval", "log-level", "csv"};
const std::set<std::string> kFluidFlags = {"quiet", "progress"};

const char* kFluidUsage = R"(usage: pliant-sim fluid [options]

A position-based fluid (docs/fluids.md) stepped at --dt for --seconds; progress on stderr every
simulated second (when stderr is a terminal, or with --progress), then one JSON line on stdout.

  --scene S          dam-break (a block of width w, height 2w, depth w in the corner of a closed
                     box 4w x 4w x w; default) | column (w x 4w x w at rest in a w x 5w x w box)
  --particles N      about N particles in the block (default 10000; the lattice rounds it)
  --spacing D        particle spacing d, m (default 0.02)
  --substeps S       substeps per step (default 2)
  --iterations K     density iterations per substep (default 4)
  --dt T             step, s (default 1/60)
  --seconds T        simulated time (default 4)
  --threads N        threads (default 2)
  --relaxation E     epsilon as a fraction of a rest particle's sum |grad C|^2 (default 0.01)
  --scorr-k K        artificial pressure k (default 0.001)
  --xsph C           XSPH viscosity c (default 0.01)
  --vorticity E      vorticity confinement epsilon, m/s (default 0)
  --friction MU      the container's static and dynamic friction (default 0)
  --sort-interval N  re-sort the particles in cell order every N substeps (default 10; 0: never)
  --settled-after F  the settled window is the run's last (1 - F) (default 0.75)
  --csv FILE         per step: step, t_s, ms (wall), density_error_mean, density_error_max,
                     contacts, particles
  --progress         progress lines even when stderr is not a terminal
  --quiet            no progress lines

JSON: particles, mean_density_error and max_density_error over the settled window (compression
rho/rho0 - 1 clamped at 0, mean over particles, then mean and max over steps), escaped (most
particles outside the container at any step), ms_per_step_mean and _p99, ns_per_particle_iteration,
cpu_ms_per_step_mean (process CPU time, all threads), realtime (mean step time <= dt), load_average (1 min, at the end); column: pressure_slope_pa_per_m
against depth, pressure_slope_expected (rho0 |g|), pressure_fit_r2.
)";

int cmd_fluid(const cli::Args& a) {
  const std::string scene = a.str("scene", "dam-break");
  if (scene != "dam-break" && scene != "column")
    throw cli::UsageError("--scene: expected dam-break or column, got '" + scene + "'");
  const long particles = a.integer("particles", 10000, 1, 5000000);
  FluidSettings s;
  s.spacing = a.number("spacing", 0.02);
  if (!(s.spacing > 0)) throw cli::UsageError("--spacing: must be > 0");
  s.substeps = static_cast<int>(a.integer("substeps", 2, 1, 1000));
  s.iterations = static_cast<int>(a.integer("iterations", 4, 1, 1000));
  s.threads = static_cast<int>(a.integer("threads", 2, 1, 256));
  s.sort_interval = static_cast<int>(a.integer("sort-interval", s.sort_interval, 0, 1000000));
  s.relaxation = a.number("relaxation", s.relaxation);
  s.scorr_k = a.number("scorr-k", s.scorr_k);
  s.xsph = a.number("xsph", s.xsph);
  s.vorticity = a.number("vorticity", s.vorticity);
  const double dt = a.number("dt", 1.0 / 60.0);
  const double seconds = a.number("seconds", 4.0);
  const double settled_after = a.number("settled-after", 0.75);
  if (!(dt > 0)) throw cli::UsageError("--dt: must be > 0");
  if (!(seconds > 0)) throw cli::UsageError("--seconds: must be > 0");
  if (!(settled_after >= 0 && settled_after < 1)) throw cli::UsageError("--settled-after: must be in [0, 1)");
  const bool quiet = a.has("quiet") || !(a.has("progress") || cli::Progress::stderr_is_terminal());

  const double d = s.spacing;
  long nx, ny, nz;
  Vec3 lo(0, 0, 0), hi;
  if (scene == "dam-break") {
    nx = std::max(1L, std::lround(std::cbrt(particles / 2.0)));
    ny = 2 * nx;
    nz = nx;
    hi = Vec3(4 * nx * d, 4 * nx * d, nz * d);
  } else {
    nx = std::max(1L, std::lround(std::cbrt(particles / 4.0)));
    ny = 4 * nx;
    nz = nx;
    hi = Vec3(nx * d, 5 * nx * d, nz * d);
  }
  s.container = Collider::box((lo + hi) / 2, (hi - lo) / 2);
  const double mu = a.number("friction", 0.0);
  if (!(mu >= 0)) throw cli::UsageError("--friction: must be >= 0");
  s.container->static_friction = mu;
  s.container->dynamic_friction = mu;
  FluidBody f(s, {FluidBlock{lo, lo + d * Vec3(nx, ny, nz)}});
  const size_t n = f.size();

  const long steps = std::max(1L, std::lround(seconds / dt));
  const long settled_from = static_cast<long>(std::floor(settled_after * steps));
  std::vector<double> ms;
  ms.reserve(steps);
  std::ofstream csv;
  if (auto path = a.str("csv")) {
    csv.open(*path);
    if (!csv) throw cli::UsageError("--csv: cannot write '" + *path + "'");
    csv << "step,t_s,ms,density_error_mean,density_error_max,contacts,particles\n";
  }
  const std::clock_t cpu0 = std::clock();
  double err_sum = 0.0, err_max = 0.0;
  long err_steps = 0;
  size_t escaped = 0;
  std::vector<double> p_sum(n, 0.0), y_sum(n, 0.0);
  for (long i = 0; i < steps; ++i) {
    const ParticleStepReport r = f.step(dt, {});
    ms.push_back(r.wall_ms);
    if (csv.is_open())
      csv << fmt::format("{},{:.6f},{:.4f},{:.6g},{:.6g},{},{}\n", i + 1, double(i + 1) * dt, r.wall_ms,
                         r.constraint_error, r.max_constraint_error, r.contacts, f.size());
    size_t out = 0;
    for (const Vec3& x : f.state().x)
      out += !((x.array() >= lo.array() - 1e-9).all() && (x.array() <= hi.array() + 1e-9).all());
    escaped = std::max(escaped, out);
    if (i >= settled_from) {
      err_sum += r.constraint_error;
      err_max = std::max(err_max, r.max_constraint_error);
      ++err_steps;
      if (scene == "column" && f.size() == n) {
        const std::vector<double> p = f.pressure();
        for (size_t q = 0; q < n; ++q) {
          p_sum[q] += p[q];
          y_sum[q] += f.state().x[q].y();
        }
      }
    }
    if (!quiet && (i + 1) % std::max(1L, std::lround(1.0 / dt)) == 0)
      std::cerr << "pliant-sim fluid: t " << (i + 1) * dt << " s, density error mean " << r.constraint_error
                << " max " << r.max_constraint_error << ", " << r.wall_ms << " ms/step, contacts " << r.contacts
                << "\n";
  }
  const double cpu_ms = 1000.0 * static_cast<double>(std::clock() - cpu0) / CLOCKS_PER_SEC / static_cast<double>(steps);
  std::vector<double> sorted = ms;
  std::sort(sorted.begin(), sorted.end());
  const double mean_ms = std::accumulate(ms.begin(), ms.end(), 0.0) / static_cast<double>(ms.size());
  const double p99 = sorted[std::min(sorted.size() - 1, static_cast<size_t>(std::ceil(0.99 * sorted.size())) - 1)];

  nlohmann::ordered_json j;
  j["command"] = "fluid";
  j["scene"] = scene;
  j["particles"] = n;
  j["spacing_m"] = d;
  j["support_radius_m"] = f.support_radius();
  j["substeps"] = s.substeps;
  j["iterations"] = s.iterations;
  j["threads"] = s.threads;
  j["dt"] = dt;
  j["steps"] = steps;
  j["settled_steps"] = err_steps;
  j["mean_density_error"] = err_steps ? err_sum / err_steps : 0.0;
  j["max_density_error"] = err_max;
  j["escaped"] = escaped;
  j["ms_per_step_mean"] = mean_ms;
  j["ms_per_step_p99"] = p99;
  j["ns_per_particle_iteration"] = mean_ms * 1e6 / (static_cast<double>(n) * s.substeps * s.iterations);
  j["cpu_ms_per_step_mean"] = cpu_ms;  // process CPU time (all threads; includes the checks here)
  j["realtime"] = mean_ms <= dt * 1000.0;
  if (scene == "column") {
    // Pressure (from the multipliers) and height of each particle averaged over the settled
    // window, averaged again over layers of thickness d by depth below the surface,
    // leaving out 3.5 d below the surface and above the floor and the particles within h of a side wall
    // (whose truncated neighbourhoods need a steeper multiplier gradient to carry their
    // weight); a line fitted to the layers.
    // The surface: the height that n particles of volume d^3 fill in the container.
    const double top = static_cast<double>(n) * d * d * d / ((hi.x() - lo.x()) * (hi.z() - lo.z()));
    std::map<long, std::pair<double, long>> layers;
    for (size_t q = 0; q < n; ++q) {
      const double y = y_sum[q] / err_steps;
      const double depth = top - y;
      const Vec3 xq = f.state().x[q];
      const double side = std::min({xq.x() - lo.x(), hi.x() - xq.x(), xq.z() - lo.z(), hi.z() - xq.z()});
      if (depth < 3.5 * d || y < 3.5 * d || side < f.support_radius()) continue;
      auto& l = layers[std::lround(depth / d)];
      l.first += p_sum[q] / err_steps;
      ++l.second;
    }
    double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0, m = 0;
    for (const auto& [layer, acc] : layers) {
      const double depth = layer * d, p = acc.first / acc.second;
      sx += depth;
      sy += p;
      sxx += depth * depth;
      sxy += depth * p;
      syy += p * p;
      ++m;
    }
    const double vx = m * sxx - sx * sx, vy = m * syy - sy * sy, cxy = m * sxy - sx * sy;
    j["pressure_layers"] = m;
    j["pressure_slope_pa_per_m"] = vx > 0 ? cxy / vx : 0.0;
    j["pressure_slope_expected"] = s.rest_density * s.gravity.norm();
    j["pressure_fit_r2"] = vx > 0 && vy > 0 ? cxy * cxy / (vx * vy) : 0.0;
  }
  j["load_average"] = cli::load_average();
  std::cout << cli::json_line(j) << std::endl;
  return 0;
}

}  // namespace pliant::sim
