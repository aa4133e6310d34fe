// SPDX-License-Identifier: Apache-2.0
// Where the tests find files: inside the source tree only.
#pragma once

#include <string>

namespace pliant::test {

// `relative` (e.g. "tests/mesh/data/cube.vtk") under the repository's root.
std::string source_path(const std::string& relative);
// The model set shipped with the repository (meshes/).
std::string model_dir();

}  // namespace pliant::test
