// SPDX-License-Identifier: Apache-2.0
// Position-based fluids below the scene: the SPH kernels, the density constraint's gradient,
// the neighbour grid against brute force, momentum of the internal corrections, the state's
// round trip and bad input.
#include "fluid/neighbour_grid.hpp"
#include "fluid/pair_gather.hpp"
#include "fluid/sph_kernels.hpp"
#include "pliant/fluid.hpp"
#include "step/thread_pool.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <functional>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

using namespace pliant;
using pliant::fluid::Kernels;

namespace {

std::vector<Vec3> random_points(size_t n, double side, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, side);
  std::vector<Vec3> x(n);
  for (Vec3& p : x) {
    const double a = u(rng), b = u(rng), c = u(rng);
    p = Vec3(a, b, c);
  }
  return x;
}

}  // namespace

TEST(FluidKernels, Poly6IntegratesToOneOverItsBall) {
  for (double h : {0.01, 0.04, 1.0}) {
    const Kernels k(h);
    // Radial integral 4 pi r^2 W(r) dr on [0, h], Simpson with 2000 intervals.
    const int n = 2000;
    double sum = 0.0;
    for (int i = 0; i <= n; ++i) {
      const double r = h * i / n;
      const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
      sum += w * 4.0 * std::numbers::pi * r * r * k.poly6(r * r);
    }
    const double integral = sum * (h / n) / 3.0;
    EXPECT_NEAR(integral, 1.0, 1e-9) << "h " << h;
  }
}

// The wall's density term: poly6's mass beyond a plane at distance y from the centre, against
// a direct integral over the cap (discs of radius sqrt(h^2 - z^2) for z from y to h, each disc's
// mass by a radial Simpson rule), and its slope against finite differences.
TEST(FluidKernels, Poly6BeyondAPlaneIsTheKernelMassOnTheFarSide) {
  const double h = 0.04;
  const Kernels k(h);
  auto simpson = [](double a, double b, int n, auto&& f) {
    double sum = 0.0;
    for (int i = 0; i <= n; ++i) {
      const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
      sum += w * f(a + (b - a) * i / n);
    }
    return sum * (b - a) / n / 3.0;
  };
  auto cap = [&](double y) {
    return simpson(y, h, 400, [&](double z) {
      const double rho_max = std::sqrt(std::max(h * h - z * z, 0.0));
      return simpson(0.0, rho_max, 400,
                     [&](double rho) { return 2.0 * std::numbers::pi * rho * k.poly6(rho * rho + z * z); });
    });
  };
  EXPECT_NEAR(fluid::poly6_beyond(k, 0.0), 0.5, 1e-12);
  EXPECT_EQ(fluid::poly6_beyond(k, h), 0.0);
  EXPECT_NEAR(fluid::poly6_beyond(k, -0.01), 0.5, 1e-12) << "a point beyond the wall counts as on it";
  for (double f : {0.1, 0.3, 0.5, 0.7, 0.9}) {
    const double y = f * h;
    EXPECT_NEAR(fluid::poly6_beyond(k, y), cap(y), 1e-9) << "y = " << f << " h";
    const double e = 1e-7 * h;
    const double fd = (fluid::poly6_beyond(k, y + e) - fluid::poly6_beyond(k, y - e)) / (2 * e);
    EXPECT_NEAR(fluid::poly6_beyond_slope(k, y), fd, 1e-6 * std::abs(fd)) << "y = " << f << " h";
  }
}

TEST(FluidKernels, SpikyIntegratesToOneAndItsGradientMatchesFiniteDifferences) {
  const double h = 0.05;
  const Kernels k(h);
  const int n = 4000;
  double sum = 0.0;
  for (int i = 0; i <= n; ++i) {
    const double r = h * i / n;
    const double w = (i == 0 || i == n) ? 1.0 : (i % 2 ? 4.0 : 2.0);
    sum += w * 4.0 * std::numbers::pi * r * r * k.spiky(r);
  }
  EXPECT_NEAR(sum * (h / n) / 3.0, 1.0, 1e-9);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-h, h);
  int checked = 0;
  for (int t = 0; t < 200; ++t) {
    const Vec3 r(u(rng), u(rng), u(rng));
    if (r.norm() > 0.95 * h || r.norm() < 0.05 * h) continue;
    const Vec3 g = k.spiky_gradient(r);
    const double e = 1e-7 * h;
    for (int a = 0; a < 3; ++a) {
      Vec3 rp = r, rm = r;
      rp[a] += e;
      rm[a] -= e;
      const double fd = (k.spiky(rp.norm()) - k.spiky(rm.norm())) / (2 * e);
      EXPECT_NEAR(g[a], fd, 1e-6 * g.norm()) << "axis " << a << " at r " << r.transpose();
    }
    ++checked;
  }
  EXPECT_GT(checked, 50);
}

TEST(FluidConstraint, GradientMatchesFiniteDifferencesOfTheSpikyDensity) {
  // The solver's gradient is the spiky kernel's (the paper's choice), the density itself poly6:
  // the gradient is that of C built on the spiky kernel. Check both the analytic form against
  // the spiky density's finite differences and that it points like poly6's.
  const double d = 0.02, h = 2.0 * d, rho0 = 1000.0, m = rho0 * d * d * d;
  const Kernels k(h);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-h, h);
  std::vector<Vec3> nb;
  while (nb.size() < 25) {
    const Vec3 q(u(rng), u(rng), u(rng));
    if (q.norm() < 0.95 * h && q.norm() > 0.1 * h) nb.push_back(q);
  }
  const Vec3 pi(0.001, -0.002, 0.0015);
  Vec3 gi;
  double sq = 0.0;
  fluid::density_constraint(k, m, rho0, pi, nb, &gi, &sq);
  auto c_spiky = [&](const Vec3& p, const std::vector<Vec3>& q) {
    double rho = m * k.spiky(0.0);
    for (const Vec3& pj : q) rho += m * k.spiky((p - pj).norm());
    return rho / rho0 - 1.0;
  };
  auto c_poly6 = [&](const Vec3& p, const std::vector<Vec3>& q) {
    return fluid::density_constraint(k, m, rho0, p, q, nullptr, nullptr);
  };
  const double e = 1e-8;
  Vec3 fd_i, fd_poly6;
  for (int a = 0; a < 3; ++a) {
    Vec3 pp = pi, pm = pi;
    pp[a] += e;
    pm[a] -= e;
    fd_i[a] = (c_spiky(pp, nb) - c_spiky(pm, nb)) / (2 * e);
    fd_poly6[a] = (c_poly6(pp, nb) - c_poly6(pm, nb)) / (2 * e);
  }
  EXPECT_LT((gi - fd_i).norm(), 1e-6 * gi.norm()) << gi.transpose() << " vs " << fd_i.transpose();
  // poly6's own gradient is a different function, yet a descent direction for the same C.
  EXPECT_GT(gi.dot(fd_poly6), 0.0) << "spiky and poly6 gradients point in opposite ways";
  // grad_j C_i = -(m / rho0) grad W(p_i - p_j): the derivative with respect to a neighbour.
  double sq_fd = 0.0;
  for (size_t j = 0; j < nb.size(); ++j) {
    Vec3 gj;
    for (int a = 0; a < 3; ++a) {
      std::vector<Vec3> qp = nb, qm = nb;
      qp[j][a] += e;
      qm[j][a] -= e;
      gj[a] = (c_spiky(pi, qp) - c_spiky(pi, qm)) / (2 * e);
    }
    const Vec3 analytic = -(m / rho0) * k.spiky_gradient(pi - nb[j]);
    EXPECT_LT((gj - analytic).norm(), 1e-6 * std::max(analytic.norm(), 1e-3)) << "neighbour " << j;
    sq_fd += gj.squaredNorm();
  }
  EXPECT_NEAR(sq, sq_fd, 1e-5 * sq);
}

TEST(FluidNeighbours, MatchBruteForceAndDoNotDependOnThreads) {
  const double h = 0.05;
  // Enough points that the grid sorts them in parallel chunks, merged.
  const std::vector<Vec3> x = random_points(6000, 0.63, 11);
  fluid::NeighbourGrid one, three;
  one.build(x, h, nullptr);
  ThreadPool pool(3);
  three.build(x, h, &pool);
  size_t total = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    std::vector<uint32_t> brute;
    for (size_t j = 0; j < x.size(); ++j)
      if (j != i && (x[i] - x[j]).squaredNorm() < h * h) brute.push_back(static_cast<uint32_t>(j));
    auto a = one.neighbours(i);
    std::vector<uint32_t> got(a.begin(), a.end());
    auto b = three.neighbours(i);
    ASSERT_TRUE(std::equal(a.begin(), a.end(), b.begin(), b.end())) << "particle " << i << ": order depends on threads";
    std::sort(got.begin(), got.end());
    ASSERT_EQ(got, brute) << "particle " << i;
    total += brute.size();
  }
  EXPECT_GT(total, 6000u) << "too few pairs to test anything";
  // Far and non-finite points do not break the grid.
  std::vector<Vec3> y = x;
  y[0] = Vec3(1e30, -1e30, 0);
  y[1] = Vec3(std::nan(""), 0, 0);
  fluid::NeighbourGrid g;
  g.build(y, h, &pool);
  EXPECT_EQ(g.size(), y.size());
}

// A compact cloud's points are counted into the box of their cells; one point far away makes
// that box too large, and the grid sorts and hashes the cells instead. The two ways give the
// same lists in the same order (the far point, last, has no neighbours).
TEST(FluidNeighbours, TheBoxOfCellsAndTheHashOfCellsGiveTheSameLists) {
  const double h = 0.05;
  const std::vector<Vec3> x = random_points(3000, 0.5, 23);
  std::vector<Vec3> y = x;
  y.push_back(Vec3(40.0, -25.0, 3.0));
  ThreadPool pool(2);
  for (ThreadPool* p : {static_cast<ThreadPool*>(nullptr), &pool}) {
    fluid::NeighbourGrid compact, spread;
    compact.build(x, h, p);
    spread.build(y, h, p);
    ASSERT_EQ(spread.pairs(), compact.pairs());
    EXPECT_TRUE(spread.neighbours(x.size()).empty());
    for (size_t i = 0; i < x.size(); ++i) {
      const auto a = compact.neighbours(i), b = spread.neighbours(i);
      ASSERT_TRUE(std::equal(a.begin(), a.end(), b.begin(), b.end())) << "point " << i;
    }
    std::vector<uint32_t> order = fluid::NeighbourGrid::cell_order(y, h, p);
    ASSERT_EQ(order.back(), uint32_t(x.size())) << "the far point's cell comes last";
    order.pop_back();
    EXPECT_EQ(order, fluid::NeighbourGrid::cell_order(x, h, p));
  }
}

// Degenerate clouds in either way of finding cells: none, one point, every point on one spot,
// every point non-finite (one clamped cell), a line of points a cell apart. Lists as brute force.
TEST(FluidNeighbours, DegenerateCloudsGiveTheBruteForceLists) {
  const double h = 0.05;
  const double nan = std::nan("");
  std::vector<std::vector<Vec3>> clouds = {
      {},
      {Vec3(0.3, -0.2, 7.0)},
      std::vector<Vec3>(9, Vec3(0.01, 0.02, 0.03)),
      std::vector<Vec3>(5, Vec3(nan, nan, nan)),
  };
  std::vector<Vec3> line;
  for (int k = 0; k < 40; ++k) line.push_back(Vec3(k * 0.049, 0.0, 0.0));
  clouds.push_back(line);
  ThreadPool pool(2);
  for (size_t c = 0; c < clouds.size(); ++c) {
    const std::vector<Vec3>& x = clouds[c];
    fluid::NeighbourGrid g;
    g.build(x, h, &pool);
    ASSERT_EQ(g.size(), x.size()) << "cloud " << c;
    size_t total = 0;
    for (size_t i = 0; i < x.size(); ++i) {
      std::vector<uint32_t> brute;
      for (size_t j = 0; j < x.size(); ++j)
        if (j != i && (x[i] - x[j]).squaredNorm() < h * h) brute.push_back(static_cast<uint32_t>(j));
      const auto a = g.neighbours(i);
      std::vector<uint32_t> got(a.begin(), a.end());
      std::sort(got.begin(), got.end());
      EXPECT_EQ(got, brute) << "cloud " << c << ", point " << i;
      total += brute.size();
    }
    EXPECT_EQ(g.pairs(), total) << "cloud " << c;
    EXPECT_EQ(fluid::NeighbourGrid::cell_order(x, h, &pool).size(), x.size());
  }
}

TEST(FluidNeighbours, SlotViewIsTheSameListsInCellOrder) {
  const double h = 0.05;
  const std::vector<Vec3> x = random_points(2000, 0.4, 17);
  ThreadPool pool(2);
  fluid::NeighbourGrid g;
  g.build(x, h, &pool);
  std::vector<bool> seen(x.size(), false);
  size_t next = 0;
  for (size_t s = 0; s < g.size(); ++s) {
    const uint32_t i = g.point(s);
    ASSERT_LT(i, x.size());
    ASSERT_FALSE(seen[i]) << "point " << i << " in two slots";
    seen[i] = true;
    // Slot lists follow each other in the list of all pairs, and are the points' lists.
    ASSERT_EQ(g.slot_first(s), next) << "slot " << s;
    ASSERT_EQ(g.first(i), next);
    const auto a = g.slot_neighbours(s), b = g.neighbours(i);
    ASSERT_TRUE(std::equal(a.begin(), a.end(), b.begin(), b.end())) << "slot " << s;
    next += a.size();
    if (s > 0) {
      const uint32_t prev = g.point(s - 1);
      auto cell = [&](uint32_t k) {
        return std::array<long, 3>{long(std::floor(x[k].z() / h)), long(std::floor(x[k].y() / h)),
                                   long(std::floor(x[k].x() / h))};
      };
      ASSERT_LE(cell(prev), cell(i)) << "slots not in cell order at " << s;
    }
  }
  EXPECT_EQ(next, g.pairs());
  EXPECT_EQ(g.slot_first(g.size()), g.pairs());
}

TEST(FluidNeighbours, CellOrderIsAPermutationGroupingCells) {
  const double h = 0.1;
  const std::vector<Vec3> x = random_points(500, 1.0, 5);
  const std::vector<uint32_t> order = fluid::NeighbourGrid::cell_order(x, h);
  std::vector<uint32_t> sorted = order;
  std::sort(sorted.begin(), sorted.end());
  for (size_t i = 0; i < sorted.size(); ++i) ASSERT_EQ(sorted[i], i);
  auto cell = [&](uint32_t i) {
    return std::array<long, 3>{long(std::floor(x[i].z() / h)), long(std::floor(x[i].y() / h)),
                               long(std::floor(x[i].x() / h))};
  };
  for (size_t i = 1; i < order.size(); ++i) ASSERT_LE(cell(order[i - 1]), cell(order[i]));
  // Sorted by chunks on three threads and merged, a larger set comes out in the same order.
  const std::vector<Vec3> y = random_points(9000, 1.0, 6);
  ThreadPool pool(3);
  EXPECT_EQ(fluid::NeighbourGrid::cell_order(y, h, &pool), fluid::NeighbourGrid::cell_order(y, h));
}

namespace {

FluidSettings free_settings() {
  FluidSettings s;
  s.spacing = 0.02;
  s.gravity = Vec3::Zero();
  s.substeps = 2;
  s.iterations = 4;
  s.vorticity = 0.0;
  return s;
}

Vec3 momentum(const FluidBody& f) {
  Vec3 p = Vec3::Zero();
  for (const Vec3& v : f.state().v) p += f.particle_mass() * v;
  return p;
}

}  // namespace

// The pair loops' gathers (four neighbours by masked loads and a transpose where AVX is there)
// give the bits of the plain expressions, for every neighbour count's tail and for the last
// particle of the array (the masked load must not read past it).
TEST(FluidGather, OffsetsAndVectorsAreThePlainExpressionsBitForBit) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Vec3> P(301);
  for (size_t i = 0; i < P.size(); ++i) {
    const double scale = i % 3 == 0 ? 1e-3 : (i % 3 == 1 ? 1.0 : 250.0);  // offsets rounding differently
    P[i] = scale * Vec3(u(rng), u(rng), u(rng));
  }
  std::uniform_int_distribution<uint32_t> pick(0, uint32_t(P.size() - 1));
  const double inv_h = 1.0 / 0.04;
  size_t checked = 0;
  for (size_t m = 0; m <= 37; ++m) {
    std::vector<uint32_t> J(m);
    for (uint32_t& j : J) j = pick(rng);
    if (m) J[m - 1] = uint32_t(P.size() - 1);
    const Vec3& c = P[m % P.size()];
    std::vector<float> rx(m + 1, -7.f), ry(m + 1, -7.f), rz(m + 1, -7.f);
    fluid::pair_offsets(c, P.data(), J.data(), m, inv_h, rx.data(), ry.data(), rz.data());
    for (size_t q = 0; q < m; ++q) {
      const Vec3& pj = P[J[q]];
      EXPECT_EQ(std::bit_cast<uint32_t>(rx[q]), std::bit_cast<uint32_t>(static_cast<float>((c.x() - pj.x()) * inv_h)));
      EXPECT_EQ(std::bit_cast<uint32_t>(ry[q]), std::bit_cast<uint32_t>(static_cast<float>((c.y() - pj.y()) * inv_h)));
      EXPECT_EQ(std::bit_cast<uint32_t>(rz[q]), std::bit_cast<uint32_t>(static_cast<float>((c.z() - pj.z()) * inv_h)));
      ++checked;
    }
    EXPECT_EQ(rx[m], -7.f) << "wrote past the " << m << " offsets";
    EXPECT_EQ(rz[m], -7.f) << "wrote past the " << m << " offsets";
    for (size_t q = 0; q + 4 <= m; q += 4) {
      const fluid::Lanes3 g = fluid::gather4(P.data(), J.data() + q);
      for (int l = 0; l < 4; ++l) {
        EXPECT_EQ(g.x[l], P[J[q + l]].x());
        EXPECT_EQ(g.y[l], P[J[q + l]].y());
        EXPECT_EQ(g.z[l], P[J[q + l]].z());
      }
    }
  }
  EXPECT_EQ(checked, 37u * 38u / 2u);
}

TEST(FluidBody, InternalCorrectionsConserveMomentum) {
  FluidSettings s = free_settings();
  s.scorr_k = 0.1;  // s_corr is pairwise symmetric too
  s.xsph = 0.05;
  // A compressed block (spacing 0.8 d) with random velocities: large corrections.
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.16, 0.16, 0.16)}});
  ParticleState st = f.state();
  std::mt19937 rng(1);
  std::normal_distribution<double> nd(0.0, 0.3);
  for (size_t i = 0; i < st.x.size(); ++i) {
    st.x[i] *= 0.8;
    st.v[i] = Vec3(nd(rng), nd(rng), nd(rng)) + Vec3(0.5, 0, 0);
  }
  f.set_state(st);
  const Vec3 p0 = momentum(f);
  double scale = 0.0;
  for (const Vec3& v : f.state().v) scale += f.particle_mass() * v.norm();
  double max_corr = 0.0;
  for (int step = 0; step < 10; ++step) {
    const ParticleState before = f.state();
    const ParticleStepReport r = f.step(1.0 / 60.0, {});
    EXPECT_EQ(r.contacts, 0u);
    for (size_t i = 0; i < before.x.size(); ++i)
      max_corr = std::max(max_corr, (f.state().x[i] - before.x[i] - before.v[i] / 60.0).norm());
    const Vec3 p = momentum(f);
    EXPECT_LT((p - p0).norm(), 1e-12 * scale) << "step " << step << ": " << p.transpose() << " vs " << p0.transpose();
  }
  EXPECT_GT(max_corr, 1e-3) << "the corrections did nothing: the test would not see a violation";
}

// One substep of one iteration from rest without gravity, walls, XSPH or vorticity moves each
// particle by exactly one Jacobi correction: recomputed here by brute force from the kernels and
// the documented formulas (lambda with epsilon, s_corr), it checks the solver's vectorised pair
// loops, its neighbour lists and its single-precision pair gradients.
TEST(FluidBody, OneIterationMatchesABruteForceJacobiCorrection) {
  FluidSettings s;
  s.spacing = 0.02;
  s.gravity = Vec3::Zero();
  s.substeps = 1;
  s.iterations = 1;
  s.xsph = 0.0;
  s.vorticity = 0.0;
  s.scorr_k = 0.1;  // large enough to matter
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.14, 0.14, 0.14)}});
  ParticleState st = f.state();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> jitter(-0.002, 0.002);
  for (Vec3& x : st.x) x = 0.85 * x + Vec3(jitter(rng), jitter(rng), jitter(rng));  // compressed
  for (Vec3& v : st.v) v.setZero();
  st.lambda.clear();
  f.set_state(st);
  const std::vector<Vec3> x = st.x;
  const size_t n = x.size();
  const double h = f.support_radius(), m = f.particle_mass(), rho0 = s.rest_density, sw = m / rho0;
  const Kernels k(h);
  // The reference denominator of a rest lattice particle, epsilon and s_corr's scale.
  std::vector<Vec3> lattice;
  for (int a = -2; a <= 2; ++a)
    for (int b = -2; b <= 2; ++b)
      for (int c = -2; c <= 2; ++c) {
        const Vec3 q = s.spacing * Vec3(a, b, c);
        if ((a || b || c) && q.squaredNorm() < h * h) lattice.push_back(q);
      }
  Vec3 g0;
  double sq0 = 0.0;
  fluid::density_constraint(k, m, rho0, Vec3::Zero(), lattice, &g0, &sq0);
  const double ref = g0.squaredNorm() + sq0, eps = s.relaxation * ref, scale = s.scorr_k / ref;
  const double wdq = k.poly6(std::pow(s.scorr_dq * h, 2));
  auto near = [&](size_t i, size_t j) { return i != j && (x[i] - x[j]).squaredNorm() < h * h; };
  std::vector<double> lam(n, 0.0);
  for (size_t i = 0; i < n; ++i) {
    double rho = m * k.poly6(0.0), sq = 0.0;
    Vec3 gi = Vec3::Zero();
    for (size_t j = 0; j < n; ++j) {
      if (!near(i, j)) continue;
      rho += m * k.poly6((x[i] - x[j]).squaredNorm());
      const Vec3 g = sw * fluid::pair_gradient(k, x[i] - x[j], uint32_t(i), uint32_t(j));
      gi += g;
      sq += g.squaredNorm();
    }
    const double c = rho / rho0 - 1.0;
    lam[i] = c > 0.0 ? -c / (gi.squaredNorm() + sq + eps) : 0.0;
  }
  f.step(1.0 / 60.0, {});
  double worst = 0.0, largest = 0.0;
  for (size_t i = 0; i < n; ++i) {
    Vec3 d = Vec3::Zero();
    for (size_t j = 0; j < n; ++j) {
      if (!near(i, j)) continue;
      const double sc = -scale * std::pow(k.poly6((x[i] - x[j]).squaredNorm()) / wdq, s.scorr_n);
      d += (lam[i] + lam[j] + sc) * fluid::pair_gradient(k, x[i] - x[j], uint32_t(i), uint32_t(j));
    }
    const Vec3 expected = x[i] + sw * d;
    worst = std::max(worst, (f.state().x[i] - expected).norm());
    largest = std::max(largest, (sw * d).norm());
  }
  EXPECT_GT(largest, 1e-4) << "the correction is too small to test anything";
  // Single-precision pair gradients: a relative error of about 1e-7 of the correction.
  EXPECT_LT(worst, 1e-6 * largest) << "largest correction " << largest;
}

// Without gravity and from rest, position-based fluids are scale-free: a compressed block a
// ten-thousandth (spacing 2 um) and a ten-millionth of the size (2 nm) moves the same way in
// units of its spacing. The kernels' constant factors (315 / (64 pi h^9), 45 / (pi h^6)) and
// their dimensional terms overflow or underflow single precision there, so this also checks that
// the single-precision pair terms are taken in units of h.
TEST(FluidBody, ATenThousandthAndATenMillionthOfTheSizeMoveTheSameWay) {
  auto run = [](double scale) {
    FluidSettings s;
    s.spacing = 0.02 * scale;
    s.gravity = Vec3::Zero();
    s.scorr_k = 0.1;
    FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.12, 0.12, 0.12) * scale}});
    ParticleState st = f.state();
    for (Vec3& x : st.x) x *= 0.85;  // compressed: the corrections push it apart
    f.set_state(st);
    for (int i = 0; i < 3; ++i) f.step(1.0 / 60.0, {});
    std::vector<Vec3> x = f.state().x;
    for (Vec3& p : x) p /= scale;
    return std::pair{st.x, x};
  };
  const auto [start, big] = run(1.0);
  double moved = 0.0;
  for (size_t i = 0; i < big.size(); ++i) moved = std::max(moved, (big[i] - start[i]).norm());
  EXPECT_GT(moved, 1e-3) << "the block did not move: the test would see nothing";
  for (double scale : {1e-4, 1e-7}) {
    const std::vector<Vec3> small = run(scale).second;
    ASSERT_EQ(big.size(), small.size());
    double worst = 0.0;
    for (size_t i = 0; i < big.size(); ++i) {
      ASSERT_TRUE(small[i].allFinite()) << "particle " << i << " at scale " << scale;
      worst = std::max(worst, (small[i] - big[i]).norm());
    }
    EXPECT_LT(worst, 1e-5 * moved) << "scale " << scale << ", largest move " << moved;
  }
}

TEST(FluidBody, ResultsDoNotDependOnTheThreadCount) {
  auto run = [](int threads) {
    FluidSettings s;
    s.threads = threads;
    s.vorticity = 0.5;
    s.sort_interval = 3;
    s.container = Collider::box(Vec3(0.1, 0.2, 0.1), Vec3(0.1, 0.2, 0.1));
    FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.1, 0.2, 0.2)}});
    for (int i = 0; i < 6; ++i) f.step(1.0 / 60.0, {});
    return f.state();
  };
  const ParticleState a = run(1), b = run(3);
  ASSERT_EQ(a.x.size(), b.x.size());
  for (size_t i = 0; i < a.x.size(); ++i) {
    ASSERT_EQ(a.x[i], b.x[i]) << "particle " << i;
    ASSERT_EQ(a.v[i], b.v[i]) << "particle " << i;
    ASSERT_EQ(a.lambda[i], b.lambda[i]) << "particle " << i;
  }
}

TEST(FluidBody, SetStateRoundTripRepeatsTheStepsBitForBit) {
  // Re-sorting every 2 substeps: the saved state carries the solver's order and the substep
  // count, so the restored body re-sorts on the same schedule from the same order and repeats
  // the steps to the bit, in the body that ran on and in a new one built from the same settings.
  FluidSettings s;
  s.sort_interval = 2;
  s.container = Collider::box(Vec3(0.1, 0.2, 0.1), Vec3(0.1, 0.2, 0.1));
  const std::vector<FluidBlock> block{FluidBlock{Vec3(0, 0, 0), Vec3(0.1, 0.16, 0.2)}};
  FluidBody f(s, block);
  for (int i = 0; i < 3; ++i) f.step(1.0 / 60.0, {});
  const ParticleState saved = f.state();
  ASSERT_EQ(saved.order.size(), saved.x.size());
  EXPECT_EQ(saved.substeps, 3u * static_cast<uint64_t>(s.substeps));
  bool sorted = false;  // the cell sort moved particles, so the order matters
  for (size_t k = 0; k < saved.order.size(); ++k) sorted |= saved.order[k] != k;
  EXPECT_TRUE(sorted);
  for (int i = 0; i < 3; ++i) f.step(1.0 / 60.0, {});
  const ParticleState first = f.state();
  f.set_state(saved);
  EXPECT_EQ(f.state().x, saved.x);
  EXPECT_EQ(f.state().v, saved.v);
  EXPECT_EQ(f.state().lambda, saved.lambda);
  EXPECT_EQ(f.state().order, saved.order);
  EXPECT_EQ(f.state().steps, saved.steps);
  FluidBody fresh(s, block);
  fresh.set_state(saved);
  for (int i = 0; i < 3; ++i) {
    f.step(1.0 / 60.0, {});
    fresh.step(1.0 / 60.0, {});
  }
  for (const FluidBody* body : {&f, &fresh}) {
    EXPECT_EQ(body->state().x, first.x);
    EXPECT_EQ(body->state().v, first.v);
    EXPECT_EQ(body->state().lambda, first.lambda);
    EXPECT_EQ(body->state().order, first.order);
    EXPECT_EQ(body->state().steps, first.steps);
  }
}

TEST(FluidBody, BadInputThrowsNamingTheField) {
  const std::vector<FluidBlock> block{FluidBlock{Vec3(0, 0, 0), Vec3(0.1, 0.1, 0.1)}};
  auto expect_field = [&](FluidSettings s, const std::string& field) {
    try {
      FluidBody f(s, block);
      ADD_FAILURE() << "no throw for " << field;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  FluidSettings s;
  s.spacing = 0.0;
  expect_field(s, "spacing");
  s.spacing = -1.0;
  expect_field(s, "spacing");
  s.spacing = std::nan("");
  expect_field(s, "spacing");
  s = FluidSettings{};
  s.rest_density = std::nan("");
  expect_field(s, "rest_density");
  s = FluidSettings{};
  s.gravity = Vec3(0, std::nan(""), 0);
  expect_field(s, "gravity");
  s = FluidSettings{};
  s.iterations = 0;
  expect_field(s, "iterations");
  s = FluidSettings{};
  s.support_ratio = 0.5;
  expect_field(s, "support_ratio");
  s = FluidSettings{};
  s.container = Collider::sphere(Vec3::Zero(), 1.0);
  expect_field(s, "container");
  try {
    FluidBody f(FluidSettings{}, {FluidBlock{Vec3(0, 0, 0), Vec3(0.001, 0.001, 0.001)}});
    ADD_FAILURE() << "no throw for zero particles";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("zero particles"), std::string::npos) << e.what();
  }
  try {
    FluidBody f(FluidSettings{}, {FluidBlock{Vec3(0, std::nan(""), 0), Vec3(0.1, 0.1, 0.1)}});
    ADD_FAILURE() << "no throw for a NaN block";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("blocks[0].min"), std::string::npos) << e.what();
  }
  FluidBody f(FluidSettings{}, block);
  ParticleState st = f.state();
  st.x.pop_back();
  EXPECT_THROW(f.set_state(st), std::invalid_argument);
  st = f.state();
  st.v[3] = Vec3(std::nan(""), 0, 0);
  try {
    f.set_state(st);
    ADD_FAILURE() << "no throw for a NaN velocity";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("state.v[3]"), std::string::npos) << e.what();
  }
  // The solver order must be a permutation of the particles.
  st = f.state();
  st.order.assign(st.x.size(), 0);
  for (size_t k = 0; k < st.order.size(); ++k) st.order[k] = static_cast<uint32_t>(k);
  st.order[5] = 4;
  try {
    f.set_state(st);
    ADD_FAILURE() << "no throw for a repeated order entry";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("state.order[5] = 4 appears twice"), std::string::npos) << e.what();
  }
  st.order[5] = static_cast<uint32_t>(st.x.size());
  EXPECT_THROW(f.set_state(st), std::invalid_argument);
  st.order.pop_back();
  EXPECT_THROW(f.set_state(st), std::invalid_argument);
  EXPECT_THROW(f.step(0.0, {}), std::invalid_argument);
  EXPECT_THROW(f.step(std::nan(""), {}), std::invalid_argument);
}

TEST(FluidBody, EmitterAddsParticlesAtItsRateUpToItsCap) {
  FluidSettings s;
  s.spacing = 0.02;
  FluidEmitter e;
  e.shape = FluidEmitter::Shape::Rectangle;
  e.centre = Vec3(0, 0.5, 0);
  e.direction = Vec3(0, -1, 0);
  e.half_u = 0.07;
  e.half_v = 0.07;  // 7 x 7 = 49 points per layer
  e.speed = 1.0;    // one layer every 0.02 s
  e.max_particles = 49 * 20;
  FluidBody f(s, {}, {e});
  EXPECT_EQ(f.size(), 0u);
  for (int i = 0; i < 12; ++i) f.step(0.01, {});  // 0.12 s: 6 layers
  EXPECT_NEAR(static_cast<double>(f.size()), 6 * 49, 49) << f.size();
  for (int i = 0; i < 100; ++i) f.step(0.01, {});
  EXPECT_EQ(f.size(), 49u * 20u);
  EXPECT_EQ(f.state().x.size(), f.size());
  EXPECT_EQ(f.inverse_masses().size(), f.size());
}

TEST(FluidBody, AnEmittingFluidRestoresItsParticlesAndEmitsOnSchedule) {
  // A block with a disc emitter above it, re-sorted every 3 substeps: a state saved between
  // layers carries the emitters' progress, so the body it is restored into (the one that ran on
  // and emitted more, or a new one that has emitted nothing) takes that particle count and
  // repeats the next steps, emissions included, to the bit.
  FluidSettings s;
  s.sort_interval = 3;
  s.container = Collider::box(Vec3(0, 0.3, 0), Vec3(0.2, 0.3, 0.2));
  const std::vector<FluidBlock> block{FluidBlock{Vec3(-0.1, 0, -0.1), Vec3(0.1, 0.06, 0.1)}};
  FluidEmitter e;
  e.centre = Vec3(0, 0.4, 0);
  e.radius = 0.03;
  e.speed = 0.7;  // a layer every 0.0286 s: not a whole number of 1/60 s steps
  e.max_particles = 600;
  FluidBody f(s, block, {e});
  const size_t blocks = f.block_particles();
  ASSERT_EQ(f.size(), blocks);
  ASSERT_EQ(f.emitter_layer_sizes().size(), 1u);
  const size_t layer = f.emitter_layer_sizes()[0];
  EXPECT_EQ(layer, 9u);  // lattice points within 3 cm of the centre at 2 cm spacing: 1 + 4 + 4
  const ParticleState initial = f.state();
  ASSERT_EQ(initial.emitters.size(), 1u);
  EXPECT_EQ(initial.emitters[0].emitted, 0u);
  for (int i = 0; i < 7; ++i) f.step(1.0 / 60.0, {});
  const ParticleState saved = f.state();
  ASSERT_EQ(saved.emitters.size(), 1u);
  EXPECT_GT(saved.emitters[0].emitted, 0u);
  EXPECT_EQ(saved.x.size(), blocks + saved.emitters[0].emitted);
  EXPECT_GT(saved.emitters[0].travelled, 0.0);  // between two layers
  for (int i = 0; i < 5; ++i) f.step(1.0 / 60.0, {});
  const ParticleState later = f.state();
  EXPECT_GT(later.x.size(), saved.x.size());
  f.grab(3, later.x.size() - 1, Vec3::Zero(), 0.0);  // a particle the restore drops
  f.set_state(saved);
  EXPECT_EQ(f.size(), saved.x.size());
  EXPECT_EQ(f.inverse_masses().size(), saved.x.size());
  EXPECT_EQ(f.state().x, saved.x);
  EXPECT_FALSE(f.release(3));
  FluidBody fresh(s, block, {e});
  fresh.set_state(saved);
  for (int i = 0; i < 5; ++i) {
    f.step(1.0 / 60.0, {});
    fresh.step(1.0 / 60.0, {});
  }
  for (const FluidBody* body : {&f, &fresh}) {
    EXPECT_EQ(body->state().x, later.x);
    EXPECT_EQ(body->state().v, later.v);
    EXPECT_EQ(body->state().lambda, later.lambda);
    EXPECT_EQ(body->state().order, later.order);
    ASSERT_EQ(body->state().emitters.size(), 1u);
    EXPECT_EQ(body->state().emitters[0].emitted, later.emitters[0].emitted);
    EXPECT_EQ(body->state().emitters[0].travelled, later.emitters[0].travelled);
  }
  // Back to the start: the blocks' particles only.
  f.set_state(initial);
  EXPECT_EQ(f.size(), blocks);
  // Progress that does not describe the body is refused, naming the field.
  ParticleState bad = saved;
  bad.emitters[0].emitted += 1;  // not a whole layer
  try {
    f.set_state(bad);
    ADD_FAILURE() << "no throw for a partial layer";
  } catch (const std::invalid_argument& err) {
    EXPECT_NE(std::string(err.what()).find("state.emitters[0].emitted"), std::string::npos) << err.what();
  }
  bad = saved;
  bad.emitters[0].emitted += layer;  // one layer more than the positions hold
  EXPECT_THROW(f.set_state(bad), std::invalid_argument);
  bad = saved;
  bad.emitters[0].travelled = s.spacing;
  EXPECT_THROW(f.set_state(bad), std::invalid_argument);
  bad = saved;
  bad.emitters.push_back({});
  EXPECT_THROW(f.set_state(bad), std::invalid_argument);
  EXPECT_EQ(f.size(), blocks);  // a refused state changes nothing
}

TEST(FluidBody, ARectangularEmitterLiesAlongItsAxis) {
  // 5 x 1 lattice points across a flow along -y, the row along z when u_axis says so.
  FluidSettings s;
  s.gravity = Vec3::Zero();
  FluidEmitter e;
  e.shape = FluidEmitter::Shape::Rectangle;
  e.direction = Vec3(0, -1, 0);
  e.half_u = 0.04;  // -2..2 x spacing
  e.half_v = 0.01;  // under one spacing: a single row
  e.u_axis = Vec3(0, 0.3, 2);  // not orthogonal to the flow: its part across it counts
  e.speed = 1.0;
  FluidBody f(s, {}, {e});
  f.step(0.02, {});
  ASSERT_EQ(f.size(), 5u);
  for (const Vec3& x : f.state().x) EXPECT_NEAR(x.x(), 0.0, 1e-12) << x.transpose();
  double zmin = 1, zmax = -1;
  for (const Vec3& x : f.state().x) {
    zmin = std::min(zmin, x.z());
    zmax = std::max(zmax, x.z());
  }
  EXPECT_NEAR(zmax - zmin, 0.08, 1e-4);  // the density corrections of the step spread them a little
}

TEST(FluidBody, GrabPullsAParticleAndReportsItsForce) {
  FluidSettings s;
  s.gravity = Vec3::Zero();
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.1, 0.1, 0.1)}});
  const Vec3 start = f.state().x[0];
  // A hard grab puts the particle on its target.
  f.grab(7, 0, start + Vec3(0, -0.05, 0), 0.0);
  f.step(1.0 / 60.0, {});
  EXPECT_LT((f.state().x[0] - (start + Vec3(0, -0.05, 0))).norm(), 1e-9);
  // A soft one far below drags the particle (and the blob) down: the force on the body points
  // to the target, as large as the compliance and the stretch say.
  const double compliance = 1.0;  // m/N
  f.grab(7, 0, start + Vec3(0, -1.0, 0), compliance);
  for (int i = 0; i < 5; ++i) {
    f.step(1.0 / 60.0, {});
    const Vec3 force = f.grab_force(7);
    const double stretch = (f.state().x[0] - (start + Vec3(0, -1.0, 0))).norm();
    EXPECT_LT(force.y(), 0.0) << force.transpose();
    EXPECT_NEAR(force.norm(), stretch / compliance, 0.05 * stretch / compliance) << "step " << i;
  }
  EXPECT_TRUE(f.move_grab(7, start));
  EXPECT_TRUE(f.release(7));
  EXPECT_FALSE(f.release(7));
  EXPECT_FALSE(f.move_grab(7, start));
  EXPECT_EQ(f.grab_force(7), Vec3::Zero());
  // Bad grabs are refused naming what is wrong (the particle bodies share this bookkeeping).
  auto refused = [](const std::function<void()>& call, const std::string& word) {
    try {
      call();
      ADD_FAILURE() << "accepted; expected a message naming " << word;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(word), std::string::npos) << e.what();
    }
  };
  refused([&] { f.grab(8, f.size(), start, 0.0); }, "particle");
  refused([&] { f.grab(8, 0, Vec3(NAN, 0, 0), 0.0); }, "target");
  refused([&] { f.grab(8, 0, start, -1.0); }, "compliance");
  refused([&] { f.grab(8, 0, start, INFINITY); }, "compliance");
  f.grab(8, 0, start, 0.0);
  refused([&] { f.move_grab(8, Vec3(0, INFINITY, 0)); }, "target");
}

TEST(FluidBody, VorticityConfinementKeepsARotatingBlobSpinning) {
  // A block spinning about y without gravity: XSPH and the density corrections take energy
  // out; confinement puts rotational energy back, so the blob keeps more kinetic energy.
  auto energy_after = [](double eps) {
    FluidSettings s;
    s.gravity = Vec3::Zero();
    s.vorticity = eps;
    s.xsph = 0.05;
    FluidBody f(s, {FluidBlock{Vec3(-0.1, 0, -0.1), Vec3(0.1, 0.1, 0.1)}});
    ParticleState st = f.state();
    for (size_t i = 0; i < st.x.size(); ++i) st.v[i] = Vec3(0, 3.0, 0).cross(Vec3(st.x[i].x(), 0, st.x[i].z()));
    f.set_state(st);
    for (int i = 0; i < 20; ++i) f.step(1.0 / 60.0, {});
    double e = 0.0;
    for (const Vec3& v : f.state().v) e += 0.5 * f.particle_mass() * v.squaredNorm();
    return e;
  };
  const double off = energy_after(0.0), on = energy_after(0.5);
  EXPECT_GT(on, 1.02 * off) << "kinetic energy with confinement " << on << " J, without " << off << " J";
}

// A scene steps bodies in contact in parts (whole substeps each): a fluid alone steps the same in
// parts as in one piece, its re-sorts included (they count substeps), to the last bit.
TEST(FluidParts, AStepInPartsIsTheStepInOnePiece) {
  FluidSettings fs;
  fs.spacing = 0.02;
  fs.substeps = 4;
  fs.sort_interval = 3;  // a re-sort inside a part and across parts
  const FluidBlock block{Vec3(-0.04, 0.01, -0.04), Vec3(0.04, 0.09, 0.04), Vec3(0.2, 0, 0)};
  const std::vector<Collider> floor = {Collider::plane(Vec3(0, 0, 0), Vec3(0, 1, 0))};
  for (int parts : {2, 4}) {
    SCOPED_TRACE("parts " + std::to_string(parts));
    FluidBody whole(fs, {block}), cut(fs, {block});
    const double dt = 1.0 / 60;
    for (int k = 0; k < 20; ++k) {
      whole.step(dt, floor);
      for (int p = 0; p < parts; ++p) cut.advance(dt / parts, fs.substeps / parts, floor, p + 1 == parts);
    }
    EXPECT_EQ(cut.state().x, whole.state().x);
    EXPECT_EQ(cut.state().v, whole.state().v);
    EXPECT_EQ(cut.state().steps, 20u);
    EXPECT_EQ(cut.state().substeps, whole.state().substeps);
  }
  FluidBody body(fs, {block});
  EXPECT_THROW(body.advance(0.01, 0, {}, true), std::invalid_argument);
}
