// SPDX-License-Identifier: Apache-2.0
// The inversion floor as a stage: passes of the unilateral volume constraint det F >= floor over
// the tets in mesh order (enforce_volume_floor), repeated while a pass still acts. The pass is a
// Gauss-Seidel sweep (a correction moves the corners later tets see), so it stays serial in
// order; what is parallel is finding the few tets it acts on. Each pass first flags, on the pool,
// the tets at or near the floor; the serial sweep then visits only those and the tets one of
// whose corners an earlier correction of the same pass moved. Any other tet has the det F it had
// when flagged, so the plain serial loop would leave it alone too: same result, same bits.
#pragma once

#include "pliant/model.hpp"
#include "step/thread_pool.hpp"

#include <functional>
#include <vector>

namespace pliant::detail {

class VolumeFloor {
 public:
  // At most max_passes passes; returns the number of corrections (0: every tet was above the
  // floor, and x is untouched). When given, stop is asked before each pass after the first (a
  // spent time budget, a cancelled step): true ends the passes there, and stopped() says so.
  int enforce(const BodyModel& model, std::vector<Vec3>& x, double floor, int max_passes, ThreadPool& pool,
              const std::function<bool()>& stop = nullptr);
  bool stopped() const { return stopped_; }
  // The passes the last enforce made (0 when no tet was near the floor).
  int passes() const { return passes_; }

 private:
  // Flags the tets with det F below the floor (plus a margin for the order of the arithmetic);
  // returns whether any is.
  bool flag(const BodyModel& model, const std::vector<Vec3>& x, double floor, ThreadPool& pool);

  std::vector<char> flagged_;  // per tet
  std::vector<char> moved_;    // per vertex, in the current pass
  std::vector<int32_t> moved_list_;
  std::vector<char> chunk_found_;
  bool stopped_ = false;
  int passes_ = 0;
};

}  // namespace pliant::detail
