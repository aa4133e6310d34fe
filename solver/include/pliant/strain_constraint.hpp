// SPDX-License-Identifier: Apache-2.0
// The strain-based XPBD constraint of one tetrahedron (thesis section 2.1.2):
// C = sqrt(V0) * c, c = (e_xx, e_yy, e_zz, g_yz, g_xz, g_xy), Green strain E = 1/2 (F^T F - I),
// engineering shears g_ij = 2 E_ij = f_i . f_j (f_i the columns of F = D_s D_m^-1).
// V0 is the REST volume (a constant), so grad C = sqrt(V0) grad c.
// With ElasticModel::Corotated the strain is S - I instead (F = R S, the polar decomposition with
// a proper rotation R), same Voigt order and engineering shears 2 S_ij, same stiffness K.
// These are the reference (readable) versions used by tests and the Newton solver; the solver's
// hot loop uses an algebraically equal fused form in src/kernels/strain_kernel.cpp.
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

// Green strain vector c (no sqrt(V0) factor).
Vec6 strain_vector(const Mat3& F);

// Rotation R of the polar decomposition F = R S with det R = +1, also for an inverted F (then S
// has one negative eigenvalue, the one of smallest magnitude: the tet is seen as flipped through
// its thinnest direction, Irving et al. 2004). A degenerate F (rank 2 or less) gets the SVD's
// completion of U, made proper.
Mat3 polar_rotation(const Mat3& F);

// Its scaled Newton iteration (also run 4 lanes at once by the SIMD kernel): at most this many
// iterations (then the SVD), the Frobenius scaling used while | |X|^2 - 3 | exceeds the band,
// converged when the squared change of X falls below kPolarConverged (quadratic convergence:
// a change of 1e-8 leaves an error of about 1e-16).
inline constexpr int kMaxPolarIterations = 20;
inline constexpr double kPolarScalingBand = 1e-2;
inline constexpr double kPolarConverged = 1e-16;

// Corotated strain vector of the stretch S (corotated_stretch below): c = (S00 - 1, S11 - 1,
// S22 - 1, 2 S12, 2 S02, 2 S01).
Vec6 corotated_strain_vector(const Mat3& S);

// The symmetric stretch S = sym(R^T F), and the inverse of tr(S) I - S, which maps a change of
// F to the rotation's change (R^T dR = [w]x with (tr(S) I - S) w = axial(R^T dF - dF^T R)).
// The inverse is returned as zero (rotation held fixed) where det(tr(S) I - S) falls below
// kRotationConditionLimit x (its trace / 3)^3: only an inverted tet with two opposite singular
// values gets there.
Mat3 corotated_stretch(const Mat3& F, const Mat3& R);
Mat3 corotated_rotation_inverse(const Mat3& S);
inline constexpr double kRotationConditionLimit = 1e-3;

// Strain vector of the given model.
Vec6 strain_vector(const Mat3& F, ElasticModel model);

// C(x) = sqrt(V0) c.
Vec6 strain_constraint(const TetRest& tet, const std::array<Vec3, 4>& x,
                       ElasticModel model = ElasticModel::StVK);

// dC/dx, 6x12, columns ordered (x0, y0, z0, x1, ..., z3). For Corotated it includes the
// rotation's change, so that it is orthogonal to rigid rotations (the sweeps conserve angular
// momentum); J^T K C is the energy gradient 2 mu (F - R) + lambda tr(S - I) R either way.
Mat6x12 strain_jacobian(const TetRest& tet, const std::array<Vec3, 4>& x,
                        ElasticModel model = ElasticModel::StVK);

// Elastic energy of the tet, 1/2 C^T K C.
double strain_energy(const TetRest& tet, const Mat6& stiffness, const std::array<Vec3, 4>& x,
                     ElasticModel model = ElasticModel::StVK);
// The same from the tet's deformation gradient F (for callers that need F as well).
double strain_energy(const TetRest& tet, const Mat6& stiffness, const Mat3& F, ElasticModel model);

// Gradient (12) and Hessian (12x12) of that energy; the Hessian includes the second-derivative
// terms of C (for Corotated, those of the rotation). With project_psd the Hessian is made
// positive semi-definite (eigenvalue clamp) so that Newton steps are descent directions far
// from equilibrium.
void strain_energy_derivatives(const TetRest& tet, const Mat6& stiffness,
                               const std::array<Vec3, 4>& x, Vec12* gradient, Mat12* hessian,
                               bool project_psd, ElasticModel model = ElasticModel::StVK);

// The same gradient, and a Hessian made PSD part by part, for Newton steps at a lower cost than
// the 12x12 clamp: StVK's Hessian is J^T K J (PSD) plus sqrt(V0) G (x) I3 with G 4x4, and only G's
// negative eigenvalues are clamped; the corotated Hessian is V0 D^T (dP/dF) D with dP/dF's
// negative eigenvalues (9x9) clamped. Equal to the exact Hessian where those parts are PSD.
void strain_energy_derivatives_psd_parts(const TetRest& tet, const Mat6& stiffness,
                                         const std::array<Vec3, 4>& x, Vec12* gradient,
                                         Mat12* hessian, ElasticModel model = ElasticModel::StVK);

// Volume ratio det(F).
double volume_ratio(const TetRest& tet, const std::array<Vec3, 4>& x);

inline std::array<Vec3, 4> gather(const std::vector<Vec3>& x, const Tet& v) {
  return {x[v[0]], x[v[1]], x[v[2]], x[v[3]]};
}

}  // namespace pliant
