// SPDX-License-Identifier: Apache-2.0
// Physical groups of Gmsh files: a 4-cube beam (tests/mesh/data/beam_groups_*.msh) with a
// named volume "body", surface "clamp" (the face x = 0), point "tip" (the corner at x = L,
// y = z = h) and an unnamed curve with physical tag 7 (the edge y = z = 0), in MSH 2.2, 4.1
// ASCII and 4.1 binary. The 2.2 file also has a node no tet uses, first, in a point group
// "stray": the loader drops it, so every other index shifts by one.
#include "pliant/mesh_io.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>

using namespace pliant;
using pliant::test::data_file;

namespace {

MeshLoadOptions quiet() {
  MeshLoadOptions o;
  o.validation.log = false;
  return o;
}

constexpr double kL = 0.1, kH = 0.025;

}  // namespace

TEST(MeshGroups, GmshPhysicalGroupsByNameAndTagInEveryVersion) {
  for (const char* file : {"beam_groups_v22.msh", "beam_groups_v41.msh", "beam_groups_v41b.msh"}) {
    SCOPED_TRACE(file);
    const TetMesh m = load_mesh(data_file(file), quiet());
    ASSERT_EQ(m.vertices.size(), 20u);  // the 2.2 file's stray node is dropped
    ASSERT_EQ(m.tets.size(), 24u);

    const std::vector<int32_t> clamp = group_vertices(m, "clamp");
    ASSERT_EQ(clamp.size(), 4u);
    for (int32_t v : clamp) EXPECT_EQ(m.vertices[v].x(), 0.0) << v;
    EXPECT_EQ(group_vertices(m, "2"), clamp);  // the same group by its physical tag

    EXPECT_EQ(group_vertices(m, "body").size(), 20u);
    const std::vector<int32_t> tip = group_vertices(m, "tip");
    ASSERT_EQ(tip.size(), 1u);
    EXPECT_NEAR(m.vertices[tip[0]].x(), kL, 1e-15);
    EXPECT_NEAR(m.vertices[tip[0]].y(), kH, 1e-15);
    EXPECT_NEAR(m.vertices[tip[0]].z(), kH, 1e-15);

    const std::vector<int32_t> edge = group_vertices(m, "7");  // unnamed: by tag only
    ASSERT_EQ(edge.size(), 5u);
    for (int32_t v : edge) {
      EXPECT_EQ(m.vertices[v].y(), 0.0);
      EXPECT_EQ(m.vertices[v].z(), 0.0);
    }
    try {
      group_vertices(m, "lid");
      ADD_FAILURE() << "no error for a group the file lacks";
    } catch (const MeshError& e) {
      const std::string msg = e.what();
      EXPECT_NE(msg.find("'lid'"), std::string::npos) << msg;
      EXPECT_NE(msg.find("\"clamp\" (surface, 4 vertices)"), std::string::npos) << msg;
      EXPECT_NE(msg.find("7 (curve, 5 vertices)"), std::string::npos) << msg;
    }
  }
  // The stray node's group survives, empty, so that naming it says "0 vertices" rather than "no such group".
  const TetMesh v22 = load_mesh(data_file("beam_groups_v22.msh"), quiet());
  EXPECT_TRUE(group_vertices(v22, "stray").empty());
}

TEST(MeshGroups, FilesWithoutGroupsHaveNone) {
  EXPECT_TRUE(load_mesh(data_file("cube_v41.msh"), quiet()).groups.empty());
  EXPECT_TRUE(load_mesh(data_file("cube.node"), quiet()).groups.empty());
  // cube_v22.msh names its volume "body" (physical tag 1): all 8 corners.
  const TetMesh cube = load_mesh(data_file("cube_v22.msh"), quiet());
  EXPECT_EQ(group_vertices(cube, "body").size(), 8u);
  EXPECT_THROW(group_vertices(cube, ""), MeshError);
}
