// SPDX-License-Identifier: Apache-2.0
#include "pliant/test/paths.hpp"

namespace pliant::test {

std::string source_path(const std::string& relative) { return std::string(PLIANT_SOURCE_DIR) + "/" + relative; }

std::string model_dir() { return source_path("meshes"); }

}  // namespace pliant::test
