// SPDX-License-Identifier: Apache-2.0
// The least distance between two segments, for tests that check contacts along ropes' links
// and cloths' edges: segment a0-a1 sampled finely (4,001 points) against segment b0-b1 exactly,
// so it is never below the true distance and above it by far less than a micrometre for links
// of centimetres. Header only (it needs Eigen, which the support library does not link).
#pragma once

#include "pliant/mesh.hpp"

#include <algorithm>
#include <cmath>

namespace pliant::test {

inline double segment_distance(const Vec3& a0, const Vec3& a1, const Vec3& b0, const Vec3& b1) {
  const Vec3 d = b1 - b0;
  double best = INFINITY;
  for (int k = 0; k <= 4000; ++k) {
    const Vec3 p = a0 + (a1 - a0) * (k / 4000.0);
    const double s = d.squaredNorm() > 0 ? std::clamp((p - b0).dot(d) / d.squaredNorm(), 0.0, 1.0) : 0.0;
    best = std::min(best, (p - (b0 + s * d)).norm());
  }
  return best;
}

}  // namespace pliant::test
