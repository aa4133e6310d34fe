// SPDX-License-Identifier: Apache-2.0
// Conversions between the solver's enums and the API's, shared by the server and the CLI so
// that a value added to one side is mapped in one place.
#pragma once

#include "pliant/material.hpp"
#include "pliant/settings.hpp"
#include "pliant/v1/pliant.pb.h"

#include <optional>

namespace pliant::proto {

// nullopt for UNSPECIFIED and for values this build does not know.
std::optional<Method> method_from(v1::Method m);
v1::Method method_to(Method m);
std::optional<Sweep> sweep_from(v1::Sweep s);
v1::Sweep sweep_to(Sweep s);
std::optional<NewtonLinearSolver> newton_linear_solver_from(v1::NewtonLinearSolver s);
v1::NewtonLinearSolver newton_linear_solver_to(NewtonLinearSolver s);
std::optional<Damping> damping_from(v1::Damping d);
v1::Damping damping_to(Damping d);
std::optional<ElasticModel> elastic_model_from(v1::ElasticModel m);
v1::ElasticModel elastic_model_to(ElasticModel m);

}  // namespace pliant::proto
