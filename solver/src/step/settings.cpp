// SPDX-License-Identifier: Apache-2.0
#include "pliant/settings.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace pliant {

std::string_view to_string(Sweep s) {
  switch (s) {
    case Sweep::GaussSeidel: return "gauss-seidel";
    case Sweep::Jacobi: return "jacobi";
    case Sweep::Sequential: return "sequential";
  }
  return "?";
}

std::string_view to_string(Method m) {
  switch (m) {
    case Method::Xpbd: return "xpbd";
    case Method::Sor: return "sor";
    case Method::LambdaSor: return "lambda-sor";
    case Method::Chebyshev: return "chebyshev";
    case Method::Anderson: return "anderson";
    case Method::AndersonSor: return "anderson-sor";
    case Method::Extrapolation: return "extrapolation";
    case Method::Vbd: return "vbd";
    case Method::Newton: return "newton";
    case Method::Auto: return "auto";
  }
  return "?";
}

std::string_view to_string(Damping d) {
  switch (d) {
    case Damping::None: return "none";
    case Damping::Simple: return "simple";
    case Damping::RigidPreserving: return "rigid";
  }
  return "?";
}

std::string_view to_string(AndersonForm f) { return f == AndersonForm::Thesis ? "thesis" : "type2"; }

std::optional<AndersonForm> parse_anderson_form(std::string_view s) {
  for (AndersonForm v : {AndersonForm::Thesis, AndersonForm::TypeII})
    if (to_string(v) == s) return v;
  return std::nullopt;
}

std::optional<Sweep> parse_sweep(std::string_view s) {
  for (Sweep v : {Sweep::GaussSeidel, Sweep::Jacobi, Sweep::Sequential})
    if (to_string(v) == s) return v;
  return std::nullopt;
}

std::optional<Method> parse_method(std::string_view s) {
  for (Method v : {Method::Xpbd, Method::Sor, Method::LambdaSor, Method::Chebyshev, Method::Anderson,
                   Method::AndersonSor, Method::Extrapolation, Method::Vbd, Method::Newton, Method::Auto})
    if (to_string(v) == s) return v;
  return std::nullopt;
}

std::string_view method_names() {
  return "xpbd, sor, lambda-sor, chebyshev, anderson, anderson-sor, extrapolation, vbd, newton, auto";
}

std::string_view sweep_names() { return "gauss-seidel, jacobi, sequential"; }

SolverFamilyKind family_of(Method m) {
  switch (m) {
    case Method::Vbd: return SolverFamilyKind::VertexBlockDescent;
    case Method::Newton: return SolverFamilyKind::Newton;
    default: return SolverFamilyKind::ConstraintProjection;
  }
}

std::optional<Damping> parse_damping(std::string_view s) {
  for (Damping v : {Damping::None, Damping::Simple, Damping::RigidPreserving})
    if (to_string(v) == s) return v;
  return std::nullopt;
}

std::string_view to_string(NewtonLinearSolver s) {
  switch (s) {
    case NewtonLinearSolver::Auto: return "auto";
    case NewtonLinearSolver::Direct: return "direct";
    case NewtonLinearSolver::Cg: return "cg";
    case NewtonLinearSolver::CgJacobi: return "cg-jacobi";
    case NewtonLinearSolver::CgFactor: return "cg-factor";
    case NewtonLinearSolver::CgTwoLevel: return "cg-twolevel";
  }
  return "?";
}

std::optional<NewtonLinearSolver> parse_newton_linear_solver(std::string_view s) {
  for (NewtonLinearSolver v : {NewtonLinearSolver::Auto, NewtonLinearSolver::Direct, NewtonLinearSolver::Cg,
                               NewtonLinearSolver::CgJacobi, NewtonLinearSolver::CgFactor,
                               NewtonLinearSolver::CgTwoLevel})
    if (to_string(v) == s) return v;
  return std::nullopt;
}

bool newton_uses_cg(NewtonLinearSolver s, int free_dofs) {
  return s == NewtonLinearSolver::Cg || s == NewtonLinearSolver::CgJacobi || s == NewtonLinearSolver::CgFactor ||
         s == NewtonLinearSolver::CgTwoLevel ||
         (s == NewtonLinearSolver::Auto && free_dofs > kNewtonDirectMaxDofs);
}

double under_resolution(double wave_courant_number, int iterations) {
  return wave_courant_number / std::sqrt(double(std::max(1, iterations)));
}

std::string validate(const SolverSettings& s) {
  std::ostringstream os;
  auto bad = [&](const char* field, double value, const char* rule) {
    os << "solver." << field << " " << rule << ", got " << value;
  };
  if (!std::isfinite(s.dt) || s.dt <= 0 || s.dt > 1.0) bad("dt", s.dt, "must be in (0, 1] s");
  else if (s.substeps < 1 || s.substeps > kMaxSubsteps) bad("substeps", s.substeps, "must be in [1, 10000]");
  else if (!(s.target_wave_courant_number >= 0 && s.target_wave_courant_number <= 1000))
    bad("target_wave_courant_number", s.target_wave_courant_number, "must be in [0, 1000] (0: use substeps)");
  else if (s.iterations < 0 || s.iterations > 100000) bad("iterations", s.iterations, "must be in [0, 100000]");
  else if (s.window < 1 || s.window > 50) bad("window", s.window, "must be in [1, 50]");
  else if (!std::isfinite(s.omega) || s.omega <= 0 || s.omega > 100) bad("omega", s.omega, "must be in (0, 100]");
  else if (!(s.condition_limit > 1)) bad("condition_limit", s.condition_limit, "must be > 1");
  else if (!(s.chebyshev.rho > 0 && s.chebyshev.rho < 1)) bad("chebyshev.rho", s.chebyshev.rho, "must be in (0, 1)");
  else if (!(s.chebyshev.gamma > 0 && s.chebyshev.gamma <= 2)) bad("chebyshev.gamma", s.chebyshev.gamma, "must be in (0, 2]");
  else if (s.chebyshev.delay < 0) bad("chebyshev.delay", s.chebyshev.delay, "must be >= 0");
  else if (!(s.jacobi_relaxation > 0 && s.jacobi_relaxation <= 2)) bad("jacobi_relaxation", s.jacobi_relaxation, "must be in (0, 2]");
  else if (!(s.tolerance >= 0 && s.tolerance < 1)) bad("tolerance", s.tolerance, "must be in [0, 1)");
  else if (!(s.time_budget_ms >= 0) || !std::isfinite(s.time_budget_ms)) bad("time_budget_ms", s.time_budget_ms, "must be >= 0");
  else if (!(s.damping_coefficient >= 0) || !std::isfinite(s.damping_coefficient)) bad("damping_coefficient", s.damping_coefficient, "must be >= 0");
  else if (s.damping == Damping::RigidPreserving && s.damping_coefficient > 1) bad("damping_coefficient", s.damping_coefficient, "must be in [0, 1] for rigid damping");
  else if (!s.gravity.allFinite()) bad("gravity", s.gravity.norm(), "must be finite");
  else if (!(s.inversion_floor >= 0 && s.inversion_floor < 1)) bad("inversion_floor", s.inversion_floor, "must be in [0, 1)");
  else if (s.threads < 1 || s.threads > 256) bad("threads", s.threads, "must be in [1, 256]");
  else if (s.sweep == Sweep::Sequential && s.threads != 1 && family_of(s.method) == SolverFamilyKind::ConstraintProjection)
    bad("threads", s.threads, "must be 1 for sweep sequential (one tet at a time in mesh order, on one thread)");
  else if (!s.record_residuals && (s.method == Method::Anderson || s.method == Method::AndersonSor ||
                                   s.method == Method::Extrapolation || s.tolerance > 0))
    os << "solver.record_residuals must be true for method " << to_string(s.method)
       << " or a tolerance (they need the residual)";
  return os.str();
}

}  // namespace pliant
