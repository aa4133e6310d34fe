// SPDX-License-Identifier: Apache-2.0
// Physical groups of a mesh file (VertexGroup), looked up by name or number.
#include "pliant/mesh_io.hpp"

#include <algorithm>
#include <cstdlib>

namespace pliant {

namespace {

const char* dimension_name(int d) {
  switch (d) {
    case 0: return "point";
    case 1: return "curve";
    case 2: return "surface";
    default: return "volume";
  }
}

bool parse_tag(const std::string& s, int64_t* tag) {
  if (s.empty()) return false;
  char* end = nullptr;
  const long long v = std::strtoll(s.c_str(), &end, 10);
  if (end != s.c_str() + s.size()) return false;
  *tag = v;
  return true;
}

}  // namespace

std::string describe_groups(const TetMesh& mesh) {
  std::string s;
  for (const VertexGroup& g : mesh.groups) {
    if (!s.empty()) s += ", ";
    s += std::to_string(g.tag);
    if (!g.name.empty()) s += " \"" + g.name + "\"";
    s += std::string(" (") + dimension_name(g.dimension) + ", " + std::to_string(g.vertices.size()) +
         (g.vertices.size() == 1 ? " vertex)" : " vertices)");
  }
  return s.empty() ? "none" : s;
}

std::vector<int32_t> group_vertices(const TetMesh& mesh, const std::string& group) {
  std::vector<int32_t> out;
  bool found = false;
  for (const VertexGroup& g : mesh.groups)
    if (!g.name.empty() && g.name == group) {
      out.insert(out.end(), g.vertices.begin(), g.vertices.end());
      found = true;
    }
  int64_t tag = 0;
  if (!found && parse_tag(group, &tag))
    for (const VertexGroup& g : mesh.groups)
      if (g.tag == tag) {
        out.insert(out.end(), g.vertices.begin(), g.vertices.end());
        found = true;
      }
  if (!found)
    throw MeshError(mesh.name + ": no physical group '" + group + "' (the mesh's groups: " + describe_groups(mesh) +
                    ")");
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

}  // namespace pliant
