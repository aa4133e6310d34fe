// SPDX-License-Identifier: Apache-2.0
// Linear-elastic material parameters (SI units) and the StVK stiffness they give the strain
// constraint: the 6x6 matrix K with energy density psi = 1/2 c^T K c for the strain vector
// c = (e_xx, e_yy, e_zz, g_yz, g_xz, g_xy) with engineering shears g_ij = 2 e_ij.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string>
#include <string_view>

namespace pliant {

using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec6 = Eigen::Matrix<double, 6, 1>;

// Which strain measure the tet constraint uses; both have the same 6x6 stiffness K (Lame
// parameters from E and nu), so they agree at small strain and differ at large strain:
//  - StVK: Green strain E = 1/2 (F^T F - I), the thesis's constraint. Its compressive stress
//    peaks at a stretch of 1/sqrt(3) and falls to zero at 0: a strongly compressed tet offers
//    little resistance (docs/solver.md, "Real-time robustness").
//  - Corotated: S - I with F = R S the polar decomposition (R a rotation, det R = +1), the
//    strain of corotational FEM. Stress is linear in stretch, so compression is resisted all
//    the way down; an inverted tet has a negative eigenvalue of S and is pushed back through it.
enum class ElasticModel { StVK, Corotated };

std::string_view to_string(ElasticModel m);
std::optional<ElasticModel> parse_elastic_model(std::string_view s);  // "stvk" | "corotated"

// Default inertia floor (fraction of the mean vertex mass), see Material::inertia_floor.
inline constexpr double kDefaultInertiaFloor = 0.1;

struct Material {
  double young = 1e6;      // E, Pa (> 0)
  double poisson = 0.4;    // nu, in (-1, 0.5)
  double density = 1000;   // rho, kg/m^3 (> 0)
  // Inertia floor, in [0, 1]: a free vertex's inertia (what a correction or a force moves) is
  // at least this fraction of the mean lumped vertex mass; its weight stays its lumped mass,
  // so a converged equilibrium does not depend on it. It keeps vertices of tiny tets from
  // jittering under one iteration per substep (docs/solver.md, "Inertia floor"). 0 = plain
  // lumped masses. Not an elastic property; it lives here because it is part of how the
  // density becomes vertex masses.
  double inertia_floor = kDefaultInertiaFloor;
  // Support inertia, in [0, 1]: a free vertex's inertia is at least this fraction of the mass
  // it carries to the fixed vertices (the mass of the body at and beyond its distance from
  // them, in edges, shared among the vertices at that distance; supported_mass in model.hpp).
  // Like the floor it leaves the weight alone, so a converged equilibrium does not depend on
  // it. Under a budget that does not resolve a stiff material (one iteration per substep, wave
  // Courant number above 1) it lets the supports hold the body instead of letting the band
  // next to them stretch and flutter, at the price of slower motion near the supports
  // (docs/solver.md, "Support inertia"). 0 = off, the default.
  double support_inertia = 0.0;
  ElasticModel model = ElasticModel::StVK;  // strain measure of the constraint (see above)
};

struct Lame {
  double lambda;  // first Lame parameter, Pa
  double mu;      // shear modulus, Pa
};

Lame lame_parameters(double young, double poisson);

// K = [[l+2m, l, l], [l, l+2m, l], [l, l, l+2m]] (+) diag(m, m, m): the inverse of the
// constraint's compliance alpha. With engineering shears this gives 1/2 c^T K c = psi_StVK.
Mat6 stvk_stiffness(const Lame& lame);

// Empty when valid, else a message naming the bad field and its value.
std::string validate(const Material& material);

}  // namespace pliant
