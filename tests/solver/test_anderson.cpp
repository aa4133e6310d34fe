// SPDX-License-Identifier: Apache-2.0
// The Anderson mixer on problems with known answers: type II on a linear contraction reaches
// the fixed point far faster than the plain iteration; the condition-number safeguard drops
// columns of a degenerate history.
#include "accelerators/accelerators.hpp"

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include <cstring>
#include <functional>
#include <random>

using namespace pliant;
using detail::AndersonMixer;

namespace {

// x -> G x + b with a symmetric G of spectral radius 0.95.
struct LinearMap {
  Eigen::MatrixXd G;
  Eigen::VectorXd b, fixed_point;
  explicit LinearMap(int n) {
    std::mt19937 rng(11);
    std::normal_distribution<double> g;
    Eigen::MatrixXd R(n, n);
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) R(i, j) = g(rng);
    Eigen::HouseholderQR<Eigen::MatrixXd> qr(R);
    Eigen::MatrixXd Q = qr.householderQ();
    Eigen::VectorXd ev = Eigen::VectorXd::LinSpaced(n, -0.5, 0.95);
    G = Q * ev.asDiagonal() * Q.transpose();
    b = Eigen::VectorXd::Ones(n);
    fixed_point = (Eigen::MatrixXd::Identity(n, n) - G).lu().solve(b);
  }
  Eigen::VectorXd operator()(const Eigen::VectorXd& x) const { return G * x + b; }
};

}  // namespace

TEST(AndersonMixer, TypeTwoAcceleratesALinearFixedPointIteration) {
  const int n = 30;
  LinearMap g(n);
  Eigen::VectorXd plain = Eigen::VectorXd::Zero(n), x = plain;
  AndersonMixer mixer(5, 1e12, 1.0);
  mixer.reset(n);
  Eigen::VectorXd out;
  for (int k = 0; k < 40; ++k) {
    plain = g(plain);
    const Eigen::VectorXd gx = g(x);
    mixer.push(x, gx - x);  // iterate and its residual
    if (mixer.ready()) {
      mixer.accelerate(out);
      x = out;
    } else {
      x = gx;
    }
  }
  const double plain_err = (plain - g.fixed_point).norm(), aa_err = (x - g.fixed_point).norm();
  EXPECT_LT(aa_err, 1e-2 * plain_err) << "plain " << plain_err << " anderson " << aa_err;
}

TEST(AndersonMixer, DropsColumnsOfADegenerateHistory) {
  // Residual differences all along one direction: dR^T dR has rank 1, so the safeguard must
  // drop the oldest columns down to two.
  const int n = 10;
  AndersonMixer mixer(5, 1e3, 0.0);
  mixer.reset(n);
  Eigen::VectorXd dir = Eigen::VectorXd::LinSpaced(n, 1, 2);
  for (int k = 0; k < 7; ++k) mixer.push(Eigen::VectorXd::Constant(n, k), std::pow(0.5, k) * dir);
  ASSERT_TRUE(mixer.ready());
  Eigen::VectorXd out;
  EXPECT_EQ(mixer.accelerate(out), 3);
  EXPECT_EQ(mixer.columns_used(), 2);
  EXPECT_TRUE(out.allFinite());
}

TEST(AndersonMixer, WaitsForAFullWindow) {
  AndersonMixer mixer(4, 1e3, 1.0);
  mixer.reset(3);
  for (int k = 0; k < 4; ++k) {
    EXPECT_FALSE(mixer.ready());
    mixer.push(Eigen::VectorXd::Constant(3, k), Eigen::VectorXd::Constant(3, 1.0 / (k + 1)));
  }
  EXPECT_FALSE(mixer.ready());
  mixer.push(Eigen::VectorXd::Constant(3, 9), Eigen::VectorXd::Constant(3, 0.1));
  EXPECT_TRUE(mixer.ready());
}

namespace {

// Pushes the same history of `size`-entry vectors into a mixer and returns its mixed iterate.
Eigen::VectorXd mix_history(const std::vector<Eigen::VectorXd>& ys, const std::vector<Eigen::VectorXd>& rs,
                            double beta, const AndersonMixer::ParallelFor& parallel) {
  AndersonMixer mixer(4, 1e12, beta);
  mixer.reset(size_t(ys[0].size()));
  for (size_t k = 0; k < ys.size(); ++k) mixer.push(ys[k].data(), rs[k].data(), parallel);
  Eigen::VectorXd out;
  mixer.accelerate(out);
  return out;
}

}  // namespace

TEST(AndersonMixer, MatchesTheLeastSquaresMixAndDoesNotDependOnHowBlocksAreShared) {
  // Three whole blocks and a partial one; seven pushes fill a window of four.
  const int n = int(3 * AndersonMixer::kBlock + 77);
  std::mt19937 rng(5);
  std::normal_distribution<double> g;
  std::vector<Eigen::VectorXd> ys, rs;
  for (int k = 0; k < 7; ++k) {
    ys.push_back(Eigen::VectorXd::NullaryExpr(n, [&] { return g(rng); }));
    rs.push_back(Eigen::VectorXd::NullaryExpr(n, [&] { return std::pow(0.7, k) * g(rng); }));
  }
  const double beta = 0.5;
  // The textbook mix with the last four differences as explicit matrices.
  Eigen::MatrixXd dY(n, 4), dR(n, 4);
  for (int a = 0; a < 4; ++a) {
    dY.col(a) = ys[6 - a] - ys[5 - a];
    dR.col(a) = rs[6 - a] - rs[5 - a];
  }
  const Eigen::VectorXd theta = dR.colPivHouseholderQr().solve(rs[6]);
  const Eigen::VectorXd expected = ys[6] - dY * theta + beta * (rs[6] - dR * theta);

  const Eigen::VectorXd serial = mix_history(ys, rs, beta, {});
  EXPECT_LT((serial - expected).norm(), 1e-9 * expected.norm());
  // Blocks handed out one at a time, last first: the same bits.
  const Eigen::VectorXd shuffled = mix_history(ys, rs, beta, [](size_t blocks, const std::function<void(size_t, size_t)>& fn) {
    for (size_t b = blocks; b-- > 0;) fn(b, b + 1);
  });
  EXPECT_EQ(0, std::memcmp(serial.data(), shuffled.data(), sizeof(double) * size_t(n)));
}

TEST(AndersonMixer, AnIncrementPushIsAPushOfTheIteratesChange) {
  // Pushed by increments the mixer keeps only the last residuals and forms the dR columns from
  // them: the same bits as push() with the change as residual, with and without the beta term,
  // over pushes that wrap its rings twice.
  const int n = 5000;
  for (double beta : {0.0, 0.5}) {
    std::mt19937 rng(8);
    std::normal_distribution<double> g;
    AndersonMixer by_increment(3, 1e12, beta), explicit_residual(3, 1e12, beta);
    by_increment.reset(n);
    explicit_residual.reset(n);
    Eigen::VectorXd previous = Eigen::VectorXd::NullaryExpr(n, [&] { return g(rng); });
    by_increment.seed(previous.data());
    for (int k = 0; k < 9; ++k) {
      const Eigen::VectorXd y = Eigen::VectorXd::NullaryExpr(n, [&] { return std::pow(0.8, k) * g(rng); });
      const Eigen::VectorXd r = y - previous;
      by_increment.push_increment(y.data());
      explicit_residual.push(y, r);
      previous = y;
      if (!by_increment.ready()) continue;
      Eigen::VectorXd a, b;
      by_increment.accelerate(a);
      explicit_residual.accelerate(b);
      ASSERT_EQ(by_increment.columns_used(), explicit_residual.columns_used());
      EXPECT_EQ(0, std::memcmp(a.data(), b.data(), sizeof(double) * size_t(n))) << "beta " << beta << " push " << k;
    }
    // A sequence is pushed one way.
    EXPECT_THROW(by_increment.push(previous, previous), std::logic_error);
    EXPECT_THROW(explicit_residual.push_increment(previous.data()), std::logic_error);
  }
}
