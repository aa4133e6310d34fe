// SPDX-License-Identifier: Apache-2.0
// The step does not depend on how many threads run it: every family splits its loops over
// work that shares no vertex (a slab's or a colour's tets, a colour's vertices) and reduces in
// fixed blocks in a fixed order, so one thread, two and four reach the same state and report the
// same residuals bit for bit. Short steps on
// beam3 (3,120 tets: four slabs in the sweeps' block order, colours large enough to be split
// in the other loops), with a tool and a grab in play.
// CI also runs these under ThreadSanitizer (scripts/sanitize.sh, SANITIZER=thread): they
// drive the thread pool through every family's parallel loops without gRPC in the process.
#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/interaction.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/model.hpp"
#include "pliant/state.hpp"
#include "pliant/stepper.hpp"
#include "kernels/strain_kernel.hpp"
#include "step/thread_pool.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <ostream>
#include <random>
#include <string>
#include <vector>

using namespace pliant;

namespace {

struct Case {
  std::string name;
  Method method;
  Sweep sweep = Sweep::GaussSeidel;
  NewtonLinearSolver linear = NewtonLinearSolver::Auto;
  int substeps = 4, iterations = 3;
};

void PrintTo(const Case& c, std::ostream* os) { *os << c.name; }

std::shared_ptr<const BodyModel> beam3(double young) {
  const TetMesh mesh = *builtin_mesh("beam3");
  return build_model(mesh, Material{young, 0.45, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
}

struct Outcome {
  BodyState state;
  StepReport last;  // the last step's report
};

Outcome run(const BodyModel& m, const Case& c, int threads) {
  SolverSettings s;
  s.method = c.method;
  s.sweep = c.sweep;
  s.newton_linear_solver = c.linear;
  s.substeps = c.substeps;
  s.iterations = c.iterations;
  s.threads = threads;
  StepInputs in;
  // A sphere pressed into the free end and a grab pulling a vertex of the middle up.
  in.tools.push_back(RigidTool::sphere(Vec3(0.095, 0.0155, 0.006), 0.006));
  const int32_t grabbed = int32_t(m.vertex_count() / 2);
  in.attachments.push_back(Attachment::vertex(grabbed, m.rest_positions[grabbed] + Vec3(0, 0.003, 0), 1e-4));
  Outcome out{rest_state(m), {}};
  Stepper stepper;
  for (int k = 0; k < 2; ++k) {
    out.last = stepper.step(m, out.state, s, in);
    EXPECT_FALSE(out.last.diverged) << c.name << " threads " << threads << " step " << k;
  }
  return out;
}

class ThreadCount : public ::testing::TestWithParam<Case> {};

TEST_P(ThreadCount, DoesNotChangeTheStep) {
  const Case& c = GetParam();
  auto m = beam3(1e6);
  const Outcome one = run(*m, c, 1);
  double scale = 0;
  for (size_t i = 0; i < one.state.x.size(); ++i)
    scale = std::max(scale, (one.state.x[i] - m->rest_positions[i]).norm());
  ASSERT_GT(scale, 1e-5) << "the body did not move: nothing was compared";
  // The residuals too (sums over the body, formed per fixed block of its work).
  ASSERT_FALSE(one.last.residuals.empty()) << "no residual was recorded: nothing was compared";
  for (int threads : {2, 4}) {
    const Outcome many = run(*m, c, threads);
    for (size_t i = 0; i < one.state.x.size(); ++i) {
      ASSERT_EQ(one.state.x[i], many.state.x[i]) << c.name << ", vertex " << i << ", " << threads << " threads";
      ASSERT_EQ(one.state.v[i], many.state.v[i]) << c.name << ", vertex " << i << ", " << threads << " threads";
    }
    EXPECT_EQ(one.last.residual_initial, many.last.residual_initial) << c.name << ", " << threads << " threads";
    EXPECT_EQ(one.last.residuals, many.last.residuals) << c.name << ", " << threads << " threads";
  }
}

INSTANTIATE_TEST_SUITE_P(
    Families, ThreadCount,
    ::testing::Values(Case{"xpbd_gauss_seidel", Method::Xpbd},
                      Case{"xpbd_jacobi", Method::Xpbd, Sweep::Jacobi},
                      Case{"anderson_sor", Method::AndersonSor, Sweep::GaussSeidel, NewtonLinearSolver::Auto, 2, 8},
                      Case{"vbd", Method::Vbd, Sweep::GaussSeidel, NewtonLinearSolver::Auto, 2, 6},
                      Case{"newton_direct", Method::Newton, Sweep::GaussSeidel, NewtonLinearSolver::Direct, 1, 2},
                      Case{"newton_cg", Method::Newton, Sweep::GaussSeidel, NewtonLinearSolver::Cg, 1, 2}),
    [](const ::testing::TestParamInfo<Case>& info) { return info.param.name; });

// Slabs of unequal sizes: the thesis hippo's four hold 648, 530, 457 and 580 packs, so its
// first phase is dealt to two or three threads by their packs, not cut in runs of equal counts
// (for_each_pack), and a thread runs slabs that are not neighbours in storage order. One Gauss-
// Seidel step with its floor passes, 1, 2 and 3 threads: the same positions, velocities and
// residuals to the bit.
TEST(ThreadCountDealt, TheHipposUnequalSlabsGiveTheSameStep) {
  const TetMesh mesh = resolve_mesh("hippo");
  const Aabb box = bounding_box(mesh.vertices);
  auto m = build_model(mesh, Material{1e5, 0.4, 1000}, clamp_below_x(box.min.x() + 0.1 * box.extent().x()));
  const auto& g = detail::packed(*m).phases.at(0).group_begin;
  ASSERT_EQ(g.size(), 5u) << "four slabs expected";
  auto size = [&](size_t k) { return g[k + 1] - g[k]; };
  // Cut in runs, two threads get slabs {0, 1} and {2, 3}; some other pairing is better balanced.
  const size_t runs = std::max(size(0) + size(1), size(2) + size(3));
  const size_t other = std::min(std::max(size(0) + size(2), size(1) + size(3)), std::max(size(0) + size(3), size(1) + size(2)));
  ASSERT_LT(other, runs) << "slabs " << size(0) << " " << size(1) << " " << size(2) << " " << size(3)
                         << " need no dealing: nothing here tests it";
  SolverSettings s;
  s.substeps = 2;
  s.iterations = 2;
  std::vector<BodyState> ends;
  std::vector<StepReport> reports;
  for (int threads : {1, 2, 3}) {
    s.threads = threads;
    BodyState st = rest_state(*m);
    Stepper stepper;
    StepReport r;
    for (int k = 0; k < 3; ++k) r = stepper.step(*m, st, s);
    ends.push_back(st);
    reports.push_back(r);
  }
  ASSERT_FALSE(reports[0].residuals.empty());
  for (size_t t = 1; t < ends.size(); ++t) {
    size_t differing = 0;
    for (size_t i = 0; i < ends[0].x.size(); ++i)
      differing += ends[t].x[i] != ends[0].x[i] || ends[t].v[i] != ends[0].v[i];
    EXPECT_EQ(differing, 0u) << t + 1 << " threads";
    EXPECT_EQ(reports[t].residuals, reports[0].residuals) << t + 1 << " threads";
  }
}

// The floor's settling passes run clusters of slivers that share no moving corner on separate
// threads, each as many passes as it needs: the armadillo standing on its feet at the default
// budget (64 x 1, E 1 MPa, under gravity, on a floor: bench_solver's step_xpbd_64x1 scene) settles
// a dozen such clusters in its third tick from rest. 1 and 2 threads: the same positions,
// velocities, corrections and passes to the bit, and the two threads did settle clusters apart.
TEST(ThreadCountSettle, SliverClustersSettledApartGiveTheSameStep) {
  const TetMesh mesh = resolve_mesh("armadillo");
  const Aabb box = bounding_box(mesh.vertices);
  FixedSelection fixed;
  fixed.boxes.push_back({Vec3(-1, -1, -1), Vec3(1, -0.040, 1)});
  auto m = build_model(mesh, Material{1e6, 0.4, 1000}, fixed);
  StepInputs in;
  in.colliders.push_back(Collider::plane(Vec3(0, box.min.y(), 0), Vec3(0, 1, 0)));
  SolverSettings s;
  s.substeps = 64;
  s.iterations = 1;
  s.record_residuals = false;
  std::vector<BodyState> ends;
  std::vector<StepReport> totals;
  for (int threads : {1, 2}) {
    s.threads = threads;
    BodyState st = rest_state(*m);
    Stepper stepper;
    StepReport total;
    for (int t = 0; t < 3; ++t) {
      const StepReport r = stepper.step(*m, st, s, in);
      total.volume_corrections += r.volume_corrections;
      total.floor_passes += r.floor_passes;
      total.floor_settle_clusters += r.floor_settle_clusters;
    }
    ends.push_back(st);
    totals.push_back(total);
  }
  EXPECT_EQ(totals[0].floor_settle_clusters, 0) << "one thread settles in one piece";
  ASSERT_GT(totals[1].floor_settle_clusters, 0) << "no cluster was settled apart: nothing was compared";
  EXPECT_EQ(totals[1].volume_corrections, totals[0].volume_corrections);
  EXPECT_EQ(totals[1].floor_passes, totals[0].floor_passes);
  size_t differing = 0;
  for (size_t i = 0; i < ends[0].x.size(); ++i) differing += ends[1].x[i] != ends[0].x[i] || ends[1].v[i] != ends[0].v[i];
  EXPECT_EQ(differing, 0u);
}

// The passes over the packs run on the positions in the sweep's own vertex numbering
// (PackedModel::sweep_vertex). A substep without contacts, grabs or tools holds that numbering
// from its first sweep to its floor passes, its residuals read on the packs so numbered; with a
// tool in the scene each pass takes the numbering for itself and the residuals read the mesh's
// packs on the positions in the mesh's numbering. A sphere tool (or a floor plane) far from the
// body touches nothing, so both must take the same step to the bit: a residual read on packs in
// another numbering than the positions', or a copy into or out of the numbering missed or
// repeated, would not (that the sweep's packs and the floor's records are the mesh's renumbered is
// SolveOrder's check, test_solve_order.cpp). Gravity pulls the
// clamped beam3, soft enough at 1 x 10 that the floor acts, with the residual recorded, on 1 and
// 2 threads.
TEST(SweepNumbering, ASubstepHeldInItGivesTheStepOfPassesThatTakeItEachForItself) {
  const TetMesh mesh = *builtin_mesh("beam3");
  const auto m = build_model(mesh, Material{3e3, 0.45, 1000}, clamp_below_x(default_clamp_x(mesh.vertices)));
  const detail::PackedModel& pm = detail::packed(*m);
  bool permuted = false;
  for (size_t v = 0; v < m->vertex_count(); ++v) permuted |= pm.sweep_vertex[v] != int32_t(v);
  ASSERT_TRUE(permuted) << "beam3's sweep numbering is its own: nothing would be compared";
  StepInputs far_tool, far_floor;
  far_tool.tools.push_back(RigidTool::sphere(Vec3(0, 10, 0), 0.01));
  far_floor.colliders.push_back(Collider::plane(Vec3(0, -10, 0), Vec3(0, 1, 0)));
  for (Method method : {Method::Xpbd, Method::Anderson, Method::Chebyshev})
    for (int threads : {1, 2})
      for (const StepInputs* other : {&far_tool, &far_floor}) {
        SolverSettings s;
        s.method = method;
        s.substeps = 1;
        s.iterations = 10;
        s.threads = threads;
        BodyState a = rest_state(*m), b = a;
        Stepper sa, sb;
        int corrections = 0, accepted = 0;
        const std::string what = std::string(to_string(method)) + ", " + std::to_string(threads) + " thread(s), " +
                                 (other == &far_tool ? "a far tool" : "a far floor");
        for (int k = 0; k < 10; ++k) {
          const StepReport ra = sa.step(*m, a, s, {});
          const StepReport rb = sb.step(*m, b, s, *other);
          ASSERT_EQ(ra.residuals, rb.residuals) << what << ", step " << k;
          ASSERT_EQ(ra.volume_corrections, rb.volume_corrections) << what << ", step " << k;
          ASSERT_EQ(rb.contacts, 0) << what;
          corrections += ra.volume_corrections;
          accepted += ra.accelerations_accepted;
        }
        for (size_t v = 0; v < m->vertex_count(); ++v) {
          ASSERT_EQ(a.x[v], b.x[v]) << what << ", vertex " << v;
          ASSERT_EQ(a.v[v], b.v[v]) << what << ", vertex " << v;
        }
        EXPECT_EQ(a.lambda, b.lambda) << what;
        if (method == Method::Xpbd) {
          EXPECT_GT(corrections, 0) << what << ": the floor never acted";
        }
        if (method == Method::Anderson) {
          EXPECT_GT(accepted, 0) << what << ": no proposal was taken";
        }
      }
}

// The pool's contract, which the bit-for-bit results above rest on: a job of n items is cut into
// size() chunks [n c / size, n (c + 1) / size), each run exactly once whichever thread claims
// it, and a job's chunks all end before parallel_for returns. With more threads than cores (8
// on a 2-core machine) workers wake up late, after the caller has run their chunks itself: a
// late worker must then run nothing, neither that job's chunks again nor a finished job's.
TEST(ThreadCountPool, RunsEveryChunkOnceWhicheverThreadClaimsIt) {
  std::mt19937 rng(7);
  for (int threads : {1, 2, 3, 8}) {
    ThreadPool pool(threads);
    ASSERT_EQ(pool.size(), threads);
    std::vector<std::atomic<int>> runs(static_cast<size_t>(threads));
    std::vector<size_t> begin(static_cast<size_t>(threads)), end(static_cast<size_t>(threads));
    for (int job = 0; job < 3000; ++job) {
      const size_t n = std::uniform_int_distribution<size_t>(0, 5000)(rng);
      for (auto& r : runs) r.store(0);
      std::atomic<size_t> items{0};
      pool.parallel_for(n, [&](int chunk, size_t b, size_t e) {
        runs[size_t(chunk)].fetch_add(1);
        begin[size_t(chunk)] = b;
        end[size_t(chunk)] = e;
        double sum = 0;  // a few microseconds of work, so that workers wake up in time for some
        for (size_t i = b; i < e; ++i) sum += std::sqrt(double(i));
        items.fetch_add(e - b + (sum < 0 ? 1 : 0));
      }, 1);
      ASSERT_EQ(items.load(), n) << threads << " threads, job " << job;
      const int chunks = n < 1 || threads == 1 ? 1 : threads;  // below min_parallel: one inline call
      for (int c = 0; c < chunks; ++c) {
        ASSERT_EQ(runs[size_t(c)].load(), 1) << threads << " threads, job " << job << ", chunk " << c;
        if (chunks == 1) continue;
        EXPECT_EQ(begin[size_t(c)], n * size_t(c) / size_t(threads));
        EXPECT_EQ(end[size_t(c)], n * size_t(c + 1) / size_t(threads));
      }
      for (int c = chunks; c < threads; ++c) ASSERT_EQ(runs[size_t(c)].load(), 0);
    }
  }
}

}  // namespace
