// SPDX-License-Identifier: Apache-2.0
// Vertex block descent (Chen et al., SIGGRAPH 2024) on the implicit-Euler incremental potential
//   G(x) = sum_i inertia_i / (2 h^2) |x_i - y_i|^2 + sum_tets E_tet(x) + grabs + tool contacts,
// y the prediction (inertia, weight and external forces: stages.hpp). Each iteration visits the
// vertex colours in turn (BodyModel::vertex_colours), the vertices of a colour in parallel, and
// gives each free vertex one 3x3 Newton step on G with every other vertex held.
#pragma once

#include "pliant/model.hpp"
#include "step/family.hpp"

#include <array>
#include <memory>
#include <vector>

namespace pliant::detail {

// How a tet's diagonal 3x3 block d2E/dx_k^2 is made positive semi-definite.
enum class VbdHessian {
  Exact,       // unmodified (may be indefinite under compression: tests only)
  Projected,   // eigenvalues of the tet's 3x3 block clamped at 0
  GaussNewton, // StVK: V0 (A F^T)^T K (A F^T) without the stress term; corotated: R held fixed
};

// Where the iterations of a substep start.
enum class VbdInitialGuess {
  Inertial,  // y, the prediction
  Adaptive,  // x + h v + h^2 a~, a~ the external acceleration scaled by the part of the previous
             // substep's acceleration along it, in [0, 1] (the paper's adaptive guess; 0 without
             // a previous substep). A body at rest in equilibrium starts where it is, so the
             // equilibrium is a fixed point of a step with any number of iterations.
};

// Defaults: the Gauss-Newton block converges as well as the projected one on the bent beams
// and costs about half (bench_solver, vbd_* on beam3; docs/solver.md).
struct VbdOptions {
  VbdHessian hessian = VbdHessian::GaussNewton;
  VbdInitialGuess initial_guess = VbdInitialGuess::Adaptive;
  // Gauss-Newton blocks from the lane kernel (vbd_lanes.hpp: a vertex's tets four at a time);
  // false, or another Hessian, takes the per-tet forms below (the tests compare the two).
  bool lanes = true;
  // After each sweep of a free body (no fixed vertex, grab or tool), the rigid translation that
  // gives the iterate the linear momentum of the substep's inertia and contacts: the exact
  // minimiser of the substep's energy along a translation (the elastic energy does not change
  // under one), so a step of few iterations keeps the momentum a converged one keeps.
  bool translation = true;
};

std::unique_ptr<SolverFamily> make_vbd_family(const VbdOptions& options);

// Gradient dE/dx_k (g) and diagonal Hessian block d2E/dx_k^2 (H) of one tet's elastic energy
// with respect to its corner k, positions p; optionally the tet's energy. H is made PSD as
// `mode` says.
void tet_vertex_derivatives(const TetRest& tet, int corner, const std::array<Vec3, 4>& p,
                            const Mat6& stiffness, ElasticModel model, VbdHessian mode, Vec3& g,
                            Mat3& H);

// The tet's elastic energy 1/2 C^T K C (equal to strain_energy, without the Jacobian).
double tet_energy(const TetRest& tet, const std::array<Vec3, 4>& p, const Mat6& stiffness,
                  ElasticModel model);

// G(x) without contacts and grabs: inertia about y plus the elastic energy (free vertices'
// inertia only).
double incremental_potential(const BodyModel& model, const std::vector<Vec3>& x,
                             const std::vector<Vec3>& y, double h);

}  // namespace pliant::detail
