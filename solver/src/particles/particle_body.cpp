// SPDX-License-Identifier: Apache-2.0
#include "pliant/particle_body.hpp"

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

}  // namespace pliant
