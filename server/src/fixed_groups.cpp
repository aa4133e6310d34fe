// SPDX-License-Identifier: Apache-2.0
#include "fixed_groups.hpp"

#include "pliant/mesh_io.hpp"
#include "pliant/server/edge.hpp"

#include <spdlog/fmt/fmt.h>

namespace pliant::server {

Error add_fixed_groups(const v1::FixedSelection& p, const std::string& prefix, const TetMesh& mesh,
                       FixedSelection* fixed, std::vector<std::string>* names) {
  names->clear();
  for (int i = 0; i < p.groups_size(); ++i) {
    const std::string& g = p.groups(i);
    if (g.empty())
      return Error::make(Code::InvalidArgument, fmt::format("{}.groups[{}] is empty: name a physical group of the mesh",
                                                            prefix, i));
    if (mesh.groups.empty())
      return Error::make(Code::InvalidArgument,
                         fmt::format("{}.groups[{}] {}: mesh {} has no physical groups (only Gmsh .msh files carry "
                                     "them)",
                                     prefix, i, echo(g), echo(mesh.name)));
    try {
      for (int32_t v : group_vertices(mesh, g)) fixed->indices.push_back(v);
    } catch (const MeshError&) {
      return Error::make(Code::InvalidArgument,
                         cap_message(fmt::format("{}.groups[{}] {}: mesh {} has no such physical group (its groups: {})",
                                                 prefix, i, echo(g), echo(mesh.name), describe_groups(mesh))));
    }
    names->push_back(g);
  }
  return {};
}

}  // namespace pliant::server
