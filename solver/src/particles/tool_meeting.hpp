// SPDX-License-Identifier: Apache-2.0
// The scene's tools inside a particle body's call (ToolBoundary): where each is at every substep,
// and per particle and tool the moves the tool gave it in the substep, whose momentum goes to the
// tool. Shared by the kinds that meet the tools (cloth and rope, fluid).
#pragma once

#include "pliant/interaction.hpp"
#include "pliant/particle_body.hpp"

#include <array>
#include <cstdint>
#include <span>
#include <vector>

namespace pliant::detail {

class ToolMeeting {
 public:
  // The tools of `boundary` grown by `radius` over a call of `substeps` substeps of dt / substeps;
  // zeroes the boundary's sums. std::invalid_argument for a radius below 0 or a tool that is not finite.
  ToolMeeting(ToolBoundary& boundary, double radius, double dt, int substeps);

  // Whether a tool can reach a particle over the call: the box of the particles at `x` grown by
  // how far `speed` (m/s, their fastest) and `gravity` (m/s^2) take them in dt, against the box
  // the grown tools sweep. A particle that gets farther does not meet them (as with the soft
  // body's surface).
  bool within_reach(std::span<const Vec3> x, double speed, double gravity) const;
  // Chooses the faces (as push_faces takes them) that a tool can reach over the call, by the same
  // test per face, from the particles at `x`: push_faces looks at these only.
  void select_faces(std::span<const std::array<uint32_t, 3>> faces, std::span<const Vec3> x, double speed,
                    double gravity);
  // The tools where they are at the end of substep s, for `particles` particles.
  void begin_substep(int s, size_t particles);
  // Starts a pass: the particles push() meets, then the faces between them (push_faces).
  void begin_pass() { ++pass_; }

  struct Push {
    double depth = 0.0;  // summed over the tools that pushed (0: none)
    Vec3 normal = Vec3::Zero();  // the last one's
    int tool = -1;       // the last one's index
  };
  // Particle i at p out of every tool it is inside, in the tools' order. Safe to call for
  // different particles from different threads.
  Push push(size_t i, Vec3& p) {
    // Most particles are nowhere near a tool: a box around the tools (grown twice) rules them out.
    if (((p.array() < lo_.array()) || (p.array() > hi_.array())).any()) return Push{};
    return push_near(i, p);
  }
  // Tool k's Coulomb friction on particle i's slip over the substep against the tool's motion
  // (held below static friction x depth, else shortened by dynamic friction x depth); the move
  // counts as the tool's. `moved`: the particle's whole motion over the substep.
  void friction(size_t i, int k, const Vec3& normal, double depth, const Vec3& moved, Vec3& p);

  // After a pass's particles: of the faces between them that select_faces chose (a cloth's
  // triangles, a rope's links as (a, b, b)), those whose inside a tool reaches while none of their
  // corners is within the body's radius of the tool's grown surface (a tool smaller than the
  // faces, between the particles; a corner touching the tool makes the face its contact's: pushed
  // out too, a face that is a chord of the tool would lift its corners off it), as the soft
  // body's faces meet a tool: the face's point closest to the tool's core goes out to the tool's
  // grown surface, with the tool's friction on its slip, each move shared by the corners by their
  // inverse masses (weights `w`; `x_prev`: where the substep started). Serial. Returns the faces
  // it pushed.
  size_t push_faces(std::span<const std::array<uint32_t, 3>> faces, std::span<Vec3> p, std::span<const Vec3> x_prev,
                    std::span<const double> w);
  // Whether a tool at the substep's pose can reach the box (lo, hi).
  bool reaches(const Vec3& lo, const Vec3& hi) const {
    return !((lo.array() > hi_.array()).any() || (hi.array() < lo_.array()).any());
  }

  // After the substep: the momentum each particle gained from each tool (its mass x the tool's
  // moves / h) and its angular momentum about the tool's centre, into the boundary's sums, with
  // the pinned corners' shares of the faces' pushes (their pins take them: the tool still feels
  // the whole push); clears the particles' records for the next substep. `mass(i)`: particle i's
  // mass. Returns the particles a tool pushed.
  template <class Mass>
  size_t give(const Mass& mass) {
    size_t pushed = 0;
    const size_t nt = tools_.size();
    for (size_t i = 0; i < touched_.size(); ++i) {
      if (!touched_[i]) continue;
      touched_[i] = 0;
      ++pushed;
      for (size_t k = 0; k < nt; ++k) {
        Vec3& d = moved_[i * nt + k];
        Vec3& moment = moment_[i * nt + k];
        if (d.isZero() && moment.isZero()) continue;
        boundary_.impulse[k] += mass(i) * d / h_;
        boundary_.angular_impulse[k] += mass(i) * moment / h_;
        d.setZero();
        moment.setZero();
      }
    }
    for (size_t k = 0; k < nt; ++k) {
      boundary_.impulse[k] += pinned_impulse_[k];
      boundary_.angular_impulse[k] += pinned_angular_[k];
    }
    boundary_.pushed = pushed;
    return pushed;
  }

 private:
  Push push_near(size_t i, Vec3& p);
  // Whether a tool's grown swept box over the call meets the box (lo, hi) grown by `reach`.
  bool swept_tools_meet(Vec3 lo, Vec3 hi, double reach) const;

  ToolBoundary& boundary_;
  Vec3 lo_, hi_;  // a box around every tool at the substep's pose, grown twice by the radius
  double radius_, dt_, h_;
  std::vector<RigidTool> tools_;  // grown, at the substep's pose
  std::vector<RigidTool> near_;   // the same grown by the radius once more
  std::vector<Vec3> moved_;       // particle-major, one per tool
  // The same moves' moments about the tool's centre, each taken where the particle was when it
  // moved (the lever of the force the tool gave it there).
  std::vector<Vec3> moment_;
  std::vector<unsigned char> touched_;
  // Per particle: the last pass that found it within the body's radius of a tool's grown surface
  // (0: none); the faces around it are its contact's.
  std::vector<uint32_t> near_in_;
  std::vector<Vec3> pinned_impulse_, pinned_angular_;  // per tool: the pins' shares in the substep
  uint32_t pass_ = 0;
  std::vector<uint32_t> faces_near_;  // select_faces's choice, in the faces' order
};

}  // namespace pliant::detail
