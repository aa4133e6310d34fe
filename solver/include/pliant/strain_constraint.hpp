// The strain-based XPBD constraint of one tetrahedron (thesis section 2.1.2):
// C = sqrt(V0) * c, c = (e_xx, e_yy, e_zz, g_yz, g_xz, g_xy), Green strain E = 1/2 (F^T F - I),
// engineering shears g_ij = 2 E_ij = f_i . f_j (f_i the columns of F = D_s D_m^-1).
// V0 is the REST volume (a constant), so grad C = sqrt(V0) grad c.
// These are the reference (readable) versions used by tests and the Newton solver; the solver's
// hot loop uses an algebraically equal fused form in projection.cpp.
#pragma once

#include "pliant/material.hpp"
#include "pliant/model.hpp"

#include <Eigen/Core>

#include <array>

namespace pliant {

using Mat6x12 = Eigen::Matrix<double, 6, 12>;
using Mat12 = Eigen::Matrix<double, 12, 12>;
using Vec12 = Eigen::Matrix<double, 12, 1>;

// Deformation gradient of a tet at positions x.
Mat3 deformation_gradient(const TetRest& tet, const std::array<Vec3, 4>& x);

// Strain vector c (no sqrt(V0) factor).
Vec6 strain_vector(const Mat3& F);

// C(x) = sqrt(V0) c.
Vec6 strain_constraint(const TetRest& tet, const std::array<Vec3, 4>& x);

// dC/dx, 6x12, columns ordered (x0, y0, z0, x1, ..., z3).
Mat6x12 strain_jacobian(const TetRest& tet, const std::array<Vec3, 4>& x);

// Elastic energy of the tet, 1/2 C^T K C.
double strain_energy(const TetRest& tet, const Mat6& stiffness, const std::array<Vec3, 4>& x);

// Gradient (12) and Hessian (12x12) of that energy; the Hessian includes the second-derivative
// terms of C. With project_psd the Hessian is made positive semi-definite (eigenvalue clamp)
// so that Newton steps are descent directions far from equilibrium.
void strain_energy_derivatives(const TetRest& tet, const Mat6& stiffness,
                               const std::array<Vec3, 4>& x, Vec12* gradient, Mat12* hessian,
                               bool project_psd);

// Volume ratio det(F).
double volume_ratio(const TetRest& tet, const std::array<Vec3, 4>& x);

inline std::array<Vec3, 4> gather(const std::vector<Vec3>& x, const Tet& v) {
  return {x[v[0]], x[v[1]], x[v[2]], x[v[3]]};
}

}  // namespace pliant
