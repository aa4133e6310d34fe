// SPDX-License-Identifier: Apache-2.0
// The inversion floor stage: its parallel search for the tets to correct must change nothing in
// the result. On a beam crushed at random (many tets inverted, corrections that push neighbours
// under the floor, so several passes), it gives the positions of the plain serial loop over all
// tets, bit for bit, with one thread and with two, for every pass limit.
#include "kernels/projection.hpp"
#include "kernels/strain_kernel.hpp"
#include "step/thread_pool.hpp"
#include "step/volume_floor.hpp"

#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/strain_constraint.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

using namespace pliant;

namespace {

// The reference: pass after pass over every tet in mesh order, until a pass does nothing.
int serial_floor(const BodyModel& m, std::vector<Vec3>& x, double floor, int max_passes, int& passes) {
  int total = 0;
  passes = 0;
  for (int pass = 0; pass < max_passes; ++pass) {
    int hits = 0;
    for (const TetRest& t : m.tets) hits += detail::enforce_volume_floor(t, x, m.inv_mass, floor);
    total += hits;
    ++passes;
    if (hits == 0) break;
  }
  return total;
}

}  // namespace

TEST(VolumeFloor, GivesThePlainSerialLoopsPositionsBitForBit) {
  const TetMesh mesh = *builtin_mesh("beam3");
  const auto model = build_model(mesh, Material{1e6, 0.4, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
  const BodyModel& m = *model;
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.3 * m.mean_edge);
  std::vector<Vec3> crushed = m.rest_positions;
  for (size_t i = 0; i < crushed.size(); ++i)
    if (m.inv_mass[i] > 0) crushed[i] += Vec3(noise(rng), noise(rng), noise(rng));
  const double floor = 0.5;
  int below = 0;
  for (const TetRest& t : m.tets) below += volume_ratio(t, gather(crushed, t.v)) < floor;
  ASSERT_GT(below, 20);

  bool several_passes = false;
  for (int threads : {1, 2}) {
    ThreadPool pool(threads);
    detail::VolumeFloor stage;
    for (int max_passes : {1, 2, 3, 20}) {
      std::vector<Vec3> expected = crushed, x = crushed;
      int passes = 0;
      const int expected_hits = serial_floor(m, expected, floor, max_passes, passes);
      several_passes |= passes > 2;
      const int hits = stage.enforce(m, x, floor, max_passes, pool);
      EXPECT_EQ(hits, expected_hits) << threads << " threads, " << max_passes << " passes";
      for (size_t i = 0; i < x.size(); ++i)
        ASSERT_EQ(x[i], expected[i]) << "vertex " << i << ", " << threads << " threads, " << max_passes << " passes";
    }
  }
  EXPECT_TRUE(several_passes);  // the crush needs more than one pass, so later passes are exercised

  // Nothing below the floor: no correction and x untouched.
  ThreadPool pool(2);
  detail::VolumeFloor stage;
  std::vector<Vec3> rest = m.rest_positions;
  EXPECT_EQ(stage.enforce(m, rest, floor, 20, pool), 0);
  EXPECT_EQ(rest, m.rest_positions);
}

// The floor's passes skip a pack when floor_may_act says no lane can be below the trigger, from
// the floor's own det F (det D_s det B) less a margin for rounding. It must never skip a pack
// the floor would correct: here the trigger is put one ulp above each lane's det F as the floor
// takes it (the floor acts on it), on bodies crushed at random into slivers and inverted tets
// and scaled far from unit size.
TEST(VolumeFloor, ThePreCheckNeverSkipsAPackTheFloorWouldCorrect) {
  const TetMesh mesh = *builtin_mesh("beam3");
  const auto model = build_model(mesh, Material{1e6, 0.4, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
  const BodyModel& m = *model;
  const detail::PackedModel& packed = detail::packed(m);
  ASSERT_EQ(packed.floor_checks.size(), packed.packs.size());
  std::mt19937 rng(11);
  int acting = 0;
  for (double spread : {0.0, 0.05, 0.3, 1.0}) {
    for (double scale : {1.0, 1e-3, 1e3}) {
      std::normal_distribution<double> noise(0.0, spread * m.mean_edge);
      std::vector<Vec3> x = m.rest_positions;
      for (Vec3& q : x) q = scale * (q + Vec3(noise(rng), noise(rng), noise(rng))) + Vec3(0.3, -2.0, 7.0);
      for (size_t i = 0; i < packed.packs.size(); ++i) {
        const detail::TetPack& p = packed.packs[i];
        const detail::v4d J = detail::floor_volume_ratio(packed.floor_checks[i], x);  // the floor's own det F
        for (int l = 0; l < p.lanes; ++l) {
          const double above = std::nextafter(J[l], INFINITY);
          ASSERT_TRUE(detail::floor_may_act(packed.floor_checks[i], x, above))
              << "pack " << i << " lane " << l << " det F " << J[l] << " spread " << spread << " scale " << scale;
          ++acting;
        }
      }
      // With the default floor most packs of a mildly deformed body are skipped (scaling the
      // positions scales det F by scale^3).
      if (spread <= 0.05 && scale == 1.0) {
        size_t skipped = 0;
        for (const detail::FloorCheck& c : packed.floor_checks) skipped += !detail::floor_may_act(c, x, 0.2);
        EXPECT_GT(skipped, packed.packs.size() * 9 / 10) << "spread " << spread << " scale " << scale;
      }
    }
  }
  EXPECT_GT(acting, 1000);
}

// volume_floor_pack moves each lane under the trigger along grad det F by relax times the
// linearised step to target: det F lands on target (relax 1) or past it by (relax - 1) times the
// deficit (the tangled body's passes), to first order. Lanes above the trigger are not moved. From
// 1% under the floor the cubic's higher-order terms stay under 1e-3 of it, against 3% for a
// relaxation or a target left out.
TEST(VolumeFloor, APackCorrectionLandsOnItsTargetTimesItsRelaxation) {
  const TetMesh mesh = *builtin_mesh("beam1");
  const auto model = build_model(mesh, Material{1e6, 0.4, 1000});
  const BodyModel& m = *model;
  const detail::PackedModel& packed = detail::packed(m);
  const double floor = 0.2;
  int checked = 0;
  for (size_t i = 0; i < packed.floor_checks.size() && checked < 40; ++i) {
    const detail::FloorCheck& c = packed.floor_checks[i];
    if (c.lanes < 2) continue;
    // Lane 0 crushed to 0.99 of the floor along its own axis (its corner 0 moved towards the
    // opposite face); the other lanes at rest (det F 1).
    std::vector<Vec3> x = m.rest_positions;
    {
      const double J0 = detail::floor_volume_ratio(c, x)[0];
      ASSERT_NEAR(J0, 1.0, 1e-9);
      const Vec3 a = x[c.v[0][0]], centroid = (x[c.v[1][0]] + x[c.v[2][0]] + x[c.v[3][0]]) / 3.0;
      // det F is affine in corner 0's move towards the opposite face.
      x[c.v[0][0]] = centroid + 0.99 * floor * (a - centroid);
    }
    const double J0 = detail::floor_volume_ratio(c, x)[0];
    ASSERT_NEAR(J0, 0.99 * floor, 1e-9);
    for (const auto& [target, relax] : {std::pair{floor, 1.0}, std::pair{1.05 * floor, 1.5}}) {
      std::vector<Vec3> y = x;
      const int corrected = detail::volume_floor_pack(c, y, floor * (1 - 1e-6), target, relax);
      const bool free = c.w[0][0] + c.w[1][0] + c.w[2][0] + c.w[3][0] > 0;
      EXPECT_EQ(corrected, free ? 1 : 0) << "only the crushed lane acts";
      if (!free) continue;
      const double J = detail::floor_volume_ratio(c, y)[0];
      const double expected = J0 + relax * (target - J0);
      EXPECT_NEAR(J, expected, 1e-3 * floor) << "pack " << i << " target " << target << " relax " << relax;
      for (int l = 1; l < c.lanes; ++l) EXPECT_NEAR(detail::floor_volume_ratio(c, y)[l], 1.0, 1e-9);
      ++checked;
    }
  }
  EXPECT_GE(checked, 40);
}
