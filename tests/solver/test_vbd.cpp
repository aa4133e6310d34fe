// SPDX-License-Identifier: Apache-2.0
// Vertex block descent as physics: the per-vertex kernel against the reference energy and
// finite differences, monotone descent of the incremental potential, the converged step equal
// to Newton's, conservation of momentum, rigid motion, fixed vertices, grabs, tools and
// inversion safety.
#include "pliant/builtin_meshes.hpp"
#include "pliant/experiments.hpp"
#include "pliant/interaction.hpp"
#include "pliant/reference_solver.hpp"
#include "pliant/stepper.hpp"
#include "pliant/strain_constraint.hpp"
#include "vbd/vbd.hpp"
#include "vbd/vbd_lanes.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <algorithm>
#include <random>

using namespace pliant;

namespace {

constexpr ElasticModel kModels[] = {ElasticModel::StVK, ElasticModel::Corotated};

std::shared_ptr<const BodyModel> beam1(double young, ElasticModel model, bool clamped = true) {
  TetMesh mesh = *builtin_mesh("beam1");
  Material mat{young, 0.4, 1000};
  mat.model = model;
  return build_model(mesh, mat, clamped ? clamp_below_x(default_clamp_x(mesh.vertices)) : FixedSelection{});
}

SolverSettings vbd_settings() {
  SolverSettings s;
  s.method = Method::Vbd;
  s.substeps = 1;
  s.iterations = 50;
  s.chebyshev.delay = s.iterations;  // plain VBD unless a test asks for the acceleration
  return s;
}

// The prediction the stage makes from a state (free vertices: x + h v + h^2 g mass/inertia).
std::vector<Vec3> predicted(const BodyModel& m, const BodyState& st, const SolverSettings& s, double h) {
  std::vector<Vec3> y = st.x;
  for (size_t i = 0; i < y.size(); ++i)
    if (m.inv_mass[i] > 0) y[i] += h * st.v[i] + h * h * s.gravity * (m.mass[i] / m.inertia[i]);
  return y;
}

Vec3 linear_momentum(const BodyModel& m, const BodyState& st) {
  Vec3 p = Vec3::Zero();
  for (size_t i = 0; i < st.v.size(); ++i) p += m.inertia[i] * st.v[i];
  return p;
}

Vec3 angular_momentum(const BodyModel& m, const BodyState& st) {
  Vec3 l = Vec3::Zero();
  for (size_t i = 0; i < st.v.size(); ++i) l += st.x[i].cross(m.inertia[i] * st.v[i]);
  return l;
}

// Sum over the free vertices of the elastic force -dE/dx_i.
Vec3 elastic_force_on_free(const BodyModel& m, const std::vector<Vec3>& x) {
  Vec3 f = Vec3::Zero();
  for (const TetRest& t : m.tets) {
    Vec12 g;
    strain_energy_derivatives(t, m.stiffness, gather(x, t.v), &g, nullptr, false, m.material.model);
    for (int k = 0; k < 4; ++k)
      if (!m.fixed[t.v[k]]) f -= g.segment<3>(3 * k);
  }
  return f;
}

// beam1 (free) bent 5 mm at the tip, spinning and drifting.
BodyState spinning_bent_beam(const BodyModel& m) {
  BodyState st = rest_state(m);
  st.x = cantilever_bend(m, default_clamp_x(m.rest_positions), 0.005);
  const Vec3 omega(0.3, 1.0, 0.2), drift(0.05, -0.02, 0.01);
  for (size_t i = 0; i < st.x.size(); ++i) st.v[i] = drift + omega.cross(st.x[i] - Vec3(0.06, 0.005, 0.005));
  return st;
}

}  // namespace

TEST(VertexBlockDescent, VertexColoursSeparateEveryTet) {
  auto m = beam1(1e6, ElasticModel::StVK);
  std::vector<int> colour(m->vertex_count(), -1);
  for (size_t c = 0; c < m->vertex_colours.size(); ++c)
    for (int32_t v : m->vertex_colours[c]) {
      EXPECT_EQ(colour[v], -1) << "vertex " << v << " in two colours";
      colour[v] = int(c);
    }
  for (size_t i = 0; i < m->vertex_count(); ++i) EXPECT_GE(colour[i], 0) << "vertex " << i << " uncoloured";
  for (const TetRest& t : m->tets)
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) EXPECT_NE(colour[t.v[a]], colour[t.v[b]]);
  // The adjacency lists each (tet, corner) once, under its vertex.
  ASSERT_EQ(m->vertex_tet_entry.size(), 4 * m->tet_count());
  for (size_t i = 0; i < m->vertex_count(); ++i)
    for (int32_t a = m->vertex_tet_start[i]; a < m->vertex_tet_start[i + 1]; ++a)
      EXPECT_EQ(m->tets[m->vertex_tet_entry[a] / 4].v[m->vertex_tet_entry[a] % 4], int32_t(i));
  // Carried by the derived models.
  auto soft = with_material(*m, Material{1e4, 0.3, 900});
  EXPECT_EQ(soft->vertex_colours, m->vertex_colours);
  EXPECT_EQ(with_fixed(*m, FixedSelection{})->vertex_tet_entry, m->vertex_tet_entry);
}

TEST(VertexBlockDescent, VertexGradientAndHessianMatchTheReferenceAndFiniteDifferences) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  auto m = beam1(1e6, ElasticModel::StVK);
  for (ElasticModel model : kModels) {
    for (int trial = 0; trial < 20; ++trial) {
      const TetRest& tet = m->tets[(trial * 97) % m->tet_count()];
      std::array<Vec3, 4> x = gather(m->rest_positions, tet.v);
      // A rotation and a deformation of up to 30% of the tet's size.
      const Mat3 R = Eigen::AngleAxisd(u(rng) * 3, Vec3(u(rng), u(rng), u(rng)).normalized()).toRotationMatrix();
      for (auto& p : x) p = R * p + 0.3 * 0.005 * Vec3(u(rng), u(rng), u(rng));
      if (volume_ratio(tet, x) <= 0.2) continue;
      Vec12 g_ref;
      Mat12 H_ref;
      strain_energy_derivatives(tet, m->stiffness, x, &g_ref, &H_ref, false, model);
      for (int k = 0; k < 4; ++k) {
        Vec3 g;
        Mat3 H;
        detail::tet_vertex_derivatives(tet, k, x, m->stiffness, model, detail::VbdHessian::Exact, g, H);
        const double gs = g_ref.norm(), hs = H_ref.norm();
        EXPECT_NEAR((g - g_ref.segment<3>(3 * k)).norm(), 0, 1e-10 * gs);
        EXPECT_NEAR((H - H_ref.block<3, 3>(3 * k, 3 * k)).norm(), 0, 1e-10 * hs);
        // Central differences of the energy (gradient) and of the gradient (Hessian).
        const double eps = 1e-7 * 0.005;
        for (int c = 0; c < 3; ++c) {
          auto xp = x, xm = x;
          xp[k][c] += eps;
          xm[k][c] -= eps;
          const double fd = (strain_energy(tet, m->stiffness, xp, model) - strain_energy(tet, m->stiffness, xm, model)) / (2 * eps);
          EXPECT_NEAR(g[c], fd, 1e-5 * gs + 1e-12);
          Vec3 gp, gm;
          Mat3 unused;
          detail::tet_vertex_derivatives(tet, k, xp, m->stiffness, model, detail::VbdHessian::Exact, gp, unused);
          detail::tet_vertex_derivatives(tet, k, xm, m->stiffness, model, detail::VbdHessian::Exact, gm, unused);
          EXPECT_NEAR(((gp - gm) / (2 * eps) - H.col(c)).norm(), 0, 1e-5 * hs);
        }
        EXPECT_NEAR(detail::tet_energy(tet, x, m->stiffness, model), strain_energy(tet, m->stiffness, x, model),
                    1e-12 * strain_energy(tet, m->stiffness, x, model) + 1e-18);
        // Both definite choices are PSD; the projection leaves a PSD block unchanged.
        for (detail::VbdHessian mode : {detail::VbdHessian::Projected, detail::VbdHessian::GaussNewton}) {
          Vec3 g2;
          Mat3 H2;
          detail::tet_vertex_derivatives(tet, k, x, m->stiffness, model, mode, g2, H2);
          EXPECT_EQ(g2, g);
          EXPECT_GE(Eigen::SelfAdjointEigenSolver<Mat3>(H2).eigenvalues()[0], -1e-9 * hs);
          if (mode == detail::VbdHessian::Projected && Eigen::SelfAdjointEigenSolver<Mat3>(H).eigenvalues()[0] >= 0) {
            EXPECT_NEAR((H2 - H).norm(), 0, 1e-10 * hs);
          }
        }
      }
    }
  }
}

TEST(VertexBlockDescent, TheLaneKernelMatchesThePerTetForms) {
  // A deformed beam: every vertex's tets four at a time (vbd_lanes.hpp) against the per-tet
  // Gauss-Newton forms summed one tet at a time, at the gathered positions and with the vertex
  // moved after the gather (no new gather), and the inversion test of the line search.
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  for (ElasticModel model : kModels) {
    auto m = beam1(1e6, model, false);
    const auto packs = detail::compile_vertex_packs<detail::v4d>(*m);
    std::vector<Vec3> x = m->rest_positions;
    const Mat3 R = Eigen::AngleAxisd(0.8, Vec3(1, -2, 1).normalized()).toRotationMatrix();
    for (Vec3& p : x) p = R * (p + Vec3(0.3 * p[0] * p[0], 0.05 * p[0], 0)) + 0.2 * m->mean_edge * Vec3(u(rng), u(rng), u(rng));
    std::vector<int> valences;
    detail::VertexTets<detail::v4d> tets;
    for (int32_t i = 0; i < int32_t(m->vertex_count()); ++i) {
      tets.gather(packs, i, x);
      valences.push_back(m->vertex_tet_start[i + 1] - m->vertex_tet_start[i]);
      for (const Vec3& d : {Vec3(Vec3::Zero()), Vec3(0.1 * m->mean_edge * Vec3(u(rng), u(rng), u(rng)))}) {
        std::vector<Vec3> xm = x;
        xm[i] += d;
        Vec3 g_ref = Vec3::Zero();
        Mat3 H_ref = Mat3::Zero();
        double e_ref = 0;
        bool inverted = false;
        for (int32_t a = m->vertex_tet_start[i]; a < m->vertex_tet_start[i + 1]; ++a) {
          const TetRest& t = m->tets[m->vertex_tet_entry[a] >> 2];
          Vec3 g;
          Mat3 H;
          detail::tet_vertex_derivatives(t, m->vertex_tet_entry[a] & 3, gather(xm, t.v), m->stiffness, model,
                                         detail::VbdHessian::GaussNewton, g, H);
          g_ref += g;
          H_ref += H;
          e_ref += detail::tet_energy(t, gather(xm, t.v), m->stiffness, model);
          inverted |= !(volume_ratio(t, gather(xm, t.v)) > 0);
        }
        Vec3 g;
        Mat3 H;
        tets.derivatives(d, m->lame, model, g, &H);
        EXPECT_NEAR((g - g_ref).norm(), 0, 1e-11 * (g_ref.norm() + H_ref.norm() * m->mean_edge)) << "vertex " << i;
        EXPECT_NEAR((H - H_ref).norm(), 0, 1e-11 * H_ref.norm()) << "vertex " << i;
        Vec3 g_only;
        tets.derivatives(d, m->lame, model, g_only, nullptr);
        EXPECT_EQ(g_only, g);
        double e = 0;
        ASSERT_EQ(tets.energy(d, m->lame, model, e), !inverted) << "vertex " << i;
        if (!inverted) {
          EXPECT_NEAR(e, e_ref, 1e-11 * e_ref) << "vertex " << i;
        }
      }
      // Pushing the vertex through the plane of one of its tets' other corners inverts it.
      const TetRest& t = m->tets[m->vertex_tet_entry[m->vertex_tet_start[i]] >> 2];
      const int k = m->vertex_tet_entry[m->vertex_tet_start[i]] & 3;
      const Vec3& a = x[t.v[(k + 1) % 4]];
      const Vec3& b = x[t.v[(k + 2) % 4]];
      const Vec3& c = x[t.v[(k + 3) % 4]];
      const Vec3 n = (b - a).cross(c - a).normalized();
      const Vec3 mirror = x[i] - 2 * (x[i] - a).dot(n) * n;
      double e = 0;
      EXPECT_FALSE(tets.energy(mirror - x[i], m->lame, model, e)) << "vertex " << i;
      EXPECT_EQ(e, 0.0);
    }
    // The beam has vertices whose tet count is not a multiple of four (padding lanes).
    EXPECT_TRUE(std::any_of(valences.begin(), valences.end(), [](int v) { return v % 4 != 0; }));
  }
}

TEST(VertexBlockDescent, TheLaneKernelTakesThePerTetFormsStep) {
  // Two steps with tools, a grab and Chebyshev: the lane kernel and the per-tet forms differ
  // only in the order of the tets' sums.
  for (ElasticModel model : kModels) {
    auto m = beam1(1e5, model);
    SolverSettings s = vbd_settings();
    s.substeps = 2;
    s.iterations = 20;
    s.chebyshev.delay = 5;
    StepInputs in;
    in.tools.push_back(RigidTool::sphere(Vec3(0.1, 0.019, 0.005), 0.01));
    in.attachments.push_back(Attachment::vertex(int32_t(m->vertex_count() - 1), m->rest_positions.back() + Vec3(0, 0.002, 0), 1e-3));
    BodyState lanes = rest_state(*m), per_tet = lanes;
    detail::VbdOptions opt;
    auto a = detail::make_vbd_family(opt);
    opt.lanes = false;
    auto b = detail::make_vbd_family(opt);
    double moved = 0, diff = 0;
    for (int step = 0; step < 2; ++step) {
      const StepReport ra = a->step(*m, lanes, s, in, {});
      const StepReport rb = b->step(*m, per_tet, s, in, {});
      EXPECT_EQ(ra.iterations, rb.iterations);
      EXPECT_NEAR((ra.tools[0].force - rb.tools[0].force).norm(), 0, 1e-7 * rb.tools[0].force.norm() + 1e-12);
    }
    for (size_t i = 0; i < lanes.x.size(); ++i) {
      moved = std::max(moved, (per_tet.x[i] - m->rest_positions[i]).norm());
      diff = std::max(diff, (lanes.x[i] - per_tet.x[i]).norm());
    }
    EXPECT_GT(moved, 1e-3);
    EXPECT_LT(diff, 1e-8 * moved) << to_string(model);
  }
}

TEST(VertexBlockDescent, RigidMotionGivesZeroForceAndNoMotion) {
  for (ElasticModel model : kModels) {
    auto m = beam1(1e6, model, false);
    const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
    BodyState st = rest_state(*m);
    for (Vec3& p : st.x) p = R * p + Vec3(0.3, -0.2, 0.1);
    double scale = 0;
    for (size_t i = 0; i < m->vertex_count(); ++i) {
      Vec3 f = Vec3::Zero();
      for (int32_t a = m->vertex_tet_start[i]; a < m->vertex_tet_start[i + 1]; ++a) {
        const TetRest& t = m->tets[m->vertex_tet_entry[a] / 4];
        Vec3 g;
        Mat3 H;
        detail::tet_vertex_derivatives(t, m->vertex_tet_entry[a] % 4, gather(st.x, t.v), m->stiffness, model,
                                       detail::VbdHessian::Projected, g, H);
        f += g;
        scale = std::max(scale, H.norm() * 0.005);
      }
      EXPECT_LT(f.norm(), 1e-9 * scale) << "vertex " << i;
    }
    SolverSettings s = vbd_settings();
    s.gravity.setZero();
    const std::vector<Vec3> before = st.x;
    Stepper stepper;
    stepper.step(*m, st, s);
    for (size_t i = 0; i < before.size(); ++i) EXPECT_NEAR((st.x[i] - before[i]).norm(), 0, 1e-12);
  }
}

TEST(VertexBlockDescent, IncrementalPotentialDecreasesEveryIteration) {
  for (ElasticModel model : kModels) {
    for (double young : {1e5, 1e7}) {
      auto m = beam1(young, model);
      SolverSettings s = vbd_settings();
      s.iterations = 40;
      s.chebyshev.delay = s.iterations;
      BodyState st = rest_state(*m);
      st.x = cantilever_bend(*m, default_clamp_x(m->rest_positions), 0.02);
      const double h = s.dt;
      const std::vector<Vec3> y = predicted(*m, st, s, h);
      std::vector<double> g{detail::incremental_potential(*m, y, y, h)};
      Stepper stepper;
      stepper.set_iteration_hook([&](int, const std::vector<Vec3>& x, double, double) {
        g.push_back(detail::incremental_potential(*m, x, y, h));
      });
      stepper.step(*m, st, s);
      ASSERT_EQ(g.size(), size_t(s.iterations + 1));
      for (size_t k = 1; k < g.size(); ++k)
        EXPECT_LE(g[k], g[k - 1] + 1e-12 * std::abs(g[0])) << to_string(model) << " E " << young << " iteration " << k;
      EXPECT_LT(g.back(), g.front());
    }
  }
}

TEST(VertexBlockDescent, ConvergesToNewtonsImplicitStep) {
  // A 2 ms step of a 100 kPa beam (VBD, a Gauss-Seidel method, needs thousands of iterations
  // where elastic stiffness dwarfs inertia / h^2: docs/solver.md).
  for (ElasticModel model : kModels) {
    auto m = beam1(1e5, model);
    BodyState st = rest_state(*m);
    st.x = cantilever_bend(*m, default_clamp_x(m->rest_positions), 0.01);
    const std::vector<Vec3> x0 = st.x;
    SolverSettings s = vbd_settings();
    s.dt = 0.002;
    s.iterations = 2000;
    s.chebyshev.delay = 2;
    s.chebyshev.rho = 0.95;
    s.tolerance = 1e-10;
    const std::vector<Vec3> y = predicted(*m, st, s, s.dt);
    NewtonOptions opt;
    opt.tolerance = 1e-13;
    const NewtonResult ref = solve_implicit_step(*m, x0, y, s.dt, opt);
    ASSERT_TRUE(ref.converged);
    Stepper stepper;
    const StepReport rep = stepper.step(*m, st, s);
    EXPECT_FALSE(rep.diverged);
    EXPECT_TRUE(rep.stopped_by_tolerance);
    double err = 0, ref_size = 0;
    for (size_t i = 0; i < x0.size(); ++i) {
      err += (st.x[i] - ref.x[i]).squaredNorm();
      ref_size += (x0[i] - ref.x[i]).squaredNorm();
    }
    EXPECT_LT(std::sqrt(err / ref_size), 1e-6) << to_string(model) << " after " << rep.iterations << " iterations";
  }
}

TEST(VertexBlockDescent, ConservesMomentumWithoutExternalForcesOrFixedVertices) {
  // A free, bent, spinning and drifting beam. The internal forces sum to zero, so a converged
  // step keeps the linear momentum (to the solve's tolerance: 1e-6 relative). Implicit Euler
  // itself changes the angular momentum by -h^2 sum v x f per step (f the elastic force at the
  // new positions): VBD keeps what Newton's steps keep (to 1e-6 of L), and that is within 1e-3.
  for (ElasticModel model : kModels) {
    auto m = beam1(1e5, model, false);
    BodyState st = spinning_bent_beam(*m);
    SolverSettings s = vbd_settings();
    s.gravity.setZero();
    s.damping = Damping::None;
    s.dt = 0.002;
    s.iterations = 2000;
    s.chebyshev.delay = 2;
    s.chebyshev.rho = 0.95;
    s.tolerance = 1e-10;
    const Vec3 p0 = linear_momentum(*m, st), l0 = angular_momentum(*m, st);
    BodyState newton = st;
    NewtonOptions opt;
    opt.tolerance = 1e-12;
    Stepper stepper;
    for (int k = 0; k < 3; ++k) {
      ASSERT_FALSE(stepper.step(*m, st, s).diverged);
      const NewtonResult r = solve_implicit_step(*m, newton.x, predicted(*m, newton, s, s.dt), s.dt, opt);
      ASSERT_TRUE(r.converged);
      for (size_t i = 0; i < r.x.size(); ++i) newton.v[i] = (r.x[i] - newton.x[i]) / s.dt;
      newton.x = r.x;
    }
    EXPECT_LT((linear_momentum(*m, st) - p0).norm(), 1e-6 * p0.norm()) << to_string(model);
    EXPECT_LT((angular_momentum(*m, st) - angular_momentum(*m, newton)).norm(), 1e-6 * l0.norm()) << to_string(model);
    EXPECT_LT((angular_momentum(*m, st) - l0).norm(), 1e-3 * l0.norm()) << to_string(model);
  }
}

TEST(VertexBlockDescent, TheTranslationStepKeepsAFreeBodysMomentumAtTheRealTimeBudget) {
  // The same free, bent, spinning and drifting beam at the real-time budget's one vertex sweep a
  // substep, far from converged: the sweep alone changes the linear momentum (its vertex steps'
  // inertia terms do not sum to the elastic forces' zero), the translation step after it puts
  // the momentum back where the substep's prediction has it: unchanged without gravity, grown by
  // the weight times the time with it, to the rounding.
  for (ElasticModel model : kModels) {
    auto m = beam1(1e5, model, false);
    double weight_mass = 0;
    for (double w : m->mass) weight_mass += w;
    for (bool gravity : {false, true})
      for (bool translation : {true, false}) {
        SCOPED_TRACE(std::string(to_string(model)) + (gravity ? ", gravity" : "") +
                     (translation ? "" : ", no translation"));
        BodyState st = spinning_bent_beam(*m);
        SolverSettings s = vbd_settings();
        if (!gravity) s.gravity.setZero();
        s.damping = Damping::None;
        s.substeps = 16;
        s.iterations = 1;
        detail::VbdOptions o;
        o.translation = translation;
        auto family = detail::make_vbd_family(o);
        const Vec3 p0 = linear_momentum(*m, st);
        const int steps = 5;
        for (int k = 0; k < steps; ++k) ASSERT_FALSE(family->step(*m, st, s, {}, {}).diverged);
        const Vec3 expected = p0 + weight_mass * s.gravity * (steps * s.dt);
        const double error = (linear_momentum(*m, st) - expected).norm() / expected.norm();
        if (translation) {
          EXPECT_LT(error, 1e-12);
        } else {
          // Above 1e-6 a step (1.6e-5 to 4e-5 over the five steps without gravity, more with it).
          EXPECT_GT(error, steps * 1e-6) << "the sweep alone should lose momentum here, or this tests nothing";
        }
      }
  }
}

TEST(VertexBlockDescent, FixedVerticesStayAndGravityBendsTheBeam) {
  auto m = beam1(1e5, ElasticModel::StVK);
  SolverSettings s = vbd_settings();
  s.substeps = 4;
  s.iterations = 10;
  BodyState st = rest_state(*m);
  Stepper stepper;
  for (int k = 0; k < 20; ++k) stepper.step(*m, st, s);
  for (size_t i = 0; i < m->vertex_count(); ++i)
    if (m->fixed[i]) {
      EXPECT_EQ(st.x[i], m->rest_positions[i]);
    }
  EXPECT_LT(tip_displacement(*m, st.x).y(), -1e-4);
}

TEST(VertexBlockDescent, AGrabPullsItsVertexToTheTarget) {
  for (double compliance : {0.0, 0.05}) {
    auto m = beam1(1e5, ElasticModel::StVK);
    SolverSettings s = vbd_settings();
    s.gravity.setZero();
    s.dt = 0.002;
    s.iterations = 20;
    s.chebyshev.delay = 2;
    s.damping_coefficient = 50;
    int32_t tip = 0;
    for (size_t i = 0; i < m->vertex_count(); ++i)
      if (m->rest_positions[i].x() > m->rest_positions[tip].x() + 1e-9 ||
          (std::abs(m->rest_positions[i].x() - m->rest_positions[tip].x()) < 1e-9 && m->rest_positions[i].y() > m->rest_positions[tip].y()))
        tip = int32_t(i);
    const Vec3 target = m->rest_positions[tip] + Vec3(0, 0.01, 0);
    StepInputs in;
    in.attachments.push_back(Attachment::vertex(tip, target, compliance));
    BodyState st = rest_state(*m);
    Stepper stepper;
    StepReport rep;
    for (int k = 0; k < 250; ++k) rep = stepper.step(*m, st, s, in);
    EXPECT_LT(max_speed(st), 1e-4);
    const Vec3 gap = target - st.x[tip];
    const Vec3 f = rep.attachment_forces.at(0);
    EXPECT_GT(f.y(), 0) << "the grab pulls the body up";
    EXPECT_GT(st.x[tip].y() - m->rest_positions[tip].y(), compliance > 0 ? 5e-4 : 0.0099);
    if (compliance > 0) {
      EXPECT_NEAR((f - gap / compliance).norm(), 0, 1e-6 * f.norm());  // a spring of stiffness 1/compliance
      EXPECT_GT(gap.norm(), 1e-4);
    } else {
      EXPECT_LT(gap.norm(), 1e-4);
    }
    // At rest the grab's force balances the elastic forces on the free vertices.
    EXPECT_NEAR((f + elastic_force_on_free(*m, st.x)).norm(), 0, 0.02 * f.norm());
  }
}

TEST(VertexBlockDescent, APressingToolFeelsTheElasticForceAtRest) {
  // A 1 cm sphere lowered over 0.1 s onto the top face near the tip, 2 mm into it, then held.
  auto m = beam1(1e5, ElasticModel::StVK);
  SolverSettings s = vbd_settings();
  s.gravity.setZero();
  s.dt = 0.002;
  s.iterations = 20;
  s.chebyshev.delay = 2;
  s.damping_coefficient = 50;
  StepInputs in;
  in.tools.push_back(RigidTool::sphere(Vec3(0.1, 0.02, 0.005), 0.01));
  BodyState st = rest_state(*m);
  Stepper stepper;
  StepReport rep;
  for (int k = 0; k < 250; ++k) {
    in.tools[0].position.y() = 0.02 - 0.002 * std::min(1.0, (k + 1) / 50.0);
    rep = stepper.step(*m, st, s, in);
  }
  EXPECT_LT(max_speed(st), 1e-4);
  const ToolReaction& tool = rep.tools.at(0);
  ASSERT_GE(tool.contacts.size(), 1u);
  EXPECT_GT(tool.force.y(), 0) << "the beam pushes the tool back up";
  EXPECT_LT(std::abs(tool.force.x()), 0.2 * tool.force.y());
  EXPECT_LT(tip_displacement(*m, st.x).y(), -1e-3);
  Vec3 sum = Vec3::Zero();
  for (const ToolContact& c : tool.contacts) sum += c.force;
  EXPECT_NEAR((sum - tool.force).norm(), 0, 1e-9 * tool.force.norm());
  // At rest: contact forces on the body + elastic forces on the free vertices = 0.
  EXPECT_NEAR((tool.force - elastic_force_on_free(*m, st.x)).norm(), 0, 0.02 * tool.force.norm())
      << "tool " << tool.force.transpose();
}

TEST(VertexBlockDescent, ASquashedStartInvertsNoTet) {
  for (ElasticModel model : kModels) {
    auto m = beam1(1e5, model);
    BodyState st = rest_state(*m);
    for (Vec3& p : st.x) p.y() *= 0.2;  // squashed to a fifth of its height
    SolverSettings s = vbd_settings();
    s.substeps = 2;
    s.iterations = 10;
    Stepper stepper;
    for (int k = 0; k < 30; ++k) {
      ASSERT_FALSE(stepper.step(*m, st, s).diverged);
      ASSERT_EQ(count_inverted(*m, st.x), 0u) << to_string(model) << " step " << k;
    }
    EXPECT_GT(st.x[0].y() + 1, 0);  // finite
  }
}

TEST(VertexBlockDescent, StopsOnToleranceAndCancelAndReportsResiduals) {
  auto m = beam1(1e5, ElasticModel::StVK);
  SolverSettings s = vbd_settings();
  EXPECT_EQ(validate(s), "");
  s.dt = 0.002;
  s.iterations = 500;
  s.tolerance = 1e-4;
  BodyState st = rest_state(*m);
  Stepper stepper;
  StepReport rep = stepper.step(*m, st, s);
  EXPECT_TRUE(rep.stopped_by_tolerance);
  EXPECT_LT(rep.iterations, 500);
  ASSERT_EQ(rep.residuals.size(), size_t(rep.iterations));
  EXPECT_LE(rep.residual_final, 1e-4 * rep.residual_initial);
  EXPECT_GT(rep.residual_initial, 0);
  std::atomic<bool> cancel{true};
  StepInputs in;
  in.cancel = &cancel;
  s.substeps = 4;
  rep = stepper.step(*m, st, s, in);
  EXPECT_TRUE(rep.cancelled);
  EXPECT_EQ(rep.iterations, 1);
  EXPECT_EQ(rep.substeps, 1);
}

TEST(VertexBlockDescent, TheAdaptiveGuessKeepsAnEquilibriumAtRest) {
  // From Newton's static solution at rest, a step of the real-time budget (64 substeps of one
  // iteration) leaves the body where it is with the adaptive guess (a body at rest starts at
  // x_t, where the gradient of G is 0); started from the prediction y instead, one iteration
  // does not get back to the equilibrium and the body moves.
  auto m = beam1(1e6, ElasticModel::StVK);
  NewtonOptions opt;
  opt.tolerance = 1e-12;
  const NewtonResult eq = solve_static(*m, m->rest_positions, Vec3(0, -9.81, 0), {}, opt);
  ASSERT_TRUE(eq.converged);
  const double sag = tip_displacement(*m, eq.x).norm();
  SolverSettings s = vbd_settings();
  s.substeps = 64;
  s.iterations = 1;
  s.damping = Damping::None;
  for (detail::VbdInitialGuess guess : {detail::VbdInitialGuess::Adaptive, detail::VbdInitialGuess::Inertial}) {
    detail::VbdOptions o;
    o.initial_guess = guess;
    auto family = detail::make_vbd_family(o);
    BodyState st = rest_state(*m);
    st.x = eq.x;
    family->step(*m, st, s, {}, {});
    const double moved = (tip_displacement(*m, st.x) - tip_displacement(*m, eq.x)).norm();
    if (guess == detail::VbdInitialGuess::Adaptive) {
      EXPECT_LT(moved, 1e-6 * sag);
    } else {
      EXPECT_GT(moved, 1e-3 * sag);
    }
  }
}

TEST(VertexBlockDescent, ThreadsDoNotChangeTheResult) {
  // The vertices of a colour share no tet: splitting a colour over threads gives the same
  // positions bit for bit.
  auto m = beam1(1e6, ElasticModel::Corotated);
  SolverSettings s = vbd_settings();
  s.substeps = 2;
  s.iterations = 15;
  s.chebyshev.delay = 5;
  StepInputs in;
  in.tools.push_back(RigidTool::sphere(Vec3(0.1, 0.019, 0.005), 0.01));
  in.attachments.push_back(Attachment::vertex(int32_t(m->vertex_count() - 1), m->rest_positions.back() + Vec3(0, 0.002, 0), 1e-3));
  size_t largest = 0;
  for (const auto& c : m->vertex_colours) largest = std::max(largest, c.size());
  ASSERT_GE(largest, 32u) << "colours too small to be split over threads";
  BodyState one = rest_state(*m), two = one;
  Stepper a, b;
  s.threads = 1;
  a.step(*m, one, s, in);
  s.threads = 2;
  b.step(*m, two, s, in);
  for (size_t i = 0; i < one.x.size(); ++i) ASSERT_EQ(one.x[i], two.x[i]) << "vertex " << i;
}
