// SPDX-License-Identifier: Apache-2.0
// Position-based fluids (Macklin & Mueller 2013): particles of spacing d carrying the mass
// rho0 d^3, one density constraint per particle C_i = rho_i / rho0 - 1 (SPH density with the
// poly6 kernel, gradients with the spiky kernel), solved by Jacobi iterations with the
// relaxation epsilon, the artificial pressure s_corr, XSPH viscosity and vorticity confinement,
// against the scene's colliders and an optional container (a box whose inside is the domain).
// Neighbours come from a uniform grid of cell h rebuilt every substep. docs/fluids.md.
#pragma once

#include "pliant/colliders.hpp"
#include "pliant/particle_body.hpp"

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <vector>

namespace pliant {

struct FluidSettings {
  double spacing = 0.02;          // d, m: the lattice spacing of blocks and emitters
  double rest_density = 1000.0;   // rho0, kg/m^3; every particle's mass is rho0 d^3
  double support_ratio = 2.0;     // h = support_ratio * d (kernel support and grid cell)
  // Relaxation epsilon of lambda_i = -C_i / (sum_k |grad_k C_i|^2 + epsilon), as a fraction of
  // sum_k |grad_k C_i|^2 of a particle inside a rest lattice (so it does not depend on d).
  double relaxation = 0.01;
  // Artificial pressure s_corr = -k (W(r) / W(dq))^n, in units of the lambda of a unit
  // compression of a rest lattice particle; dq = scorr_dq * h.
  double scorr_k = 0.001;
  int scorr_n = 4;
  double scorr_dq = 0.2;
  double xsph = 0.01;             // XSPH c (dimensionless: v_i += c sum_j V (v_j - v_i) W_ij)
  double vorticity = 0.0;         // confinement epsilon, m/s (acceleration eps (N x omega))
  Vec3 gravity{0.0, -9.81, 0.0};  // m/s^2
  int substeps = 2;               // per step
  int iterations = 4;             // density iterations per substep
  int threads = 1;                // the calling thread included
  int sort_interval = 10;         // re-sort particles by grid cell every this many substeps
  double particle_radius = 0.5;   // collision radius, as a fraction of d
  // A box whose inside is the domain ("inside-out" box): particles are kept inside it,
  // with the box collider's friction. Colliders passed to step() keep particles outside.
  std::optional<Collider> container;
  // The container's walls count as fluid at rest beyond them in the density (the kernel's mass
  // fraction beyond each wall plane), so particles along a wall are not under-dense.
  bool container_density = true;
  // The soft body's surface met inside the step (ParticleBody::advance's SurfaceBoundary) counts
  // as fluid at rest beyond the plane of the face closest to each particle, as the walls do.
  bool surface_density = true;
  // Particles allowed in all (blocks + emitters); emitters stop there.
  size_t max_particles = 1000000;
};

// A box filled on a lattice of spacing d: points min + (i + 1/2) d inside [min, max].
struct FluidBlock {
  Vec3 min{0, 0, 0};
  Vec3 max{0, 0, 0};
  Vec3 velocity{0, 0, 0};
};

// Particles entering through a disc (radius) or a rectangle (half sizes along two axes
// orthogonal to `direction`) at `speed`: one lattice layer every d / speed seconds, which is
// speed * area / d^3 particles per second; stops at `max_particles` (its own) or at the
// body's cap. The rectangle's half_u runs along `u_axis` made orthogonal to the direction
// (zero, or parallel to it: an axis of the solver's choosing).
struct FluidEmitter {
  enum class Shape { Disc, Rectangle };
  Shape shape = Shape::Disc;
  Vec3 centre{0, 0, 0};
  Vec3 direction{0, -1, 0};  // unit, the flow's direction
  double radius = 0.05;      // disc, m
  double half_u = 0.05;      // rectangle, m
  double half_v = 0.05;
  Vec3 u_axis{0, 0, 0};
  double speed = 1.0;        // m/s
  size_t max_particles = 100000;
};

// Wall time spent in each phase of the substeps since construction (or the last reset), ms,
// all threads together (a parallel phase counts once): the profile of docs/fluids.md.
struct FluidPhaseTimes {
  double sort_ms = 0.0;        // re-sorting particles by grid cell (every sort_interval substeps)
  double predict_ms = 0.0;     // gravity, prediction, colliders and container
  double neighbours_ms = 0.0;  // grid and neighbour lists
  double density_ms = 0.0;     // densities and multipliers lambda (all iterations)
  double correction_ms = 0.0;  // position corrections with s_corr, applied, then colliders and
                               // container (all iterations)
  double grabs_ms = 0.0;       // grabs (all iterations)
  double velocity_ms = 0.0;    // friction and velocities
  double xsph_ms = 0.0;        // XSPH viscosity
  double vorticity_ms = 0.0;   // vorticity confinement
  uint64_t substeps = 0;
};

class FluidBody final : public ParticleBody {
 public:
  // Throws std::invalid_argument naming the field for bad settings (d <= 0, NaN, ...), or when
  // the blocks hold no particle and there is no emitter.
  FluidBody(const FluidSettings& settings, const std::vector<FluidBlock>& blocks,
            const std::vector<FluidEmitter>& emitters = {});
  ~FluidBody() override;

  // Particles the blocks created, and the lattice points of each emitter's layer (in the
  // emitters' order): with the state's emitter progress they give the particle count.
  size_t block_particles() const;
  std::vector<size_t> emitter_layer_sizes() const;

  std::string kind() const override { return "fluid"; }
  size_t size() const override;
  // Particles in the order they were created (blocks first, then emitted ones); the solver
  // keeps its own cache-friendly order internally. lambda: each particle's density multiplier
  // summed over the last substep's iterations (m^2; pressure() converts it). emitters: each
  // emitter's progress. set_state accepts a state with another particle count when its
  // emitters' progress gives that count (blocks + the particles emitted): a snapshot taken
  // before or after some layers were emitted; grabs of particles it drops are released.
  const ParticleState& state() const override;
  void set_state(const ParticleState& state) override;
  std::span<const double> inverse_masses() const override;
  double contact_radius() const override;  // particle_radius x spacing

  int substeps() const override;
  using ParticleBody::advance;
  ParticleStepReport advance(double dt, int substeps, std::span<const Collider> colliders, bool ends_step,
                             SurfaceBoundary* surface, ToolBoundary* tools) override;
  void set_gravity(const Vec3& gravity) override;

  const FluidSettings& settings() const;
  double particle_mass() const;    // kg
  double support_radius() const;   // h, m
  // Pressure of each particle (Pa, creation order) from its multiplier: p = -lambda rho0 kappa /
  // dt_s^2 with dt_s the last substep (the multiplier is the substep's position-level impulse)
  // and kappa = sum_j d^3 (x_j - x_i)_y dW/dy over a rest lattice (0.956 at h = 2d).
  std::vector<double> pressure() const;
  // rho_i / rho0 of each particle at the current positions (creation order).
  std::vector<double> density_ratios() const;
  const FluidPhaseTimes& phase_times() const;
  void reset_phase_times();

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace pliant
