// SPDX-License-Identifier: Apache-2.0
// The thesis's sweep: Gauss-Seidel over the tets one at a time in mesh order, on the calling
// thread, with the kernel on one lane (kernels/strain_kernel.hpp). The multipliers stay in the model's
// solve order (BodyModel::tet_slot), so the residual and the accelerators, which work on slots,
// see the same layout whichever sweep ran.
#pragma once

#include "kernels/projection.hpp"
#include "kernels/strain_kernel.hpp"

#include <vector>

namespace pliant::detail {

// One sweep over every tet in the order of model.tets: each tet's increment is computed from the
// positions its predecessors left and applied at once. lambda and dlambda are in slot order.
// Returns the number of tets the inversion floor corrected during the sweep.
int sweep_sequential(const BodyModel& model, std::vector<Vec3>& x,
                     std::vector<Vec6>& lambda, std::vector<Vec6>& dlambda, const ProjectionParams& params);

}  // namespace pliant::detail
