// SPDX-License-Identifier: Apache-2.0
#include "accelerators/accelerators.hpp"

#include <Eigen/Dense>

#include <cmath>

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
class MultiplierAcceleration final : public Accelerator {
 public:
  enum class Form { Thesis, TypeII, Extrapolation };
  MultiplierAcceleration(const SolverSettings& s, Form form, double omega)
      : form_(form), omega_(omega), window_(s.window),
        mixer_(s.window, s.condition_limit, form == Form::TypeII ? omega : 0.0) {}
  void begin_substep(size_t, size_t tets) override {
    mixer_.reset(6 * tets);
    increment_.resize(tets);
    prev_d_.setZero(6 * Eigen::Index(tets));
    pushes_ = 0;
  }
  bool after_sweep(SweepResult& it, AcceleratorServices& services) override {
    const auto d = flat(it.dlambda);
    bool ready = false;
    switch (form_) {
      case Form::Thesis:
        if (pushes_ > 0) {
          e_.noalias() = d - prev_d_;
          mixer_.push(d, e_);
        }
        prev_d_ = d;
        ready = mixer_.ready();
        break;
      case Form::TypeII:
        e_.noalias() = flat(it.lambda) - d;  // the iterate the sweep started from
        mixer_.push(e_, d);
        ready = mixer_.ready();
        break;
      case Form::Extrapolation:
        ready = pushes_ >= window_ + 1;  // same start as the Anderson forms
        break;
    }
    ++pushes_;
    if (!ready) return false;
    auto inc = flat(increment_);
    switch (form_) {
      case Form::Thesis:
        services.report->anderson_columns_dropped += mixer_.accelerate(aa_);
        inc = omega_ * aa_;
        break;
      case Form::TypeII:
        services.report->anderson_columns_dropped += mixer_.accelerate(aa_);
        inc = aa_ - flat(it.lambda);
        break;
      case Form::Extrapolation:
        inc = omega_ * d;
        break;
    }
    flat(it.lambda) += inc;
    services.apply_increment(increment_);
    return true;
  }

 private:
  Form form_;
  double omega_;
  int window_;
  AndersonMixer mixer_;
  Eigen::VectorXd aa_, prev_d_, e_;
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

// ---------------------------------------------------------------------------------------------

AndersonMixer::AndersonMixer(int window, double condition_limit, double beta)
    : m_(window), condition_limit_(condition_limit), beta_(beta) {}

void AndersonMixer::reset(size_t size) {
  count_ = 0;
  head_ = -1;
  y_.setZero(Eigen::Index(size));
  r_.setZero(Eigen::Index(size));
  dy_.assign(m_, Eigen::VectorXd::Zero(Eigen::Index(size)));
  dr_.assign(m_, Eigen::VectorXd::Zero(Eigen::Index(size)));
  gram_.setZero(m_, m_);
  theta_.resize(0);
  columns_used_ = 0;
}

void AndersonMixer::push(const Eigen::Ref<const Eigen::VectorXd>& y, const Eigen::Ref<const Eigen::VectorXd>& r) {
  if (count_ > 0) {
    head_ = (head_ + 1) % m_;
    dy_[head_] = y - y_;
    dr_[head_] = r - r_;
    for (int j = 0; j < m_; ++j) gram_(head_, j) = gram_(j, head_) = dr_[head_].dot(dr_[j]);
  }
  y_ = y;
  r_ = r;
  ++count_;
}

int AndersonMixer::accelerate(Eigen::VectorXd& out) {
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
  for (int a = 0; a < cols; ++a) rhs[a] = dr_[slot(a)].dot(r_);
  Eigen::VectorXd theta = Eigen::CompleteOrthogonalDecomposition<Eigen::MatrixXd>(A).solve(rhs);
  if (beta_ != 0) out.noalias() = y_ + beta_ * r_;
  else out = y_;
  if (!theta.allFinite()) return dropped;
  for (int a = 0; a < cols; ++a) {
    out.noalias() -= theta[a] * dy_[slot(a)];
    if (beta_ != 0) out.noalias() -= (theta[a] * beta_) * dr_[slot(a)];
    theta_[a] = theta[a];
  }
  columns_used_ = cols;
  return dropped;
}

}  // namespace pliant::detail
