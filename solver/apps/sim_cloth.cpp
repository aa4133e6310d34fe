// SPDX-License-Identifier: Apache-2.0
// pliant-sim cloth: a cloth grid (or a triangle surface file) dropped on a sphere, a floor or
// nothing; pliant-sim rope: a rope hung between two pins, compared with the catenary.
#include "sim_cloth.hpp"

#include "pliant/cloth.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <numeric>
#include <vector>

namespace pliant::sim {

const char* kClothUsage = R"(
cloth:     --grid N (64: N x N particles) --size M (1.0 m) --mass-per-area KG_M2 (0.2)
           --mesh FILE (a triangle surface read with assimp instead of the grid) --scale S (1)
           --drape sphere|floor|none (sphere: radius --radius 0.3 m at the origin, cloth
           --height 0.05 m above its top; floor: a plane at y = 0, cloth 0.3 m above)
           --seconds T (3) --dt H (1/60) --substeps S (16) --iterations K (1)
           --stretch-compliance C (1e-9 m/N) --shear-compliance C (1e-6 m/N)
           --bend-compliance C (1e3 1/(N m); none: no bending) --damping D (0 1/s)
           --thickness R (0.005 m) --threads T (1) --no-self-collision
           --pressure P (a closed --mesh: keep P x its rest volume; off by default)
           --volume-compliance C (0 m^5/N)
           --csv FILE (per step: step, t_s, ms, max_stretch, rms_stretch, max_speed_m_s,
           self_contacts, collider_contacts, min_clearance_m)
           Last line: JSON with ms_per_step_mean/p99, max_stretch (largest relative edge
           stretch over the run), final_stretch_rms, penetrations (particle-steps inside the
           sphere), min_clearance_m (closest particle or triangle centre to the sphere's
           surface over the run), nan, max_speed, self_contacts, load_average.
rope:      --segments N (100) --span S (1 m) --length L (1.2 m) --linear-density KG_M (0.05)
           --seconds T (10) --dt H (1/60) --substeps S (100) --iterations K (1)
           --stretch-compliance C (0 m/N) --bend-compliance C (none: a chain; else m/N)
           --damping D (2 1/s) --threads T (1)
           The rope starts as a V between two pins at equal height and settles. Last line: JSON
           with sag_m, catenary_sag_m, catenary_error (|sag - catenary| / catenary sag),
           shape_error (largest |y - y_catenary| / catenary sag), max_stretch, ms per step.
)";

const std::set<std::string> kClothValued = {
    "log-level", "grid", "size", "mass-per-area", "mesh", "scale", "drape", "radius", "height", "seconds", "dt",
    "substeps", "iterations", "stretch-compliance", "shear-compliance", "bend-compliance", "damping",
    "thickness", "threads", "pressure", "volume-compliance", "csv", "segments", "span", "length", "linear-density"};
const std::set<std::string> kClothFlags = {"quiet", "no-self-collision"};

namespace {


ConstraintBodySettings settings_from(const cli::Args& a, const ConstraintBodySettings& base) {
  ConstraintBodySettings s = base;
  s.substeps = int(a.integer("substeps", s.substeps, 1, 10000));
  s.iterations = int(a.integer("iterations", s.iterations, 1, 10000));
  s.threads = int(a.integer("threads", s.threads, 1, 256));
  s.stretch_compliance = a.number("stretch-compliance", s.stretch_compliance);
  s.shear_compliance = a.number("shear-compliance", s.shear_compliance);
  if (a.str("bend-compliance", "") == "none")
    s.bending = false;
  else if (a.has("bend-compliance")) {
    s.bending = true;
    s.bend_compliance = a.number("bend-compliance", s.bend_compliance);
  }
  s.damping = a.number("damping", s.damping);
  s.thickness = a.number("thickness", s.thickness);
  if (a.has("no-self-collision")) s.self_collision = false;
  if (a.has("pressure")) {
    s.volume = true;
    s.pressure = a.number("pressure", 1.0);
    if (!std::isfinite(s.pressure) || s.pressure <= 0.0)
      throw cli::UsageError(fmt::format("--pressure: must be > 0 (got {})", s.pressure));
  }
  s.volume_compliance = a.number("volume-compliance", s.volume_compliance);
  auto check = [](const char* flag, double v, bool strict) {
    if (!std::isfinite(v) || v < 0.0 || (strict && v == 0.0))
      throw cli::UsageError(fmt::format("--{}: must be a number {} 0 (got {})", flag, strict ? ">" : ">=", v));
  };
  check("stretch-compliance", s.stretch_compliance, false);
  check("shear-compliance", s.shear_compliance, false);
  check("bend-compliance", s.bend_compliance, false);
  check("damping", s.damping, false);
  check("volume-compliance", s.volume_compliance, false);
  check("thickness", s.thickness, true);
  return s;
}

double time_step(const cli::Args& a) {
  const double dt = a.has("dt") ? cli::parse_number("dt", *a.str("dt")) : 1.0 / 60.0;
  if (!std::isfinite(dt) || dt <= 0.0) throw cli::UsageError(fmt::format("--dt: must be > 0 s (got {})", dt));
  return dt;
}

double positive(const cli::Args& a, const char* name, double fallback) {
  const double v = a.number(name, fallback);
  if (!std::isfinite(v) || v <= 0.0) throw cli::UsageError(fmt::format("--{}: must be > 0 (got {})", name, v));
  return v;
}

struct Timing {
  std::vector<double> ms;
  double mean() const { return ms.empty() ? 0.0 : std::accumulate(ms.begin(), ms.end(), 0.0) / double(ms.size()); }
  double p99() const {
    if (ms.empty()) return 0.0;
    std::vector<double> s = ms;
    const size_t k = std::min(s.size() - 1, size_t(std::ceil(0.99 * double(s.size()))) - 1);
    std::nth_element(s.begin(), s.begin() + long(k), s.end());
    return s[k];
  }
};

}  // namespace

int cmd_cloth(const cli::Args& a, cli::Progress& progress) {
  ConstraintBodySettings base;
  const ConstraintBodySettings s = settings_from(a, base);
  const std::string drape = a.str("drape", "sphere");
  if (drape != "sphere" && drape != "floor" && drape != "none")
    throw cli::UsageError("--drape: '" + drape + "' is not one of sphere, floor, none");
  const double radius = positive(a, "radius", 0.3);
  const double height = a.number("height", 0.05);
  const double size = positive(a, "size", 1.0);
  const double mass_per_area = positive(a, "mass-per-area", 0.2);
  const double seconds = positive(a, "seconds", 3.0);
  const double dt = time_step(a);
  const double top = drape == "sphere" ? radius + height : drape == "floor" ? 0.3 : 0.0;

  std::unique_ptr<ConstraintBody> body;
  std::string source;
  if (auto mesh = a.str("mesh")) {
    body = ConstraintBody::cloth_from_file(*mesh, positive(a, "scale", 1.0), mass_per_area, s);
    // centre the surface over the collider, its lowest point at `top`
    ParticleState st = body->state();
    Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
    for (const Vec3& p : st.x) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
    }
    const Vec3 shift = Vec3(-(lo.x() + hi.x()) / 2, top - lo.y(), -(lo.z() + hi.z()) / 2);
    for (Vec3& p : st.x) p += shift;
    body->set_state(st);
    source = *mesh;
  } else {
    ClothGridSpec g;
    g.nx = g.ny = int(a.integer("grid", 64, 2, 4096));
    g.size_x = g.size_y = size;
    g.mass_per_area = mass_per_area;
    g.origin = Vec3(-size / 2, top, -size / 2);
    body = ConstraintBody::cloth_grid(g, s);
    source = fmt::format("grid {}x{}", g.nx, g.ny);
  }
  std::vector<Collider> colliders;
  if (drape == "sphere") colliders.push_back(Collider::sphere(Vec3::Zero(), radius));
  if (drape == "floor") colliders.push_back(Collider::plane(Vec3::Zero(), Vec3(0, 1, 0)));

  const long steps = std::max(1L, long(std::lround(seconds / dt)));
  Timing timing;
  double max_stretch = 0.0, min_clear = 1e300, max_speed = 0.0;
  long penetrations = 0;
  bool nan = false;
  size_t self_contacts = 0, contacts = 0;
  std::ofstream csv;
  if (auto path = a.str("csv")) {
    csv.open(*path);
    if (!csv) throw cli::UsageError("--csv: cannot write '" + *path + "'");
    csv << "step,t_s,ms,max_stretch,rms_stretch,max_speed_m_s,self_contacts,collider_contacts,min_clearance_m\n";
  }
  ParticleStepReport last;
  for (long k = 0; k < steps; ++k) {
    last = body->step(dt, colliders);
    timing.ms.push_back(last.wall_ms);
    contacts = last.contacts;
    self_contacts = std::max(self_contacts, body->self_contacts());
    const auto& x = body->state().x;
    double speed = 0.0, clear = 1e300;
    for (size_t i = 0; i < x.size(); ++i) {
      if (!x[i].allFinite() || !body->state().v[i].allFinite()) nan = true;
      speed = std::max(speed, body->state().v[i].norm());
    }
    max_speed = std::max(max_speed, speed);
    if (drape == "sphere") {
      for (const Vec3& p : x) {
        const double c = p.norm() - radius;
        clear = std::min(clear, c);
        if (c < 0.0) ++penetrations;
      }
      for (const auto& t : body->triangles())
        clear = std::min(clear, ((x[t[0]] + x[t[1]] + x[t[2]]) / 3.0).norm() - radius);
      min_clear = std::min(min_clear, clear);
    }
    max_stretch = std::max(max_stretch, last.max_constraint_error);
    if (csv.is_open())
      csv << fmt::format("{},{:.6f},{:.4f},{:.6g},{:.6g},{:.6g},{},{},{}\n", k + 1, double(k + 1) * dt, last.wall_ms,
                         last.max_constraint_error, last.constraint_error, speed, body->self_contacts(),
                         last.contacts, drape == "sphere" ? fmt::format("{:.6g}", clear) : std::string());
    progress.set(fmt::format("step {}/{}: {:.2f} ms, max stretch {:.2e}", k + 1, steps, last.wall_ms,
                             last.max_constraint_error));
    if (nan) break;
  }
  nlohmann::ordered_json j;
  j["command"] = "cloth";
  j["source"] = source;
  j["drape"] = drape;
  j["particles"] = body->size();
  j["triangles"] = body->triangles().size();
  j["distance_constraints"] = body->distance_constraints();
  j["bending_constraints"] = body->bending_constraints();
  j["colours"] = body->colours();
  j["steps"] = timing.ms.size();
  j["dt"] = dt;
  j["substeps"] = s.substeps;
  j["iterations"] = s.iterations;
  j["threads"] = s.threads;
  j["stretch_compliance"] = s.stretch_compliance;
  j["bend_compliance"] = s.bending ? nlohmann::ordered_json(s.bend_compliance) : nlohmann::ordered_json(nullptr);
  j["thickness"] = s.thickness;
  j["self_collision"] = s.self_collision;
  j["ms_per_step_mean"] = timing.mean();
  j["ms_per_step_p99"] = timing.p99();
  j["realtime"] = timing.mean() <= dt * 1000.0;
  j["max_stretch"] = max_stretch;
  j["final_stretch_rms"] = last.constraint_error;
  j["penetrations"] = penetrations;
  j["min_clearance_m"] = drape == "sphere" ? nlohmann::ordered_json(min_clear) : nlohmann::ordered_json(nullptr);
  j["nan"] = nan;
  j["max_speed"] = max_speed;
  j["contacts"] = contacts;
  j["self_contacts"] = self_contacts;
  if (s.volume) j["volume_ratio"] = body->volume() / body->rest_volume();
  j["load_average"] = cli::load_average();
  std::cout << cli::json_line(j) << std::endl;
  return nan ? 1 : 0;
}

int cmd_rope(const cli::Args& a, cli::Progress& progress) {
  ConstraintBodySettings base;
  base.stretch_compliance = 0.0;
  base.bending = false;
  base.damping = 2.0;
  base.substeps = 100;
  base.self_collision = false;
  const ConstraintBodySettings s = settings_from(a, base);
  const int segments = int(a.integer("segments", 100, 2, 1000000));
  const double span = positive(a, "span", 1.0);
  const double length = positive(a, "length", 1.2);
  if (length <= span) throw cli::UsageError(fmt::format("--length: must exceed --span {} m (got {} m)", span, length));
  const double density = positive(a, "linear-density", 0.05);
  const double seconds = positive(a, "seconds", 10.0);
  const double dt = time_step(a);
  const double drop = std::sqrt(length * length - span * span) / 2.0;
  auto rope = ConstraintBody::rope({Vec3(-span / 2, 0, 0), Vec3(0, -drop, 0), Vec3(span / 2, 0, 0)}, segments, density, s);
  rope->pin(0);
  rope->pin(rope->size() - 1);
  // the rope's own length, the sum of its rest lengths (a V resampled into an odd number of
  // segments cuts its corner)
  double rest_length = 0.0;
  for (size_t i = 0; i + 1 < rope->size(); ++i) rest_length += (rope->state().x[i + 1] - rope->state().x[i]).norm();
  const long steps = std::max(1L, long(std::lround(seconds / dt)));
  Timing timing;
  for (long k = 0; k < steps; ++k) {
    const auto rep = rope->step(dt, {});
    timing.ms.push_back(rep.wall_ms);
    progress.set(fmt::format("step {}/{}: max stretch {:.2e}", k + 1, steps, rep.max_constraint_error));
  }
  const auto& x = rope->state().x;
  const double a_cat = cloth_math::catenary_parameter(span, rest_length);
  const double sag_cat = cloth_math::catenary_sag(span, rest_length);
  double lowest = 0.0, worst = 0.0;
  bool nan = false;
  for (const Vec3& p : x) {
    nan = nan || !p.allFinite();
    lowest = std::min(lowest, p.y());
    worst = std::max(worst, std::abs(p.y() - a_cat * (std::cosh(p.x() / a_cat) - std::cosh(span / (2 * a_cat)))));
  }
  nlohmann::ordered_json j;
  j["command"] = "rope";
  j["segments"] = segments;
  j["span"] = span;
  j["length"] = rest_length;
  j["linear_density"] = density;
  j["steps"] = steps;
  j["dt"] = dt;
  j["substeps"] = s.substeps;
  j["iterations"] = s.iterations;
  j["stretch_compliance"] = s.stretch_compliance;
  j["bend_compliance"] = s.bending ? nlohmann::ordered_json(s.bend_compliance) : nlohmann::ordered_json(nullptr);
  j["damping"] = s.damping;
  j["ms_per_step_mean"] = timing.mean();
  j["ms_per_step_p99"] = timing.p99();
  j["sag_m"] = -lowest;
  j["catenary_sag_m"] = sag_cat;
  j["catenary_error"] = std::abs(-lowest - sag_cat) / sag_cat;
  j["shape_error"] = worst / sag_cat;
  j["max_stretch"] = rope->max_stretch();
  j["nan"] = nan;
  j["load_average"] = cli::load_average();
  std::cout << cli::json_line(j) << std::endl;
  return nan ? 1 : 0;
}

}  // namespace pliant::sim
