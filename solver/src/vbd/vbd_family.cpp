// SPDX-License-Identifier: Apache-2.0
// The vertex block descent family (vbd.hpp): substeps, colour sweeps of per-vertex Newton
// steps, the paper's Chebyshev acceleration and adaptive initial guess, grabs and tools as
// energies, static colliders through the shared stage, and the report.
#include "vbd/vbd.hpp"
#include "vbd/vbd_lanes.hpp"

#include "kernels/projection.hpp"
#include "pliant/strain_constraint.hpp"
#include "step/stages.hpp"
#include "step/thread_pool.hpp"
#include "step/obstacles.hpp"
#include "step/volume_floor.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

namespace pliant::detail {

namespace {

// A hard grab (compliance 0) is a spring this many times stiffer than its stiffest vertex's
// own diagonal stiffness (inertia / h^2 plus the elastic rest stiffness): the grabbed point
// then sits within about 1e-4 of the elastic displacement scale of its target.
constexpr double kHardGrabRatio = 1e4;
// Tool contacts are a penalty k/2 depth^2 with k this many times the vertex's diagonal
// stiffness: the remaining penetration is about 1e-3 of what the force alone would cause.
constexpr double kContactRatio = 1e3;
// Tangential slip below which tool friction acts as a stiff spring (the smoothed Coulomb law
// of IPC: |f_t| = mu f_n min(|u| / eps, 1)), as a fraction of the mean edge.
constexpr double kFrictionSlip = 1e-3;
// Per-vertex backtracking: halve the Newton step at most this many times.
constexpr int kLineSearchHalvings = 6;
// Newton steps a vertex may take from rejected points before it stays where it was.
constexpr int kLocalNewtonSteps = 3;
// Inversion floor passes at the end of a substep (as the constraint-projection stepper).
constexpr int kVolumePasses = 20;

// One grab's coupling to one of its vertices.
struct GrabTerm {
  int32_t vertex;
  int32_t attachment;
  double weight;
};

// A tool as it is during the current substep.
struct ToolPose {
  RigidTool tool;
  double h;  // the substep: tool.motion(p, h) is its surface's displacement at p over it
};

Vec3 solve3(const Mat3& H, const Vec3& f, bool& ok) {
  Eigen::LLT<Mat3> llt(H);
  ok = llt.info() == Eigen::Success;
  return ok ? Vec3(llt.solve(f)) : Vec3::Zero();
}

class VbdFamily final : public SolverFamily {
 public:
  explicit VbdFamily(const VbdOptions& o) : opt_(o) {}

  StepReport step(const BodyModel& m, BodyState& state, const SolverSettings& s, const StepInputs& inputs,
                  const Stepper::IterationHook& hook) override;

 private:
  // Substep data the vertex kernels read.
  struct Substep {
    double h = 0, inv_h2 = 0;
    const StepInputs* inputs = nullptr;
    bool line_search = true;
  };

  ThreadPool& threads(int n) {
    if (!pool_ || pool_threads_ != n) {
      pool_ = std::make_unique<ThreadPool>(n);
      pool_threads_ = n;
    }
    return *pool_;
  }
  void prepare_model(const BodyModel& m);
  void prepare_grabs(const BodyModel& m, const StepInputs& inputs, double h);
  void initial_guess(const BodyModel& m, BodyState& state, const SolverSettings& s, const StepInputs& inputs,
                     double h, const std::vector<Vec3>& v_before);
  double diagonal_stiffness(const BodyModel& m, int32_t i) const {
    return m.inertia[i] * sub_.inv_h2 + rest_stiffness_[i];
  }
  // -dG/dx_i (f) and the vertex's 3x3 block (H; skipped when null) at positions x. With the
  // lane kernel, `tets` holds the vertex's tets gathered with x_i at `origin`.
  void vertex_system(const BodyModel& m, int32_t i, const std::vector<Vec3>& x, const VertexTets<v4d>* tets,
                     const Vec3& origin, Vec3& f, Mat3* H) const;
  // The part of G that depends on x_i, with x_i at p: +inf if a tet of i would invert.
  double vertex_energy(const BodyModel& m, int32_t i, const std::vector<Vec3>& x, const VertexTets<v4d>* tets,
                       const Vec3& origin, const Vec3& p) const;
  // The vertex's tets gathered at x for the lane kernel (this thread's buffer), or null when
  // the per-tet forms are used.
  const VertexTets<v4d>* gather_tets(int32_t i, const std::vector<Vec3>& x) const;
  // Contact (and friction) force on the body from one tool at vertex i, position p, added to
  // f, with its Hessian and energy when asked. Returns false when i does not touch the tool.
  bool tool_force(const BodyModel& m, const ToolPose& tool, int32_t i, const Vec3& p, Vec3& f, Mat3* H,
                  double* energy, Vec3* normal = nullptr) const;
  void tool_forces(const BodyModel& m, int32_t i, const Vec3& p, Vec3& f, Mat3* H, double* energy) const {
    for (const ToolPose& t : tools_) tool_force(m, t, i, p, f, H, energy);
  }
  void solve_vertex(const BodyModel& m, int32_t i, std::vector<Vec3>& x) const;
  void sweep(const BodyModel& m, std::vector<Vec3>& x, ThreadPool& tp) const;
  double gradient_norm(const BodyModel& m, const std::vector<Vec3>& x, ThreadPool& tp);
  void chebyshev(const BodyModel& m, std::vector<Vec3>& x, double omega);
  // sum over the vertices of inertia (x - y), in vertex order (the same bits for any thread count).
  Vec3 momentum_offset(const BodyModel& m, const std::vector<Vec3>& x) const;
  void accumulate_reactions(const BodyModel& m, const std::vector<Vec3>& x, const StepInputs& inputs,
                            StepReport& total);

  VbdOptions opt_;
  std::unique_ptr<ThreadPool> pool_;
  VolumeFloor volume_floor_;
  ObstacleContacts obstacles_;
  int pool_threads_ = 0;
  uint64_t model_id_ = 0;               // the model rest_stiffness_ and packs_ belong to
  std::vector<double> rest_stiffness_;  // sum over the vertex's tets of V0 (lambda + 2 mu) |b|^2
  bool free_body_ = false;              // no vertex is fixed
  double total_inertia_ = 0;            // sum of the vertices' inertia
  bool lanes_ = false;                  // the lane kernel applies (vbd_lanes.hpp)
  VertexPacks<v4d> packs_;
  std::vector<Vec3> x_start_, y_, v_before_, v_last_, x_prev_, x_prev2_;
  std::vector<double> partial_;
  Substep sub_;
  std::vector<ToolPose> tools_;
  std::vector<GrabTerm> grabs_;          // sorted by vertex
  std::vector<uint8_t> grabbed_;         // per vertex: has grab terms
  std::vector<double> grab_stiffness_;   // per attachment
  // Per tool: force on the tool summed over the substeps, per vertex, and the last normal.
  struct ToolAccumulator {
    std::vector<Vec3> force, normal;
    std::vector<uint8_t> marked;
    std::vector<int32_t> vertices;
  };
  std::vector<ToolAccumulator> tool_acc_;
};

void VbdFamily::prepare_model(const BodyModel& m) {
  if (model_id_ == m.id && m.id != 0 && rest_stiffness_.size() == m.vertex_count()) return;
  model_id_ = m.id;
  free_body_ = !m.inv_mass.empty();
  total_inertia_ = 0;
  for (size_t i = 0; i < m.inv_mass.size(); ++i) {
    free_body_ = free_body_ && m.inv_mass[i] > 0;
    total_inertia_ += m.inertia[i];
  }
  rest_stiffness_.assign(m.vertex_count(), 0.0);
  const double modulus = m.lame.lambda + 2 * m.lame.mu;
  for (const TetRest& t : m.tets) {
    Eigen::RowVector3d b3 = -(t.dm_inv.row(0) + t.dm_inv.row(1) + t.dm_inv.row(2));
    for (int k = 0; k < 4; ++k) {
      const double b2 = k < 3 ? t.dm_inv.row(k).squaredNorm() : b3.squaredNorm();
      rest_stiffness_[t.v[k]] += t.volume * modulus * b2;
    }
  }
  v_last_.clear();
  // The lane kernel writes K through the Lame parameters: only for the isotropic K it has.
  lanes_ = opt_.lanes && opt_.hessian == VbdHessian::GaussNewton && m.stiffness == stvk_stiffness(m.lame);
  packs_ = lanes_ ? compile_vertex_packs<v4d>(m) : VertexPacks<v4d>{};
}

const VertexTets<v4d>* VbdFamily::gather_tets(int32_t i, const std::vector<Vec3>& x) const {
  if (!lanes_) return nullptr;
  thread_local VertexTets<v4d> tets;
  tets.gather(packs_, i, x);
  return &tets;
}

void VbdFamily::prepare_grabs(const BodyModel& m, const StepInputs& inputs, double h) {
  for (const GrabTerm& g : grabs_) grabbed_[g.vertex] = 0;
  grabs_.clear();
  grabbed_.resize(m.vertex_count(), 0);
  grab_stiffness_.assign(inputs.attachments.size(), 0.0);
  for (size_t j = 0; j < inputs.attachments.size(); ++j) {
    const Attachment& a = inputs.attachments[j];
    double stiffest = 0;
    for (int k = 0; k < 4; ++k)
      if (a.vertices[k] >= 0 && m.inv_mass[a.vertices[k]] > 0) {
        stiffest = std::max(stiffest, m.inertia[a.vertices[k]] / (h * h) + rest_stiffness_[a.vertices[k]]);
        grabs_.push_back(GrabTerm{a.vertices[k], int32_t(j), a.weights[k]});
        grabbed_[a.vertices[k]] = 1;
      }
    grab_stiffness_[j] = a.compliance > 0 ? 1.0 / a.compliance : kHardGrabRatio * stiffest;
  }
  std::sort(grabs_.begin(), grabs_.end(), [](const GrabTerm& a, const GrabTerm& b) { return a.vertex < b.vertex; });
}

void VbdFamily::initial_guess(const BodyModel& m, BodyState& state, const SolverSettings& s,
                              const StepInputs& inputs, double h, const std::vector<Vec3>& v_before) {
  if (opt_.initial_guess == VbdInitialGuess::Inertial) return;  // x = y already
  // Without a previous substep (first use, another model) the previous acceleration is 0.
  const bool history = v_last_.size() == m.vertex_count();
  const bool forces = inputs.external_forces.size() == m.vertex_count();
  for (size_t i = 0; i < m.vertex_count(); ++i) {
    if (m.inv_mass[i] == 0) continue;
    Vec3 a_ext = s.gravity * (m.mass[i] * m.inv_mass[i]);
    if (forces) a_ext += inputs.external_forces[i] * m.inv_mass[i];
    const double norm = a_ext.norm();
    Vec3 a = Vec3::Zero();
    if (norm > 0) {
      const Vec3 dir = a_ext / norm;
      const double along = history ? (v_before[i] - v_last_[i]).dot(dir) / h : 0.0;  // previous acceleration
      a = std::clamp(along, 0.0, norm) * dir;
    }
    state.x[i] = x_start_[i] + h * v_before[i] + h * h * a;
  }
}

bool VbdFamily::tool_force(const BodyModel& m, const ToolPose& tp, int32_t i, const Vec3& p, Vec3& f,
                           Mat3* H, double* energy, Vec3* normal) const {
  Vec3 q, n;
  double depth;
  if (!tool_contact(tp.tool, p, q, n, depth)) return false;
  if (normal) *normal = n;
  const double k = kContactRatio * diagonal_stiffness(m, i);
  const double fn = k * depth;
  f += fn * n;
  if (H) *H += k * n * n.transpose();
  if (energy) *energy += 0.5 * k * depth * depth;
  // Smoothed Coulomb friction on the slip relative to the tool since the substep began (the
  // tool's surface moving as it does where the vertex started: constant in p).
  const double mu = tp.tool.dynamic_friction;
  if (mu <= 0) return true;
  const Mat3 T = Mat3::Identity() - n * n.transpose();
  const Vec3 u = T * ((p - x_start_[i]) - tp.tool.motion(x_start_[i], tp.h));
  const double eps = kFrictionSlip * m.mean_edge, len = u.norm();
  const double scale = mu * fn / std::max(len, eps);
  f -= scale * u;
  if (H) *H += scale * T;
  if (energy) *energy += mu * fn * (len < eps ? 0.5 * len * len / eps : len - 0.5 * eps);
  return true;
}

void VbdFamily::vertex_system(const BodyModel& m, int32_t i, const std::vector<Vec3>& x, const VertexTets<v4d>* tets,
                              const Vec3& origin, Vec3& f, Mat3* H) const {
  const double mi = m.inertia[i] * sub_.inv_h2;
  f = -mi * (x[i] - y_[i]);
  if (H) *H = mi * Mat3::Identity();
  const VbdHessian mode = opt_.hessian;
  if (tets) {
    Vec3 g;
    Mat3 Ht;
    tets->derivatives(x[i] - origin, m.lame, m.material.model, g, H ? &Ht : nullptr);
    f -= g;
    if (H) *H += Ht;
  } else {
    for (int32_t a = m.vertex_tet_start[i]; a < m.vertex_tet_start[i + 1]; ++a) {
      const TetRest& t = m.tets[m.vertex_tet_entry[a] >> 2];
      Vec3 g;
      Mat3 Ht;
      tet_vertex_derivatives(t, m.vertex_tet_entry[a] & 3, gather(x, t.v), m.stiffness, m.material.model, mode, g, Ht);
      f -= g;
      if (H) *H += Ht;
    }
  }
  if (!grabs_.empty() && grabbed_[i]) {
    const auto range = std::equal_range(grabs_.begin(), grabs_.end(), GrabTerm{i, 0, 0},
                                        [](const GrabTerm& a, const GrabTerm& b) { return a.vertex < b.vertex; });
    for (auto g = range.first; g != range.second; ++g) {
      const Attachment& at = sub_.inputs->attachments[g->attachment];
      const double k = grab_stiffness_[g->attachment];
      f -= k * g->weight * (at.point(x) - at.target);
      if (H) H->diagonal().array() += k * g->weight * g->weight;
    }
  }
  if (!tools_.empty()) tool_forces(m, i, x[i], f, H, nullptr);
}

double VbdFamily::vertex_energy(const BodyModel& m, int32_t i, const std::vector<Vec3>& x, const VertexTets<v4d>* tets,
                                const Vec3& origin, const Vec3& p) const {
  double e = 0.5 * m.inertia[i] * sub_.inv_h2 * (p - y_[i]).squaredNorm();
  if (tets) {
    if (!tets->energy(p - origin, m.lame, m.material.model, e)) return HUGE_VAL;  // a tet would invert
  } else {
    for (int32_t a = m.vertex_tet_start[i]; a < m.vertex_tet_start[i + 1]; ++a) {
      const TetRest& t = m.tets[m.vertex_tet_entry[a] >> 2];
      std::array<Vec3, 4> q = gather(x, t.v);
      q[m.vertex_tet_entry[a] & 3] = p;
      if (!(volume_ratio(t, q) > 0)) return HUGE_VAL;  // the step would invert a tet
      e += tet_energy(t, q, m.stiffness, m.material.model);
    }
  }
  if (!grabs_.empty() && grabbed_[i]) {
    const auto range = std::equal_range(grabs_.begin(), grabs_.end(), GrabTerm{i, 0, 0},
                                        [](const GrabTerm& a, const GrabTerm& b) { return a.vertex < b.vertex; });
    for (auto g = range.first; g != range.second; ++g) {
      const Attachment& at = sub_.inputs->attachments[g->attachment];
      const Vec3 c = at.point(x) + g->weight * (p - x[i]) - at.target;
      e += 0.5 * grab_stiffness_[g->attachment] * c.squaredNorm();
    }
  }
  if (!tools_.empty()) {
    Vec3 f = Vec3::Zero();
    tool_forces(m, i, p, f, nullptr, &e);
  }
  return e;
}

void VbdFamily::solve_vertex(const BodyModel& m, int32_t i, std::vector<Vec3>& x) const {
  Vec3 f;
  Mat3 H;
  bool ok;
  const Vec3 origin = x[i];
  const VertexTets<v4d>* tets = gather_tets(i, x);
  if (!sub_.line_search) {
    vertex_system(m, i, x, tets, origin, f, &H);
    const Vec3 dx = solve3(H, f, ok);
    if (ok && dx.allFinite()) x[i] += dx;
    return;
  }
  // Backtrack until the vertex's part of G does not grow (G then decreases monotonically; a
  // step that would invert one of the vertex's tets counts as growth). When no fraction of the
  // step helps, the system changed along it (a contact began: its stiffness was not in H), so
  // take another Newton step from the rejected point, still judged against the start. Writing
  // x[i] while trying is safe: no other vertex of the colour reads it.
  const double e0 = vertex_energy(m, i, x, tets, origin, origin);
  for (int attempt = 0; attempt < kLocalNewtonSteps; ++attempt) {
    vertex_system(m, i, x, tets, origin, f, &H);
    const Vec3 dx = solve3(H, f, ok);
    if (!ok || !dx.allFinite()) break;
    const Vec3 from = x[i];
    double scale = 1;
    for (int k = 0; k <= kLineSearchHalvings; ++k, scale *= 0.5)
      if (vertex_energy(m, i, x, tets, origin, from + scale * dx) <= e0) {
        x[i] = from + scale * dx;
        return;
      }
    x[i] = from + dx;
  }
  x[i] = origin;
}

void VbdFamily::sweep(const BodyModel& m, std::vector<Vec3>& x, ThreadPool& tp) const {
  for (const std::vector<int32_t>& colour : m.vertex_colours)
    tp.parallel_for(colour.size(), [&](int, size_t b, size_t e) {
      for (size_t c = b; c < e; ++c)
        if (m.inv_mass[colour[c]] > 0) solve_vertex(m, colour[c], x);
    }, 16);  // a vertex costs microseconds: even small colours are worth splitting
}

double VbdFamily::gradient_norm(const BodyModel& m, const std::vector<Vec3>& x, ThreadPool& tp) {
  // Summed per block of vertices: the same bits with any thread count.
  return std::sqrt(block_sum(tp, m.vertex_count(), 256, partial_, [&](size_t b, size_t e) {
    double sum = 0;
    for (size_t i = b; i < e; ++i) {
      if (m.inv_mass[i] == 0) continue;
      Vec3 f;
      vertex_system(m, int32_t(i), x, gather_tets(int32_t(i), x), x[i], f, nullptr);
      sum += f.squaredNorm();
    }
    return sum;
  }));
}

Vec3 VbdFamily::momentum_offset(const BodyModel& m, const std::vector<Vec3>& x) const {
  Vec3 sum = Vec3::Zero();
  for (size_t i = 0; i < x.size(); ++i) sum += m.inertia[i] * (x[i] - y_[i]);
  return sum;
}

// x <- omega (x - x_{k-1}) + x_{k-1} over the free vertices, x_{k-1} the iterate before last.
void VbdFamily::chebyshev(const BodyModel& m, std::vector<Vec3>& x, double omega) {
  for (size_t i = 0; i < x.size(); ++i)
    if (m.inv_mass[i] > 0) x[i] = omega * (x[i] - x_prev2_[i]) + x_prev2_[i];
}


// The substep's tool reactions (minus the contact forces on the body, at the substep's end
// positions) and grab forces, added to the step's sums.
void VbdFamily::accumulate_reactions(const BodyModel& m, const std::vector<Vec3>& x, const StepInputs& inputs,
                                     StepReport& total) {
  for (size_t j = 0; j < inputs.attachments.size(); ++j) {
    const Attachment& a = inputs.attachments[j];
    total.attachment_forces[j] -= grab_stiffness_[j] * (a.point(x) - a.target);
  }
  for (size_t t = 0; t < tools_.size(); ++t) {
    ToolAccumulator& acc = tool_acc_[t];
    const RigidTool& tool = tools_[t].tool;
    for (size_t i = 0; i < m.vertex_count(); ++i) {
      if (m.inv_mass[i] == 0) continue;
      Vec3 f = Vec3::Zero(), n;
      if (!tool_force(m, tools_[t], int32_t(i), x[i], f, nullptr, nullptr, &n)) continue;
      const Vec3 f_tool = -f;
      total.tools[t].force += f_tool;
      total.tools[t].torque += (x[i] - tool.position).cross(f_tool);
      acc.force[i] += f_tool;
      acc.normal[i] = n;
      if (!acc.marked[i]) {
        acc.marked[i] = 1;
        acc.vertices.push_back(int32_t(i));
      }
      total.contacts++;
    }
  }
}

StepReport VbdFamily::step(const BodyModel& m, BodyState& state, const SolverSettings& s, const StepInputs& inputs,
                           const Stepper::IterationHook& hook) {
  const auto t_start = Clock::now();
  prepare_model(m);
  ThreadPool& tp = threads(s.threads);
  int n = effective_substeps(m, s);
  const double h = s.dt / n;
  const size_t nv = m.vertex_count();
  StepReport total;
  total.tools.assign(inputs.tools.size(), ToolReaction{});
  total.attachment_forces.assign(inputs.attachments.size(), Vec3::Zero());
  tool_acc_.resize(inputs.tools.size());
  for (ToolAccumulator& acc : tool_acc_) {
    acc.force.assign(nv, Vec3::Zero());
    acc.normal.assign(nv, Vec3::Zero());
    acc.marked.assign(nv, 0);
    acc.vertices.clear();
  }
  sub_.h = h;
  sub_.inv_h2 = 1.0 / (h * h);
  sub_.inputs = &inputs;
  sub_.line_search = s.line_search;
  prepare_grabs(m, inputs, h);
  obstacles_.begin_step(m, state.x, inputs.obstacles);
  // The translation step (VbdOptions::translation): on a free body whose only outside pushes
  // are the contacts' projections (colliders, obstacles), which it counts.
  const bool translate = opt_.translation && free_body_ && inputs.tools.empty() && inputs.attachments.empty();

  for (int substep = 0; substep < n; ++substep) {
    const bool last = substep + 1 == n;
    const auto t_other = Clock::now();
    v_before_ = state.v.size() == nv ? state.v : std::vector<Vec3>(nv, Vec3::Zero());
    predict(m, state, s, inputs, h, x_start_);
    y_ = state.x;
    initial_guess(m, state, s, inputs, h, v_before_);
    v_last_ = v_before_;
    tools_.clear();
    for (const RigidTool& t : inputs.tools) {
      tools_.push_back(ToolPose{t.at((substep + 1 - n) * h), h});
    }
    total.times.other_ms += ms_since(t_other);

    double budget = 0;
    if (s.time_budget_ms > 0)
      budget = std::max(1e-6, (s.time_budget_ms - ms_since(t_start)) / (n - substep));
    const auto t_sub = Clock::now();
    double hook_ms = 0;
    const bool residuals = (s.record_residuals && last) || s.tolerance > 0 || bool(hook);
    double r0 = 0;
    if (residuals) {
      const auto t = Clock::now();
      r0 = gradient_norm(m, state.x, tp);
      total.times.residual_ms += ms_since(t);
    }
    if (last) {
      total.residuals.clear();
      total.residual_initial = total.residual_final = r0;
    }
    const bool accelerate = s.chebyshev.delay < s.iterations;
    double omega = 1;
    int collider_contacts = 0, obstacle_contacts = 0;
    // sum of inertia (x - y) the contacts' projections gave the iterate in this substep: with
    // the inertia's own (x - y) summing to it, the substep's momentum is the prediction's plus
    // the contacts' impulses.
    Vec3 pushed = Vec3::Zero();
    for (int it = 0; it < s.iterations; ++it) {
      {
        const auto t = Clock::now();
        if (accelerate) {
          x_prev2_.swap(x_prev_);
          x_prev_ = state.x;
        }
        sweep(m, state.x, tp);
        total.times.projection_ms += ms_since(t);
      }
      if (accelerate && it >= s.chebyshev.delay) {
        // Chebyshev semi-iterative acceleration (Wang 2015) with the paper's schedule.
        const auto t = Clock::now();
        const double rho2 = s.chebyshev.rho * s.chebyshev.rho;
        const int k = it - s.chebyshev.delay;  // 0 for the first accelerated iteration
        omega = k == 0 ? 1.0 : k == 1 ? 2.0 / (2.0 - rho2) : 4.0 / (4.0 - rho2 * omega);
        if (k > 0) chebyshev(m, state.x, omega);
        total.times.update_ms += ms_since(t);
      }
      if (translate) {
        // The elastic forces sum to zero, so at the substep's minimum sum inertia (x - y) is
        // what the contacts pushed; a sweep of vertex steps leaves it elsewhere, and moving every
        // vertex by the same t puts it there without changing the elastic energy.
        const auto t = Clock::now();
        const Vec3 shift = (pushed - momentum_offset(m, state.x)) / total_inertia_;
        for (Vec3& x : state.x) x += shift;
        total.times.update_ms += ms_since(t);
      }
      if (!inputs.colliders.empty()) {
        const auto t = Clock::now();
        collider_contacts = resolve_colliders(m, state.x, x_start_, inputs.colliders);
        total.times.other_ms += ms_since(t);
      }
      if (obstacles_.active()) {
        const auto t = Clock::now();
        obstacle_contacts = obstacles_.resolve(m, state.x, x_start_, h);
        total.times.other_ms += ms_since(t);
      }
      if (translate && (!inputs.colliders.empty() || obstacles_.active())) pushed = momentum_offset(m, state.x);
      total.iterations++;
      double r = 0;
      if (residuals) {
        const auto t = Clock::now();
        r = gradient_norm(m, state.x, tp);
        total.times.residual_ms += ms_since(t);
        if (last) {
          total.residuals.push_back(r);
          total.residual_final = r;
        }
      }
      if (hook) call_iteration_hook(hook, it, state.x, r, t_sub, hook_ms);
      if (residuals && !std::isfinite(r)) {
        total.diverged = true;
        break;
      }
      if (s.tolerance > 0 && r <= s.tolerance * r0) {
        total.stopped_by_tolerance = true;
        break;
      }
      if (inputs.cancel && inputs.cancel->load(std::memory_order_relaxed)) {
        total.cancelled = true;
        break;
      }
      if (budget > 0 && ms_since(t_sub) - hook_ms >= budget) {
        total.stopped_by_budget |= it + 1 < s.iterations;
        break;
      }
    }
    const auto t_end = Clock::now();
    if (s.inversion_floor > 0) {
      const auto t_floor = Clock::now();
      // The later passes belong to the substep's time, as the iterations do.
      const auto cancelled = [&] { return inputs.cancel && inputs.cancel->load(std::memory_order_relaxed); };
      total.volume_corrections = volume_floor_.enforce(m, state.x, s.inversion_floor, kVolumePasses, tp, [&] {
        return cancelled() || (budget > 0 && ms_since(t_sub) - hook_ms >= budget);
      });
      total.floor_passes += volume_floor_.passes();
      if (volume_floor_.stopped() && cancelled()) total.cancelled = true;
      else if (volume_floor_.stopped()) total.floor_stopped_by_budget = true;
      total.times.floor_ms += ms_since(t_floor);
    }
    total.contacts = collider_contacts + obstacle_contacts;
    accumulate_reactions(m, state.x, inputs, total);
    finish_substep(m, state, x_start_, s, h);
    total.times.other_ms += ms_since(t_end);
    if (total.cancelled || total.diverged) {
      n = substep + 1;  // the averages below are over the substeps run
      break;
    }
  }
  obstacles_.finish(total);
  // Averages over the substeps: the impulse delivered during the step divided by dt.
  for (size_t t = 0; t < total.tools.size(); ++t) {
    ToolReaction& r = total.tools[t];
    r.force /= n;
    r.torque /= n;
    for (int32_t v : tool_acc_[t].vertices)
      r.contacts.push_back(ToolContact{v, state.x[v], tool_acc_[t].normal[v], tool_acc_[t].force[v] / n});
  }
  for (Vec3& f : total.attachment_forces) f /= n;
  // The constraint multipliers a converged XPBD step would hold, lambda = -h^2 K C(x), so that
  // state.lambda keeps its meaning (the strain forces of the last substep) for every family.
  state.lambda.assign(m.slot_count(), Vec6::Zero());
  for (size_t t = 0; t < m.tet_count(); ++t)
    state.lambda[m.tet_slot[t]] = -(h * h) * (m.stiffness * strain_constraint(m.tets[t], gather(state.x, m.tets[t].v), m.material.model));
  state.lambda_h = h;
  total.substeps = n;
  state.time += total.cancelled || total.diverged ? n * h : s.dt;
  state.steps++;
  if (!is_finite(state)) total.diverged = true;
  total.wall_ms = ms_since(t_start);
  return total;
}

}  // namespace

std::unique_ptr<SolverFamily> make_vbd_family(const VbdOptions& options) {
  return std::make_unique<VbdFamily>(options);
}

std::unique_ptr<SolverFamily> make_vbd_family() { return make_vbd_family(VbdOptions{}); }

}  // namespace pliant::detail
