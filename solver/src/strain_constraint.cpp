#include "pliant/strain_constraint.hpp"

#include <Eigen/Dense>

namespace pliant {

namespace {

// Shear rows 3, 4, 5 couple columns (1,2), (0,2), (0,1) of F.
constexpr int kShearA[3] = {1, 0, 0};
constexpr int kShearB[3] = {2, 2, 1};

// b_k: derivative of F's columns with respect to vertex k is b_k[i] * I (column i).
std::array<Eigen::RowVector3d, 4> shape_rows(const Mat3& B) {
  std::array<Eigen::RowVector3d, 4> b;
  for (int k = 0; k < 3; ++k) b[k] = B.row(k);
  b[3] = -(b[0] + b[1] + b[2]);
  return b;
}

}  // namespace

Mat3 deformation_gradient(const TetRest& tet, const std::array<Vec3, 4>& x) {
  Mat3 ds;
  for (int c = 0; c < 3; ++c) ds.col(c) = x[c] - x[3];
  return ds * tet.dm_inv;
}

Vec6 strain_vector(const Mat3& F) {
  Vec6 c;
  for (int i = 0; i < 3; ++i) c[i] = 0.5 * (F.col(i).squaredNorm() - 1.0);
  for (int s = 0; s < 3; ++s) c[3 + s] = F.col(kShearA[s]).dot(F.col(kShearB[s]));
  return c;
}

Vec6 strain_constraint(const TetRest& tet, const std::array<Vec3, 4>& x) {
  return tet.sqrt_volume * strain_vector(deformation_gradient(tet, x));
}

Mat6x12 strain_jacobian(const TetRest& tet, const std::array<Vec3, 4>& x) {
  const Mat3 F = deformation_gradient(tet, x);
  const auto b = shape_rows(tet.dm_inv);
  Mat6x12 J;
  for (int k = 0; k < 4; ++k) {
    for (int i = 0; i < 3; ++i) J.block<1, 3>(i, 3 * k) = (F.col(i) * b[k][i]).transpose();
    for (int s = 0; s < 3; ++s) {
      const int a = kShearA[s], c = kShearB[s];
      J.block<1, 3>(3 + s, 3 * k) = (F.col(c) * b[k][a] + F.col(a) * b[k][c]).transpose();
    }
  }
  return tet.sqrt_volume * J;
}

double strain_energy(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x) {
  const Vec6 C = strain_constraint(tet, x);
  return 0.5 * C.dot(K * C);
}

void strain_energy_derivatives(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x,
                               Vec12* gradient, Mat12* hessian, bool project_psd) {
  const Vec6 C = strain_constraint(tet, x);
  const Mat6x12 J = strain_jacobian(tet, x);
  const Vec6 KC = K * C;
  if (gradient) *gradient = J.transpose() * KC;
  if (!hessian) return;
  Mat12 H = J.transpose() * K * J;
  // Second derivatives of C: each row is sqrt(V0) times a bilinear form in the b_k, times I3.
  const auto b = shape_rows(tet.dm_inv);
  for (int k = 0; k < 4; ++k)
    for (int l = 0; l < 4; ++l) {
      double w = 0;
      for (int i = 0; i < 3; ++i) w += KC[i] * b[k][i] * b[l][i];
      for (int s = 0; s < 3; ++s) {
        const int a = kShearA[s], c = kShearB[s];
        w += KC[3 + s] * (b[k][a] * b[l][c] + b[k][c] * b[l][a]);
      }
      H.block<3, 3>(3 * k, 3 * l).diagonal().array() += tet.sqrt_volume * w;
    }
  if (project_psd) {
    Eigen::SelfAdjointEigenSolver<Mat12> eig(H);
    Vec12 ev = eig.eigenvalues().cwiseMax(0.0);
    H = eig.eigenvectors() * ev.asDiagonal() * eig.eigenvectors().transpose();
  }
  *hessian = H;
}

double volume_ratio(const TetRest& tet, const std::array<Vec3, 4>& x) {
  return deformation_gradient(tet, x).determinant();
}

}  // namespace pliant
