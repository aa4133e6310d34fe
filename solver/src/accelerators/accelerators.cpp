// SPDX-License-Identifier: Apache-2.0
#include "accelerators/accelerators.hpp"

#include <Eigen/Dense>

#include <cmath>
#include <cstring>
#include <stdexcept>

namespace pliant::detail {

namespace {

using VecMap = Eigen::Map<Eigen::VectorXd>;
using ConstVecMap = Eigen::Map<const Eigen::VectorXd>;

ConstVecMap flat(const std::vector<Vec6>& v) { return ConstVecMap(v.data()->data(), 6 * Eigen::Index(v.size())); }
VecMap flat(std::vector<Vec6>& v) { return VecMap(v.data()->data(), 6 * Eigen::Index(v.size())); }

class NoAcceleration final : public Accelerator {
 public:
  bool after_sweep(SweepResult&, AcceleratorServices&) override { return false; }
};

// Over-relaxation of the positions between sweeps: x <- x_prev + omega (x_sweep - x_prev).
class PositionSor final : public Accelerator {
 public:
  explicit PositionSor(double omega) : omega_(omega) {}
  bool needs_previous() const override { return true; }
  bool after_sweep(SweepResult& it, AcceleratorServices&) override {
    for (size_t i = 0; i < it.x.size(); ++i) it.x[i] = it.x_before[i] + omega_ * (it.x[i] - it.x_before[i]);
    return false;
  }

 private:
  double omega_;
};

// Over-relaxation of every projection's multiplier increment, inside the sweep.
class LambdaSor final : public Accelerator {
 public:
  explicit LambdaSor(double omega) : omega_(omega) {}
  double increment_scale() const override { return omega_; }
  bool after_sweep(SweepResult&, AcceleratorServices&) override { return false; }

 private:
  double omega_;
};

// Chebyshev semi-iterative acceleration of the positions (Wang 2015):
// x_{k+1} = w_{k+1} (gamma (x^_{k+1} - x_k) + x_k - x_{k-1}) + x_{k-1}, with w = 1 for the first
// `delay` iterations, then w = 2 / (2 - rho^2), then w = 4 / (4 - rho^2 w).
class Chebyshev final : public Accelerator {
 public:
  explicit Chebyshev(const ChebyshevParams& p) : p_(p) {}
  bool needs_previous() const override { return true; }
  void begin_substep(size_t vertices, size_t) override {
    prev_.assign(vertices, Vec3::Zero());
    omega_ = 1.0;
  }
  bool after_sweep(SweepResult& it, AcceleratorServices&) override {
    const int k = it.iteration;
    if (k < p_.delay) omega_ = 1.0;
    else if (k == p_.delay) omega_ = 2.0 / (2.0 - p_.rho * p_.rho);
    else omega_ = 4.0 / (4.0 - p_.rho * p_.rho * omega_);
    for (size_t i = 0; i < it.x.size(); ++i) {
      const Vec3 xk = it.x_before[i];
      const Vec3 xkm1 = k == 0 ? xk : prev_[i];
      it.x[i] = omega_ * (p_.gamma * (it.x[i] - xk) + xk - xkm1) + xkm1;
      prev_[i] = xk;
    }
    return false;
  }

 private:
  ChebyshevParams p_;
  std::vector<Vec3> prev_;
  double omega_ = 1.0;
};

// Accelerated multiplier increments, proposed once the window is full and kept only if the
// residual decreases (thesis algorithm 2.4). Three forms share the loop:
//  - Thesis: Anderson on the sequence of increments D_k with residual e_k = D_k - D_{k-1}
//    (eq. 2.11-2.15); the proposal is omega * (D_k - sum_j theta_j e_{k-j+1}) on top of lambda.
//  - TypeII: textbook Anderson on the fixed-point map lambda -> lambda + D(lambda) with mixing
//    beta = omega: lambda_new = lambda_in - dX theta + omega (D_k - dD theta).
//  - Extrapolation: theta = 0 in the thesis form, i.e. omega * D_k (what Anderson adds over it
//    is what this baseline measures).
// The vector work runs by the mixer's blocks on the step's threads.
class MultiplierAcceleration final : public Accelerator {
 public:
  enum class Form { Thesis, TypeII, Extrapolation };
  MultiplierAcceleration(const SolverSettings& s, Form form, double omega)
      : form_(form), omega_(omega), window_(s.window),
        mixer_(s.window, s.condition_limit, form == Form::TypeII ? omega : 0.0) {}
  bool needs_increments() const override { return true; }
  void begin_substep(size_t, size_t tets) override {
    mixer_.reset(6 * tets);
    increment_.resize(tets);
    pushes_ = 0;
  }
  bool after_sweep(SweepResult& it, AcceleratorServices& services) override {
    const double* d = it.dlambda.data()->data();
    const double* lambda = it.lambda.data()->data();
    double* proposed = it.lambda_proposed->data()->data();
    const AndersonMixer::ParallelFor& parallel = services.parallel_for;
    bool ready = false;
    switch (form_) {
      case Form::Thesis:
        if (pushes_ == 0) mixer_.seed(d);
        else mixer_.push_increment(d, parallel);
        ready = mixer_.ready();
        break;
      case Form::TypeII:
        e_.noalias() = flat(it.lambda) - flat(it.dlambda);  // the iterate the sweep started from
        mixer_.push(e_.data(), d, parallel);
        ready = mixer_.ready();
        break;
      case Form::Extrapolation:
        ready = pushes_ >= window_ + 1;  // same start as the Anderson forms
        break;
    }
    ++pushes_;
    if (!ready) return false;
    if (form_ != Form::Extrapolation) services.report->anderson_columns_dropped += mixer_.solve();
    double* inc = increment_.data()->data();
    const size_t n = mixer_.size();
    // The increment and the new multipliers, block by block while the block is in cache.
    auto blocks = [&](size_t b0, size_t b1) {
      const size_t i0 = b0 * AndersonMixer::kBlock, i1 = std::min(n, b1 * AndersonMixer::kBlock);
      switch (form_) {
        case Form::Thesis:
          mixer_.mixed(i0, i1, inc + i0);
          for (size_t i = i0; i < i1; ++i) inc[i] *= omega_;
          break;
        case Form::TypeII:
          mixer_.mixed(i0, i1, inc + i0);
          for (size_t i = i0; i < i1; ++i) inc[i] -= lambda[i];
          break;
        case Form::Extrapolation:
          for (size_t i = i0; i < i1; ++i) inc[i] = omega_ * d[i];
          break;
      }
      for (size_t i = i0; i < i1; ++i) proposed[i] = lambda[i] + inc[i];
    };
    if (parallel) parallel(mixer_.blocks(), blocks);
    else blocks(0, mixer_.blocks());
    services.apply_increment(increment_);
    return true;
  }

 private:
  Form form_;
  double omega_;
  int window_;
  AndersonMixer mixer_;
  Eigen::VectorXd e_;
  std::vector<Vec6> increment_;
  int pushes_ = 0;
};

}  // namespace

std::unique_ptr<Accelerator> make_accelerator(const SolverSettings& s) {
  switch (s.method) {
    case Method::Xpbd: return std::make_unique<NoAcceleration>();
    case Method::Sor: return std::make_unique<PositionSor>(s.omega);
    case Method::LambdaSor: return std::make_unique<LambdaSor>(s.omega);
    case Method::Chebyshev: return std::make_unique<Chebyshev>(s.chebyshev);
    case Method::Anderson:
    case Method::AndersonSor: {
      using F = MultiplierAcceleration::Form;
      const F form = s.anderson_form == AndersonForm::TypeII ? F::TypeII : F::Thesis;
      return std::make_unique<MultiplierAcceleration>(s, form, s.method == Method::Anderson ? 1.0 : s.omega);
    }
    case Method::Extrapolation:
      return std::make_unique<MultiplierAcceleration>(s, MultiplierAcceleration::Form::Extrapolation, s.omega);
    case Method::Vbd:
    case Method::Newton:
    case Method::Auto:
      break;  // not projection methods: the step never asks for their accelerator
  }
  return std::make_unique<NoAcceleration>();
}

AcceleratorKey accelerator_key(const SolverSettings& s) {
  return {s.method, s.anderson_form, s.omega, s.window, s.condition_limit, s.chebyshev.rho, s.chebyshev.gamma,
          s.chebyshev.delay};
}

// ---------------------------------------------------------------------------------------------

AndersonMixer::AndersonMixer(int window, double condition_limit, double beta)
    : m_(window), condition_limit_(condition_limit), beta_(beta) {}

void AndersonMixer::reset(size_t size) {
  count_ = 0;
  head_ = -1;
  e_head_ = -1;
  if (size_ != size) {
    size_ = size;
    y_.resize(Eigen::Index(size));
    r_.resize(0);  // each kind of push sizes its own storage at its first push
    dy_.clear();
    dr_.clear();
    e_.clear();
  }
  // Only columns already pushed are read (slot(a) for a < the count of differences).
  gram_.setZero(m_, m_);
  rhs_.setZero(m_);
  theta_.resize(0);
  columns_used_ = 0;
}

void AndersonMixer::seed(const double* y) { std::copy(y, y + size_, y_.data()); }

void AndersonMixer::push(const double* y, const double* r, const ParallelFor& parallel) { push_impl(y, r, parallel); }

void AndersonMixer::push_increment(const double* y, const ParallelFor& parallel) { push_impl(y, nullptr, parallel); }

namespace {

// Sixteen running sums (four 4-lane vectors: one chain of additions would wait on its latency)
// in a fixed order, so a block's sum never depends on who computes it.
double block_dot(const double* a, const double* b, size_t n) {
  typedef double D4 __attribute__((vector_size(32)));
  auto load = [](const double* p) {
    D4 v;
    std::memcpy(&v, p, sizeof v);
    return v;
  };
  D4 s0 = {0, 0, 0, 0}, s1 = s0, s2 = s0, s3 = s0;
  size_t i = 0;
  for (; i + 16 <= n; i += 16) {
    s0 += load(a + i) * load(b + i);
    s1 += load(a + i + 4) * load(b + i + 4);
    s2 += load(a + i + 8) * load(b + i + 8);
    s3 += load(a + i + 12) * load(b + i + 12);
  }
  const D4 s = (s0 + s1) + (s2 + s3);
  double sum = (s[0] + s[1]) + (s[2] + s[3]);
  for (; i < n; ++i) sum += a[i] * b[i];
  return sum;
}

}  // namespace

void AndersonMixer::push_impl(const double* y, const double* r, const ParallelFor& parallel) {
  if (count_ == 0) {
    increments_ = r == nullptr;
    const Eigen::Index n = Eigen::Index(size_);
    if (increments_ && e_.size() != size_t(m_ + 1)) e_.assign(m_ + 1, Eigen::VectorXd(n));
    if (!increments_ && dy_.size() != size_t(m_)) {
      r_.resize(n);
      dy_.assign(m_, Eigen::VectorXd(n));
      dr_.assign(m_, Eigen::VectorXd(n));
    }
  } else if (increments_ != (r == nullptr)) {
    throw std::logic_error("AndersonMixer: a sequence is pushed by push() or by push_increment(), not both");
  }
  if (increments_) {
    push_increment_impl(y, parallel);
    return;
  }
  const bool differences = count_ > 0;
  const int h = differences ? (head_ + 1) % m_ : 0;
  // Columns after this push, newest (slot h) first.
  const int columns = differences ? std::min<int>(m_, int(count_)) : 0;
  auto column_slot = [&](int a) { return ((h - a) % m_ + m_) % m_; };
  const size_t nb = blocks(), stride = 2 * size_t(m_);
  partial_.resize(nb * stride);
  auto work = [&](size_t b0, size_t b1) {
    for (size_t blk = b0; blk < b1; ++blk) {
      const size_t i0 = blk * kBlock, n = std::min(kBlock, size_ - i0);
      double* yp = y_.data() + i0;
      double* rp = r_.data() + i0;
      const double* yn = y + i0;
      if (!differences) {
        for (size_t i = 0; i < n; ++i) {
          rp[i] = r ? r[i0 + i] : yn[i] - yp[i];
          yp[i] = yn[i];
        }
        continue;
      }
      double* dyh = dy_[h].data() + i0;
      double* drh = dr_[h].data() + i0;
      for (size_t i = 0; i < n; ++i) {
        const double dy = yn[i] - yp[i];
        const double rn = r ? r[i0 + i] : dy;
        dyh[i] = dy;
        drh[i] = rn - rp[i];
        yp[i] = yn[i];
        rp[i] = rn;
      }
      double* out = partial_.data() + blk * stride;
      for (int a = 0; a < columns; ++a) {
        const double* dj = dr_[column_slot(a)].data() + i0;
        out[a] = block_dot(drh, dj, n);
        out[m_ + a] = block_dot(dj, rp, n);
      }
    }
  };
  if (parallel && nb > 1) parallel(nb, work);
  else work(0, nb);
  end_push(differences, h, columns);
}

// push_impl by increments: the residual is the iterate's change, kept in the ring of m + 1; the
// new dR column and the older ones are formed block by block from consecutive residuals (the
// same subtractions push() stores), then dotted as push() dots its stored columns.
void AndersonMixer::push_increment_impl(const double* y, const ParallelFor& parallel) {
  const bool differences = count_ > 0;
  const int h = differences ? (head_ + 1) % m_ : 0;
  const int columns = differences ? std::min<int>(m_, int(count_)) : 0;
  e_head_ = (e_head_ + 1) % (m_ + 1);  // this push's residual: residual_slot(0)
  const size_t nb = blocks(), stride = 2 * size_t(m_);
  partial_.resize(nb * stride);
  auto work = [&](size_t b0, size_t b1) {
    double drh[kBlock], dj[kBlock];
    for (size_t blk = b0; blk < b1; ++blk) {
      const size_t i0 = blk * kBlock, n = std::min(kBlock, size_ - i0);
      double* yp = y_.data() + i0;
      double* en = e_[size_t(residual_slot(0))].data() + i0;
      const double* yn = y + i0;
      if (!differences) {
        for (size_t i = 0; i < n; ++i) {
          en[i] = yn[i] - yp[i];
          yp[i] = yn[i];
        }
        continue;
      }
      const double* ep = e_[size_t(residual_slot(1))].data() + i0;
      for (size_t i = 0; i < n; ++i) {
        const double dy = yn[i] - yp[i];
        en[i] = dy;
        drh[i] = dy - ep[i];
        yp[i] = yn[i];
      }
      double* out = partial_.data() + blk * stride;
      for (int a = 0; a < columns; ++a) {
        const double* column = drh;
        if (a > 0) {
          const double* e0 = e_[size_t(residual_slot(a))].data() + i0;
          const double* e1 = e_[size_t(residual_slot(a + 1))].data() + i0;
          for (size_t i = 0; i < n; ++i) dj[i] = e0[i] - e1[i];
          column = dj;
        }
        out[a] = block_dot(drh, column, n);
        out[m_ + a] = block_dot(column, en, n);
      }
    }
  };
  if (parallel && nb > 1) parallel(nb, work);
  else work(0, nb);
  end_push(differences, h, columns);
}

// A push's end: the blocks' partial sums added in block order into the new Gram row and the
// right-hand side (the new column in ring slot h).
void AndersonMixer::end_push(bool differences, int h, int columns) {
  if (differences) {
    const size_t nb = blocks(), stride = 2 * size_t(m_);
    head_ = h;
    for (int a = 0; a < columns; ++a) {
      double g = 0, q = 0;
      for (size_t blk = 0; blk < nb; ++blk) {
        g += partial_[blk * stride + a];
        q += partial_[blk * stride + m_ + a];
      }
      gram_(h, slot(a)) = gram_(slot(a), h) = g;
      rhs_[slot(a)] = q;
    }
  }
  ++count_;
}

int AndersonMixer::solve() {
  theta_.setZero(m_);
  columns_used_ = 0;
  int cols = std::min<int>(m_, int(count_) - 1);
  int dropped = 0;
  Eigen::MatrixXd A;
  for (;;) {
    A.resize(cols, cols);
    for (int a = 0; a < cols; ++a)
      for (int b = 0; b < cols; ++b) A(a, b) = gram_(slot(a), slot(b));
    if (cols <= 2) break;
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(A, Eigen::EigenvaluesOnly);
    const double lo = eig.eigenvalues().minCoeff(), hi = eig.eigenvalues().maxCoeff();
    if (lo > 0 && hi / lo <= condition_limit_) break;
    --cols;  // the oldest column goes
    ++dropped;
  }
  Eigen::VectorXd rhs(cols);
  for (int a = 0; a < cols; ++a) rhs[a] = rhs_[slot(a)];
  const Eigen::VectorXd theta = Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>(A).solve(rhs);
  if (!theta.allFinite()) return dropped;  // the plain iterate (theta = 0)
  theta_.head(cols) = theta;
  columns_used_ = cols;
  return dropped;
}

void AndersonMixer::mixed(size_t begin, size_t end, double* out) const {
  const size_t n = end - begin;
  const double* yp = y_.data() + begin;
  const double* rp = (increments_ ? e_[size_t(residual_slot(0))].data() : r_.data()) + begin;
  if (beta_ != 0)
    for (size_t i = 0; i < n; ++i) out[i] = yp[i] + beta_ * rp[i];
  else
    std::copy(yp, yp + n, out);
  for (int a = 0; a < columns_used_; ++a) {
    const double t = theta_[a], tb = theta_[a] * beta_;
    // By increments dY's column is a residual and dR's the difference with the one before.
    const double* dy = (increments_ ? e_[size_t(residual_slot(a))] : dy_[size_t(slot(a))]).data() + begin;
    for (size_t i = 0; i < n; ++i) out[i] -= t * dy[i];
    if (beta_ == 0) continue;
    if (increments_) {
      const double* older = e_[size_t(residual_slot(a + 1))].data() + begin;
      for (size_t i = 0; i < n; ++i) out[i] -= tb * (dy[i] - older[i]);
    } else {
      const double* dr = dr_[size_t(slot(a))].data() + begin;
      for (size_t i = 0; i < n; ++i) out[i] -= tb * dr[i];
    }
  }
}

int AndersonMixer::accelerate(Eigen::VectorXd& out) {
  const int dropped = solve();
  out.resize(Eigen::Index(size_));
  mixed(0, size_, out.data());
  return dropped;
}

}  // namespace pliant::detail
