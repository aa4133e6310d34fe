// SPDX-License-Identifier: Apache-2.0
#include "pliant/particle_body.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
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

void ParticleBody::grab(uint64_t id, size_t particle, const Vec3& target, double compliance) {
  if (particle >= size())
    throw std::invalid_argument("grab: particle " + std::to_string(particle) + " out of range (body has " +
                                std::to_string(size()) + ")");
  if (!target.allFinite()) throw std::invalid_argument("grab: target is not finite");
  if (!std::isfinite(compliance) || compliance < 0.0)
    throw std::invalid_argument("grab: compliance must be a finite number >= 0 m/N (got " +
                                fmt::format("{:g}", compliance) + ")");
  grabs_[id] = ParticleGrab{particle, target, compliance};
}

bool ParticleBody::move_grab(uint64_t id, const Vec3& target) {
  auto it = grabs_.find(id);
  if (it == grabs_.end()) return false;
  if (!target.allFinite()) throw std::invalid_argument("move_grab: target is not finite");
  it->second.target = target;
  return true;
}

bool ParticleBody::release(uint64_t id) { return grabs_.erase(id) > 0; }

Vec3 ParticleBody::grab_force(uint64_t id) const {
  auto it = grabs_.find(id);
  return it == grabs_.end() ? Vec3::Zero() : it->second.force;
}

int shared_step_parts(std::span<const int> substeps) {
  int parts = 0;
  for (int n : substeps) parts = std::gcd(parts, std::max(n, 1));
  return std::max(parts, 1);
}

}  // namespace pliant
