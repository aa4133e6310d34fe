// SPDX-License-Identifier: Apache-2.0
// Accelerators: each one small class with one job, combined with any sweep by the solver loop
// (stepper.cpp). After every projection sweep the loop calls after_sweep(); an accelerator may
// change positions (SOR, Chebyshev) unconditionally, or propose an accelerated iterate that the
// loop keeps only if the residual decreased (Anderson, extrapolation: thesis algorithm 2.4).
#pragma once

#include "pliant/settings.hpp"
#include "pliant/stepper.hpp"

#include <Eigen/Core>

#include <functional>
#include <memory>
#include <tuple>
#include <vector>

namespace pliant::detail {

struct SweepResult {
  std::vector<Vec3>& x;                 // positions after the sweep (may be changed)
  std::vector<Vec6>& lambda;            // multipliers after the sweep (may be changed)
  const std::vector<Vec6>& dlambda;     // the sweep's multiplier increment
  const std::vector<Vec3>& x_before;    // positions before the sweep (when needs_previous())
  int iteration;                        // 0-based within the substep
  // A proposal's multipliers (as many as lambda), written there instead of over lambda: the
  // loop takes them if the proposal passes the residual check, and has nothing to restore if not.
  std::vector<Vec6>* lambda_proposed = nullptr;
};

struct AcceleratorServices {
  // x += M^-1 grad C(x)^T dl for all tets (colour-parallel); timed as "update".
  std::function<void(const std::vector<Vec6>& dl)> apply_increment;
  // Calls fn(begin, end) on contiguous ranges covering [0, n), on the step's threads.
  std::function<void(size_t n, const std::function<void(size_t, size_t)>& fn)> parallel_for;
  StepReport* report;
};

class Accelerator {
 public:
  virtual ~Accelerator() = default;
  virtual void begin_substep(size_t vertices, size_t tets) {}
  // Factor applied to each projection's increment inside the sweep (lambda-SOR).
  virtual double increment_scale() const { return 1.0; }
  // Whether x_before must be kept (position-space methods).
  virtual bool needs_previous() const { return false; }
  // Whether it reads SweepResult::dlambda (a sweep that keeps no increment writes less).
  virtual bool needs_increments() const { return false; }
  // Returns true when it made a proposal that must pass the residual check (its multipliers in
  // it.lambda_proposed, its positions in it.x).
  virtual bool after_sweep(SweepResult& it, AcceleratorServices& services) = 0;
};

std::unique_ptr<Accelerator> make_accelerator(const SolverSettings& settings);
// What make_accelerator reads: settings with equal keys make the same accelerator, so the
// stepper keeps one (and its buffers) from substep to substep.
using AcceleratorKey = std::tuple<Method, AndersonForm, double, int, double, double, double, int>;
AcceleratorKey accelerator_key(const SolverSettings& settings);

// Anderson mixing of a sequence of iterates y_k with residuals r_k (type II, Walker & Ni):
// theta = argmin || r_k - dR theta ||, output = y_k - dY theta + beta (r_k - dR theta), where dR, dY
// hold the last m differences r_{j} - r_{j-1}, y_{j} - y_{j-1} (newest first). The normal
// equations dR^T dR theta = dR^T r_k are kept up to date incrementally (one new Gram row and the
// right-hand side per push, in the same pass as the differences) and solved by a complete
// orthogonal decomposition after dropping the oldest columns while cond(dR^T dR) exceeds the
// limit (keeping at least 2), as in thesis algorithm 2.3.
// The vectors are walked in blocks of kBlock entries, each block's dot products summed on its
// own and the blocks' sums added in block order: the same result for any number of threads.
// Pushed by increments (push_increment: r_k = y_k - y_{k-1}), the newest residual is the newest
// dY column and each dR column the difference of two consecutive ones: the mixer then keeps the
// last m + 1 residuals only and forms dR's entries as it reads them (the same doubles as stored
// ones, so the same results), writing one vector a push instead of four.
class AndersonMixer {
 public:
  static constexpr size_t kBlock = 2048;
  // Runs fn(first block, end block) over ranges covering [0, blocks); empty: one thread.
  using ParallelFor = std::function<void(size_t blocks, const std::function<void(size_t, size_t)>& fn)>;

  AndersonMixer(int window, double condition_limit, double beta);
  // Starts a new sequence of `size`-entry vectors (storage is kept when the size is unchanged).
  void reset(size_t size);
  size_t size() const { return size_; }
  size_t blocks() const { return (size_ + kBlock - 1) / kBlock; }
  // Makes y the previous iterate of the next push_increment without counting it as a push.
  void seed(const double* y);
  void push(const double* y, const double* r, const ParallelFor& parallel = {});
  // push(y, y - the previous iterate): the residual is the iterate's change (after seed() or a push).
  // A sequence's pushes are all push() or all push_increment() (std::logic_error otherwise).
  void push_increment(const double* y, const ParallelFor& parallel = {});
  void push(const Eigen::Ref<const Eigen::VectorXd>& y, const Eigen::Ref<const Eigen::VectorXd>& r) {
    push(y.data(), r.data());
  }
  // m difference columns exist (m + 1 pushes).
  bool ready() const { return count_ >= size_t(m_ + 1); }
  // Solves for theta; returns the number of columns dropped by the safeguard.
  int solve();
  // out[i - begin] = the mixed iterate's entry i, for i in [begin, end) (after solve()).
  void mixed(size_t begin, size_t end, double* out) const;
  // solve() and the whole mixed iterate.
  int accelerate(Eigen::VectorXd& out);
  const Eigen::VectorXd& last_theta() const { return theta_; }
  int columns_used() const { return columns_used_; }

 private:
  int slot(int newest_first) const { return ((head_ - newest_first) % m_ + m_) % m_; }
  // The ring slot of the residual pushed newest_first pushes ago (by increments).
  int residual_slot(int newest_first) const { return ((e_head_ - newest_first) % (m_ + 1) + (m_ + 1)) % (m_ + 1); }
  void push_impl(const double* y, const double* r, const ParallelFor& parallel);
  void push_increment_impl(const double* y, const ParallelFor& parallel);
  void end_push(bool differences, int h, int columns);

  int m_;
  double condition_limit_;
  double beta_;
  size_t size_ = 0;
  size_t count_ = 0;
  bool increments_ = false;             // pushed by push_increment
  Eigen::VectorXd y_, r_;               // newest iterate and residual (r_: pushed by push())
  std::vector<Eigen::VectorXd> dy_, dr_;  // rings of differences (pushed by push())
  std::vector<Eigen::VectorXd> e_;      // ring of the last m + 1 residuals (pushed by increments)
  int e_head_ = -1;
  Eigen::MatrixXd gram_;                // dr^T dr by ring slot
  Eigen::VectorXd rhs_;                 // dr^T r_ by ring slot
  std::vector<double> partial_;         // per block: the new Gram row, then the right-hand side
  int head_ = -1;
  Eigen::VectorXd theta_;
  int columns_used_ = 0;
};

}  // namespace pliant::detail
