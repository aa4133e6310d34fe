// SPDX-License-Identifier: Apache-2.0
// Shared helpers for the mesh tests: the test data's paths; the model set and a scratch
// directory per test come from the test support library.
#pragma once

#include "pliant/test/paths.hpp"
#include "pliant/test/scratch_dir.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>

namespace pliant::test {

inline std::string data_file(const std::string& name) { return source_path("tests/mesh/data/" + name); }

}  // namespace pliant::test
