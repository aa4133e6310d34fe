// SPDX-License-Identifier: Apache-2.0
#include "step/sequential_sweep.hpp"

namespace pliant::detail {

int sweep_sequential(const BodyModel& m, std::vector<Vec3>& x,
                     std::vector<Vec6>& lambda, std::vector<Vec6>& dlambda, const ProjectionParams& params) {
  int floor_hits = 0;
  for (size_t t = 0; t < m.tets.size(); ++t) {
    const TetRest& tet = m.tets[t];
    const int32_t slot = m.tet_slot[t];
    const Vec3* p[4] = {&x[tet.v[0]], &x[tet.v[1]], &x[tet.v[2]], &x[tet.v[3]]};
    const double w[4] = {m.inv_mass[tet.v[0]], m.inv_mass[tet.v[1]], m.inv_mass[tet.v[2]], m.inv_mass[tet.v[3]]};
    Vec3 dx[4];
    double det = 1;  // det F before the projection, for the inversion floor (as the packed sweep)
    strain_increment(tet, p, w, lambda[slot], params, dlambda[slot], dx, &det);
    lambda[slot] += dlambda[slot];
    for (int k = 0; k < 4; ++k) x[tet.v[k]] += dx[k];
    if (params.inversion_floor > 0 && det < params.inversion_floor)
      floor_hits += enforce_volume_floor(tet, x, m.inv_mass, params.inversion_floor);
  }
  return floor_hits;
}

}  // namespace pliant::detail
