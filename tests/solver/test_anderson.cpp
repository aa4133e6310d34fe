// SPDX-License-Identifier: Apache-2.0
// The Anderson mixer on problems with known answers: type II on a linear contraction reaches
// the fixed point far faster than the plain iteration; the condition-number safeguard drops
// columns of a degenerate history.
#include "accelerators/accelerators.hpp"

#include <Eigen/Dense>
#include <gtest/gtest.h>

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
