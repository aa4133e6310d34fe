// SPDX-License-Identifier: Apache-2.0
// Position-based fluids: one substep is (Macklin & Mueller 2013, algorithm 1) gravity and
// prediction, the neighbour grid on the predicted positions, `iterations` Jacobi passes of the
// density constraints (lambda_i, then the corrections with s_corr, then colliders and grabs),
// friction, the velocity from the positions, XSPH viscosity and vorticity confinement.
#include "pliant/fluid.hpp"

#include "fluid/neighbour_grid.hpp"
#include "fluid/pair_gather.hpp"
#include "fluid/sph_kernels.hpp"
#include "particles/surface_contact.hpp"
#include "particles/tool_meeting.hpp"
#include "step/thread_pool.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <map>
#include <numeric>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace pliant {

namespace {

void require(bool ok, const std::string& field, const std::string& what, double value) {
  if (!ok) throw std::invalid_argument("fluid: " + field + " " + what + " (got " + fmt::format("{:g}", value) + ")");
}

bool finite(const Vec3& v) { return v.allFinite(); }

void require_vec(const Vec3& v, const std::string& field) {
  if (!finite(v)) throw std::invalid_argument("fluid: " + field + " must be finite");
}

// Two unit vectors orthogonal to the unit vector n (and to each other).
void basis(const Vec3& n, Vec3& u, Vec3& w) {
  const Vec3 a = std::abs(n.x()) < 0.9 ? Vec3(1, 0, 0) : Vec3(0, 1, 0);
  u = n.cross(a).normalized();
  w = n.cross(u);
}

// The precision of the per-pair kernel terms: the offsets (p_i - p_j) / h are taken in double
// and rounded, then poly6, |r|, the spiky gradient and s_corr are computed in single precision
// in units of h (8 lanes per AVX2 instruction, and single-precision square roots and divisions
// are several times faster; dimensionless, they neither overflow nor underflow at any scale),
// and summed per particle in double with the dimensional factors. The pair's two entries stay
// exactly opposite (the rounded offsets are), so momentum is still conserved.
using PairReal = float;
// The pair loops' loads (fluid/pair_gather.hpp) take and give single precision.
static_assert(std::is_same_v<PairReal, float>);

// Four doubles in one vector register (GCC and Clang vector extensions).
using fluid::Double4;
using fluid::widen4;
// The sum of the four lanes, in a fixed order.
inline double lanes4(const Double4& a) { return (a[0] + a[1]) + (a[2] + a[3]); }

// The SIMD loops of the pair terms, over arrays that do not overlap (__restrict lets the
// compiler vectorise without run-time overlap checks). Selects are written as max(a, 0) of an
// already computed a, the one conditional form the compiler turns into vector code here.
// Poly6 in units of pc h^6 from the offsets in units of h: max(1 - r^2, 0)^3 (0 from h on, and
// for NaN).
void poly6_terms(size_t m, const PairReal* __restrict rx, const PairReal* __restrict ry,
                 const PairReal* __restrict rz, PairReal* __restrict w) {
  for (size_t q = 0; q < m; ++q) {
    const PairReal ax = rx[q], ay = ry[q], az = rz[q];
    const PairReal t0 = PairReal(1) - (ax * ax + ay * ay + az * az);
    const PairReal t = t0 > PairReal(0) ? t0 : PairReal(0);
    w[q] = t * t * t;
  }
}
// The constants of the pair terms, rounded once.
struct PairConstants {
  PairReal same, inv_tdq, scorr_scale;
};
// All the pair terms of the density pass in one SIMD loop, from the offsets r in units of h:
// poly6 W / (pc h^6) = max(1 - r^2, 0)^3 (pc = 315 / (64 pi h^9)), the spiky gradient
// grad W / (sg h^2) = max(1 - |r|, 0)^2 r / |r| (sg = -45 / (pi h^6)) and, with ScorrN > 0,
// s_corr = -scale (W / W(dq))^ScorrN (inv_tdq = 1 / (1 - dq^2)^3, dq in units of h). Returns whether some pair lies on the same point (|r|^2 <= same;
// its gradient is 0 / 0 here, patched by the caller). The square root is correctly rounded in
// every lane: this file is built without errno (see solver/CMakeLists.txt), and Eigen's
// single-precision packet sqrt, an approximation that its scalar tail is not, would make a
// pair's two entries differ.
template <int ScorrN>
bool density_terms(size_t m, const PairReal* __restrict rx, const PairReal* __restrict ry,
                   const PairReal* __restrict rz, const PairConstants& c, PairReal* __restrict w,
                   PairReal* __restrict gx, PairReal* __restrict gy, PairReal* __restrict gz,
                   PairReal* __restrict sc) {
  const PairReal zero = 0;
  int coincident = 0;
  for (size_t q = 0; q < m; ++q) {
    const PairReal ax = rx[q], ay = ry[q], az = rz[q];
    const PairReal d2 = ax * ax + ay * ay + az * az;
    coincident |= static_cast<int>(!(d2 > c.same));
    const PairReal t0 = PairReal(1) - d2;
    const PairReal t = t0 > zero ? t0 : zero;
    const PairReal wq = t * t * t;
    w[q] = wq;
    const PairReal len = std::sqrt(d2);
    const PairReal u0 = PairReal(1) - len;
    const PairReal u = u0 > zero ? u0 : zero;
    const PairReal f = u * u / len;
    gx[q] = f * ax;
    gy[q] = f * ay;
    gz[q] = f * az;
    if constexpr (ScorrN > 0) {
      const PairReal r = wq * c.inv_tdq;
      PairReal rn = r;
      for (int e = 1; e < ScorrN; ++e) rn *= r;
      sc[q] = -c.scorr_scale * rn;
    }
  }
  return coincident != 0;
}

}  // namespace

struct FluidBody::Impl {
  struct Emitter {
    FluidEmitter spec;
    std::vector<Vec3> layer;  // lattice points of one layer, relative to the centre
    double travelled = 0.0;   // m since the last layer
    size_t emitted = 0;
  };

  FluidSettings s;
  fluid::Kernels k;
  double mass = 0.0;
  double h = 0.0;
  double ref_denominator = 0.0;  // sum_k |grad_k C_i|^2 inside a rest lattice, 1/m^2
  double epsilon = 0.0;          // 1/m^2
  double scorr_scale = 0.0;      // k / ref_denominator, m^2
  double wdq = 0.0;              // W(dq)
  double gradient_scale = 1.0;   // the spiky gradient's first moment on the rest lattice
  double last_dt = 0.0;          // the last substep, s

  // Internal (cell-sorted) order.
  std::vector<Vec3> x, v, p, x_prev, dp, omega;
  std::vector<double> lam, lam_sum, ratio, depth, mu_s, mu_k;
  std::vector<Vec3> contact_n;
  // The soft body's surface over a call that passes one, and per particle within a substep: its
  // last push's hit, the closest face within the kernel's support (the surface's density) and
  // that density's gradient in the last iteration, the moves the surface gave (their momentum
  // goes to the surface), whether it pushed the particle, and whether the particle's last
  // contact was the surface (friction against its motion).
  detail::SurfaceMeeting* surface = nullptr;
  std::vector<detail::FaceHit> surface_hit, surface_near;
  std::vector<Vec3> surface_grad, surface_moved;
  std::vector<uint8_t> surface_touched, surface_last;
  // The scene's tools over a call that passes them, and per particle within a substep the tool
  // of its last contact (-1: the last was no tool; friction against that tool's motion).
  detail::ToolMeeting* tools = nullptr;
  std::vector<int> tool_last;
  // Per particle within a substep: whether a collider or the container pushed it (the report's
  // contacts; the surface's and the tools' are counted apart).
  std::vector<uint8_t> walled;
  std::vector<Vec3> wall_grad;       // per particle, within one iteration
  // Per pair, within one iteration: grad W and s_corr, in single precision (half the memory
  // traffic; the pair's two entries stay exactly opposite, so momentum is still conserved).
  std::vector<PairReal> pair_gx, pair_gy, pair_gz, pair_sc;
  std::vector<uint32_t> perm;  // internal -> creation order
  std::vector<uint32_t> inv;   // creation order -> internal

  ParticleState state;  // creation order
  std::vector<double> inv_mass;
  std::vector<Emitter> emitters;
  size_t block_count = 0;  // particles the blocks created (the first ones in creation order)
  std::map<uint64_t, ParticleGrab>& grabs;  // the body's (particle: in creation order)
  fluid::NeighbourGrid grid;
  std::unique_ptr<ThreadPool> pool;
  uint64_t substeps_done = 0;
  FluidPhaseTimes times;

  // Adds the time since *t to the phase's total and moves *t on.
  static void lap(std::chrono::steady_clock::time_point& t, double& total) {
    const auto now = std::chrono::steady_clock::now();
    total += std::chrono::duration<double, std::milli>(now - t).count();
    t = now;
  }

  Impl(const FluidSettings& settings, std::map<uint64_t, ParticleGrab>& body_grabs)
      : s(settings), k(settings.spacing * settings.support_ratio), grabs(body_grabs) {}

  // fn over [0, n) on the pool (one out-of-line copy of it with any thread count: run_parallel).
  void parallel(size_t n, const std::function<void(size_t, size_t)>& fn) {
    run_parallel(pool.get(), n, [&](int, size_t b, size_t e) { fn(b, e); }, 256);
  }

  size_t n() const { return x.size(); }
  // The dimensional factors of the pair terms kept in units of h: poly6 pc h^6, the spiky
  // gradient sg h^2.
  double poly6_scale() const { return k.poly6_c * k.h2 * k.h2 * k.h2; }
  double gradient_unit() const { return k.spiky_g * k.h2; }

  // Pair terms of one particle or of a block of particles, in arrays the compiler vectorises:
  // the offsets (p_i - p_j) / h and poly6 in units of pc h^6. The spiky gradients in units of
  // sg h^2 (fluid::pair_gradient except for pairs on the same point, which the caller patches)
  // and s_corr go straight to the caller's per-pair arrays.
  struct PairScratch {
    std::vector<PairReal> rx, ry, rz, w;
    bool coincident = false;  // some pair on the same point (its gradient is left to the caller)
    void fit(size_t m) {
      if (rx.size() >= m) return;
      for (auto* a : {&rx, &ry, &rz, &w}) a->resize(m + 64);
    }
  };
  // The offsets of particle i to its neighbours nb in units of h, from scratch index `at` on,
  // taken in double and rounded (fluid::pair_offsets: four neighbours a masked load each and a
  // transpose); the arithmetic after it is SIMD.
  void gather(size_t i, std::span<const uint32_t> nb, PairScratch& ps, size_t at) const {
    fluid::pair_offsets(p[i], p.data(), nb.data(), nb.size(), 1.0 / k.h, ps.rx.data() + at, ps.ry.data() + at,
                        ps.rz.data() + at);
  }

  // One particle's poly6 terms (XSPH), in units of pc h^6 (see density_terms).
  void poly6_pairs(size_t i, std::span<const uint32_t> nb, PairScratch& ps) const {
    ps.fit(nb.size());
    gather(i, nb, ps, 0);
    poly6_terms(nb.size(), ps.rx.data(), ps.ry.data(), ps.rz.data(), ps.w.data());
  }

  // The kernel terms of the m pairs whose offsets are in ps (units of h): poly6 / (pc h^6) in ps.w, the gradients / (sg h^2) to
  // g*, and with Scorr s_corr = -scale (W / W(dq))^n to fsc (n = ScorrN when > 0, else the
  // setting).
  template <bool Scorr, int ScorrN>
  void kernel_terms(size_t m, PairScratch& ps, PairReal* gx, PairReal* gy, PairReal* gz, PairReal* fsc) const {
    const PairConstants c{PairReal(1e-18), static_cast<PairReal>(poly6_scale() / wdq),
                          static_cast<PairReal>(scorr_scale)};
    constexpr int kFused = Scorr ? ScorrN : 0;
    ps.coincident = density_terms<kFused>(m, ps.rx.data(), ps.ry.data(), ps.rz.data(), c, ps.w.data(), gx, gy, gz, fsc);
    if constexpr (Scorr && ScorrN <= 0) {
      const PairReal* w = ps.w.data();
      const int n_exp = s.scorr_n;
      for (size_t q = 0; q < m; ++q) {
        const PairReal t = w[q] * c.inv_tdq;
        PairReal tn = t;
        for (int e = 1; e < n_exp; ++e) tn *= t;
        fsc[q] = -c.scorr_scale * tn;
      }
    }
  }

  // lambda_i of the particles at grid slots [b, e), with their density ratio and wall
  // gradient; the pairs' gradients and s_corr go to pair_g* and pair_sc for the correction
  // pass. The kernel terms are computed for blocks of particles at once (long SIMD loops).
  template <bool Scorr, int ScorrN>
  void density_pass(size_t b, size_t e, PairScratch& ps) {
    const double sw = mass / s.rest_density;  // m / rho0
    const double w0 = mass * k.poly6(0.0);
    constexpr size_t kBlock = 32;
    for (size_t s0 = b; s0 < e; s0 += kBlock) {
      const size_t s1 = std::min(e, s0 + kBlock);
      const size_t f0 = grid.slot_first(s0);
      const size_t m_all = grid.slot_first(s1) - f0;
      ps.fit(m_all);
      for (size_t sl = s0; sl < s1; ++sl)
        gather(grid.point(sl), grid.slot_neighbours(sl), ps, grid.slot_first(sl) - f0);
      PairReal* const gxb = pair_gx.data() + f0;
      PairReal* const gyb = pair_gy.data() + f0;
      PairReal* const gzb = pair_gz.data() + f0;
      kernel_terms<Scorr, ScorrN>(m_all, ps, gxb, gyb, gzb, pair_sc.data() + f0);
      if (ps.coincident) {
        // Particles on the same point (a container's corner can put several there): the
        // signed diagonal of fluid::pair_gradient instead of 0 / 0 (in units of sg h^2).
        const double diag = 1.0 / std::sqrt(3.0);
        const PairReal same = PairReal(1e-18);
        for (size_t sl = s0; sl < s1; ++sl) {
          const uint32_t i = grid.point(sl);
          const std::span<const uint32_t> nb = grid.slot_neighbours(sl);
          const size_t at = grid.slot_first(sl) - f0;
          for (size_t q = 0; q < nb.size(); ++q) {
            const PairReal ax = ps.rx[at + q], ay = ps.ry[at + q], az = ps.rz[at + q];
            if (ax * ax + ay * ay + az * az > same && std::isfinite(gxb[at + q])) continue;
            const PairReal d = static_cast<PairReal>(i < nb[q] ? diag : -diag);
            gxb[at + q] = gyb[at + q] = gzb[at + q] = d;
          }
        }
      }
      for (size_t sl = s0; sl < s1; ++sl) {
        const size_t i = grid.point(sl);
        const size_t at = grid.slot_first(sl) - f0;
        const size_t m = grid.slot_first(sl + 1) - f0 - at;
        const PairReal* w = ps.w.data() + at;
        const PairReal* gxs = gxb + at;
        const PairReal* gys = gyb + at;
        const PairReal* gzs = gzb + at;
        // Sums in double with the constant factors applied once, in four lanes (pair q in
        // lane q mod 4, whatever the block or thread), then the lanes and the last pairs in a
        // fixed order.
        Double4 l_w{}, l_x{}, l_y{}, l_z{}, l_s{};
        size_t q = 0;
        for (; q + 4 <= m; q += 4) {
          const Double4 gxq = widen4(gxs + q), gyq = widen4(gys + q), gzq = widen4(gzs + q);
          l_w += widen4(w + q);
          l_x += gxq;
          l_y += gyq;
          l_z += gzq;
          l_s += gxq * gxq + gyq * gyq + gzq * gzq;
        }
        double a_w = lanes4(l_w), a_x = lanes4(l_x), a_y = lanes4(l_y), a_z = lanes4(l_z), a_s = lanes4(l_s);
        for (; q < m; ++q) {
          const double gxq = gxs[q], gyq = gys[q], gzq = gzs[q];
          a_w += w[q];
          a_x += gxq;
          a_y += gyq;
          a_z += gzq;
          a_s += gxq * gxq + gyq * gyq + gzq * gzq;
        }
        const double rho = w0 + mass * poly6_scale() * a_w;
        const double gs = sw * gradient_unit();
        const double gx = gs * a_x, gy = gs * a_y, gz = gs * a_z;
        const double sq = gs * gs * a_s;
        Vec3 gw, gsurf;
        const double c = rho / s.rest_density + wall_density(p[i], gw) + surface_density(i, gsurf) - 1.0;
        if (surface) surface_grad[i] = gsurf;
        gw += gsurf;
        wall_grad[i] = gw;
        const Vec3 gi = Vec3(gx, gy, gz) + gw;
        ratio[i] = c + 1.0;
        // Only compression is corrected (C clamped at 0): multipliers stay <= 0.
        lam[i] = c > 0.0 ? -c / (gi.squaredNorm() + sq + epsilon) : 0.0;
      }
    }
  }

  // Corrections of particles [b, e): sum_j (lam_i + lam_j + s_corr) grad W, and the walls'
  // share of grad_i C_i (pair terms from the density pass, the same positions), applied to p,
  // then the colliders and the container.
  template <bool Scorr>
  void correction_pass(size_t b, size_t e, std::span<const Collider> inflated) {
    const double gs = mass / s.rest_density * gradient_unit();  // m / rho0 in units of the gradients
    for (size_t i = b; i < e; ++i) {
      const std::span<const uint32_t> nb = grid.neighbours(i);
      const size_t f = grid.first(i);
      const PairReal* gxs = pair_gx.data() + f;
      const PairReal* gys = pair_gy.data() + f;
      const PairReal* gzs = pair_gz.data() + f;
      const PairReal* scs = pair_sc.data() + f;
      const size_t m = nb.size();
      const double li = lam[i];
      const uint32_t* J = nb.data();
      const double* L = lam.data();
      // In four lanes as in the density pass, then the lanes and the last pairs.
      Double4 l_x{}, l_y{}, l_z{};
      size_t q = 0;
      for (; q + 4 <= m; q += 4) {
        const Double4 lj = {L[J[q]], L[J[q + 1]], L[J[q + 2]], L[J[q + 3]]};
        const Double4 c = Scorr ? li + lj + widen4(scs + q) : li + lj;
        l_x += c * widen4(gxs + q);
        l_y += c * widen4(gys + q);
        l_z += c * widen4(gzs + q);
      }
      double dx = lanes4(l_x), dy = lanes4(l_y), dz = lanes4(l_z);
      for (; q < m; ++q) {
        const double c = Scorr ? li + L[J[q]] + scs[q] : li + L[J[q]];
        dx += c * gxs[q];
        dy += c * gys[q];
        dz += c * gzs[q];
      }
      p[i] += gs * Vec3(dx, dy, dz) + li * wall_grad[i];
      if (surface) surface_moved[i] += li * surface_grad[i];
      lam_sum[i] += li;
      collide(i, inflated);
    }
  }

  void add_particle(const Vec3& xi, const Vec3& vi) {
    const uint32_t id = static_cast<uint32_t>(state.x.size());
    x.push_back(xi);
    v.push_back(vi);
    lam_sum.push_back(0.0);
    perm.push_back(id);
    inv.push_back(static_cast<uint32_t>(x.size() - 1));
    state.x.push_back(xi);
    state.v.push_back(vi);
    state.lambda.push_back(0.0);
    inv_mass.push_back(1.0 / mass);
  }

  void reorder() {
    const std::vector<uint32_t> order = fluid::NeighbourGrid::cell_order(x, h, pool.get());
    auto gather = [&](auto& a) {
      std::remove_reference_t<decltype(a)> b(a.size());
      for (size_t i = 0; i < order.size(); ++i) b[i] = a[order[i]];
      a.swap(b);
    };
    gather(x);
    gather(v);
    gather(lam_sum);
    gather(perm);
    for (size_t i = 0; i < perm.size(); ++i) inv[perm[i]] = static_cast<uint32_t>(i);
  }

  void emit(double dt) {
    for (Emitter& e : emitters) {
      e.travelled += e.spec.speed * dt;
      while (e.travelled >= s.spacing) {
        e.travelled -= s.spacing;
        if (e.emitted + e.layer.size() > e.spec.max_particles ||
            n() + e.layer.size() > s.max_particles) {
          e.travelled = 0.0;
          break;
        }
        const Vec3 at = e.spec.centre + e.travelled * e.spec.direction;
        for (const Vec3& q : e.layer) add_particle(at + q, e.spec.speed * e.spec.direction);
        e.emitted += e.layer.size();
      }
    }
  }

  // Pushes p out of the colliders (inflated by the particle radius), into the container, out of
  // the soft body's surface and out of the scene's tools; accumulates the depth and keeps the
  // last normal and friction for particle i.
  void collide(size_t i, std::span<const Collider> cols) {
    const double r = s.particle_radius * s.spacing;
    Vec3& pi = p[i];
    for (const Collider& c : cols) {
      ContactPoint cp;
      if (!find_contact(c, pi, cp) || !(cp.depth > 0)) continue;
      pi += cp.depth * cp.normal;
      depth[i] += cp.depth;
      walled[i] = 1;
      contact_n[i] = cp.normal;
      mu_s[i] = c.static_friction;
      mu_k[i] = c.dynamic_friction;
      if (surface) surface_last[i] = 0;
      if (tools) tool_last[i] = -1;
    }
    if (s.container) {
      const Collider& c = *s.container;
      for (int a = 0; a < 3; ++a) {
        const double hi = c.point[a] + c.half_extent[a] - r;
        const double lo = c.point[a] - c.half_extent[a] + r;
        double d = 0.0;
        Vec3 nrm = Vec3::Zero();
        if (pi[a] > hi) {
          d = pi[a] - hi;
          pi[a] = hi;
          nrm[a] = -1.0;
        } else if (pi[a] < lo) {
          d = lo - pi[a];
          pi[a] = lo;
          nrm[a] = 1.0;
        }
        if (d > 0) {
          depth[i] += d;
          walled[i] = 1;
          contact_n[i] = nrm;
          mu_s[i] = c.static_friction;
          mu_k[i] = c.dynamic_friction;
          if (surface) surface_last[i] = 0;
          if (tools) tool_last[i] = -1;
        }
      }
    }
    if (surface) {
      const Vec3 before = pi;
      const double d = surface->push(x_prev[i], pi, surface_hit[i]);
      if (d > 0) {
        depth[i] += d;
        contact_n[i] = surface_hit[i].n;
        mu_s[i] = mu_k[i] = surface->friction();
        surface_moved[i] += pi - before;
        surface_touched[i] = surface_last[i] = 1;
        if (tools) tool_last[i] = -1;
      }
    }
    if (tools) {
      const detail::ToolMeeting::Push pr = tools->push(i, pi);
      if (pr.tool >= 0) {
        depth[i] += pr.depth;
        contact_n[i] = pr.normal;
        tool_last[i] = pr.tool;
        if (surface) surface_last[i] = 0;
      }
    }
  }

  // The container's walls as fluid at rest beyond them (boundary density): the density
  // fraction they add to particle at q (rho / rho0) and its gradient with respect to q.
  double wall_density(const Vec3& q, Vec3& grad) const {
    grad.setZero();
    if (!s.container || !s.container_density) return 0.0;
    const Collider& c = *s.container;
    double f = 0.0;
    for (int a = 0; a < 3; ++a) {
      const double ylo = q[a] - (c.point[a] - c.half_extent[a]);
      const double yhi = (c.point[a] + c.half_extent[a]) - q[a];
      if (ylo < h) {
        f += fluid::poly6_beyond(k, ylo);
        grad[a] += fluid::poly6_beyond_slope(k, ylo);
      }
      if (yhi < h) {
        f += fluid::poly6_beyond(k, yhi);
        grad[a] -= fluid::poly6_beyond_slope(k, yhi);
      }
    }
    return f;
  }

  // The soft body's surface as fluid at rest beyond the plane of the face closest to particle i
  // (within the support; SurfaceBoundary): the density fraction it adds and its gradient.
  double surface_density(size_t i, Vec3& grad) {
    grad.setZero();
    if (!surface || !s.surface_density) return 0.0;
    double y;
    detail::FaceHit hit;
    if (!surface->closest(p[i], hit, y) || !(y < h)) return 0.0;
    surface_near[i] = hit;
    grad = fluid::poly6_beyond_slope(k, y) * hit.n;
    return fluid::poly6_beyond(k, y);
  }

  // The step's largest buffers filled once when the body is built: a neighbour search of the
  // particles where they are and the per-pair arrays sized for its pairs and a quarter more. The
  // first step of a new body then costs about what the next ones do, where it took half as long
  // again to fill them (docs/fluids.md, "Figures"). Every step still sizes and rebuilds them.
  void prepare_buffers() {
    if (x.empty()) return;
    grid.build(x, h, pool.get());
    const size_t pairs = grid.pairs() + grid.pairs() / 4;
    for (auto* a : {&pair_gx, &pair_gy, &pair_gz, &pair_sc}) a->resize(pairs);
  }

  void substep(int sub, double dt, std::span<const Collider> inflated, ParticleStepReport& rep) {
    emit(dt);
    auto clock = std::chrono::steady_clock::now();
    if (s.sort_interval > 0 && substeps_done % static_cast<uint64_t>(s.sort_interval) == 0) reorder();
    lap(clock, times.sort_ms);
    ++substeps_done;
    ++times.substeps;
    last_dt = dt;
    const size_t N = n();
    p.resize(N);
    x_prev.resize(N);
    dp.resize(N);
    lam.resize(N);
    ratio.resize(N);
    depth.assign(N, 0.0);
    walled.assign(N, 0);
    contact_n.resize(N);
    mu_s.resize(N);
    mu_k.resize(N);
    if (surface) {
      surface_hit.resize(N);
      surface_near.assign(N, detail::FaceHit{});
      surface_grad.assign(N, Vec3::Zero());
      surface_moved.assign(N, Vec3::Zero());
      surface_touched.assign(N, 0);
      surface_last.assign(N, 0);
    }
    if (tools) {
      tools->begin_substep(sub, N);
      tool_last.assign(N, -1);
    }
    const Vec3 g = s.gravity;
    parallel(N, [&](size_t b, size_t e) {
      for (size_t i = b; i < e; ++i) {
        v[i] += dt * g;
        x_prev[i] = x[i];
        p[i] = x[i] + dt * v[i];
        lam_sum[i] = 0.0;
        collide(i, inflated);
      }
    });
    lap(clock, times.predict_ms);
    grid.build(p, h, pool.get());
    lap(clock, times.neighbours_ms);
    for (auto& [id, gr] : grabs) gr.lambda[0] = 0.0;

    const double sw = mass / s.rest_density;  // m / rho0
    wall_grad.resize(N);
    // Each iteration: the multipliers, then the corrections from the same positions, so the
    // pairs' kernel gradients and s_corr are computed once and kept for the second pass.
    pair_gx.resize(grid.pairs());
    pair_gy.resize(grid.pairs());
    pair_gz.resize(grid.pairs());
    pair_sc.resize(grid.pairs());
    for (int it = 0; it < s.iterations; ++it) {
      parallel(N, [&](size_t b, size_t e) {
        PairScratch ps;
        if (!(scorr_scale > 0.0))
          density_pass<false, 0>(b, e, ps);
        else if (s.scorr_n == 4)
          density_pass<true, 4>(b, e, ps);
        else
          density_pass<true, 0>(b, e, ps);
      });
      lap(clock, times.density_ms);
      // The corrections read multipliers and pair terms only, never positions, so each
      // particle's is applied (with its colliders) as soon as it is known: one pass.
      parallel(N, [&](size_t b, size_t e) {
        if (scorr_scale > 0.0)
          correction_pass<true>(b, e, inflated);
        else
          correction_pass<false>(b, e, inflated);
      });
      lap(clock, times.correction_ms);
      const double w = 1.0 / mass;
      for (auto& [id, gr] : grabs) {
        Vec3& pg = p[inv[gr.particle]];
        const Vec3 diff = pg - gr.target;
        const double len = diff.norm();
        if (len < 1e-12) continue;
        gr.normal = diff / len;
        const double alpha = gr.compliance / (dt * dt);
        const double dl = (-len - alpha * gr.lambda[0]) / (w + alpha);
        pg += w * dl * gr.normal;
        gr.lambda[0] += dl;
      }
      lap(clock, times.grabs_ms);
    }
    for (auto& [id, gr] : grabs) gr.force = gr.normal * gr.lambda[0] / (dt * dt);

    // Friction at position level against each particle's last contact, then velocities.
    size_t contacts = 0;
    for (size_t i = 0; i < N; ++i) contacts += walled[i];
    parallel(N, [&](size_t b, size_t e) {
      for (size_t i = b; i < e; ++i) {
        if (depth[i] > 0.0 && tools && tool_last[i] >= 0) {
          // The slip against the tool's motion when that was the last contact.
          tools->friction(i, tool_last[i], contact_n[i], depth[i], Vec3(p[i] - x_prev[i]), p[i]);
        } else if (depth[i] > 0.0) {
          // The slip against the surface's own motion when that was the last contact.
          const bool on_surface = surface && surface_last[i];
          const Vec3 nn = contact_n[i];
          const Vec3 moved = p[i] - x_prev[i] - (on_surface ? Vec3(dt * surface->velocity(surface_hit[i])) : Vec3::Zero());
          const Vec3 tang = moved - moved.dot(nn) * nn;
          const double tl = tang.norm();
          if (tl > 0.0) {
            const Vec3 back = tl <= mu_s[i] * depth[i] ? tang : Vec3(tang * std::min(mu_k[i] * depth[i] / tl, 1.0));
            p[i] -= back;
            if (on_surface) surface_moved[i] -= back;
          }
        }
        v[i] = (p[i] - x_prev[i]) / dt;
      }
    });
    if (surface) {
      // The momentum the surface's moves gave each particle (its pushes and its density's),
      // handed to the corners of the face it last pushed from, else of its closest face.
      size_t touching = 0;
      for (size_t i = 0; i < N; ++i) {
        touching += surface_touched[i];
        const detail::FaceHit& at = surface_touched[i] ? surface_hit[i] : surface_near[i];
        if (at.triangle >= 0 && !surface_moved[i].isZero()) surface->give(at, mass * surface_moved[i] / dt);
      }
      rep.soft_body_contacts = touching;
    }
    if (tools) rep.tool_contacts = tools->give([this](size_t) { return mass; });
    lap(clock, times.velocity_ms);
    // XSPH viscosity (Jacobi: from the velocities before it), symmetric weights.
    if (s.xsph > 0.0) {
      parallel(N, [&](size_t b, size_t e) {
        PairScratch ps;
        for (size_t i = b; i < e; ++i) {
          const std::span<const uint32_t> nb = grid.neighbours(i);
          poly6_pairs(i, nb, ps);
          const Vec3 vi = v[i];
          const size_t m = nb.size();
          const uint32_t* J = nb.data();
          const PairReal* W = ps.w.data();
          // In four lanes as in the density pass, then the lanes and the last pairs.
          Double4 l_x{}, l_y{}, l_z{};
          size_t q = 0;
          for (; q + 4 <= m; q += 4) {
            const fluid::Lanes3 vj = fluid::gather4(v.data(), J + q);
            const Double4 w = widen4(W + q);
            l_x += (vj.x - vi.x()) * w;
            l_y += (vj.y - vi.y()) * w;
            l_z += (vj.z - vi.z()) * w;
          }
          double ax = lanes4(l_x), ay = lanes4(l_y), az = lanes4(l_z);
          for (; q < m; ++q) {
            const Vec3& vj = v[J[q]];
            const double w = W[q];
            ax += (vj.x() - vi.x()) * w;
            ay += (vj.y() - vi.y()) * w;
            az += (vj.z() - vi.z()) * w;
          }
          dp[i] = vi + s.xsph * sw * poly6_scale() * Vec3(ax, ay, az);
        }
      });
      std::swap(v, dp);
    }
    lap(clock, times.xsph_ms);
    if (s.vorticity > 0.0) {
      omega.resize(N);
      parallel(N, [&](size_t b, size_t e) {
        for (size_t i = b; i < e; ++i) {
          Vec3 w = Vec3::Zero();
          for (uint32_t j : grid.neighbours(i)) w += k.spiky_gradient(p[i] - p[j]).cross(v[j] - v[i]);
          omega[i] = sw * w;
        }
      });
      parallel(N, [&](size_t b, size_t e) {
        for (size_t i = b; i < e; ++i) {
          const double wi = omega[i].norm();
          Vec3 eta = Vec3::Zero();
          for (uint32_t j : grid.neighbours(i)) eta += (omega[j].norm() - wi) * k.spiky_gradient(p[i] - p[j]);
          const double len = eta.norm();
          dp[i] = len > 1e-12 ? Vec3(dt * s.vorticity * (eta / len).cross(omega[i])) : Vec3::Zero();
        }
      });
      for (size_t i = 0; i < N; ++i) v[i] += dp[i];
    }
    lap(clock, times.vorticity_ms);
    std::swap(x, p);
    rep.contacts = contacts;
  }

  void sync_state() {
    const size_t N = n();
    for (size_t i = 0; i < N; ++i) {
      const uint32_t u = perm[i];
      state.x[u] = x[i];
      state.v[u] = v[i];
      state.lambda[u] = lam_sum[i];
    }
    state.order = perm;
    state.substeps = substeps_done;
    state.emitters.resize(emitters.size());
    for (size_t e = 0; e < emitters.size(); ++e) state.emitters[e] = {emitters[e].travelled, emitters[e].emitted};
  }

  // Another particle count (a restored state emitted more or fewer layers): the solver's order
  // becomes the creation order and grabs of particles that no longer exist are released.
  void resize(size_t count) {
    for (auto* a : {&x, &v, &state.x, &state.v}) a->resize(count, Vec3::Zero());
    lam_sum.resize(count, 0.0);
    state.lambda.resize(count, 0.0);
    inv_mass.assign(count, 1.0 / mass);
    perm.resize(count);
    std::iota(perm.begin(), perm.end(), 0u);
    inv = perm;
    for (auto it = grabs.begin(); it != grabs.end();) it = it->second.particle >= count ? grabs.erase(it) : std::next(it);
  }
};

FluidBody::FluidBody(const FluidSettings& st, const std::vector<FluidBlock>& blocks,
                     const std::vector<FluidEmitter>& emitters) {
  require(std::isfinite(st.spacing) && st.spacing > 0, "spacing", "must be > 0", st.spacing);
  require(std::isfinite(st.rest_density) && st.rest_density > 0, "rest_density", "must be > 0", st.rest_density);
  require(std::isfinite(st.support_ratio) && st.support_ratio > 1.0 && st.support_ratio <= 4.0, "support_ratio",
          "must be in (1, 4]", st.support_ratio);
  require(std::isfinite(st.relaxation) && st.relaxation > 0, "relaxation", "must be > 0", st.relaxation);
  require(std::isfinite(st.scorr_k) && st.scorr_k >= 0, "scorr_k", "must be >= 0", st.scorr_k);
  require(st.scorr_n >= 1 && st.scorr_n <= 16, "scorr_n", "must be in [1, 16]", st.scorr_n);
  require(std::isfinite(st.scorr_dq) && st.scorr_dq > 0 && st.scorr_dq < 1, "scorr_dq", "must be in (0, 1)",
          st.scorr_dq);
  require(std::isfinite(st.xsph) && st.xsph >= 0 && st.xsph <= 1, "xsph", "must be in [0, 1]", st.xsph);
  require(std::isfinite(st.vorticity) && st.vorticity >= 0, "vorticity", "must be >= 0", st.vorticity);
  require_vec(st.gravity, "gravity");
  require(st.substeps >= 1, "substeps", "must be >= 1", st.substeps);
  require(st.iterations >= 1, "iterations", "must be >= 1", st.iterations);
  require(st.threads >= 1 && st.threads <= 256, "threads", "must be in [1, 256]", st.threads);
  require(st.sort_interval >= 0, "sort_interval", "must be >= 0", st.sort_interval);
  require(std::isfinite(st.particle_radius) && st.particle_radius >= 0 && st.particle_radius <= 1,
          "particle_radius", "must be in [0, 1]", st.particle_radius);
  require(st.max_particles >= 1 && st.max_particles < (size_t(1) << 31), "max_particles",
          "must be in [1, 2^31)", static_cast<double>(st.max_particles));
  if (st.container) {
    const Collider& c = *st.container;
    if (c.shape != Collider::Shape::Box) throw std::invalid_argument("fluid: container must be a box collider");
    require_vec(c.point, "container.point");
    require_vec(c.half_extent, "container.half_extent");
    require(c.half_extent.minCoeff() > st.particle_radius * st.spacing, "container.half_extent",
            "must exceed the particle radius on every axis", c.half_extent.minCoeff());
  }

  impl_ = std::make_unique<Impl>(st, grabs_);
  Impl& m = *impl_;
  m.h = st.spacing * st.support_ratio;
  m.mass = st.rest_density * st.spacing * st.spacing * st.spacing;
  if (st.threads > 1) m.pool = std::make_unique<ThreadPool>(st.threads);

  // The reference denominator: a particle inside a rest lattice of spacing d.
  {
    std::vector<Vec3> nb;
    const int r = static_cast<int>(std::ceil(st.support_ratio));
    for (int a = -r; a <= r; ++a)
      for (int b = -r; b <= r; ++b)
        for (int c = -r; c <= r; ++c) {
          const Vec3 q = st.spacing * Vec3(a, b, c);
          if ((a || b || c) && q.squaredNorm() < m.h * m.h) nb.push_back(q);
        }
    Vec3 gi;
    double sq = 0.0;
    const double c0 = fluid::density_constraint(m.k, m.mass, st.rest_density, Vec3::Zero(), nb, &gi, &sq);
    m.ref_denominator = gi.squaredNorm() + sq;
    // sum_j d^3 (x_j - x_i)_y dW/dy on the lattice: 1 for the continuous kernel, a little less
    // on a lattice. A multiplier field lambda = a y pushes particles by a kappa per substep, so
    // the pressure whose gradient the corrections balance is -lambda rho0 kappa / dt^2.
    m.gradient_scale = 0.0;
    for (const Vec3& q : nb) m.gradient_scale += st.spacing * st.spacing * st.spacing * q.y() * m.k.spiky_gradient(-q).y();
    m.epsilon = st.relaxation * m.ref_denominator;
    m.scorr_scale = st.scorr_k / m.ref_denominator;
    m.wdq = m.k.poly6(std::pow(st.scorr_dq * m.h, 2));
    spdlog::debug("fluid: h {} m, mass {} kg, {} lattice neighbours, lattice rho/rho0 {:.4f}", m.h, m.mass,
                  nb.size(), c0 + 1.0);
  }

  for (size_t bi = 0; bi < blocks.size(); ++bi) {
    const FluidBlock& b = blocks[bi];
    const std::string f = "blocks[" + std::to_string(bi) + "]";
    require_vec(b.min, f + ".min");
    require_vec(b.max, f + ".max");
    require_vec(b.velocity, f + ".velocity");
    const Vec3 ext = b.max - b.min;
    require(ext.minCoeff() >= 0, f + ".max", "must not be below min", ext.minCoeff());
    const long nx = static_cast<long>(std::floor(ext.x() / st.spacing + 1e-9));
    const long ny = static_cast<long>(std::floor(ext.y() / st.spacing + 1e-9));
    const long nz = static_cast<long>(std::floor(ext.z() / st.spacing + 1e-9));
    require(static_cast<double>(nx) * ny * nz + m.n() <= static_cast<double>(st.max_particles), f,
            "holds more particles than max_particles", static_cast<double>(nx) * ny * nz);
    for (long c = 0; c < nz; ++c)
      for (long bb = 0; bb < ny; ++bb)
        for (long a = 0; a < nx; ++a)
          m.add_particle(b.min + st.spacing * Vec3(a + 0.5, bb + 0.5, c + 0.5), b.velocity);
  }
  m.block_count = m.n();
  for (size_t ei = 0; ei < emitters.size(); ++ei) {
    const FluidEmitter& e = emitters[ei];
    const std::string f = "emitters[" + std::to_string(ei) + "]";
    require_vec(e.centre, f + ".centre");
    require_vec(e.direction, f + ".direction");
    require(e.direction.norm() > 1e-12, f + ".direction", "must not be zero", e.direction.norm());
    require_vec(e.u_axis, f + ".u_axis");
    require(std::isfinite(e.speed) && e.speed > 0, f + ".speed", "must be > 0", e.speed);
    Impl::Emitter em;
    em.spec = e;
    em.spec.direction = e.direction.normalized();
    Vec3 u, w;
    basis(em.spec.direction, u, w);
    const Vec3 across = e.u_axis - e.u_axis.dot(em.spec.direction) * em.spec.direction;
    if (across.norm() > 1e-9 * std::max(1.0, e.u_axis.norm())) {
      u = across.normalized();
      w = em.spec.direction.cross(u);
    }
    if (e.shape == FluidEmitter::Shape::Disc) {
      require(std::isfinite(e.radius) && e.radius > 0, f + ".radius", "must be > 0", e.radius);
      const int r = static_cast<int>(std::floor(e.radius / st.spacing + 1e-9));
      for (int a = -r; a <= r; ++a)
        for (int b = -r; b <= r; ++b)
          if ((a * a + b * b) * st.spacing * st.spacing <= e.radius * e.radius * (1 + 1e-9))
            em.layer.push_back(st.spacing * (a * u + b * w));
    } else {
      require(std::isfinite(e.half_u) && e.half_u > 0, f + ".half_u", "must be > 0", e.half_u);
      require(std::isfinite(e.half_v) && e.half_v > 0, f + ".half_v", "must be > 0", e.half_v);
      const int ru = static_cast<int>(std::floor(e.half_u / st.spacing + 1e-9));
      const int rv = static_cast<int>(std::floor(e.half_v / st.spacing + 1e-9));
      for (int a = -ru; a <= ru; ++a)
        for (int b = -rv; b <= rv; ++b) em.layer.push_back(st.spacing * (a * u + b * w));
    }
    m.emitters.push_back(std::move(em));
  }
  if (m.n() == 0 && m.emitters.empty())
    throw std::invalid_argument("fluid: blocks hold no particle and there is no emitter (zero particles)");
  m.state.emitters.assign(m.emitters.size(), EmitterProgress{});
  m.prepare_buffers();
}

FluidBody::~FluidBody() = default;

size_t FluidBody::size() const { return impl_->n(); }
size_t FluidBody::block_particles() const { return impl_->block_count; }
std::vector<size_t> FluidBody::emitter_layer_sizes() const {
  std::vector<size_t> out;
  for (const Impl::Emitter& e : impl_->emitters) out.push_back(e.layer.size());
  return out;
}
const ParticleState& FluidBody::state() const { return impl_->state; }
std::span<const double> FluidBody::inverse_masses() const { return impl_->inv_mass; }
double FluidBody::contact_radius() const { return impl_->s.particle_radius * impl_->s.spacing; }
const FluidSettings& FluidBody::settings() const { return impl_->s; }

void FluidBody::set_gravity(const Vec3& gravity) {
  if (!gravity.allFinite()) throw std::invalid_argument("FluidSettings.gravity must be finite");
  impl_->s.gravity = gravity;
}
double FluidBody::particle_mass() const { return impl_->mass; }
double FluidBody::support_radius() const { return impl_->h; }

void FluidBody::set_state(const ParticleState& st) {
  Impl& m = *impl_;
  // The particle count: the body's own, or the one the state's emitter progress gives.
  size_t N = m.n();
  if (!st.emitters.empty()) {
    if (st.emitters.size() != m.emitters.size())
      throw std::invalid_argument("fluid: state.emitters has " + std::to_string(st.emitters.size()) +
                                  " entries, the body " + std::to_string(m.emitters.size()) + " emitters (or give none)");
    N = m.block_count;
    for (size_t e = 0; e < st.emitters.size(); ++e) {
      const EmitterProgress& ep = st.emitters[e];
      const Impl::Emitter& em = m.emitters[e];
      const std::string f = "state.emitters[" + std::to_string(e) + "]";
      require(std::isfinite(ep.travelled) && ep.travelled >= 0 && ep.travelled < m.s.spacing, f + ".travelled",
              "must be in [0, spacing)", ep.travelled);
      if (ep.emitted > em.spec.max_particles || ep.emitted % em.layer.size() != 0)
        throw std::invalid_argument("fluid: " + f + ".emitted is " + std::to_string(ep.emitted) +
                                    ", not a whole number of layers of " + std::to_string(em.layer.size()) +
                                    " particles up to the emitter's max_particles " +
                                    std::to_string(em.spec.max_particles));
      N += ep.emitted;
    }
    if (N > m.s.max_particles)
      throw std::invalid_argument("fluid: state.emitters give " + std::to_string(N) +
                                  " particles, more than max_particles " + std::to_string(m.s.max_particles));
  }
  check_particle_counts(st, N, "fluid");
  if (!st.lambda.empty() && st.lambda.size() != N)
    throw std::invalid_argument("fluid: state.lambda has " + std::to_string(st.lambda.size()) +
                                " multipliers, the body " + std::to_string(N) + " particles (or give none)");
  for (size_t i = 0; i < N; ++i) {
    if (!st.x[i].allFinite()) throw std::invalid_argument("fluid: state.x[" + std::to_string(i) + "] is not finite");
    if (!st.v[i].allFinite()) throw std::invalid_argument("fluid: state.v[" + std::to_string(i) + "] is not finite");
    if (!st.lambda.empty() && !std::isfinite(st.lambda[i]))
      throw std::invalid_argument("fluid: state.lambda[" + std::to_string(i) + "] is not finite");
  }
  require(std::isfinite(st.time), "state.time", "must be finite", st.time);
  if (!st.order.empty()) {
    // The solver's particle order: a permutation of the particles.
    if (st.order.size() != N)
      throw std::invalid_argument("fluid: state.order has " + std::to_string(st.order.size()) + " entries, the body " +
                                  std::to_string(N) + " particles (or give none)");
    std::vector<char> seen(N, 0);
    for (size_t k = 0; k < N; ++k) {
      const uint32_t u = st.order[k];
      if (u >= N || seen[u])
        throw std::invalid_argument("fluid: state.order[" + std::to_string(k) + "] = " + std::to_string(u) +
                                    (u >= N ? " is out of range" : " appears twice") + " (a permutation of the " +
                                    std::to_string(N) + " particles)");
      seen[u] = 1;
    }
  }
  if (N != m.n()) m.resize(N);
  if (!st.order.empty()) {
    m.perm = st.order;
    for (size_t k = 0; k < N; ++k) m.inv[m.perm[k]] = static_cast<uint32_t>(k);
    m.substeps_done = st.substeps;
  }
  for (size_t e = 0; e < st.emitters.size(); ++e) {
    m.emitters[e].travelled = st.emitters[e].travelled;
    m.emitters[e].emitted = st.emitters[e].emitted;
  }
  for (size_t i = 0; i < N; ++i) {
    const uint32_t k = m.inv[i];
    m.x[k] = st.x[i];
    m.v[k] = st.v[i];
    m.lam_sum[k] = st.lambda.empty() ? 0.0 : st.lambda[i];
  }
  m.state.time = st.time;
  m.state.steps = st.steps;
  m.sync_state();
}

int FluidBody::substeps() const { return impl_->s.substeps; }

ParticleStepReport FluidBody::advance(double dt, int substeps, std::span<const Collider> colliders, bool ends_step,
                                      SurfaceBoundary* surface, ToolBoundary* tools) {
  require(std::isfinite(dt) && dt > 0, "dt", "must be > 0", dt);
  require(substeps >= 1, "substeps", "must be >= 1", substeps);
  Impl& m = *impl_;
  const auto t0 = std::chrono::steady_clock::now();
  const double r = m.s.particle_radius * m.s.spacing;
  std::vector<Collider> inflated(colliders.begin(), colliders.end());
  for (Collider& c : inflated) {
    switch (c.shape) {
      case Collider::Shape::Plane: c.point += r * c.normal; break;
      case Collider::Shape::Sphere: c.radius += r; break;
      case Collider::Shape::Box: c.half_extent += Vec3::Constant(r); break;
    }
  }
  ParticleStepReport rep;
  rep.substeps = substeps;
  rep.iterations = m.s.iterations;
  const double h = dt / substeps;
  std::optional<detail::SurfaceMeeting> meeting;
  if (surface) {
    // The surface near where the particles can get over the call (the particles and the layers
    // the emitters may add): as far as their speed and gravity take them over dt, and a kernel
    // support for the density corrections. A particle that gets farther does not meet it.
    double fastest = 0.0;
    for (const Vec3& vi : m.v) fastest = std::max(fastest, vi.norm());
    std::vector<Vec3> with_layers;  // the particles and the emitters' layers, when there are emitters
    for (const Impl::Emitter& e : m.emitters) {
      fastest = std::max(fastest, e.spec.speed);
      for (const Vec3& q : e.layer) with_layers.push_back(e.spec.centre + q);
    }
    if (!with_layers.empty()) with_layers.insert(with_layers.end(), m.x.begin(), m.x.end());
    const std::span<const Vec3> near = with_layers.empty() ? std::span<const Vec3>(m.x) : with_layers;
    const double reach = dt * (fastest + m.s.gravity.norm() * dt) + m.h + surface->radius;
    meeting.emplace(*surface, near, std::isfinite(reach) ? reach : m.h, m.s.surface_density ? m.h : 0.0);
    m.surface = &*meeting;
  }
  std::optional<detail::ToolMeeting> on_tools;
  if (tools && !tools->tools.empty()) {
    on_tools.emplace(*tools, r, dt, substeps);
    m.tools = &*on_tools;
  }
  try {
    for (int sub = 0; sub < substeps; ++sub) m.substep(sub, h, inflated, rep);
  } catch (...) {
    m.surface = nullptr;
    m.tools = nullptr;
    throw;
  }
  m.surface = nullptr;
  m.tools = nullptr;
  // Density error at the last iteration (before its correction): compression only.
  double sum = 0.0, mx = 0.0;
  for (size_t i = 0; i < m.n(); ++i) {
    const double e = std::max(m.ratio[i] - 1.0, 0.0);
    sum += e;
    mx = std::max(mx, e);
  }
  rep.constraint_error = m.n() ? sum / static_cast<double>(m.n()) : 0.0;
  rep.max_constraint_error = mx;
  m.state.time += dt;
  if (ends_step) ++m.state.steps;
  m.sync_state();
  rep.wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

std::vector<double> FluidBody::pressure() const {
  const Impl& m = *impl_;
  std::vector<double> out(m.n(), 0.0);
  if (m.last_dt <= 0.0) return out;
  for (size_t i = 0; i < m.n(); ++i) out[i] = -m.state.lambda[i] * m.s.rest_density * m.gradient_scale / (m.last_dt * m.last_dt);
  return out;
}

const FluidPhaseTimes& FluidBody::phase_times() const { return impl_->times; }
void FluidBody::reset_phase_times() { impl_->times = FluidPhaseTimes{}; }

std::vector<double> FluidBody::density_ratios() const {
  const Impl& m = *impl_;
  const std::vector<Vec3>& x = m.state.x;
  fluid::NeighbourGrid g;
  g.build(x, m.h, nullptr);
  std::vector<double> out(x.size());
  std::vector<Vec3> nb;
  for (size_t i = 0; i < x.size(); ++i) {
    nb.clear();
    for (uint32_t j : g.neighbours(i)) nb.push_back(x[j]);
    Vec3 gw;
    out[i] = fluid::density_constraint(m.k, m.mass, m.s.rest_density, x[i], nb, nullptr, nullptr) + 1.0 +
             m.wall_density(x[i], gw);
  }
  return out;
}

}  // namespace pliant
