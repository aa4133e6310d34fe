// SPDX-License-Identifier: Apache-2.0
// Position-based fluids brought to rest and thrown about: a column at rest in a box keeps a
// hydrostatic pressure (from the density multipliers) and its density; a dam break stays in
// its container.
#include "pliant/fluid.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>

using namespace pliant;

namespace {

struct Fit {
  double slope = 0.0, intercept = 0.0, r2 = 0.0;
};

Fit fit_line(const std::vector<double>& x, const std::vector<double>& y) {
  const double n = static_cast<double>(x.size());
  double sx = 0, sy = 0, sxx = 0, sxy = 0, syy = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    sx += x[i];
    sy += y[i];
    sxx += x[i] * x[i];
    sxy += x[i] * y[i];
    syy += y[i] * y[i];
  }
  Fit f;
  f.slope = (n * sxy - sx * sy) / (n * sxx - sx * sx);
  f.intercept = (sy - f.slope * sx) / n;
  const double vx = n * sxx - sx * sx, vy = n * syy - sy * sy, cxy = n * sxy - sx * sy;
  f.r2 = cxy * cxy / (vx * vy);
  return f;
}

}  // namespace

TEST(FluidPhysics, ColumnAtRestIsHydrostatic) {
  // A column 14 x 36 x 14 particles in a frictionless box, with a budget that converges (8
  // substeps x 4 iterations at 60 Hz): the pressure from the multipliers, averaged over the
  // last half second and over layers, grows linearly with depth at rho0 |g| within 5%. The
  // fit leaves out the particles within h of a side wall (truncated neighbourhoods), the
  // floor's layers and the surface's.
  FluidSettings s;
  s.spacing = 0.02;
  s.substeps = 8;
  s.iterations = 4;
  s.threads = 2;
  s.xsph = 0.1;  // viscous enough to come to rest in two seconds
  const double w = 0.28, height = 0.72;
  s.container = Collider::box(Vec3(w / 2, 0.45, w / 2), Vec3(w / 2, 0.45, w / 2));
  s.container->static_friction = s.container->dynamic_friction = 0.0;
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(w, height, w)}});
  const size_t n = f.size();
  const double dt = 1.0 / 60.0;
  std::vector<double> p_sum(n, 0.0), y_sum(n, 0.0);
  double err_sum = 0.0, err_max = 0.0, vmean = 0.0;
  const int steps = 120, window = 30;
  for (int i = 0; i < steps; ++i) {
    const ParticleStepReport r = f.step(dt, {});
    if (i < steps - window) continue;
    const std::vector<double> p = f.pressure();
    for (size_t q = 0; q < n; ++q) {
      p_sum[q] += p[q] / window;
      y_sum[q] += f.state().x[q].y() / window;
      vmean += f.state().v[q].norm() / (window * static_cast<double>(n));
    }
    err_sum += r.constraint_error / window;
    err_max = std::max(err_max, r.max_constraint_error);
  }
  // The surface: the height that n particles of volume d^3 fill.
  const double top = static_cast<double>(n) * std::pow(s.spacing, 3) / (w * w);
  std::map<long, std::pair<double, int>> layers;
  for (size_t q = 0; q < n; ++q) {
    const double depth = top - y_sum[q];
    const Vec3& xq = f.state().x[q];
    const double side = std::min({xq.x(), w - xq.x(), xq.z(), w - xq.z()});
    if (depth < 3.5 * s.spacing || y_sum[q] < 3.5 * s.spacing || side < f.support_radius()) continue;
    auto& l = layers[std::lround(depth / s.spacing)];
    l.first += p_sum[q];
    ++l.second;
  }
  std::vector<double> depth, pres;
  for (const auto& [layer, acc] : layers) {
    depth.push_back(layer * s.spacing);
    pres.push_back(acc.first / acc.second);
  }
  ASSERT_GT(depth.size(), 15u);
  const Fit fit = fit_line(depth, pres);
  const double expected = s.rest_density * 9.81;
  EXPECT_NEAR(fit.slope, expected, 0.05 * expected) << "pressure slope (Pa/m), R^2 " << fit.r2;
  EXPECT_GT(fit.r2, 0.99) << "slope " << fit.slope;
  // Every layer within 5% of the fitted line's pressure at the bottom.
  for (size_t i = 0; i < depth.size(); ++i)
    EXPECT_NEAR(pres[i], fit.slope * depth[i] + fit.intercept, 0.05 * expected * depth.back())
        << "layer at depth " << depth[i];
  EXPECT_LT(err_sum, 0.01) << "mean density error over the last half second, max " << err_max;
  EXPECT_LT(err_max, 0.05);
  EXPECT_LT(vmean, 0.02) << "the column is not at rest (mean speed, m/s)";
}

TEST(FluidPhysics, DamBreakStaysInItsContainer) {
  FluidSettings s;
  s.spacing = 0.02;
  s.threads = 2;
  const Vec3 lo(0, 0, 0), hi(0.8, 0.4, 0.2);
  s.container = Collider::box((lo + hi) / 2, (hi - lo) / 2);
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(0.24, 0.3, 0.2)}});
  const double dt = 1.0 / 60.0;
  size_t escaped_max = 0;
  for (int i = 0; i < 180; ++i) {
    f.step(dt, {});
    size_t escaped = 0;
    for (const Vec3& x : f.state().x)
      escaped += !((x.array() >= lo.array() - 1e-9).all() && (x.array() <= hi.array() + 1e-9).all());
    escaped_max = std::max(escaped_max, escaped);
  }
  EXPECT_EQ(escaped_max, 0u);
  for (const Vec3& v : f.state().v) ASSERT_TRUE(v.allFinite());
}

TEST(FluidPhysics, StaysOutOfASphereAndOnAFloorPlane) {
  FluidSettings s;
  s.spacing = 0.02;
  const std::vector<Collider> cols{Collider::plane(Vec3(0, 0, 0), Vec3(0, 1, 0)),
                                   Collider::sphere(Vec3(0.1, 0.15, 0.1), 0.06)};
  FluidBody f(s, {FluidBlock{Vec3(0, 0.25, 0), Vec3(0.2, 0.35, 0.2)}});
  for (int i = 0; i < 60; ++i) f.step(1.0 / 60.0, cols);
  const double r = s.particle_radius * s.spacing;
  for (const Vec3& x : f.state().x) {
    ASSERT_GE(x.y(), r - 1e-9);
    ASSERT_GE((x - cols[1].point).norm(), cols[1].radius + r - 1e-9);
  }
}
