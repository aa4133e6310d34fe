// SPDX-License-Identifier: Apache-2.0
// The static shapes against an independent FEM code: CalculiX (Debian's calculix-ccx, `ccx`)
// solves the same problem (the same tets as C3D4 elements, the same E, nu and density, gravity
// as a body load, the same fixed vertices) with geometric nonlinearity, where its linear
// elastic material is St. Venant-Kirchhoff: the energy Pliant's strain constraints minimise
// (docs/solver.md, "Choices": 1/2 C^T K C = V0 psi_StVK). Pliant's side is the Newton
// reference (`solve_static`) that every real-time method is measured against. Parameters are
// fixed here once (beam3, nu 0.4, 1000 kg/m^3, 9.81 m/s^2 down, the beam's first 10% of x
// clamped): nothing is tuned to the result.
#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/model.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/test/scratch_dir.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

using namespace pliant;

namespace {

std::string fmt_g(double v) {
  std::ostringstream s;
  s.precision(7);
  s << v;
  return s.str();
}

// The .inp deck: nodes and elements numbered from 1, the clamped nodes in NFIX.
std::string calculix_deck(const TetMesh& mesh, const BodyModel& model, const Material& mat, const Vec3& g) {
  std::ostringstream in;
  in.precision(17);
  in << "*HEADING\nPliant beam under gravity\n*NODE, NSET=NALL\n";
  for (size_t i = 0; i < mesh.vertices.size(); ++i)
    in << i + 1 << ", " << mesh.vertices[i].x() << ", " << mesh.vertices[i].y() << ", " << mesh.vertices[i].z() << "\n";
  in << "*ELEMENT, TYPE=C3D4, ELSET=EALL\n";
  for (size_t t = 0; t < mesh.tets.size(); ++t) {
    const Tet& tet = mesh.tets[t];  // positive orientation, as C3D4 wants it
    in << t + 1 << ", " << tet[0] + 1 << ", " << tet[1] + 1 << ", " << tet[2] + 1 << ", " << tet[3] + 1 << "\n";
  }
  in << "*NSET, NSET=NFIX\n";
  int on_line = 0;
  for (size_t i = 0; i < model.inv_mass.size(); ++i) {
    if (model.inv_mass[i] != 0.0) continue;
    in << i + 1 << (++on_line % 8 == 0 ? ",\n" : ", ");
  }
  in << "\n*MATERIAL, NAME=BODY\n*ELASTIC\n" << mat.young << ", " << mat.poisson << "\n*DENSITY\n" << mat.density << "\n";
  in << "*SOLID SECTION, ELSET=EALL, MATERIAL=BODY\n*BOUNDARY\nNFIX, 1, 3\n";
  const double gn = g.norm();
  // Nonlinear geometry, the load in automatic increments; equilibrium to 1e-9 of the mean force
  // (CalculiX's default, 5e-3, would be the looser of the two codes).
  in << "*STEP, NLGEOM, INC=200\n*STATIC\n0.1, 1.0, 1e-6, 1.0\n";
  in << "*CONTROLS, PARAMETERS=FIELD\n1e-9, 1e-9\n";
  in << "*DLOAD\nEALL, GRAV, " << gn << ", " << g.x() / gn << ", " << g.y() / gn << ", " << g.z() / gn << "\n";
  in << "*NODE PRINT, NSET=NALL\nU\n*END STEP\n";
  return in.str();
}

// Displacements from the .dat file: the block after the last "displacements" header.
std::map<int, Vec3> read_displacements(const std::string& path) {
  std::ifstream f(path);
  std::map<int, Vec3> out;
  bool in_block = false;
  for (std::string line; std::getline(f, line);) {
    if (line.find("displacements") != std::string::npos) {
      out.clear();
      in_block = true;
      continue;
    }
    if (!in_block) continue;
    std::istringstream ss(line);
    int node = 0;
    Vec3 u;
    if (ss >> node >> u.x() >> u.y() >> u.z()) out[node] = u;
    else if (!out.empty()) in_block = false;
  }
  return out;
}

void compare_with_calculix(double young) {
  const TetMesh mesh = *builtin_mesh("beam3");
  const Material mat{young, 0.4, 1000};
  const auto model = build_model(mesh, mat, clamp_below_x(default_clamp_x(mesh.vertices)));
  const Vec3 g(0, -9.81, 0);

  NewtonOptions opt;
  opt.tolerance = 1e-11;
  opt.max_iterations = 200;
  opt.load_steps = 4;
  const NewtonResult pliant = solve_static(*model, model->rest_positions, g, {}, opt);
  ASSERT_TRUE(pliant.converged) << "Newton's static solve, gradient " << pliant.gradient_norm;

  test::ScratchDir dir("pliant-calculix");
  dir.write("beam.inp", calculix_deck(mesh, *model, mat, g));
  const std::string cmd = "cd '" + dir.path().string() + "' && ccx -i beam > ccx.log 2>&1";
  const int rc = std::system(cmd.c_str());
  ASSERT_EQ(rc, 0) << "ccx failed or is missing (Debian package calculix-ccx; scripts/deps.sh installs it): "
                   << cmd;
  const auto u_ccx = read_displacements(dir.file("beam.dat"));
  ASSERT_EQ(u_ccx.size(), mesh.vertices.size()) << "displacements read from " << dir.file("beam.dat");

  double u_max = 0, diff_max = 0;
  int tip = 0;
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Vec3 u_pliant = pliant.x[i] - model->rest_positions[i];
    if (u_pliant.norm() > u_max) {
      u_max = u_pliant.norm();
      tip = int(i);
    }
    diff_max = std::max(diff_max, (u_pliant - u_ccx.at(int(i) + 1)).norm());
  }
  ASSERT_GT(u_max, 1e-5) << "the beam did not sag: nothing was compared";
  const Vec3 tip_pliant = pliant.x[tip] - model->rest_positions[tip];
  const Vec3 tip_ccx = u_ccx.at(tip + 1);
  ::testing::Test::RecordProperty("tip_pliant_m", fmt_g(tip_pliant.y()));
  ::testing::Test::RecordProperty("tip_calculix_m", fmt_g(tip_ccx.y()));
  ::testing::Test::RecordProperty("largest_difference_over_sag", fmt_g(diff_max / u_max));
  // Same elements, same energy: the two solutions differ by the solvers' tolerances only.
  EXPECT_LT(diff_max, 1e-4 * u_max) << "E " << young << ": largest difference " << diff_max << " m of a "
                                      << u_max << " m sag; tip Pliant " << tip_pliant.transpose()
                                      << ", CalculiX " << tip_ccx.transpose();
}

TEST(CalculiX, StaticSagOfBeam3At1MPaMatchesPliantsNewtonSolution) { compare_with_calculix(1e6); }

// Soft enough that the sag is large (a few percent of the length): the nonlinear regime.
TEST(CalculiX, StaticSagOfBeam3At30kPaMatchesPliantsNewtonSolution) { compare_with_calculix(3e4); }

}  // namespace
