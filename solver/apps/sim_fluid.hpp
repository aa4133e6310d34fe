// SPDX-License-Identifier: Apache-2.0
// pliant-sim fluid: a position-based fluid scene (dam break, column at rest) stepped at a fixed
// rate, with its density error, escapes, cost and hydrostatics as one JSON line.
#pragma once

#include "cli.hpp"

#include <set>
#include <string>

namespace pliant::sim {

extern const std::set<std::string> kFluidValued;
extern const std::set<std::string> kFluidFlags;
extern const char* kFluidUsage;

int cmd_fluid(const cli::Args& a);

}  // namespace pliant::sim
