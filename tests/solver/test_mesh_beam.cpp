// Builtin thesis beams: counts, sizes, conformity (the only boundary faces are the box's).
#include "pliant/builtin_meshes.hpp"
#include "pliant/model.hpp"

#include <gtest/gtest.h>

using namespace pliant;

struct BeamCase {
  const char* name;
  int nx, ny, nz;
  size_t tets;
  double length;
};

void PrintTo(const BeamCase& c, std::ostream* os) { *os << c.name; }

class BeamTest : public ::testing::TestWithParam<BeamCase> {};

TEST_P(BeamTest, CountsSizeAndConformity) {
  const BeamCase& c = GetParam();
  TetMesh mesh = *builtin_mesh(c.name);
  EXPECT_EQ(mesh.vertices.size(), size_t(c.nx) * c.ny * c.nz);
  EXPECT_EQ(mesh.tets.size(), c.tets);
  Aabb box = bounding_box(mesh.vertices);
  EXPECT_NEAR(box.extent().x(), c.length, 1e-12);
  EXPECT_NEAR(box.extent().y(), 0.01, 1e-12);
  EXPECT_NEAR(box.extent().z(), 0.01, 1e-12);
  EXPECT_NEAR(total_volume(mesh), c.length * 1e-4, 1e-12);
  for (size_t t = 0; t < mesh.tets.size(); ++t) ASSERT_GT(tet_volume(mesh, t), 0.0) << t;
  // A conforming split leaves exactly 2 triangles per boundary square of the box.
  const size_t qx = c.nx - 1, qy = c.ny - 1, qz = c.nz - 1;
  EXPECT_EQ(boundary_triangles(mesh.tets).size(), 4 * (qx * qy + qx * qz + qy * qz));
}

INSTANTIATE_TEST_SUITE_P(Thesis, BeamTest,
                         ::testing::Values(BeamCase{"beam1", 24, 3, 3, 460, 0.115},
                                           BeamCase{"beam2", 32, 4, 4, 1395, 0.31 / 3.0},
                                           BeamCase{"beam3", 40, 5, 5, 3120, 0.0975}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(Beam, ThesisMassOfBeam1) {
  auto model = build_model(*builtin_mesh("beam1"), Material{1e6, 0.4, 1000});
  EXPECT_NEAR(model->total_mass(), 0.0115, 1e-12);  // 11.5 g, thesis table 3.1
}

TEST(Colouring, NoTwoTetsOfAColourShareAVertex) {
  auto model = build_model(*builtin_mesh("beam2"), Material{});
  size_t total = 0;
  for (const auto& colour : model->colours) {
    std::vector<int> seen(model->vertex_count(), 0);
    for (int32_t t : colour)
      for (int32_t v : model->tets[t].v) ASSERT_EQ(seen[v]++, 0) << "vertex " << v;
    total += colour.size();
  }
  EXPECT_EQ(total, model->tet_count());
}
