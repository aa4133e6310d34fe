// SPDX-License-Identifier: Apache-2.0
#include "pliant/particle_body.hpp"

#include <algorithm>
#include <numeric>
#include <stdexcept>

namespace pliant {

void check_particle_counts(const ParticleState& state, size_t particles, const std::string& kind) {
  auto check = [&](size_t got, const char* field, const char* what) {
    if (got != particles)
      throw std::invalid_argument(kind + ": ParticleState." + field + " has " + std::to_string(got) + " " + what +
                                  ", the body " + std::to_string(particles) + " particles");
  };
  check(state.x.size(), "x", "positions");
  check(state.v.size(), "v", "velocities");
}

int shared_step_parts(std::span<const int> substeps) {
  int parts = 0;
  for (int n : substeps) parts = std::gcd(parts, std::max(n, 1));
  return std::max(parts, 1);
}

}  // namespace pliant
