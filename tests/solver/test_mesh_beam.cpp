// SPDX-License-Identifier: Apache-2.0
// Builtin thesis beams: counts, sizes, conformity (the only boundary faces are the box's).
#include "pliant/builtin_meshes.hpp"
#include "pliant/model.hpp"
#include "pliant/stepper.hpp"

#include <gtest/gtest.h>

#include <cmath>

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

TEST(Beam, WaveCourantNumberFromTheMaterialAndTheEdges) {
  // beam1: cubes of a = 5 mm cut into 5 tets: 4 corner tets with 3 cube edges and 3 face
  // diagonals each, and a middle tet with 6 face diagonals, so the mean edge over tets is
  // a (12 + 18 sqrt 2) / 30. The pressure-wave speed from E and nu directly (not from the
  // Lame constants the model uses): c_p^2 = E (1 - nu) / ((1 + nu) (1 - 2 nu) rho).
  const double E = 1e6, nu = 0.4, rho = 1000, a = 0.005;
  auto model = build_model(*builtin_mesh("beam1"), Material{E, nu, rho});
  EXPECT_NEAR(model->mean_edge, a * (12 + 18 * std::sqrt(2.0)) / 30, 1e-12);
  const double c_p = std::sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu) * rho));
  EXPECT_NEAR(pressure_wave_speed(*model), c_p, 1e-9 * c_p);
  const double h = 1.0 / 60 / 64;
  EXPECT_NEAR(wave_courant_number(*model, h), c_p * h / model->mean_edge, 1e-12);
  // Four times stiffer: twice the wave speed; the edges survive a material change.
  auto stiffer = with_material(*model, Material{4 * E, nu, rho});
  EXPECT_EQ(stiffer->mean_edge, model->mean_edge);
  EXPECT_NEAR(wave_courant_number(*stiffer, h), 2 * wave_courant_number(*model, h), 1e-12);
}

TEST(Beam, SubstepsChosenFromTheWaveCourantTarget) {
  // The fewest substeps that keep c_p h / mean edge at or below the target; substeps as given
  // without a target; at most 10000.
  auto model = build_model(*builtin_mesh("beam1"), Material{1e6, 0.4, 1000});
  SolverSettings s;
  EXPECT_EQ(effective_substeps(*model, s), s.substeps);
  s.target_wave_courant_number = 0.3;
  const int n = effective_substeps(*model, s);
  EXPECT_LE(wave_courant_number(*model, s.dt / n), 0.3);
  EXPECT_GT(wave_courant_number(*model, s.dt / (n - 1)), 0.3);
  // And a step runs them.
  BodyState state = rest_state(*model);
  Stepper stepper;
  s.iterations = 1;
  EXPECT_EQ(stepper.step(*model, state, s).substeps, n);
  s.target_wave_courant_number = 1e-9;
  EXPECT_EQ(effective_substeps(*model, s), 10000);
}
