// SPDX-License-Identifier: Apache-2.0
#include "pliant/strain_constraint.hpp"

#include <Eigen/Dense>
#include <Eigen/SVD>

namespace pliant {

namespace {

// Shear rows 3, 4, 5 couple columns (1,2), (0,2), (0,1) of F.
constexpr int kShearA[3] = {1, 0, 0};
constexpr int kShearB[3] = {2, 2, 1};

// [v]x, the matrix of v x ., and axial(M), the vector of M's skew part: [axial(M)]x = (M - M^T) / 2.
Mat3 cross_matrix(const Vec3& v) {
  Mat3 m;
  m << 0, -v[2], v[1], v[2], 0, -v[0], -v[1], v[0], 0;
  return m;
}

Vec3 axial(const Mat3& M) {
  return 0.5 * Vec3(M(2, 1) - M(1, 2), M(0, 2) - M(2, 0), M(1, 0) - M(0, 1));
}

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

namespace {

// Inversion-aware polar rotation from the SVD (the general case: any F).
Mat3 polar_rotation_svd(const Mat3& F) {
  Eigen::JacobiSVD<Mat3> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 U = svd.matrixU();
  const Mat3 V = svd.matrixV();
  // Singular values come sorted, largest first: flipping U's last column when U V^T would be a
  // reflection negates the smallest one (and makes a rank-2 F's R proper as well).
  if (U.determinant() * V.determinant() < 0) U.col(2) = -U.col(2);
  return U * V.transpose();
}

}  // namespace

Mat3 polar_rotation(const Mat3& F) {
  // For det F > 0: X <- (g X + X^-T / g) / 2 converges quadratically to the rotation, keeping
  // det X > 0 (it acts on the singular values only: s <- (g s + 1 / (g s)) / 2). Roughly 20x
  // cheaper than a Jacobi SVD; inverted and degenerate tets (rare) take the SVD.
  Mat3 X = F;
  for (int it = 0; it < kMaxPolarIterations; ++it) {
    Mat3 cof;  // cofactor matrix: X^-T = cof / det X
    cof.col(0) = X.col(1).cross(X.col(2));
    cof.col(1) = X.col(2).cross(X.col(0));
    cof.col(2) = X.col(0).cross(X.col(1));
    const double det = X.col(0).dot(cof.col(0));
    if (!(det > 0)) break;
    const double nx = X.squaredNorm();
    // Frobenius scaling g = sqrt(|X^-1| / |X|) while far from orthogonal; 1 once close (the
    // unscaled iteration converges quadratically from there and the scaling would only add
    // round-off).
    const double ninv = cof.squaredNorm() / (det * det);
    const double g = std::abs(nx - 3.0) > kPolarScalingBand ? std::sqrt(std::sqrt(ninv / nx)) : 1.0;
    const Mat3 next = 0.5 * (g * X + cof / (g * det));
    const double change = (next - X).squaredNorm();
    X = next;
    if (change < kPolarConverged) return X;  // with the scaled Newton iteration, about 3
    // iterations near rest and under 10 for a condition number of 1e6 (Higham 1986)
  }
  return polar_rotation_svd(F);
}

Vec6 corotated_strain_vector(const Mat3& S) {
  Vec6 c;
  for (int i = 0; i < 3; ++i) c[i] = S(i, i) - 1.0;
  for (int s = 0; s < 3; ++s) c[3 + s] = 2.0 * S(kShearA[s], kShearB[s]);
  return c;
}

Vec6 strain_vector(const Mat3& F, ElasticModel model) {
  if (model != ElasticModel::Corotated) return strain_vector(F);
  return corotated_strain_vector(corotated_stretch(F, polar_rotation(F)));
}

Vec6 strain_constraint(const TetRest& tet, const std::array<Vec3, 4>& x, ElasticModel model) {
  return tet.sqrt_volume * strain_vector(deformation_gradient(tet, x), model);
}

Mat6x12 strain_jacobian(const TetRest& tet, const std::array<Vec3, 4>& x, ElasticModel model) {
  const Mat3 F = deformation_gradient(tet, x);
  const auto b = shape_rows(tet.dm_inv);
  Mat6x12 J;
  if (model == ElasticModel::Corotated) {
    // Row i of c is <E_i, S> (E_i = e_p e_p^T, or e_a e_c^T + e_c e_a^T for a shear), and its
    // gradient in F is R (E_i - 2 [u_i]x), u_i = (tr(S) I - S)^-1 axial(skew(E_i S)): the
    // first term holds R fixed, the second is the rotation's change (docs/solver.md).
    const Mat3 R = polar_rotation(F);
    const Mat3 S = corotated_stretch(F, R);
    const Mat3 Ginv = corotated_rotation_inverse(S);
    for (int i = 0; i < 6; ++i) {
      Mat3 E = Mat3::Zero();
      if (i < 3) E(i, i) = 1;
      else E(kShearA[i - 3], kShearB[i - 3]) = E(kShearB[i - 3], kShearA[i - 3]) = 1;
      const Mat3 D = R * (E - 2.0 * cross_matrix(Ginv * axial(E * S)));
      for (int k = 0; k < 4; ++k) J.block<1, 3>(i, 3 * k) = (D * b[k].transpose()).transpose();
    }
    return tet.sqrt_volume * J;
  }
  // Green strain: d(|f_i|^2 / 2) = f_i . df_i, d(f_a . f_c) = f_c . df_a + f_a . df_c.
  for (int k = 0; k < 4; ++k) {
    for (int i = 0; i < 3; ++i) J.block<1, 3>(i, 3 * k) = (F.col(i) * b[k][i]).transpose();
    for (int s = 0; s < 3; ++s) {
      const int a = kShearA[s], c = kShearB[s];
      J.block<1, 3>(3 + s, 3 * k) = (F.col(c) * b[k][a] + F.col(a) * b[k][c]).transpose();
    }
  }
  return tet.sqrt_volume * J;
}

Mat3 corotated_stretch(const Mat3& F, const Mat3& R) {
  const Mat3 S = R.transpose() * F;
  return 0.5 * (S + S.transpose());
}

Mat3 corotated_rotation_inverse(const Mat3& S) {
  const Mat3 G = S.trace() * Mat3::Identity() - S;
  const double t = G.trace() / 3.0;
  const double det = G.determinant();
  // G's eigenvalues are s_i + s_j (pairs of S's): positive unless the tet is inverted. Near a
  // zero the rotation is ill-defined (R turns by large angles for tiny changes of F): the
  // rotation term is dropped there, leaving R held fixed.
  if (!(det > kRotationConditionLimit * t * t * t)) return Mat3::Zero();
  return G.inverse();
}

double strain_energy(const TetRest& tet, const Mat6& K, const Mat3& F, ElasticModel model) {
  const Vec6 C = tet.sqrt_volume * strain_vector(F, model);
  return 0.5 * C.dot(K * C);
}

double strain_energy(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x, ElasticModel model) {
  return strain_energy(tet, K, deformation_gradient(tet, x), model);
}

namespace {

using Mat9 = Eigen::Matrix<double, 9, 9>;

// First Piola-Kirchhoff stress of the corotated energy density 1/2 c^T K c = mu |S - I|^2 +
// lambda/2 tr(S - I)^2: P = 2 mu (F - R) + lambda tr(S - I) R, and its derivative dP/dF as a
// 9x9 matrix on column-major vec(F). With F = R S and R^T dR = [w]x, the rotation's change
// solves (tr(S) I - S) w = axial(R^T dF - dF^T R).
Mat9 corotated_stress_derivative(const Mat3& F, const Mat3& R, const Lame& lame) {
  const Mat3 S = corotated_stretch(F, R);
  const double tr = S.trace();
  // Zero where the rotation is ill-defined: R held fixed, as in strain_jacobian.
  const Mat3 Ginv = corotated_rotation_inverse(S);
  Mat9 T;
  for (int e = 0; e < 9; ++e) {
    Mat3 dF = Mat3::Zero();
    dF(e % 3, e / 3) = 1.0;
    // axial(R^T dF - dF^T R) = 2 axial(R^T dF), R^T dF - dF^T R being skew.
    const Mat3 dR = R * cross_matrix(Ginv * (2.0 * axial(R.transpose() * dF)));
    const Mat3 dP = 2.0 * lame.mu * (dF - dR) + lame.lambda * (R.transpose() * dF).trace() * R +
                    lame.lambda * (tr - 3.0) * dR;
    T.col(e) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(dP.data());
  }
  return T;
}

}  // namespace

namespace {

// Clamps the negative eigenvalues of a symmetric matrix to zero.
template <int N>
Eigen::Matrix<double, N, N> clamp_to_psd(const Eigen::Matrix<double, N, N>& A) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig(A);
  const Eigen::Matrix<double, N, 1> ev = eig.eigenvalues().cwiseMax(0.0);
  return eig.eigenvectors() * ev.asDiagonal() * eig.eigenvectors().transpose();
}

// The stress term of the StVK Hessian is G = B S B^T, B the four shape-function gradients as
// rows (rank 3) and S the symmetric 3x3 stress matrix of K C (S_ii = KC_i, S_ac = KC_shear).
// With B^T B = L L^T, Q = B L^-T has orthonormal columns and G = Q M Q^T, M = L^T S L: G's
// nonzero eigenpairs are M's, so its projection is Q clamp(M) Q^T = B P B^T with
// P = L^-T clamp(M) L^-1. A closed-form 3x3 eigen solve instead of an iterative 4x4 one;
// nothing to do when M has no negative eigenvalue (a tensile stress).
Eigen::Matrix4d clamp_stress_term_to_psd(const Eigen::Matrix4d& G, const std::array<Eigen::RowVector3d, 4>& b,
                                         const Vec6& KC) {
  Eigen::Matrix<double, 4, 3> B;
  for (int k = 0; k < 4; ++k) B.row(k) = b[k];
  const Eigen::LLT<Mat3> llt(B.transpose() * B);
  if (llt.info() != Eigen::Success) return clamp_to_psd<4>(G);  // a degenerate rest shape
  const Mat3 L = llt.matrixL();
  Mat3 S;
  for (int i = 0; i < 3; ++i) S(i, i) = KC[i];
  for (int s = 0; s < 3; ++s) S(kShearA[s], kShearB[s]) = S(kShearB[s], kShearA[s]) = KC[3 + s];
  Eigen::SelfAdjointEigenSolver<Mat3> eig;
  eig.computeDirect(L.transpose() * S * L);
  if (eig.eigenvalues().minCoeff() >= 0) return G;
  const Mat3 clamped = eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).asDiagonal() *
                       eig.eigenvectors().transpose();
  const Mat3 L_inv = L.triangularView<Eigen::Lower>().solve(Mat3::Identity());
  const Mat3 P = L_inv.transpose() * clamped * L_inv;
  return B * P * B.transpose();
}

// How the Hessian is made positive semi-definite.
enum class Psd { None, Whole, Parts };

// The Green-strain energy's gradient alone, without the Jacobian: row i of J is sqrt(V0) times
// f_i b_k[i] (stretch) or f_c b_k[a] + f_a b_k[c] (shear a-c), so J^T K C gathers into
// dE/dx_k = sqrt(V0) F T b_k^T with T the symmetric matrix of K C's entries (00 11 22 on the
// diagonal, the shears off it): the first Piola-Kirchhoff stress times V0, applied to b_k.
Vec12 green_strain_gradient(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x) {
  const Mat3 F = deformation_gradient(tet, x);
  const Vec6 KC = K * (tet.sqrt_volume * strain_vector(F));
  Mat3 T;
  for (int i = 0; i < 3; ++i) T(i, i) = KC[i];
  for (int s = 0; s < 3; ++s) T(kShearA[s], kShearB[s]) = T(kShearB[s], kShearA[s]) = KC[3 + s];
  const Mat3 P = tet.sqrt_volume * F * T;
  const Mat3 G = P * tet.dm_inv.transpose();  // column k: dE/dx_k for k < 3
  Vec12 g;
  for (int k = 0; k < 3; ++k) g.segment<3>(3 * k) = G.col(k);
  g.segment<3>(9) = -(G.col(0) + G.col(1) + G.col(2));
  return g;
}

void derivatives(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x, Vec12* gradient,
                 Mat12* hessian, Psd psd, ElasticModel model) {
  if (!hessian && model != ElasticModel::Corotated) {
    if (gradient) *gradient = green_strain_gradient(tet, K, x);
    return;
  }
  const Vec6 C = strain_constraint(tet, x, model);
  const Mat6x12 J = strain_jacobian(tet, x, model);
  const Vec6 KC = K * C;
  if (gradient) *gradient = J.transpose() * KC;
  if (!hessian) return;
  const auto b = shape_rows(tet.dm_inv);
  Mat12 H;
  if (model == ElasticModel::Corotated) {
    // H = V0 D^T (dP/dF) D with D = d vec(F) / dx: dF(c, i) / dx_k(c) = b_k[i].
    // K holds the Lame parameters: K(0,1) = lambda, K(3,3) = mu.
    const Lame lame{K(0, 1), K(3, 3)};
    const Mat3 F = deformation_gradient(tet, x);
    Mat9 T = corotated_stress_derivative(F, polar_rotation(F), lame);
    if (psd == Psd::Parts) T = clamp_to_psd<9>(T);
    Eigen::Matrix<double, 9, 12> D = Eigen::Matrix<double, 9, 12>::Zero();
    for (int k = 0; k < 4; ++k)
      for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 3; ++c) D(3 * i + c, 3 * k + c) = b[k][i];
    // lazyProduct: coefficient-based products; Eigen's default sends these fixed sizes through
    // its blocked GEMM, whose packing costs more than the arithmetic here.
    H = tet.volume * D.transpose().lazyProduct(Eigen::Matrix<double, 9, 12>(T.lazyProduct(D)));
  } else {
    H = J.transpose().lazyProduct(Mat6x12(K.lazyProduct(J)));
    // Second derivatives of C: each row is sqrt(V0) times a bilinear form in the b_k, times I3,
    // so the whole term is sqrt(V0) G (x) I3 with G a 4x4 matrix.
    Eigen::Matrix4d G;
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l) {
        double w = 0;
        for (int i = 0; i < 3; ++i) w += KC[i] * b[k][i] * b[l][i];
        for (int s = 0; s < 3; ++s) {
          const int a = kShearA[s], c = kShearB[s];
          w += KC[3 + s] * (b[k][a] * b[l][c] + b[k][c] * b[l][a]);
        }
        G(k, l) = w;
      }
    if (psd == Psd::Parts) G = clamp_stress_term_to_psd(G, b, KC);
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l) H.block<3, 3>(3 * k, 3 * l).diagonal().array() += tet.sqrt_volume * G(k, l);
  }
  if (psd == Psd::Whole) H = clamp_to_psd<12>(H);
  *hessian = H;
}

}  // namespace

void strain_energy_derivatives(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x,
                               Vec12* gradient, Mat12* hessian, bool project_psd, ElasticModel model) {
  derivatives(tet, K, x, gradient, hessian, project_psd ? Psd::Whole : Psd::None, model);
}

void strain_energy_derivatives_psd_parts(const TetRest& tet, const Mat6& K, const std::array<Vec3, 4>& x,
                                         Vec12* gradient, Mat12* hessian, ElasticModel model) {
  derivatives(tet, K, x, gradient, hessian, Psd::Parts, model);
}

double volume_ratio(const TetRest& tet, const std::array<Vec3, 4>& x) {
  return deformation_gradient(tet, x).determinant();
}

}  // namespace pliant
