// SPDX-License-Identifier: Apache-2.0
// FixedSelection.groups: the vertices of a mesh file's physical groups, fixed.
#pragma once

#include "pliant/model.hpp"
#include "pliant/server/scene.hpp"
#include "pliant/v1/pliant.pb.h"

#include <string>
#include <vector>

namespace pliant::server {

// Adds the vertices of every group named in `p.groups()` (by name or physical tag) to
// `fixed->indices` and the group names to `names`. An empty name, or a group `mesh` does not
// have, is InvalidArgument naming the field (`prefix`.groups[i]), the group and the mesh's groups.
Error add_fixed_groups(const v1::FixedSelection& p, const std::string& prefix, const TetMesh& mesh,
                       FixedSelection* fixed, std::vector<std::string>* names);

}  // namespace pliant::server
