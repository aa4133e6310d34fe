// SPDX-License-Identifier: Apache-2.0
#include "pliant/reference_solver.hpp"

#include "pliant/strain_constraint.hpp"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <spdlog/spdlog.h>

#include <cmath>

namespace pliant {

namespace {

// Energy of a configuration: optional inertia, elasticity, minus the work of constant loads.
struct Problem {
  const BodyModel& m;
  double inertia_weight = 0;             // 1/h^2, or 0 for statics
  const std::vector<Vec3>* target = nullptr;  // x~ for the inertia term
  std::vector<Vec3> load;                // constant force per vertex
  std::vector<int> dof;                  // vertex -> first free dof, -1 if fixed
  int ndof = 0;
  double length_scale = 1;               // largest extent of the rest shape

  explicit Problem(const BodyModel& model) : m(model) {
    dof.assign(m.vertex_count(), -1);
    for (size_t i = 0; i < m.vertex_count(); ++i)
      if (m.inv_mass[i] > 0) {
        dof[i] = ndof;
        ndof += 3;
      }
    load.assign(m.vertex_count(), Vec3::Zero());
    length_scale = std::max(bounding_box(m.rest_positions).extent().maxCoeff(), 1e-300);
  }

  double energy(const std::vector<Vec3>& x) const {
    double e = 0;
    for (const TetRest& t : m.tets) e += strain_energy(t, m.stiffness, gather(x, t.v), m.material.model);
    for (size_t i = 0; i < x.size(); ++i) {
      if (dof[i] < 0) continue;
      e -= load[i].dot(x[i]);
      if (inertia_weight > 0) e += 0.5 * inertia_weight * m.inertia[i] * (x[i] - (*target)[i]).squaredNorm();
    }
    return e;
  }

  void assemble(const std::vector<Vec3>& x, Eigen::VectorXd& g, Eigen::SparseMatrix<double>& H) const {
    g.setZero(ndof);
    std::vector<Eigen::Triplet<double>> trip;
    trip.reserve(m.tets.size() * 144 + ndof);
    Vec12 gt;
    Mat12 ht;
    for (const TetRest& t : m.tets) {
      strain_energy_derivatives(t, m.stiffness, gather(x, t.v), &gt, &ht, true, m.material.model);
      for (int a = 0; a < 4; ++a) {
        const int da = dof[t.v[a]];
        if (da < 0) continue;
        g.segment<3>(da) += gt.segment<3>(3 * a);
        for (int b = 0; b < 4; ++b) {
          const int db = dof[t.v[b]];
          if (db < 0) continue;
          for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) trip.emplace_back(da + i, db + j, ht(3 * a + i, 3 * b + j));
        }
      }
    }
    for (size_t i = 0; i < x.size(); ++i) {
      const int d = dof[i];
      if (d < 0) continue;
      g.segment<3>(d) -= load[i];
      if (inertia_weight > 0) {
        g.segment<3>(d) += inertia_weight * m.inertia[i] * (x[i] - (*target)[i]);
        for (int k = 0; k < 3; ++k) trip.emplace_back(d + k, d + k, inertia_weight * m.inertia[i]);
      }
    }
    H.resize(ndof, ndof);
    H.setFromTriplets(trip.begin(), trip.end());
  }
};

NewtonResult newton(const Problem& p, std::vector<Vec3> x, const NewtonOptions& opt, double force_scale) {
  NewtonResult res;
  Eigen::VectorXd g;
  Eigen::SparseMatrix<double> H;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
  bool analysed = false;
  double e = p.energy(x);
  const double stop = opt.tolerance * std::max(force_scale, 1e-300);
  for (int it = 0; it < opt.max_iterations; ++it) {
    p.assemble(x, g, H);
    res.gradient_norm = g.norm();
    if (res.gradient_norm <= stop) {
      res.converged = true;
      break;
    }
    if (!analysed) {
      ldlt.analyzePattern(H);
      analysed = true;
    }
    ldlt.factorize(H);
    if (ldlt.info() != Eigen::Success) {
      // The projected Hessian is PSD; a zero pivot means an unconstrained rigid mode (no fixed
      // vertex and no inertia). Regularise slightly.
      Eigen::SparseMatrix<double> I(H.rows(), H.cols());
      I.setIdentity();
      H += 1e-9 * H.diagonal().cwiseAbs().maxCoeff() * I;
      ldlt.factorize(H);
      if (ldlt.info() != Eigen::Success) break;
    }
    const Eigen::VectorXd d = ldlt.solve(-g);
    const double slope = g.dot(d);
    // A Newton step below round-off of the coordinates: converged as far as double precision
    // can tell (the gradient then sits at its round-off floor, which for stiff materials is
    // above a relative force tolerance).
    if (d.lpNorm<Eigen::Infinity>() <= 1e-13 * p.length_scale) {
      res.converged = true;
      res.iterations = it + 1;
      break;
    }
    double alpha = 1.0;
    std::vector<Vec3> trial = x;
    bool moved = false;
    for (int ls = 0; ls < 40; ++ls, alpha *= 0.5) {
      for (size_t i = 0; i < x.size(); ++i)
        if (p.dof[i] >= 0) trial[i] = x[i] + alpha * d.segment<3>(p.dof[i]);
      const double et = p.energy(trial);
      if (et <= e + 1e-4 * alpha * slope || (std::abs(et - e) <= 1e-14 * std::abs(e) && ls > 0)) {
        x.swap(trial);
        e = et;
        moved = true;
        break;
      }
    }
    res.iterations = it + 1;
    if (!moved) {
      // No decrease representable in double: we are at the solution to machine precision.
      p.assemble(x, g, H);
      res.gradient_norm = g.norm();
      res.converged = res.gradient_norm <= 1e3 * stop;
      break;
    }
  }
  res.x = std::move(x);
  res.energy = e;
  return res;
}

}  // namespace

NewtonResult solve_implicit_step(const BodyModel& model, const std::vector<Vec3>& x_start,
                                 const std::vector<Vec3>& x_predicted, double h,
                                 const NewtonOptions& options) {
  Problem p(model);
  p.inertia_weight = 1.0 / (h * h);
  p.target = &x_predicted;
  // Force scale: the inertial force of the initial offset plus the elastic forces there.
  Eigen::VectorXd g;
  Eigen::SparseMatrix<double> H;
  p.assemble(x_start, g, H);
  double scale = g.norm();
  NewtonResult r = newton(p, x_start, options, scale);
  spdlog::debug("reference implicit step: {} Newton iterations, |g| {:.3e} (scale {:.3e})",
                r.iterations, r.gradient_norm, scale);
  return r;
}

NewtonResult solve_static(const BodyModel& model, const std::vector<Vec3>& x_start,
                          const Eigen::Vector3d& gravity, const std::vector<Vec3>& external_forces,
                          const NewtonOptions& options) {
  Problem p(model);
  std::vector<Vec3> full(model.vertex_count());
  double scale = 0;
  for (size_t i = 0; i < full.size(); ++i) {
    full[i] = model.mass[i] * gravity;
    if (external_forces.size() == full.size()) full[i] += external_forces[i];
    if (p.dof[i] >= 0) scale += full[i].squaredNorm();
  }
  scale = std::sqrt(scale);
  NewtonResult r;
  r.x = x_start;
  const int steps = std::max(1, options.load_steps);
  for (int k = 1; k <= steps; ++k) {
    const double f = double(k) / steps;
    for (size_t i = 0; i < full.size(); ++i) p.load[i] = f * full[i];
    const int before = r.iterations;
    r = newton(p, r.x, options, scale);
    r.iterations += before;
    if (!r.converged && k == steps)
      spdlog::warn("reference static solve: not converged after {} iterations (|g| {:.3e}, scale {:.3e})",
                   r.iterations, r.gradient_norm, scale);
  }
  return r;
}

}  // namespace pliant
