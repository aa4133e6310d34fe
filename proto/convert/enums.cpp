// SPDX-License-Identifier: Apache-2.0
#include "pliant/proto/enums.hpp"

#include <array>
#include <cstddef>
#include <utility>

namespace pliant::proto {

namespace {

constexpr std::array<std::pair<Method, v1::Method>, 10> kMethods{{
    {Method::Xpbd, v1::METHOD_XPBD},
    {Method::Sor, v1::METHOD_SOR},
    {Method::LambdaSor, v1::METHOD_LAMBDA_SOR},
    {Method::Chebyshev, v1::METHOD_CHEBYSHEV},
    {Method::Anderson, v1::METHOD_ANDERSON},
    {Method::AndersonSor, v1::METHOD_ANDERSON_SOR},
    {Method::Extrapolation, v1::METHOD_EXTRAPOLATION},
    {Method::Vbd, v1::METHOD_VBD},
    {Method::Newton, v1::METHOD_NEWTON},
    {Method::Auto, v1::METHOD_AUTO},
}};

constexpr std::array<std::pair<Sweep, v1::Sweep>, 3> kSweeps{{
    {Sweep::GaussSeidel, v1::SWEEP_GAUSS_SEIDEL},
    {Sweep::Jacobi, v1::SWEEP_JACOBI},
    {Sweep::Sequential, v1::SWEEP_SEQUENTIAL},
}};

constexpr std::array<std::pair<NewtonLinearSolver, v1::NewtonLinearSolver>, 6> kNewtonLinearSolvers{{
    {NewtonLinearSolver::Auto, v1::NEWTON_LINEAR_SOLVER_AUTO},
    {NewtonLinearSolver::Direct, v1::NEWTON_LINEAR_SOLVER_DIRECT},
    {NewtonLinearSolver::Cg, v1::NEWTON_LINEAR_SOLVER_CG},
    {NewtonLinearSolver::CgJacobi, v1::NEWTON_LINEAR_SOLVER_CG_JACOBI},
    {NewtonLinearSolver::CgFactor, v1::NEWTON_LINEAR_SOLVER_CG_FACTOR},
    {NewtonLinearSolver::CgTwoLevel, v1::NEWTON_LINEAR_SOLVER_CG_TWOLEVEL},
}};

constexpr std::array<std::pair<Damping, v1::Damping>, 3> kDampings{{
    {Damping::None, v1::DAMPING_NONE},
    {Damping::Simple, v1::DAMPING_SIMPLE},
    {Damping::RigidPreserving, v1::DAMPING_RIGID_PRESERVING},
}};

constexpr std::array<std::pair<ElasticModel, v1::ElasticModel>, 2> kElasticModels{{
    {ElasticModel::StVK, v1::ELASTIC_MODEL_STVK},
    {ElasticModel::Corotated, v1::ELASTIC_MODEL_COROTATED},
}};

// One lookup for every table: ours from theirs (nullopt when absent) and theirs from ours.
template <class Ours, class Theirs, size_t N>
std::optional<Ours> ours_of(const std::array<std::pair<Ours, Theirs>, N>& table, Theirs value) {
  for (const auto& [ours, theirs] : table)
    if (theirs == value) return ours;
  return std::nullopt;
}

template <class Ours, class Theirs, size_t N>
Theirs theirs_of(const std::array<std::pair<Ours, Theirs>, N>& table, Ours value, Theirs unspecified) {
  for (const auto& [ours, theirs] : table)
    if (ours == value) return theirs;
  return unspecified;
}

}  // namespace

std::optional<Method> method_from(v1::Method m) { return ours_of(kMethods, m); }
v1::Method method_to(Method m) { return theirs_of(kMethods, m, v1::METHOD_UNSPECIFIED); }
std::optional<Sweep> sweep_from(v1::Sweep s) { return ours_of(kSweeps, s); }
v1::Sweep sweep_to(Sweep s) { return theirs_of(kSweeps, s, v1::SWEEP_UNSPECIFIED); }
std::optional<NewtonLinearSolver> newton_linear_solver_from(v1::NewtonLinearSolver s) {
  return ours_of(kNewtonLinearSolvers, s);
}
v1::NewtonLinearSolver newton_linear_solver_to(NewtonLinearSolver s) {
  return theirs_of(kNewtonLinearSolvers, s, v1::NEWTON_LINEAR_SOLVER_UNSPECIFIED);
}
std::optional<Damping> damping_from(v1::Damping d) { return ours_of(kDampings, d); }
v1::Damping damping_to(Damping d) { return theirs_of(kDampings, d, v1::DAMPING_UNSPECIFIED); }
std::optional<ElasticModel> elastic_model_from(v1::ElasticModel m) { return ours_of(kElasticModels, m); }
v1::ElasticModel elastic_model_to(ElasticModel m) {
  return theirs_of(kElasticModels, m, v1::ELASTIC_MODEL_UNSPECIFIED);
}

}  // namespace pliant::proto
