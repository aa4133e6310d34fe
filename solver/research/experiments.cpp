// SPDX-License-Identifier: Apache-2.0
#include "pliant/experiments.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>

namespace pliant {

FixedSelection clamp_below_x(double x_max) {
  FixedSelection sel;
  sel.half_spaces.push_back({Vec3(x_max, 0, 0), Vec3(1, 0, 0)});
  return sel;
}

double default_clamp_x(const std::vector<Vec3>& rest) {
  const Aabb box = bounding_box(rest);
  return box.min.x() + 1e-6 * std::max(box.extent().maxCoeff(), 1e-12);
}

std::vector<Vec3> cantilever_bend(const BodyModel& model, double x_clamp, double tip) {
  const Aabb box = bounding_box(model.rest_positions);
  const double L = box.max.x() - x_clamp;
  const double yc = 0.5 * (box.min.y() + box.max.y());
  std::vector<Vec3> x = model.rest_positions;
  if (!(L > 0)) return x;
  for (size_t i = 0; i < x.size(); ++i) {
    if (model.fixed[i]) continue;
    const Vec3& X = model.rest_positions[i];
    const double s = std::max(0.0, X.x() - x_clamp);
    const double v = -tip * s * s * (3 * L - s) / (2 * L * L * L);
    const double slope = -tip * (6 * L * s - 3 * s * s) / (2 * L * L * L);
    const double eta = X.y() - yc;
    x[i].x() = X.x() - eta * slope;
    x[i].y() = X.y() + v;
  }
  return x;
}

ConvergenceRun run_convergence(const BodyModel& model, const std::vector<Vec3>& x0,
                               const std::vector<Vec3>& x_star, double h,
                               const SolverSettings& settings) {
  ConvergenceRun run;
  double e0 = 0;
  if (!x_star.empty())
    for (size_t i = 0; i < x0.size(); ++i) e0 += (x0[i] - x_star[i]).squaredNorm();
  e0 = std::sqrt(e0);
  Stepper stepper;
  stepper.set_iteration_hook([&](int, const std::vector<Vec3>& x, double r, double elapsed) {
    run.residual.push_back(r);
    run.elapsed_ms.push_back(elapsed);
    if (!x_star.empty()) {
      double e = 0;
      for (size_t i = 0; i < x.size(); ++i) e += (x[i] - x_star[i]).squaredNorm();
      run.error.push_back(e0 > 0 ? std::sqrt(e) / e0 : 0.0);
    }
  });
  std::vector<Vec3> x = x0;
  std::vector<Vec6> lambda(model.slot_count(), Vec6::Zero());
  SolverSettings s = settings;
  s.substeps = 1;
  s.record_residuals = true;
  run.report = stepper.solve_substep(model, x0, x, lambda, h, s);
  run.residual0 = run.report.residual_initial;
  return run;
}

Vec3 tip_displacement(const BodyModel& model, const std::vector<Vec3>& x) {
  double xmax = -std::numeric_limits<double>::infinity();
  for (const Vec3& p : model.rest_positions) xmax = std::max(xmax, p.x());
  const double tol = 1e-9 * std::max(1.0, std::abs(xmax));
  Vec3 sum = Vec3::Zero();
  int n = 0;
  for (size_t i = 0; i < x.size(); ++i)
    if (model.rest_positions[i].x() >= xmax - tol) {
      sum += x[i] - model.rest_positions[i];
      ++n;
    }
  return n ? Vec3(sum / n) : Vec3::Zero();
}

RestResult run_to_rest(const BodyModel& model, const SolverSettings& settings, int max_steps,
                       double speed_tolerance, int calm_steps,
                       const std::function<void(int, double)>& progress) {
  RestResult res;
  res.state = rest_state(model);
  Stepper stepper;
  int calm = 0;
  for (int k = 0; k < max_steps; ++k) {
    res.last_report = stepper.step(model, res.state, settings);
    res.steps = k + 1;
    const double vmax = max_speed(res.state);
    res.max_speed = vmax;
    if (res.last_report.diverged || !std::isfinite(vmax)) {
      res.diverged = true;
      break;
    }
    if (progress) progress(k + 1, vmax);
    calm = vmax < speed_tolerance ? calm + 1 : 0;
    if (calm >= calm_steps) {
      res.at_rest = true;
      break;
    }
  }
  return res;
}

}  // namespace pliant
