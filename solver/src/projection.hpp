// The hot loop of the solver: the fused strain-constraint projection of one tet, the position
// update from a given multiplier increment, and the constraint residual. Algebraically equal to
// the readable forms in strain_constraint.cpp (tests compare them), but written on the
// deformation gradient's columns: with S = F^T F and Q = sum_k w_k b_k b_k^T, the 6x6 system
// matrix is V0 * (bilinear terms in S and Q) + alpha~, and the position update is
// dx_k = w_k sqrt(V0) F P b_k with P the symmetric 3x3 built from the increment.
#pragma once

#include "pliant/model.hpp"

#include <Eigen/Core>

#include <vector>

namespace pliant::detail {

struct ProjectionParams {
  ElasticModel model = ElasticModel::StVK;  // which strain the constraint measures
  Mat6 alpha_tilde;          // compliance / h^2
  double lambda_scale = 1;   // over-relaxation of the increment (lambda-SOR), 1 otherwise
  double inversion_floor = 0;
  bool line_search = false;  // shorten a tet's step until its residual does not grow
};

// Line search of one tet's projection (both kernels; StVK only: the corotated strain is linear
// in x for the rotation it is linearised at, so its step lands on the tet's linearised solution
// and only the rotation's change, second order, is left): the step is halved at most kMaxHalvings
// times until the tet's own residual ||C + alpha~ lambda|| does not grow. Steps that change F by
// less than kSmallStep (Frobenius) are taken whole: their quadratic remainder is below
// kSmallStep^2 / 2 in strain, and testing them would only compare round-off near convergence.
// Why: the Green strain is quadratic in x, so the linearised step overshoots when a tet is
// compressed (correcting a singular value s costs (1 - s^2) / 2s: 2.4 rest heights for a tet
// squashed to 20%), and in a Gauss-Seidel sweep that overshoot reaches the neighbours as
// velocity. Near rest the full step passes and nothing changes.
constexpr int kMaxHalvings = 5;
constexpr double kSmallStep = 0.1;

// Computes the multiplier increment of one tet at positions x (does not move anything).
// Returns the increment in dlambda and the per-vertex corrections in dx (already scaled by
// inverse masses); lambda_t is read, not written.
void strain_increment(const TetRest& tet, const Vec3* const p[4], const double w[4],
                      const Vec6& lambda_t, const ProjectionParams& params, Vec6& dlambda,
                      Vec3 dx[4], double* det_f = nullptr);

// Unilateral volume constraint det(F) >= floor for one tet, solved as a hard constraint.
// Returns true if it acted.
bool enforce_volume_floor(const TetRest& tet, std::vector<Vec3>& x, const std::vector<double>& inv_mass,
                          double floor);

// r_t = C_t(x) + alpha~ lambda_t, squared norm.
double residual_squared(const TetRest& tet, const std::vector<Vec3>& x, const Vec6& lambda_t,
                        const Mat6& alpha_tilde, ElasticModel model = ElasticModel::StVK);

// The corotated strain of F given by its columns f, and the columns r of its rotation (the
// Jacobian's columns, see strain_jacobian): c = (r_i . f_i - 1, r_a . f_c + r_c . f_a).
Vec6 corotated_from_columns(const Vec3 f[3], Vec3 r[3]);

}  // namespace pliant::detail
