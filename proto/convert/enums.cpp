// SPDX-License-Identifier: Apache-2.0
#include "pliant/proto/enums.hpp"

#include <array>
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

}  // namespace

std::optional<Method> method_from(v1::Method m) {
  for (const auto& [ours, theirs] : kMethods)
    if (theirs == m) return ours;
  return std::nullopt;
}

v1::Method method_to(Method m) {
  for (const auto& [ours, theirs] : kMethods)
    if (ours == m) return theirs;
  return v1::METHOD_UNSPECIFIED;
}

std::optional<Sweep> sweep_from(v1::Sweep s) {
  for (const auto& [ours, theirs] : kSweeps)
    if (theirs == s) return ours;
  return std::nullopt;
}

v1::Sweep sweep_to(Sweep s) {
  for (const auto& [ours, theirs] : kSweeps)
    if (ours == s) return theirs;
  return v1::SWEEP_UNSPECIFIED;
}

}  // namespace pliant::proto
