// SPDX-License-Identifier: Apache-2.0
// The global implicit step: Newton's method on the incremental potential of implicit Euler,
//   G(x) = sum_i I_i / (2 h^2) |x_i - y_i|^2 + sum_tets E_tet(x) + contact and grab energies,
// y the prediction (stages.hpp: inertia, gravity on the weight, external forces), I_i the
// vertex inertia. Each iteration assembles the gradient and the per-tet PSD-projected Hessian
// into a sparse matrix whose pattern (and the Cholesky's symbolic analysis) is built once per
// model, solves H d = -g with a sparse LDL^T, and backtracks along d until G decreases (Armijo).
// Grabs are the energies of their XPBD compliant constraints (compliance 0: a stiff penalty);
// colliders and tools push vertices out through a penalty energy k/2 depth^2 (k fixed per vertex
// and substep) with lagged Coulomb friction (Li et al. 2020's smoothed static/dynamic friction),
// and the force on a tool is that energy's gradient: at convergence it is exactly the force the
// body's inertia and elasticity put on it. The line search sees the true penalty of every vertex,
// so a step that pushes a vertex into an obstacle is shortened. Near the solution (after a full
// step) the exact Hessian is tried first: Newton then converges quadratically; where it is not
// positive definite the per-tet PSD-projected one is used.
//
// Inexact Newton (newton_linear_solver cg, or auto above kNewtonDirectMaxDofs free dofs): where
// the factorisation does not fit a tick, H d = -g is solved by conjugate gradients on the same
// assembled matrix, preconditioned by a factorisation of an earlier Hessian (single precision
// where it keeps every pivot positive, else double; up to kFactorPreconditionerMaxDofs) or above
// that by the two-level preconditioner (newton/two_level.hpp: the 3x3 vertex blocks plus a coarse
// solve on rigid motions of vertex aggregates), to a relative residual
// eta = min(cap, sqrt(|g| / |g0|)) (a forcing term that tightens as Newton converges, so the outer
// iteration stays superlinear); the time budget stops CG too, and its last iterate is still a
// descent direction for the line search. Negative curvature of the exact Hessian sends the
// iteration back to the projected one, as the failed factorisation does. A body that has hardly
// moved since its last Hessian keeps it (a chord step with the exact gradient).
#include "kernels/projection.hpp"
#include "newton/two_level.hpp"
#include "step/family.hpp"
#include "step/obstacles.hpp"
#include "step/stages.hpp"
#include "step/thread_pool.hpp"
#include "step/volume_floor.hpp"

#include "pliant/strain_constraint.hpp"

#include <Eigen/Dense>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>

namespace pliant::detail {

namespace {

// Penalty stiffness of a hard grab or a contact, relative to the stiffest of the vertex's inertia
// term I/h^2 and its elastic diagonal: the penetration left is about this fraction of the
// displacement the penalty resists, while the force it reports is exact at equilibrium.
constexpr double kHardScale = 1e6;
constexpr double kContactScale = 1e4;
// Friction's static region: tangential slip below this speed (m/s) times h is treated as
// sticking (the smoothed Coulomb model's epsilon_v).
constexpr double kStickSpeed = 1e-3;
// Inexact Newton: the loosest relative residual CG is asked for (first iterations), and the
// most CG iterations per Newton iteration.
constexpr double kMaxForcing = 0.5;
// The same for the two-level preconditioner, measured on the hanging armadillo (docs/solver.md,
// "The armadillo at 1 MPa"): its norm weighs the slow modes little, and at one half a tick's CG
// left the sag 7% short (0.1: creeping 8% long after the first swing; 0.01: within 0.1%).
constexpr double kTwoLevelForcing = 0.01;
constexpr int kMaxCgIterations = 2000;
// Tets a block of the elastic energy's sum (per block, then in block order: the same bits with
// any thread count).
constexpr size_t kEnergyBlock = 2048;
// Up to this many free dofs CG is preconditioned by a factorisation of an earlier Hessian (the
// hippo's costs a few ticks' budget, once; the armadillo's 1.8 s and each of its solves tens of
// ms, so it gets the 3x3 vertex blocks unless newton_linear_solver is cg-factor); it is refreshed
// when a solve needs more than kRefactorAfter CG iterations.
constexpr int kFactorPreconditionerMaxDofs = 20000;
constexpr int kRefactorAfter = 20;
// The two-level preconditioner's aggregation rounds (each round groups a node with its
// neighbours: one round gives aggregates of about 15 vertices on a tet mesh, two about 15 of those).
constexpr int kTwoLevelRounds = 2;
// Inexact Newton keeps the last projected Hessian while no free vertex has moved more than this
// fraction of the mean edge since it was assembled.
constexpr double kHessianReuseMotion = 1e-3;
// Which preconditioner CG uses for `linear` on a body of ndof free dofs.
enum class Preconditioning { Factor, TwoLevel, Blocks };
Preconditioning preconditioning_for(NewtonLinearSolver linear, int ndof) {
  switch (linear) {
    case NewtonLinearSolver::CgFactor: return Preconditioning::Factor;
    case NewtonLinearSolver::CgTwoLevel: return Preconditioning::TwoLevel;
    case NewtonLinearSolver::CgJacobi: return Preconditioning::Blocks;
    default: return ndof <= kFactorPreconditionerMaxDofs ? Preconditioning::Factor : Preconditioning::TwoLevel;
  }
}
double max_forcing(Preconditioning p) { return p == Preconditioning::TwoLevel ? kTwoLevelForcing : kMaxForcing; }

// Relative size below which a change of the incremental potential is round-off of its sum (tens of
// thousands of terms of mixed sign, each with a relative error of a few 1e-16).
constexpr double kEnergyResolution = 1e-13;
// Passes of the inversion floor after an iteration, at most (each repeats while one still acts).
constexpr int kVolumePasses = 20;

// The sparse Cholesky factorisation of the Hessian, its symbolic analysis (ordering, elimination
// tree) done once per model. Eigen's simplicial LDL^T: CHOLMOD's supernodal LL^T (Debian
// SuiteSparse) measured 1.4-4x slower on beam3 and the hippo and 1.6x faster only on the
// armadillo (docs/solver.md), so it is not used.
class SparseCholesky {
 public:
  void analyze(const Eigen::SparseMatrix<double>& A) {
    solver_.analyzePattern(A);
    single_.analyzePattern(A.cast<float>());
  }
  // False unless A was positive definite. Single precision first (half the memory traffic of
  // every preconditioner solve); double where single loses a pivot.
  bool factorize(const Eigen::SparseMatrix<double>& A) {
    single_.factorize(A.cast<float>());
    use_single_ = single_.info() == Eigen::Success && single_.vectorD().minCoeff() > 0;
    if (use_single_) return true;
    solver_.factorize(A);
    return solver_.info() == Eigen::Success && solver_.vectorD().minCoeff() > 0;
  }
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const {
    if (use_single_) return single_.solve(b.cast<float>()).cast<double>();
    return solver_.solve(b);
  }
  bool single() const { return use_single_; }

 private:
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<float>> single_;
  bool use_single_ = false;
};

// One vertex touching a collider, a tool or a triangle obstacle in this iteration's active set.
struct Contact {
  int32_t vertex;
  int tool;              // index in inputs.tools, or -1 for a static collider or an obstacle
  Vec3 normal;           // outward normal of the obstacle
  double depth;          // penetration at the positions the contact was found at
  double friction;       // mu
  double normal_force;   // friction's bound: the contact's k depth at the end of the last iteration
  Vec3 obstacle_motion;  // the obstacle's displacement over the substep (tools with velocity)
  int obstacle = -1;     // index in inputs.obstacles (a cloth's triangles), with its hit
  ObstacleContacts::Hit hit{};
};

class NewtonFamily final : public SolverFamily {
 public:
  StepReport step(const BodyModel& m, BodyState& state, const SolverSettings& s,
                  const StepInputs& inputs, const Stepper::IterationHook& hook) override;

 private:
  // The sparse pattern of the Hessian over the free dofs and, per tet, where its 12x12 block's
  // entries land in the matrix's value array (-1 where a corner is fixed). Built once per model.
  void compile(const BodyModel& m);
  // The gradient g_ at x, and with `hessian` the Hessian's values (elastic and inertia terms).
  // `exact`: the Hessian as it is; else made PSD tet by tet.
  void assemble(const BodyModel& m, const std::vector<Vec3>& x, double h, ThreadPool& tp, bool hessian,
                bool exact = false);
  // The penalty stiffness of each free vertex for this substep (from the assembled diagonal).
  void set_contact_stiffness(const BodyModel& m, double h);
  // g_ with the grabs' and contacts' terms (and their Hessian blocks with `hessian`).
  void add_interaction(const BodyModel& m, const std::vector<Vec3>& x, double h, const StepInputs& in,
                       bool hessian);
  double potential(const BodyModel& m, const std::vector<Vec3>& x, double h, const StepInputs& in) const;
  // potential() given its inertial and elastic part e at x: e plus the grabs', friction's and
  // penetration's energies (the same sum, in the same order).
  double with_interaction_energy(double e, const BodyModel& m, const std::vector<Vec3>& x, double h,
                                 const StepInputs& in) const;
  // The contacts at x: every free vertex inside a collider or a tool, each with the normal force
  // it had at the end of the last iteration (lagged_) as its friction bound.
  void find_contacts(const BodyModel& m, const std::vector<Vec3>& x, double h, const StepInputs& in);
  // The penetration energy of every vertex at x (true geometry, not the contacts' planes).
  double penetration_energy(const BodyModel& m, const std::vector<Vec3>& x, const StepInputs& in) const;
  RigidTool tool_now(const StepInputs& in, size_t t) const;
  double attachment_stiffness(const BodyModel& m, const Attachment& a, double h) const;
  double elastic_diagonal(int32_t v) const;
  double inertial_elastic_energy(const BodyModel& m, const std::vector<Vec3>& x, double h) const;
  // Sum of the tets' strain energies at x (in parallel on pool_).
  double elastic_energy(const BodyModel& m, const std::vector<Vec3>& x) const;
  // The warm start's candidates in one pass over the tets (each tet's corners loaded once for
  // all of them): energy[c] = inertial_elastic_energy of candidate c, to the bit; kept[c] whether
  // no tet of it falls below the inversion floor `floor` (0: no floor) or below where it was in
  // candidate 0, the substep's start.
  static constexpr int kCandidates = 3;
  void warm_start_pass(const BodyModel& m, const std::array<const std::vector<Vec3>*, kCandidates>& candidates,
                       double h, double floor, std::array<double, kCandidates>& energy,
                       std::array<bool, kCandidates>& kept);
  // lagged_ = contacts_ with their normal forces at the current positions.
  void remember_normal_forces();
  // contact_force_ for contacts_ at x (tool and obstacle contacts need them; empty work without
  // one).
  void contact_forces(const BodyModel& m, const std::vector<Vec3>& x, double h, ThreadPool& tp);
  // y = H_ x, rows in parallel (H_ stores both triangles, so column c is row c).
  void multiply(ThreadPool& tp, const Eigen::VectorXd& x, Eigen::VectorXd& y) const;
  // d_ from CG on H_ d = -g_ to |H d + g| <= eta |g| in the preconditioner's norm, at most
  // kMaxCgIterations or until out_of_time() says so; the CG iterations run are added to
  // `iterations`. `projected`: H_ is the PSD-projected Hessian (else the exact one, which may
  // be indefinite). False when H_ showed non-positive curvature before any progress, or at all
  // when not projected (d_ is then unusable). Preconditioner: conjugate_gradients' comment.
  bool conjugate_gradients(ThreadPool& tp, double eta, bool projected, NewtonLinearSolver linear,
                           const std::function<bool()>& out_of_time, int& iterations);
  using Preconditioner = std::function<void(const Eigen::VectorXd& r, Eigen::VectorXd& z)>;
  Preconditioning preconditioning(NewtonLinearSolver linear) const { return preconditioning_for(linear, ndof_); }
  // The CG loop itself, z = M^-1 r by `precondition`.
  bool preconditioned_cg(ThreadPool& tp, double eta, bool projected, const std::function<bool()>& out_of_time,
                         int& iterations, const Preconditioner& precondition);

  uint64_t compiled_model_ = 0;
  std::vector<int> dof_;  // vertex -> first dof, -1 when fixed
  int ndof_ = 0;
  Eigen::SparseMatrix<double> H_;
  // 48 per tet, [12 a + c]: where rows 3a..3a+2 of the tet's column c land in H_.valuePtr()
  // (three consecutive entries: a vertex's dofs are consecutive rows), -1 where a corner is fixed.
  std::vector<int32_t> tet_entry_;
  std::vector<int32_t> diag_entry_; // 9 per vertex: its diagonal block's entries
  // H_ in 3x3 blocks: free vertex q's (dof / 3) block column holds the blocks of the free vertices
  // block_row_[block_begin_[q] ..] (ascending), so column 3q + j of H_ is those blocks' rows in
  // triples and multiply() reads one index per block instead of one per entry.
  std::vector<int32_t> block_begin_, block_row_;
  SparseCholesky cholesky_;
  bool analysed_ = false;  // cholesky_ has this model's symbolic analysis
  Eigen::VectorXd g_, d_;
  // The elastic gradient per tet, 12 values per tet in solve order (colour by colour), and per
  // vertex where its corners sit in it (ascending, so in colour order): assemble() writes the
  // former and sums the latter per vertex.
  std::vector<double> tet_gradient_;
  std::vector<int32_t> corner_begin_, corner_at_;
  Eigen::VectorXd cg_r_, cg_z_, cg_p_, cg_q_;  // CG's residual, preconditioned residual, direction, H p
  std::vector<Eigen::Matrix3d> block_inverse_;  // per free vertex (dof / 3): its diagonal block's inverse
  TwoLevelPreconditioner two_level_;
  // The projected Hessian in H_ was assembled at hessian_x_ for substep hessian_at_h_ (0: H_ holds
  // something else: the exact Hessian, a grab's penalties, or nothing yet). Contact penalties
  // added to it since (penalties_in_hessian_) come off by restoring elastic_values_, H_'s values
  // as assembled, saved before the first penalty went in (elastic_saved_) when H_ may be kept.
  double hessian_at_h_ = 0;
  // H_'s values changed since the preconditioner's vertex blocks were inverted: the two-level
  // blocks (two_level_) or the block-Jacobi inverses (block_inverse_), whichever was last built.
  bool hessian_changed_ = true;
  Preconditioning blocks_of_ = Preconditioning::Factor;  // Factor: neither
  std::vector<Vec3> hessian_x_;
  std::vector<double> elastic_values_;
  bool elastic_saved_ = false, penalties_in_hessian_ = false;
  // H_ was just assembled (its values are the elastic and inertial Hessian alone).
  void hessian_assembled() {
    elastic_saved_ = penalties_in_hessian_ = false;
    hessian_changed_ = true;
  }
  // add_interaction into the Hessian, saving H_'s values first when penalties go in.
  void add_interaction_to_hessian(const BodyModel& m, const std::vector<Vec3>& x, double h, const StepInputs& in);
  double max_motion_since_hessian(const std::vector<Vec3>& x) const {
    double d2 = 0;
    for (size_t i = 0; i < x.size(); ++i)
      if (dof_[i] >= 0) d2 = std::max(d2, (x[i] - hessian_x_[i]).squaredNorm());
    return std::sqrt(d2);
  }
  std::vector<Vec3> free_rest_;   // rest positions of the free vertices, in dof order
  bool two_level_built_ = false;  // two_level_ has this model's aggregates
  bool coarse_ready_ = false;     // two_level_ holds a coarse operator of an earlier Hessian
  bool factored_ = false;   // cholesky_ holds a factorisation of an earlier Hessian (CG's preconditioner)
  bool refactor_ = false;   // the last CG solve was slow: refresh it at the next one
  size_t factored_contacts_ = 0, factored_attachments_ = 0;  // the penalties it was factorised with
  std::vector<Vec3> y_, x_start_, trial_, v_before_;
  VolumeFloor volume_floor_;
  std::vector<Contact> contacts_;
  std::vector<Contact> lagged_;  // the contacts at the end of the last iteration, normal force k depth
  std::vector<double> attachment_k_;
  std::vector<double> contact_k_;  // per vertex: its penalty stiffness in this substep
  std::vector<Vec3> contact_force_;   // per contact in contacts_: the force on the body at the end
  std::vector<double> penalty_sum_;   // per vertex: sum of its contacts' k depth (scratch)
  bool inputs_have_obstacles_ = false;
  ObstacleContacts triangles_;  // the step's triangle obstacles (a cloth's), as penalty contacts
  double tool_time_offset_ = 0;  // the substep's end relative to the step's end (<= 0)
  std::unique_ptr<ThreadPool> pool_;
};

void NewtonFamily::compile(const BodyModel& m) {
  if (compiled_model_ == m.id && m.id != 0) return;
  compiled_model_ = m.id;
  lagged_.clear();
  const size_t nv = m.vertex_count();
  dof_.assign(nv, -1);
  ndof_ = 0;
  for (size_t i = 0; i < nv; ++i)
    if (m.inv_mass[i] > 0) {
      dof_[i] = ndof_;
      ndof_ += 3;
    }
  std::vector<Eigen::Triplet<double>> trip;
  trip.reserve(m.tets.size() * 144 + 9 * nv);
  for (size_t i = 0; i < nv; ++i)
    if (dof_[i] >= 0)
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) trip.emplace_back(dof_[i] + a, dof_[i] + b, 0.0);
  for (const TetRest& t : m.tets)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const int da = dof_[t.v[a]], db = dof_[t.v[b]];
        if (da < 0 || db < 0) continue;
        for (int i = 0; i < 3; ++i)
          for (int j = 0; j < 3; ++j) trip.emplace_back(da + i, db + j, 0.0);
      }
  H_.resize(ndof_, ndof_);
  H_.setFromTriplets(trip.begin(), trip.end());
  H_.makeCompressed();
  // Where entry (r, c) sits in the compressed column-major value array.
  auto entry = [&](int r, int c) -> int32_t {
    const int* begin = H_.innerIndexPtr() + H_.outerIndexPtr()[c];
    const int* end = H_.innerIndexPtr() + H_.outerIndexPtr()[c + 1];
    return int32_t(std::lower_bound(begin, end, r) - H_.innerIndexPtr());
  };
  tet_entry_.assign(m.tets.size() * 48, -1);
  for (size_t t = 0; t < m.tets.size(); ++t)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const int da = dof_[m.tets[t].v[a]], db = dof_[m.tets[t].v[b]];
        if (da < 0 || db < 0) continue;
        for (int j = 0; j < 3; ++j) tet_entry_[t * 48 + 12 * a + 3 * b + j] = entry(da, db + j);
      }
  // Each free vertex's corners in the tets' gradients, in solve order.
  corner_begin_.assign(nv + 1, 0);
  for (const TetRest& t : m.tets)
    for (int a = 0; a < 4; ++a) corner_begin_[size_t(t.v[a]) + 1]++;
  for (size_t v = 0; v < nv; ++v) corner_begin_[v + 1] += corner_begin_[v];
  corner_at_.assign(size_t(corner_begin_[nv]), 0);
  {
    std::vector<int32_t> fill(corner_begin_.begin(), corner_begin_.end() - 1);
    int32_t slot = 0;
    for (const auto& colour : m.colours)
      for (const int32_t t : colour) {
        for (int a = 0; a < 4; ++a) corner_at_[size_t(fill[size_t(m.tets[t].v[a])]++)] = 12 * slot + 3 * a;
        ++slot;
      }
  }
  tet_gradient_.assign(m.tets.size() * 12, 0.0);
  diag_entry_.assign(9 * nv, -1);
  for (size_t v = 0; v < nv; ++v)
    if (dof_[v] >= 0)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) diag_entry_[9 * v + 3 * i + j] = entry(dof_[v] + i, dof_[v] + j);
  // The pattern holds full 3x3 blocks (above), so column 3q's rows are the block rows' triples.
  const int blocks = ndof_ / 3;
  block_begin_.assign(size_t(blocks) + 1, 0);
  block_row_.clear();
  for (int q = 0; q < blocks; ++q) {
    for (int k = H_.outerIndexPtr()[3 * q]; k < H_.outerIndexPtr()[3 * q + 1]; k += 3)
      block_row_.push_back(H_.innerIndexPtr()[k] / 3);
    block_begin_[size_t(q) + 1] = int32_t(block_row_.size());
  }
  analysed_ = false;
  factored_ = refactor_ = false;
  two_level_built_ = coarse_ready_ = false;
  hessian_at_h_ = 0;
  hessian_assembled();
  free_rest_.clear();
  for (size_t v = 0; v < nv; ++v)
    if (dof_[v] >= 0) free_rest_.push_back(m.rest_positions[v]);
  g_.setZero(ndof_);
}

// Elastic part of the gradient and Hessian (tets of a colour share no vertex, so a colour's tets
// scatter into disjoint entries and run in parallel), then the inertia term. Each tet's gradient
// goes into its own place in solve order, summed per vertex afterwards in that same order (so the
// sums do not depend on the thread count): scattered straight into g, the threads' vertices, spread
// over the mesh, made neighbouring vertices' entries (2-3 vertices per cache line) bounce between
// the cores.
namespace {
void prefetch_tet(const TetRest& tet) {
  const char* p = reinterpret_cast<const char*>(&tet);
  for (size_t line = 0; line < sizeof(TetRest); line += 64) __builtin_prefetch(p + line);
}
}  // namespace

void NewtonFamily::assemble(const BodyModel& m, const std::vector<Vec3>& x, double h, ThreadPool& tp,
                            bool hessian, bool exact) {
  double* values = H_.valuePtr();
  if (hessian) std::fill(values, values + H_.nonZeros(), 0.0);
  size_t first_slot = 0;  // the colour's first tet in solve order
  for (const auto& colour : m.colours) {
    tp.parallel_for(colour.size(), [&](int, size_t b, size_t e) {
      Vec12 gt;
      Mat12 ht;
      for (size_t k = b; k < e; ++k) {
        // A colour visits the tets out of memory order: fetch the tet a few ahead, then its
        // corners and its Hessian entries, so the loads overlap this tet's arithmetic.
        if (k + 8 < e) prefetch_tet(m.tets[colour[k + 8]]);
        // Two ahead, the Hessian entries themselves (their indices were fetched two tets ago):
        // the matrix is a few MB, and a colour's tets write all over it.
        if (hessian && k + 2 < e) {
          const int32_t* next = &tet_entry_[size_t(colour[k + 2]) * 48];
          for (int q = 0; q < 48; ++q)
            if (next[q] >= 0) __builtin_prefetch(values + next[q], 1);
        }
        if (k + 4 < e) {
          const int32_t ahead = colour[k + 4];
          for (int c = 0; c < 4; ++c) __builtin_prefetch(&x[m.tets[ahead].v[c]]);
          if (hessian)
            for (int line = 0; line < 48 * 4; line += 64)
              __builtin_prefetch(reinterpret_cast<const char*>(&tet_entry_[size_t(ahead) * 48]) + line);
        }
        const int32_t t = colour[k];
        const TetRest& tet = m.tets[t];
        if (exact || !hessian)
          strain_energy_derivatives(tet, m.stiffness, gather(x, tet.v), &gt, hessian ? &ht : nullptr, false,
                                    m.material.model);
        else
          strain_energy_derivatives_psd_parts(tet, m.stiffness, gather(x, tet.v), &gt, &ht, m.material.model);
        Eigen::Map<Vec12> slot_gradient(&tet_gradient_[12 * (first_slot + k)]);
        slot_gradient = gt;
        if (!hessian) continue;
        const int32_t* ent = &tet_entry_[size_t(t) * 48];
        for (int a = 0; a < 4; ++a) {
          if (dof_[tet.v[a]] < 0) continue;
          for (int c = 0; c < 12; ++c) {
            const int32_t i = ent[12 * a + c];
            if (i < 0) continue;
            const double* col = &ht(3 * a, c);  // column-major: rows 3a..3a+2 are consecutive
            values[i] += col[0];
            values[i + 1] += col[1];
            values[i + 2] += col[2];
          }
        }
      }
    }, 16);
    first_slot += colour.size();
  }
  const double inv_h2 = 1.0 / (h * h);
  g_.resize(ndof_);
  tp.parallel_for(m.vertex_count(), [&](int, size_t b, size_t e) {
    for (size_t v = b; v < e; ++v) {
      const int d = dof_[v];
      if (d < 0) continue;
      Vec3 sum = Vec3::Zero();
      for (int32_t c = corner_begin_[v]; c < corner_begin_[v + 1]; ++c)
        sum += Eigen::Map<const Vec3>(&tet_gradient_[size_t(corner_at_[size_t(c)])]);
      sum += inv_h2 * m.inertia[v] * (x[v] - y_[v]);
      g_.segment<3>(d) = sum;
      if (hessian)
        for (int i = 0; i < 3; ++i) values[diag_entry_[9 * v + 4 * i]] += inv_h2 * m.inertia[v];
    }
  }, 1024);
}

void NewtonFamily::multiply(ThreadPool& tp, const Eigen::VectorXd& x, Eigen::VectorXd& y) const {
  y.resize(ndof_);
  const int* outer = H_.outerIndexPtr();
  const double* values = H_.valuePtr();
  const double* xs = x.data();
  // Block column q: its three columns at once, each x block loaded once for them; each column's
  // sum runs over its entries in storage order, as a plain CSC product would.
  tp.parallel_for(block_begin_.size() - 1, [&](int, size_t b, size_t e) {
    for (size_t q = b; q < e; ++q) {
      const double* v0 = values + outer[3 * q];
      const double* v1 = values + outer[3 * q + 1];
      const double* v2 = values + outer[3 * q + 2];
      double s0 = 0, s1 = 0, s2 = 0;
      const int32_t first = block_begin_[q], count = block_begin_[q + 1] - first;
      for (int32_t k = 0; k < count; ++k) {
        const double* xp = xs + 3 * block_row_[size_t(first + k)];
        const double x0 = xp[0], x1 = xp[1], x2 = xp[2];
        s0 += v0[3 * k] * x0;
        s0 += v0[3 * k + 1] * x1;
        s0 += v0[3 * k + 2] * x2;
        s1 += v1[3 * k] * x0;
        s1 += v1[3 * k + 1] * x1;
        s1 += v1[3 * k + 2] * x2;
        s2 += v2[3 * k] * x0;
        s2 += v2[3 * k + 1] * x1;
        s2 += v2[3 * k + 2] * x2;
      }
      y[Eigen::Index(3 * q)] = s0;
      y[Eigen::Index(3 * q + 1)] = s1;
      y[Eigen::Index(3 * q + 2)] = s2;
    }
  }, 1365);
}

bool NewtonFamily::conjugate_gradients(ThreadPool& tp, double eta, bool projected, NewtonLinearSolver linear,
                                       const std::function<bool()>& out_of_time, int& iterations) {
  const Preconditioning kind = preconditioning(linear);
  const bool use_factor = kind == Preconditioning::Factor;
  // Refactorised from a projected Hessian only (the exact one may not be positive definite, and a
  // failed factorisation would lose the earlier factor).
  // Contacts and grabs add penalties far stiffer than the body: a factor without them (or with
  // others) preconditions them badly, so a change of either set refreshes it.
  if (contacts_.size() != factored_contacts_ || attachment_k_.size() != factored_attachments_) refactor_ = true;
  if (use_factor && (!factored_ || refactor_) && projected) {
    if (!analysed_) {
      cholesky_.analyze(H_);
      analysed_ = true;
    }
    factored_ = cholesky_.factorize(H_);
    refactor_ = false;
    factored_contacts_ = contacts_.size();
    factored_attachments_ = attachment_k_.size();
    spdlog::debug("newton cg: preconditioner factorised ({}, {})", factored_ ? "ok" : "not positive definite",
                  cholesky_.single() ? "single" : "double");
  }
  if (kind == Preconditioning::TwoLevel) {
    if (!two_level_built_) {
      two_level_.build(block_begin_, block_row_, free_rest_, kTwoLevelRounds);
      two_level_built_ = true;
      hessian_changed_ = true;
      spdlog::debug("newton cg: {} aggregates, {} coarse dofs", two_level_.aggregates(), two_level_.coarse_dofs());
    }
    if (hessian_changed_ || blocks_of_ != Preconditioning::TwoLevel) two_level_.update_blocks(H_);
    hessian_changed_ = false;
    blocks_of_ = Preconditioning::TwoLevel;
    if ((!coarse_ready_ || refactor_) && projected) {
      coarse_ready_ = two_level_.refresh_coarse(H_);
      refactor_ = false;
      factored_contacts_ = contacts_.size();
      factored_attachments_ = attachment_k_.size();
      spdlog::debug("newton cg: coarse operator refreshed ({})", coarse_ready_ ? "ok" : "not positive definite");
    }
    const int before = iterations;
    const bool ok = preconditioned_cg(tp, eta, projected, out_of_time, iterations,
                                      [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) { two_level_.apply(r, z); });
    if (iterations - before > kRefactorAfter) refactor_ = true;
    return ok;
  }
  if (use_factor && factored_) {
    const int before = iterations;
    const bool ok = preconditioned_cg(tp, eta, projected, out_of_time, iterations,
                                      [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) { z = cholesky_.solve(r); });
    if (iterations - before > kRefactorAfter) refactor_ = true;
    return ok;
  }
  // The block-Jacobi preconditioner: each free vertex's 3x3 diagonal block inverted (its
  // diagonal's where the block is not positive definite, as the exact Hessian's may not be),
  // again only when H_ changed (not for a Hessian kept at rest).
  if (hessian_changed_ || blocks_of_ != Preconditioning::Blocks || block_inverse_.size() != size_t(ndof_ / 3)) {
    const double* values = H_.valuePtr();
    block_inverse_.resize(size_t(ndof_ / 3));
    for (size_t v = 0; v < dof_.size(); ++v) {
      if (dof_[v] < 0) continue;
      Eigen::Matrix3d b;
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) b(i, j) = values[diag_entry_[9 * v + 3 * i + j]];
      block_inverse_[size_t(dof_[v] / 3)] = invert_block(b);
    }
    hessian_changed_ = false;
    blocks_of_ = Preconditioning::Blocks;
  }
  return preconditioned_cg(tp, eta, projected, out_of_time, iterations, [&](const Eigen::VectorXd& r, Eigen::VectorXd& z) {
    z.resize(ndof_);
    for (int k = 0; k < ndof_ / 3; ++k) z.segment<3>(3 * k) = block_inverse_[size_t(k)] * r.segment<3>(3 * k);
  });
}

bool NewtonFamily::preconditioned_cg(ThreadPool& tp, double eta, bool projected,
                                     const std::function<bool()>& out_of_time, int& iterations,
                                     const Preconditioner& precondition) {
  d_.setZero(ndof_);
  cg_r_ = -g_;
  precondition(cg_r_, cg_z_);
  cg_p_ = cg_z_;
  double rz = cg_r_.dot(cg_z_);
  // Measured in the preconditioner's norm |r|_M^-1 = sqrt(r^T z): the plain |r| is dominated by
  // the stiffest dofs (slivers) and wanders for hundreds of iterations while the step improves.
  const double rz0 = rz, target = eta * eta * rz;
  for (int k = 0; k < kMaxCgIterations; ++k) {
    multiply(tp, cg_p_, cg_q_);
    const double curvature = cg_p_.dot(cg_q_);
    // Non-positive curvature: the exact Hessian is not positive definite here (the caller goes
    // back to the projected one); on the projected one only round-off, so keep what CG has.
    if (!(curvature > 0)) return projected && k > 0;
    const double a = rz / curvature;
    d_ += a * cg_p_;
    cg_r_ -= a * cg_q_;
    ++iterations;
    precondition(cg_r_, cg_z_);
    const double rz_next = cg_r_.dot(cg_z_);
    if (rz_next <= target || out_of_time()) break;
    if (k + 1 == kMaxCgIterations)
      spdlog::debug("newton cg: {} iterations left |r|_M / |g|_M = {:.3g} (asked {:.3g})", kMaxCgIterations,
                    std::sqrt(rz_next / rz0), eta);
    cg_p_ = cg_z_ + (rz_next / rz) * cg_p_;
    rz = rz_next;
  }
  return true;
}

void NewtonFamily::set_contact_stiffness(const BodyModel& m, double h) {
  contact_k_.assign(m.vertex_count(), 0.0);
  if (inputs_have_obstacles_)
    for (size_t i = 0; i < m.vertex_count(); ++i)
      if (dof_[i] >= 0) contact_k_[i] = kContactScale * std::max(m.inertia[i] / (h * h), elastic_diagonal(int32_t(i)));
}

double NewtonFamily::elastic_diagonal(int32_t v) const {
  if (dof_[v] < 0) return 0;
  const double* values = H_.valuePtr();
  return std::max({values[diag_entry_[9 * v]], values[diag_entry_[9 * v + 4]], values[diag_entry_[9 * v + 8]]});
}

// A grab's spring: 1 / compliance, or for a hard grab a penalty far stiffer than what it holds
// (the effective inertia of the grabbed point over h^2 and the elastic stiffness at its corners).
double NewtonFamily::attachment_stiffness(const BodyModel& m, const Attachment& a, double h) const {
  if (a.compliance > 0) return 1.0 / a.compliance;
  double wsum = 0, diag = 0;
  for (int k = 0; k < 4; ++k)
    if (a.vertices[k] >= 0) {
      wsum += a.weights[k] * a.weights[k] * m.inv_mass[a.vertices[k]];
      diag = std::max(diag, elastic_diagonal(a.vertices[k]));
    }
  if (wsum <= 0) return 0;
  return kHardScale * std::max(1.0 / (wsum * h * h), diag);
}

RigidTool NewtonFamily::tool_now(const StepInputs& in, size_t t) const {
  return in.tools[t].at(tool_time_offset_);
}

void NewtonFamily::remember_normal_forces() {
  lagged_ = contacts_;
  for (Contact& c : lagged_) c.normal_force = contact_k_[c.vertex] * c.depth;
}

void NewtonFamily::find_contacts(const BodyModel& m, const std::vector<Vec3>& x, double h,
                                 const StepInputs& in) {
  contacts_.clear();
  auto lagged = [&](int32_t v, int tool, int obstacle = -1) {
    for (const Contact& c : lagged_)
      if (c.vertex == v && c.tool == tool && c.obstacle == obstacle) return c.normal_force;
    return 0.0;
  };
  triangles_.for_each_hit(m, x, [&](size_t o, int32_t v, const ObstacleContacts::Hit& hit) {
    Contact c{v, -1, hit.n, -hit.C, triangles_.friction(o), lagged(v, -1, int(o)), Vec3::Zero()};
    c.obstacle = int(o);
    c.hit = hit;
    contacts_.push_back(c);
  });
  if (in.colliders.empty() && in.tools.empty()) return;
  for (size_t i = 0; i < x.size(); ++i) {
    if (m.inv_mass[i] == 0) continue;
    for (const Collider& col : in.colliders) {
      ContactPoint cp;
      if (!find_contact(col, x[i], cp) || !(cp.depth > 0)) continue;
      contacts_.push_back(Contact{int32_t(i), -1, cp.normal, cp.depth, col.dynamic_friction,
                                  lagged(int32_t(i), -1), Vec3::Zero()});
    }
    for (size_t t = 0; t < in.tools.size(); ++t) {
      const RigidTool tool = tool_now(in, t);
      Vec3 q, n;
      double depth;
      if (!tool_contact(tool, x[i], q, n, depth) || !(depth > 0)) continue;
      contacts_.push_back(Contact{int32_t(i), int(t), n, depth, tool.dynamic_friction, lagged(int32_t(i), int(t)),
                                  tool.motion(q, h)});
    }
  }
}

double NewtonFamily::penetration_energy(const BodyModel& m, const std::vector<Vec3>& x,
                                        const StepInputs& in) const {
  double e = 0;
  triangles_.for_each_hit(m, x, [&](size_t, int32_t v, const ObstacleContacts::Hit& hit) {
    e += 0.5 * contact_k_[size_t(v)] * hit.C * hit.C;
  });
  if (in.colliders.empty() && in.tools.empty()) return e;
  std::vector<RigidTool> tools;
  for (size_t t = 0; t < in.tools.size(); ++t) tools.push_back(tool_now(in, t));
  for (size_t i = 0; i < x.size(); ++i) {
    if (m.inv_mass[i] == 0) continue;
    for (const Collider& col : in.colliders) {
      ContactPoint cp;
      if (find_contact(col, x[i], cp) && cp.depth > 0) e += 0.5 * contact_k_[i] * cp.depth * cp.depth;
    }
    for (const RigidTool& tool : tools) {
      Vec3 q, n;
      double depth;
      if (tool_contact(tool, x[i], q, n, depth) && depth > 0) e += 0.5 * contact_k_[i] * depth * depth;
    }
  }
  return e;
}

// Tangential slip of a contact's vertex since the start of the substep, relative to the obstacle.
Vec3 slip(const Contact& c, const std::vector<Vec3>& x, const std::vector<Vec3>& x_start) {
  const Vec3 u = x[c.vertex] - x_start[c.vertex] - c.obstacle_motion;
  return u - u.dot(c.normal) * c.normal;
}

// Friction energy of a contact: mu f_n (|u_t|^2 / (2 eps) below eps, |u_t| - eps/2 above), u_t the
// slip relative to the obstacle along the plane of the contact.
double friction_energy(const Contact& c, const std::vector<Vec3>& x, const std::vector<Vec3>& x_start,
                       double eps) {
  const double bound = c.friction * c.normal_force;
  if (!(bound > 0)) return 0;
  const double u = slip(c, x, x_start).norm();
  return bound * (u < eps ? u * u / (2 * eps) : u - eps / 2);
}

// Friction force on the body from a contact (minus the friction energy's gradient).
Vec3 friction_force(const Contact& c, const std::vector<Vec3>& x, const std::vector<Vec3>& x_start, double eps) {
  const double bound = c.friction * c.normal_force;
  if (!(bound > 0)) return Vec3::Zero();
  const Vec3 ut = slip(c, x, x_start);
  const double u = ut.norm();
  return u < eps ? Vec3(-bound / eps * ut) : Vec3(-bound * ut / u);
}

void NewtonFamily::contact_forces(const BodyModel& m, const std::vector<Vec3>& x, double h, ThreadPool& tp) {
  contact_force_.assign(contacts_.size(), Vec3::Zero());
  bool touched = false;
  for (const Contact& c : contacts_) touched = touched || c.tool >= 0 || c.obstacle >= 0;
  if (!touched) return;
  // What holds each touching vertex where it is: the inertial and elastic gradient of the
  // incremental potential at x (at the solution it equals the contacts' penalty and friction
  // forces, whose gradients cancel it), shared between the vertex's contacts in proportion to
  // their penalty forces. An iterate short of the solution can leave a vertex a little inside an
  // obstacle that the iteration did not see (a body springing back after a tool that is lifted
  // away); its penalty k depth is then far from any force the body exerts (tens of newtons for
  // a few tens of micrometres), while the balance stays the force the body puts on the tool.
  assemble(m, x, h, tp, false);
  const double eps = kStickSpeed * h;
  penalty_sum_.assign(m.vertex_count(), 0.0);
  for (const Contact& c : contacts_) penalty_sum_[c.vertex] += contact_k_[c.vertex] * c.depth;
  for (size_t k = 0; k < contacts_.size(); ++k) {
    const Contact& c = contacts_[k];
    const double share = penalty_sum_[c.vertex] > 0 ? contact_k_[c.vertex] * c.depth / penalty_sum_[c.vertex] : 0.0;
    const Vec3 balance = share * Vec3(g_.segment<3>(dof_[c.vertex]));
    // An obstacle only pushes, and friction stays inside the cone of that push (bounded by the
    // penalty's own friction force, which is what the iteration used).
    const double fn = std::max(0.0, balance.dot(c.normal));
    Vec3 ft = balance - balance.dot(c.normal) * c.normal;
    const double ft_max = std::min(c.friction * fn, friction_force(c, x, x_start_, eps).norm());
    if (ft.norm() > ft_max) ft *= ft_max / ft.norm();
    contact_force_[k] = fn * c.normal + ft;
  }
}

void NewtonFamily::add_interaction_to_hessian(const BodyModel& m, const std::vector<Vec3>& x, double h,
                                              const StepInputs& in) {
  if (!contacts_.empty() || !in.attachments.empty()) {
    if (!elastic_saved_ && hessian_at_h_ > 0) {  // only a Hessian that may be kept
      elastic_values_.assign(H_.valuePtr(), H_.valuePtr() + H_.nonZeros());
      elastic_saved_ = true;
    }
    penalties_in_hessian_ = true;
    hessian_changed_ = true;
  }
  add_interaction(m, x, h, in, true);
}

void NewtonFamily::add_interaction(const BodyModel& m, const std::vector<Vec3>& x, double h,
                                   const StepInputs& in, bool hessian) {
  double* values = H_.valuePtr();
  if (hessian) {
    attachment_k_.assign(in.attachments.size(), 0.0);
    for (size_t j = 0; j < in.attachments.size(); ++j) attachment_k_[j] = attachment_stiffness(m, in.attachments[j], h);
  }
  for (size_t j = 0; j < in.attachments.size(); ++j) {
    const Attachment& a = in.attachments[j];
    const double k = attachment_k_[j];
    if (k <= 0) continue;
    const Vec3 c = a.point(x) - a.target;
    for (int p = 0; p < 4; ++p) {
      const int32_t vp = a.vertices[p];
      if (vp < 0 || dof_[vp] < 0) continue;
      g_.segment<3>(dof_[vp]) += k * a.weights[p] * c;
      for (int q = 0; q < 4 && hessian; ++q) {
        const int32_t vq = a.vertices[q];
        if (vq < 0 || dof_[vq] < 0) continue;
        // An in-tet grab's corners share its tet, so their coupling block is in the pattern.
        const double kk = k * a.weights[p] * a.weights[q];
        for (int i = 0; i < 3; ++i) {
          const int* begin = H_.innerIndexPtr() + H_.outerIndexPtr()[dof_[vq] + i];
          const int* end = H_.innerIndexPtr() + H_.outerIndexPtr()[dof_[vq] + i + 1];
          const int* at = std::lower_bound(begin, end, dof_[vp] + i);
          if (at != end && *at == dof_[vp] + i) values[at - H_.innerIndexPtr()] += kk;
        }
      }
    }
  }
  const double eps = kStickSpeed * h;
  for (const Contact& c : contacts_) {
    const int d = dof_[c.vertex];
    const double k = contact_k_[c.vertex];
    g_.segment<3>(d) -= k * c.depth * c.normal;
    Eigen::Matrix3d block = k * c.normal * c.normal.transpose();
    const double bound = c.friction * c.normal_force;
    if (bound > 0) {
      const Vec3 ut = slip(c, x, x_start_);
      const double u = ut.norm();
      const Eigen::Matrix3d T = Eigen::Matrix3d::Identity() - c.normal * c.normal.transpose();
      // Static region: the quadratic's own curvature. Sliding: the cone |u| has none along the
      // slip, which would let the Newton step slide a vertex as far as its inertia alone allows;
      // its majorizer (|u'|^2 + |u|^2) / (2 |u|) has curvature 1/|u| in every tangential direction.
      g_.segment<3>(d) += bound / std::max(u, eps) * ut;
      block += bound / std::max(u, eps) * T;
    }
    if (hessian)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) values[diag_entry_[9 * size_t(c.vertex) + 3 * i + j]] += block(i, j);
  }
}

double NewtonFamily::elastic_energy(const BodyModel& m, const std::vector<Vec3>& x) const {
  // Per block of tets, summed in block order: the same bits with any thread count.
  std::vector<double> part;
  return block_sum(*pool_, m.tets.size(), kEnergyBlock, part, [&](size_t b, size_t e) {
    double sum = 0;
    for (size_t t = b; t < e; ++t) sum += strain_energy(m.tets[t], m.stiffness, gather(x, m.tets[t].v), m.material.model);
    return sum;
  });
}

double NewtonFamily::inertial_elastic_energy(const BodyModel& m, const std::vector<Vec3>& x, double h) const {
  double e = elastic_energy(m, x);
  for (size_t i = 0; i < x.size(); ++i)
    if (dof_[i] >= 0) e += 0.5 / (h * h) * m.inertia[i] * (x[i] - y_[i]).squaredNorm();
  return e;
}

void NewtonFamily::warm_start_pass(const BodyModel& m,
                                   const std::array<const std::vector<Vec3>*, kCandidates>& candidates, double h,
                                   double floor, std::array<double, kCandidates>& energy,
                                   std::array<bool, kCandidates>& kept) {
  struct Part {
    std::array<double, kCandidates> elastic{};
    std::array<bool, kCandidates> kept{true, true, true};
  };
  std::vector<Part> parts(block_count(m.tets.size(), kEnergyBlock));
  // In elastic_energy()'s blocks, summed in the same order, so that each candidate's energy is
  // the bits potential() gives for it.
  for_each_block(*pool_, m.tets.size(), kEnergyBlock, [&](size_t block, size_t b, size_t e) {
    // Summed here and stored once: the blocks' parts share cache lines.
    Part part;
    for (size_t t = b; t < e; ++t) {
      const TetRest& tet = m.tets[t];
      double start_ratio = 0;
      for (int c = 0; c < kCandidates; ++c) {
        // The energy and the volume ratio from one deformation gradient.
        const Mat3 F = deformation_gradient(tet, gather(*candidates[size_t(c)], tet.v));
        part.elastic[size_t(c)] += strain_energy(tet, m.stiffness, F, m.material.model);
        if (!(floor > 0)) continue;
        const double ratio = F.determinant();
        if (c == 0) start_ratio = ratio;
        else if (ratio < std::min(floor, start_ratio)) part.kept[size_t(c)] = false;
      }
    }
    parts[block] = part;
  });
  for (int c = 0; c < kCandidates; ++c) {
    double e = 0;
    bool k = true;
    for (const Part& part : parts) {
      e += part.elastic[size_t(c)];
      k = k && part.kept[size_t(c)];
    }
    const std::vector<Vec3>& x = *candidates[size_t(c)];
    for (size_t i = 0; i < x.size(); ++i)
      if (dof_[i] >= 0) e += 0.5 / (h * h) * m.inertia[i] * (x[i] - y_[i]).squaredNorm();
    energy[size_t(c)] = e;
    kept[size_t(c)] = k;
  }
}

double NewtonFamily::potential(const BodyModel& m, const std::vector<Vec3>& x, double h,
                               const StepInputs& in) const {
  return with_interaction_energy(inertial_elastic_energy(m, x, h), m, x, h, in);
}

double NewtonFamily::with_interaction_energy(double e, const BodyModel& m, const std::vector<Vec3>& x, double h,
                                             const StepInputs& in) const {
  for (size_t j = 0; j < in.attachments.size(); ++j)
    if (attachment_k_[j] > 0) e += 0.5 * attachment_k_[j] * (in.attachments[j].point(x) - in.attachments[j].target).squaredNorm();
  const double eps = kStickSpeed * h;
  for (const Contact& c : contacts_) e += friction_energy(c, x, x_start_, eps);
  return e + penetration_energy(m, x, in);
}

StepReport NewtonFamily::step(const BodyModel& m, BodyState& state, const SolverSettings& s,
                              const StepInputs& in, const Stepper::IterationHook& hook) {
  const auto t_start = Clock::now();
  StepReport total;
  int n = effective_substeps(m, s);
  const double h = s.dt / n;
  if (!pool_ || int(pool_->size()) != s.threads) pool_ = std::make_unique<ThreadPool>(s.threads);
  ThreadPool& tp = *pool_;
  {
    const auto t0 = Clock::now();
    compile(m);
    total.times.other_ms += ms_since(t0);
  }
  total.tools.assign(in.tools.size(), ToolReaction{});
  total.attachment_forces.assign(in.attachments.size(), Vec3::Zero());
  triangles_.begin_step(m, state.x, in.obstacles);
  double hook_ms = 0;
  for (int sub = 0; sub < n && !total.cancelled; ++sub) {
    const auto t_sub = Clock::now();
    tool_time_offset_ = (sub + 1 - n) * h;
    v_before_ = state.v;
    predict(m, state, s, in, h, x_start_);
    inputs_have_obstacles_ = !in.colliders.empty() || !in.tools.empty() || triangles_.active();
    y_ = state.x;
    std::vector<Vec3>& x = state.x;
    // Warm start: of the prediction y, the motion continued without this step's loads (x + h v:
    // the previous solution itself for a body at rest; from y a stiff body at rest must climb back
    // the whole h^2 g every step) and the start x, the one of lowest potential that keeps every
    // tet above the inversion floor (x always does, or is where the body already was).
    // Its inertial and elastic energy starts the first line search.
    double start_energy = 0;
    {
      trial_ = x_start_;
      if (v_before_.size() == x.size())
        for (size_t i = 0; i < x.size(); ++i)
          if (dof_[i] >= 0) trial_[i] += h * v_before_[i];
      const std::array<const std::vector<Vec3>*, kCandidates> candidates = {&x_start_, &y_, &trial_};
      std::array<double, kCandidates> energy;
      std::array<bool, kCandidates> kept;
      warm_start_pass(m, candidates, h, std::max(0.0, s.inversion_floor), energy, kept);
      size_t best = 0;  // the start: in order, a later candidate must be strictly lower
      for (size_t c = 1; c < size_t(kCandidates); ++c)
        if (kept[c] && energy[c] < energy[best]) best = c;
      x = *candidates[best];
      start_energy = energy[best];
    }
    contacts_.clear();
    const double start_ms = ms_since(t_sub);  // prediction and warm start
    const double budget = s.time_budget_ms > 0
                              ? std::max(1e-6, (s.time_budget_ms - (ms_since(t_start) - hook_ms)) / (n - sub))
                              : 0.0;
    StepReport rep;
    rep.times.other_ms += start_ms;
    attachment_k_.assign(in.attachments.size(), 0.0);
    const bool cg = newton_uses_cg(s.newton_linear_solver, ndof_);
    if (!cg && !analysed_) {
      cholesky_.analyze(H_);
      analysed_ = true;
    }
    auto out_of_time = [&] {
      return (budget > 0 && ms_since(t_sub) >= budget) || (in.cancel && in.cancel->load(std::memory_order_relaxed));
    };
    double g0 = -1;
    bool full_step = false;  // the last iteration took the whole Newton step
    for (int it = 0; it < s.iterations; ++it) {
      const auto t_asm = Clock::now();
      bool exact = full_step;
      // Inexact Newton on a body that has hardly moved since its Hessian was assembled keeps that
      // Hessian (a chord step: the gradient is exact, so the fixed point is the same; the matrix
      // differs by about the relative motion): only for the projected Hessian, and not with grabs
      // (a dragged body moves); contacts' penalties are taken off and put back fresh.
      const bool reuse = cg && !exact && hessian_at_h_ == h && in.attachments.empty() &&
                         max_motion_since_hessian(x) <= kHessianReuseMotion * m.mean_edge;
      if (reuse && penalties_in_hessian_) {
        std::copy(elastic_values_.begin(), elastic_values_.end(), H_.valuePtr());
        penalties_in_hessian_ = false;
        hessian_changed_ = true;
      }
      assemble(m, x, h, tp, !reuse, exact);
      if (!reuse) hessian_assembled();
      if (cg && !reuse) {
        hessian_at_h_ = exact || !in.attachments.empty() ? 0.0 : h;
        hessian_x_ = x;
      }
      rep.hessian_reused += reuse;
      if (it == 0) set_contact_stiffness(m, h);
      find_contacts(m, x, h, in);
      add_interaction_to_hessian(m, x, h, in);
      const double gnorm = g_.norm();
      rep.times.projection_ms += ms_since(t_asm);
      if (g0 < 0) rep.residual_initial = rep.residual_final = g0 = gnorm;
      if (!std::isfinite(gnorm)) {
        rep.diverged = true;
        break;
      }
      if (gnorm == 0) {  // at the solution already (a body at rest without loads)
        rep.stopped_by_tolerance = true;
        break;
      }
      const auto t_solve = Clock::now();
      const double cap = s.newton_forcing > 0 ? s.newton_forcing : max_forcing(preconditioning(s.newton_linear_solver));
      const double eta = std::min(cap, std::sqrt(gnorm / g0));
      auto solve = [&] {
        return cg ? conjugate_gradients(tp, eta, !exact, s.newton_linear_solver, out_of_time,
                                      rep.linear_iterations) : cholesky_.factorize(H_);
      };
      bool factored = solve();
      if (exact && !factored) {
        // Not positive definite here: the projected Hessian instead.
        exact = false;
        assemble(m, x, h, tp, true, false);
        hessian_assembled();
        if (cg) {
          hessian_at_h_ = in.attachments.empty() ? h : 0.0;
          hessian_x_ = x;
        }
        add_interaction_to_hessian(m, x, h, in);
        factored = solve();
      }
      if (!factored) {
        rep.diverged = true;
        break;
      }
      if (!cg) d_ = cholesky_.solve(-g_);
      else
        spdlog::debug("newton iteration {}: |g| {:.3e}, cg to {:.2g}: {} CG iterations so far in the substep", it,
                      gnorm, eta, rep.linear_iterations);
      rep.times.update_ms += ms_since(t_solve);
      // A step below round-off of the coordinates: converged as far as double precision can tell.
      if (d_.lpNorm<Eigen::Infinity>() <= 1e-13 * m.mean_edge) {
        rep.stopped_by_tolerance = true;
        break;
      }
      const auto t_ls = Clock::now();
      const double slope = g_.dot(d_);
      // The first iteration starts where the warm start measured the inertial and elastic part.
      const double e0 = it == 0 ? with_interaction_energy(start_energy, m, x, h, in) : potential(m, x, h, in);
      double alpha = 1.0;
      bool moved = false;
      trial_ = x;
      if (slope < 0 && -slope <= kEnergyResolution * std::abs(e0)) {
        // The whole step's predicted decrease is below the round-off of the potential's sum (a
        // body at rest, or the last iterations of a tight solve): the energy cannot judge it, and
        // halving it thirty times cost thirty passes over the mesh in every tick of a scene at
        // rest, to refuse a step that small. It is taken: the direction descends (CG's iterate
        // from zero, or the factorised solve) and its length in the Hessian's norm is that decrease.
        for (size_t i = 0; i < x.size(); ++i)
          if (dof_[i] >= 0) trial_[i] = x[i] + d_.segment<3>(dof_[i]);
        moved = true;
      }
      for (int ls = 0; ls < 30 && slope < 0 && !moved; ++ls, alpha *= 0.5) {
        for (size_t i = 0; i < x.size(); ++i)
          if (dof_[i] >= 0) trial_[i] = x[i] + alpha * d_.segment<3>(dof_[i]);
        const double e = potential(m, trial_, h, in);
        if (std::isfinite(e) && e <= e0 + 1e-4 * alpha * slope) {
          moved = true;
          break;
        }
      }
      if (moved) x.swap(trial_);
      full_step = moved && alpha == 1.0;
      // Inversion safety as in the projection family: tets pushed under the floor are pushed back
      // by the unilateral volume constraint (repeated while a pass still acts, at most 20).
      if (moved && s.inversion_floor > 0) {
        const auto t_floor = Clock::now();
        const int hits = volume_floor_.enforce(m, x, s.inversion_floor, kVolumePasses, tp, [&] {
          return (in.cancel && in.cancel->load(std::memory_order_relaxed)) || (budget > 0 && ms_since(t_sub) >= budget);
        });
        rep.volume_corrections += hits;
        rep.floor_passes += volume_floor_.passes();
        // A cut floor is reported; the iteration's own checks below then stop the substep.
        if (volume_floor_.stopped() && !(in.cancel && in.cancel->load(std::memory_order_relaxed)))
          rep.floor_stopped_by_budget = true;
        if (hits > 0) full_step = false;
        rep.times.floor_ms += ms_since(t_floor);
      }
      rep.times.other_ms += ms_since(t_ls);
      rep.iterations++;
      // The residual after the iteration: |grad G| at the new positions, over the free dofs.
      double r = gnorm;
      // Measured when something reads it: a stop rule, the hook, the report of the last substep.
      const bool measure = s.tolerance > 0 || hook || (s.record_residuals && sub + 1 == n);
      if (moved && measure) {
        const auto t_res = Clock::now();
        assemble(m, x, h, tp, false);
        find_contacts(m, x, h, in);
        add_interaction(m, x, h, in, false);
        r = g_.norm();
        remember_normal_forces();
        rep.times.residual_ms += ms_since(t_res);
      } else {
        // Friction's bound from the contacts this iteration started with: without it a step that
        // measures nothing would have none.
        remember_normal_forces();
      }
      rep.residuals.push_back(r);
      rep.residual_final = r;
      if (hook) call_iteration_hook(hook, it, x, r, t_start, hook_ms);
      if (!std::isfinite(r)) {
        rep.diverged = true;
        break;
      }
      // No decrease representable in double: at the solution to machine precision.
      if (!moved || (s.tolerance > 0 && r <= s.tolerance * g0)) {
        rep.stopped_by_tolerance = true;
        break;
      }
      if (in.cancel && in.cancel->load(std::memory_order_relaxed)) {
        rep.cancelled = true;
        break;
      }
      if (budget > 0 && ms_since(t_sub) >= budget) {
        rep.stopped_by_budget = it + 1 < s.iterations;
        break;
      }
    }
    // Reactions of this substep at the final positions.
    const auto t_fin = Clock::now();
    find_contacts(m, x, h, in);
    contact_forces(m, x, h, tp);
    for (size_t k = 0; k < contacts_.size(); ++k) {
      const Contact& c = contacts_[k];
      // A triangle obstacle gives the body this force over the substep; its corners take the
      // opposite impulse (the scene adds it to the cloth's velocities).
      if (c.obstacle >= 0) triangles_.add_impulse(size_t(c.obstacle), c.hit, h * contact_force_[k]);
      if (c.tool < 0) continue;
      const Vec3& f_body = contact_force_[k];
      ToolReaction& r = total.tools[c.tool];
      const Vec3 f_tool = -f_body;
      r.force += f_tool;
      r.torque += (x[c.vertex] - tool_now(in, c.tool).position).cross(f_tool);
      bool found = false;
      for (ToolContact& tc : r.contacts)
        if (tc.vertex == c.vertex) {
          tc.force += f_tool;
          tc.point = x[c.vertex];
          tc.normal = c.normal;
          found = true;
        }
      if (!found) r.contacts.push_back(ToolContact{c.vertex, x[c.vertex], c.normal, f_tool});
    }
    const int contacts = int(contacts_.size());
    // The force a grab puts on the body: minus its spring's gradient.
    for (size_t j = 0; j < in.attachments.size(); ++j)
      total.attachment_forces[j] -= attachment_k_[j] * (in.attachments[j].point(x) - in.attachments[j].target);
    finish_substep(m, state, x_start_, s, h);
    rep.times.other_ms += ms_since(t_fin);

    rep.contacts = contacts;
    const bool cancelled = rep.cancelled;
    add_substep(total, std::move(rep));
    if (cancelled) n = sub + 1;
  }
  // Averages over the substeps run: the impulse delivered during the step divided by its length.
  for (ToolReaction& r : total.tools) {
    r.force /= n;
    r.torque /= n;
    for (ToolContact& c : r.contacts) c.force /= n;
  }
  for (Vec3& f : total.attachment_forces) f /= n;
  triangles_.finish(total);
  total.substeps = n;
  // The multipliers belong to the constraint-projection family: none here.
  state.lambda.assign(m.slot_count(), Vec6::Zero());
  state.lambda_h = h;
  state.time += total.cancelled ? n * h : s.dt;
  state.steps++;
  if (!is_finite(state)) total.diverged = true;
  total.wall_ms = ms_since(t_start) - hook_ms;
  return total;
}

}  // namespace

std::unique_ptr<SolverFamily> make_newton_family() { return std::make_unique<NewtonFamily>(); }

}  // namespace pliant::detail
