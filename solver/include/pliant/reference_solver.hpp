// SPDX-License-Identifier: Apache-2.0
// Ground truth for tests and experiments: Newton's method with a sparse direct solve on the
// same equations the XPBD iterations approximate.
//  - implicit step: x* = argmin 1/(2h^2) (x - x~)^T M (x - x~) + sum_t 1/2 C_t^T K C_t, the
//    converged XPBD step from the prediction x~ (M(x - x~) = grad C^T lambda, C + alpha~ lambda = 0),
//    M the solver's inertia (BodyModel::inertia; the stepper predicts x~ with gravity
//    mass/inertia x g, so that the weight is the lumped mass);
//  - static equilibrium: x = argmin sum_t 1/2 C_t^T K C_t - sum_i (m_i g + f_i) . x_i, m the
//    lumped mass (no inertia).
// Fixed vertices (inverse mass 0) keep their positions. Hessians are made positive
// semi-definite per tet and steps are damped by a backtracking line search on the energy, so
// large deflections converge too (optionally in load steps).
#pragma once

#include "pliant/model.hpp"

#include <Eigen/Core>

#include <vector>

namespace pliant {

struct NewtonOptions {
  int max_iterations = 100;
  double tolerance = 1e-9;   // stop when ||grad|| <= tolerance * ||reference force||
  int load_steps = 1;        // static solve: ramp the load in this many equal steps
};

struct NewtonResult {
  std::vector<Vec3> x;
  int iterations = 0;
  double gradient_norm = 0;
  double energy = 0;
  bool converged = false;
};

NewtonResult solve_implicit_step(const BodyModel& model, const std::vector<Vec3>& x_start,
                                 const std::vector<Vec3>& x_predicted, double h,
                                 const NewtonOptions& options = {});

NewtonResult solve_static(const BodyModel& model, const std::vector<Vec3>& x_start,
                          const Eigen::Vector3d& gravity,
                          const std::vector<Vec3>& external_forces = {},
                          const NewtonOptions& options = {});

}  // namespace pliant
