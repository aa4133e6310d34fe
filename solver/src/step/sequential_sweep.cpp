// SPDX-License-Identifier: Apache-2.0
#include "step/sequential_sweep.hpp"

namespace pliant::detail {

int sweep_sequential(const BodyModel& m, std::vector<Vec3>& x, std::vector<Vec6>& lambda, std::vector<Vec6>& dlambda,
                     const ProjectionParams& params) {
  const PackedModel& pm = packed(m);
  int floor_hits = 0;
  for (size_t t = 0; t < m.tets.size(); ++t) {
    const int32_t slot = m.tet_slot[t];
    floor_hits += project_lanes(lane_of(pm.packs[slot / 4], slot % 4), x, lambda, &dlambda, m, params.alpha_tilde,
                                params.lambda_scale, params.inversion_floor, params.line_search);
  }
  return floor_hits;
}

}  // namespace pliant::detail
