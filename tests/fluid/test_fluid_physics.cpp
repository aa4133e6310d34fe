// SPDX-License-Identifier: Apache-2.0
// Position-based fluids brought to rest and thrown about: a column at rest in a box keeps a
// hydrostatic pressure (from the density multipliers) and its density; a dam break stays in
// its container.
#include "pliant/fluid.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

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
  FluidSettings s;
  s.spacing = 0.02;
  s.substeps = 2;
  s.iterations = 4;
  const double w = 0.16, height = 0.4;
  s.container = Collider::box(Vec3(w / 2, 0.5, w / 2), Vec3(w / 2, 0.5, w / 2));
  FluidBody f(s, {FluidBlock{Vec3(0, 0, 0), Vec3(w, height, w)}});
  const double dt = 1.0 / 60.0;
  ParticleStepReport r;
  for (int i = 0; i < 240; ++i) r = f.step(dt, {});
  // Pressure against depth below the surface (the highest particle), away from the walls'
  // layer and the surface layer (where the clamped constraint is inactive).
  const ParticleState& st = f.state();
  double top = -1e9;
  for (const Vec3& x : st.x) top = std::max(top, x.y());
  const std::vector<double> p = f.pressure();
  std::vector<double> depth, pres;
  double vmax = 0.0;
  for (size_t i = 0; i < st.x.size(); ++i) {
    vmax = std::max(vmax, st.v[i].norm());
    const double dd = top - st.x[i].y();
    if (dd < 2.5 * s.spacing || st.x[i].y() < 2.5 * s.spacing) continue;
    depth.push_back(dd);
    pres.push_back(p[i]);
  }
  ASSERT_GT(depth.size(), 100u);
  const Fit fit = fit_line(depth, pres);
  const double expected = s.rest_density * 9.81;
  EXPECT_NEAR(fit.slope, expected, 0.05 * expected) << "pressure slope (Pa/m), R^2 " << fit.r2;
  EXPECT_GT(fit.r2, 0.95) << "slope " << fit.slope;
  EXPECT_LT(r.constraint_error, 0.01) << "mean density error, max " << r.max_constraint_error;
  EXPECT_LT(r.max_constraint_error, 0.05);
  EXPECT_LT(vmax, 0.05) << "the column is not at rest";
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
