// SPDX-License-Identifier: Apache-2.0
// Real-time robustness: at a 60 Hz tick with the default substeps x iterations,
// the thesis beams, hippo and armadillo hang under gravity from a clamp for E from 10 kPa to
// 10 MPa (nu = 0.4) without blowing up, the beams with no inverted tet at the end and the thesis
// models within a documented bound; the hippo brought to rest at the default budget; and a
// budget that resolves the material.
#include "pliant/experiments.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/stepper.hpp"
#include "pliant/strain_constraint.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <tuple>

using namespace pliant;

namespace {

struct Case {
  const char* mesh;
  int ticks;  // the big models run fewer ticks to keep the suite fast on 2 cores
  // Inverted tets allowed at the end of the run. The beams: none. Known limitation: the thesis
  // hippo (slivers down to 6e-15 m^3) and armadillo can end a tick mid-swing with a few inverted
  // tets at the default 64 x 1 budget (measured worst in colour order: hippo 1 of 10,361 at
  // 100 kPa, armadillo 0 of 54,855; in block order hippo 2 at 10 kPa; docs/solver.md "Real-time
  // robustness"). The bound is the colour order's worst case plus 2: room for another CPU's
  // rounding, yet plain lumped masses (hippo 9 at 10 kPa, 4 at 100 kPa) would fail it. At rest
  // none is left (DefaultBudget, SupportInertiaMatrix below).
  size_t max_inverted;
  ElasticModel model = ElasticModel::StVK;
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.mesh << " " << to_string(c.model); }

class Robustness : public ::testing::TestWithParam<std::tuple<Case, double>> {};

}  // namespace

TEST_P(Robustness, StaysStableAtSixtyHertz) {
  const auto [c, young] = GetParam();
  const TetMesh mesh = resolve_mesh(c.mesh);
  Material material{young, 0.4, 1000};
  material.model = c.model;
  auto model = build_model(mesh, material,
                           clamp_below_x(bounding_box(mesh.vertices).min.x() + 0.1 * bounding_box(mesh.vertices).extent().x()));
  SolverSettings s;  // defaults: 60 Hz tick
  s.threads = 1;  // ctest runs suites side by side on 2 cores
  s.record_residuals = false;
  BodyState state = rest_state(*model);
  Stepper stepper;
  for (int k = 0; k < c.ticks; ++k) {
    const StepReport r = stepper.step(*model, state, s);
    ASSERT_FALSE(r.diverged) << "tick " << k;
  }
  ASSERT_TRUE(is_finite(state));
  const size_t inverted = count_inverted(*model, state.x);
  EXPECT_LE(inverted, c.max_inverted) << "inverted tets of " << model->tet_count() << " after " << c.ticks << " ticks";
  // Nothing flew away: every vertex stays within a few body lengths of its rest place.
  const double size = bounding_box(mesh.vertices).extent().maxCoeff();
  double worst = 0;
  for (size_t i = 0; i < state.x.size(); ++i) worst = std::max(worst, (state.x[i] - mesh.vertices[i]).norm());
  EXPECT_LT(worst, 3 * size);
}

INSTANTIATE_TEST_SUITE_P(
    Matrix, Robustness,
    ::testing::Combine(::testing::Values(Case{"beam1", 60, 0}, Case{"beam2", 60, 0}, Case{"beam3", 60, 0},
                                         Case{"hippo", 20, 3}, Case{"armadillo", 6, 2}),
                       ::testing::Values(1e4, 1e5, 1e6, 1e7)),
    [](const auto& info) {
      return std::string(std::get<0>(info.param).mesh) + "_E" +
             std::to_string(int(std::log10(std::get<1>(info.param))));
    });

// The same for the corotated strain on the beams (the thesis models: docs/data/rest_matrix_corotated.jsonl).
INSTANTIATE_TEST_SUITE_P(
    CorotatedMatrix, Robustness,
    ::testing::Combine(::testing::Values(Case{"beam1", 60, 0, ElasticModel::Corotated},
                                         Case{"beam2", 60, 0, ElasticModel::Corotated},
                                         Case{"beam3", 60, 0, ElasticModel::Corotated}),
                       ::testing::Values(1e4, 1e5, 1e6, 1e7)),
    [](const auto& info) {
      return std::string(std::get<0>(info.param).mesh) + "_E" +
             std::to_string(int(std::log10(std::get<1>(info.param))));
    });

namespace {

// A thesis model hanging from its first 10% of x (as scripts/rest-matrix.sh), stepped to rest
// under the default budget (64 x 1 per 60 Hz tick) with damping 5/s, as pliant-sim static
// --damping 5, so that it settles in seconds; at most 300 ticks.
struct Hung {
  std::shared_ptr<const BodyModel> model;
  RestResult rest;
};

Hung hang_at_default_budget(const std::string& name, const Material& material) {
  const TetMesh mesh = resolve_mesh(name);
  const Aabb box = bounding_box(mesh.vertices);
  Hung h;
  h.model = build_model(mesh, material, clamp_below_x(box.min.x() + 0.1 * box.extent().x()));
  SolverSettings s;
  s.threads = 1;
  s.damping_coefficient = 5;
  s.record_residuals = false;
  EXPECT_EQ(effective_substeps(*h.model, s), 64);
  EXPECT_EQ(s.iterations, 1);
  h.rest = run_to_rest(*h.model, s, 300, 1e-3);
  return h;
}

void expect_at_rest_upright(const Hung& h) {
  EXPECT_FALSE(h.rest.diverged);
  EXPECT_TRUE(h.rest.at_rest) << "max speed " << h.rest.max_speed << " after " << h.rest.steps << " ticks";
  EXPECT_EQ(count_inverted(*h.model, h.rest.state.x), 0u);
}

}  // namespace

class DefaultBudget : public ::testing::TestWithParam<double> {};

TEST_P(DefaultBudget, HippoComesToRestWithNoInvertedTet) {
  // The robustness case brought to rest on the thesis hippo. At 1 MPa under the default 64 x 1 with plain
  // lumped masses it keeps a sliver (tet 594) inverted and a 1.6 mg vertex jittering at 2 m/s
  // after 600 ticks, at 100 kPa one inverted tet and 0.11 m/s (docs/solver.md, "Real-time
  // robustness"). With the default inertia floor (vertices of tiny tets move as if they
  // weighed 1/10 of the mean vertex, their weight unchanged) it comes to rest in about 150-170
  // ticks with no inverted tet at 100 kPa, 1 MPa and 10 MPa. (At 10 kPa one spot still creeps
  // at a few mm/s after 600 ticks with no inverted tet: not asserted here.)
  const Hung h = hang_at_default_budget("hippo", Material{GetParam(), 0.4, 1000});
  EXPECT_GT(h.model->floored_vertices(), 0u);
  expect_at_rest_upright(h);
}

INSTANTIATE_TEST_SUITE_P(Hippo, DefaultBudget, ::testing::Values(1e5, 1e6, 1e7),
                         [](const auto& info) {
                           std::string name(1, 'E');  // not "E" + ...: a GCC 12 -Wrestrict false positive
                           name += std::to_string(int(std::log10(info.param)));
                           return name;
                         });

TEST(ResolvedBudget, HippoSettlesWithNoInvertedTet) {
  // A budget that resolves the material needs no inertia floor for the body: with plain lumped
  // masses the hippo at 100 kPa (one inverted tet and a jittering vertex after 600 ticks of
  // 64 x 1) settles with no inverted tet at the fewest substeps with a pressure wave crossing
  // at most 0.3 elements per substep (144 here), 1 iteration each. What the floor is for
  // remains: a cluster of sliver vertices near x = -0.058 m (1e-10 to 1e-7 kg) may keep
  // jittering at up to 0.2 m/s, depending on the sweep order alone (`pliant-sim static --mesh
  // hippo --young 1e5 --inertia-floor 0 --wave-courant 0.3 --iterations 1 --damping 5
  // --speed-tol 1e-3 --max-steps 400 --fix-x-max -0.07159`: in colour order, tets as numbered
  // at rest after 166 ticks, reversed 0.20 m/s, shuffled 0.13 m/s after 400; in the block order
  // 0.22 m/s; rms speed 1e-5 to 5e-5 m/s in all). So: the vertices still faster than the rest
  // tolerance weigh a ten-thousandth of the body at most.
  const TetMesh mesh = resolve_mesh("hippo");
  const Aabb box = bounding_box(mesh.vertices);
  Material material{1e5, 0.4, 1000};
  material.inertia_floor = 0;
  auto model = build_model(mesh, material, clamp_below_x(box.min.x() + 0.1 * box.extent().x()));
  SolverSettings s;
  s.target_wave_courant_number = 0.3;
  s.iterations = 1;
  s.threads = 1;
  s.damping_coefficient = 5;  // settle in seconds, as pliant-sim static --damping 5
  s.record_residuals = false;
  ASSERT_EQ(effective_substeps(*model, s), 144);
  const double tolerance = 1e-3;
  const RestResult r = run_to_rest(*model, s, 400, tolerance);
  EXPECT_FALSE(r.diverged);
  double moving = 0, total = 0;
  for (size_t i = 0; i < r.state.v.size(); ++i) {
    total += model->mass[i];
    if (r.state.v[i].norm() >= tolerance) moving += model->mass[i];
  }
  EXPECT_LT(moving, 1e-4 * total) << "max speed " << r.max_speed << " after " << r.steps << " ticks; "
                                  << moving / total << " of the mass faster than " << tolerance << " m/s";
  EXPECT_EQ(count_inverted(*model, r.state.x), 0u);
}

class SupportInertiaMatrix : public ::testing::TestWithParam<std::tuple<std::string, double>> {};

TEST_P(SupportInertiaMatrix, ComesToRestWithNoInvertedTetAtTheDefaultBudget) {
  // The robustness case brought to rest on both thesis models at every E, under the default 64 x 1 at
  // 60 Hz, with support_inertia 1 (docs/solver.md, "Support inertia"). Without it the armadillo
  // at 1 and 10 MPa never settles: a band of vertices next to the clamp keeps moving at 1.6 /
  // 3.4 m/s after 400 ticks (docs/data/rest_matrix.jsonl). Measured with it: at rest after
  // 115-185 ticks, none inverted (docs/data/rest_matrix_support.jsonl). The armadillo at 10 MPa also hangs within 3x of the
  // Newton equilibrium's |tip| of 5.8 mm ([-1.5, -5.6] mm: `pliant-sim reference --mesh
  // armadillo --young 1e7 --fix-x-max -0.04936`, 200 s, too slow to repeat here), measured 2.05x,
  // where the default material hangs it 11 cm down.
  const auto [name, young] = GetParam();
  Material material{young, 0.4, 1000};
  material.support_inertia = 1;
  const Hung h = hang_at_default_budget(name, material);
  expect_at_rest_upright(h);
  if (name == "armadillo" && young == 1e7) {
    const double tip = tip_displacement(*h.model, h.rest.state.x).norm();
    EXPECT_GT(tip, 5.8e-3);  // no stiffer than the material
    EXPECT_LT(tip, 3 * 5.8e-3);
  }
}

INSTANTIATE_TEST_SUITE_P(SupportInertia, SupportInertiaMatrix,
                         ::testing::Combine(::testing::Values(std::string("hippo"), std::string("armadillo")),
                                            ::testing::Values(1e4, 1e5, 1e6, 1e7)),
                         [](const auto& info) {
                           std::string name = std::get<0>(info.param) + "_E";
                           name += std::to_string(int(std::log10(std::get<1>(info.param))));
                           return name;
                         });

// The armadillo standing on its fixed feet (the service's scene: E 1 MPa, gravity, a floor plane,
// the default 64 x 1): a cluster of slivers next to the fixed vertices is inverted again by
// every substep's sweep, and the floor's passes, each reaching it only through the vertices the
// previous one moved, brought it back by a small fraction a pass; the passes over the packs the
// floor acted on settle it. Without them the fourth tick ended with a tet at det F = -0.21 and
// the fifth at 0.18 (floor 0.2); with them every tick of these twelve ends at 0.19 or above.
TEST(Floor, SettlesTheSliversOfTheStandingArmadilloEveryTick) {
  const TetMesh mesh = resolve_mesh("armadillo");
  FixedSelection feet;
  feet.boxes.push_back({Vec3(-1, -1, -1), Vec3(1, -0.040, 1)});
  auto model = build_model(mesh, Material{1e6, 0.4, 1000}, feet);
  StepInputs in;
  in.colliders.push_back(Collider::plane(Vec3(0, bounding_box(mesh.vertices).min.y(), 0), Vec3(0, 1, 0)));
  SolverSettings s;
  s.threads = 1;
  s.record_residuals = false;
  BodyState state = rest_state(*model);
  Stepper stepper;
  for (int k = 0; k < 12; ++k) {
    stepper.step(*model, state, s, in);
    double lowest = 1e300;
    for (const TetRest& t : model->tets) lowest = std::min(lowest, volume_ratio(t, gather(state.x, t.v)));
    EXPECT_GE(lowest, s.inversion_floor / 2) << "tick " << k;
  }
}
