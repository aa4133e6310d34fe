// SPDX-License-Identifier: Apache-2.0
// Conversions between the solver's enums and the API's, shared by the server and the CLI so
// that a value added to one side is mapped in one place.
#pragma once

#include "pliant/settings.hpp"
#include "pliant/v1/pliant.pb.h"

#include <optional>

namespace pliant::proto {

// nullopt for UNSPECIFIED and for values this build does not know.
std::optional<Method> method_from(v1::Method m);
v1::Method method_to(Method m);
std::optional<Sweep> sweep_from(v1::Sweep s);
v1::Sweep sweep_to(Sweep s);

}  // namespace pliant::proto
