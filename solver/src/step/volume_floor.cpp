// SPDX-License-Identifier: Apache-2.0
#include "step/volume_floor.hpp"

#include "kernels/projection.hpp"
#include "pliant/strain_constraint.hpp"

#include <algorithm>
#include <cmath>

namespace pliant::detail {

bool VolumeFloor::flag(const BodyModel& m, const std::vector<Vec3>& x, double floor, ThreadPool& pool) {
  // Slightly above the floor: enforce_volume_floor computes det F in another order, so a tet it
  // would act on is never missed.
  const double bound = floor + 1e-9 * std::max(1.0, std::abs(floor));
  flagged_.resize(m.tets.size());
  chunk_found_.assign(size_t(pool.size()), 0);
  pool.parallel_for(m.tets.size(), [&](int chunk, size_t b, size_t e) {
    bool found = false;
    for (size_t t = b; t < e; ++t) {
      const bool low = !(volume_ratio(m.tets[t], gather(x, m.tets[t].v)) >= bound);
      flagged_[t] = low;
      found |= low;
    }
    chunk_found_[size_t(chunk)] = found;
  }, 2048);
  return std::any_of(chunk_found_.begin(), chunk_found_.end(), [](char f) { return f != 0; });
}

int VolumeFloor::enforce(const BodyModel& m, std::vector<Vec3>& x, double floor, int max_passes,
                         ThreadPool& pool, const std::function<bool()>& stop) {
  stopped_ = false;
  passes_ = 0;
  if (max_passes <= 0 || !flag(m, x, floor, pool)) return 0;
  // A tet's det F changes only when one of its corners moves: after the first pass, the tets to
  // visit are those with a corner the previous pass or this one moved (mark 2: moved in this
  // pass; 1: in the previous one).
  moved_.assign(x.size(), 0);
  int total = 0;
  for (int pass = 0; pass < max_passes; ++pass) {
    if (pass > 0 && stop && stop()) {
      stopped_ = true;
      break;
    }
    int hits = 0;
    ++passes_;
    for (size_t t = 0; t < m.tets.size(); ++t) {
      const TetRest& tet = m.tets[t];
      const bool visit = pass == 0 ? flagged_[t] || moved_[tet.v[0]] || moved_[tet.v[1]] || moved_[tet.v[2]] ||
                                         moved_[tet.v[3]]
                                   : (moved_[tet.v[0]] | moved_[tet.v[1]] | moved_[tet.v[2]] | moved_[tet.v[3]]) != 0;
      if (!visit || !enforce_volume_floor(tet, x, m.inv_mass, floor)) continue;
      ++hits;
      for (int32_t v : tet.v)
        if (moved_[v] != 2) {
          if (moved_[v] == 0) moved_list_.push_back(v);
          moved_[v] = 2;
        }
    }
    total += hits;
    if (hits == 0) break;
    // This pass's marks become the previous pass's; older ones are dropped.
    size_t kept = 0;
    for (int32_t v : moved_list_) {
      if (moved_[v] == 2) {
        moved_[v] = 1;
        moved_list_[kept++] = v;
      } else {
        moved_[v] = 0;
      }
    }
    moved_list_.resize(kept);
  }
  for (int32_t v : moved_list_) moved_[v] = 0;
  moved_list_.clear();
  return total;
}

}  // namespace pliant::detail
