// SPDX-License-Identifier: Apache-2.0
// pliant-sim's cloth and rope commands (constraint bodies; docs/cloth.md).
#pragma once

#include "cli.hpp"

#include <set>
#include <string>

namespace pliant::sim {

extern const char* kClothUsage;
extern const std::set<std::string> kClothValued;
extern const std::set<std::string> kClothFlags;

// Each prints progress through `progress` (may be disabled) and one JSON line on stdout.
int cmd_cloth(const cli::Args& a, cli::Progress& progress);
int cmd_rope(const cli::Args& a, cli::Progress& progress);

}  // namespace pliant::sim
