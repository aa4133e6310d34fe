// SPDX-License-Identifier: Apache-2.0
// A two-level preconditioner for CG on the Newton step's Hessian of a large body: the inverses of
// its 3x3 vertex blocks (which damp the stiff, local error) plus a coarse correction that solves
// the same system restricted to piecewise rigid motions of aggregates of neighbouring vertices
// (which carries the slow, global error: a body's sag, which block-Jacobi CG barely moves at a
// forcing term of one half). Additive form, symmetric positive definite:
//   z = B r + P (P^T H P)^-1 P^T r,
// B the block inverses, P the aggregates' rigid modes (3 translations and 3 infinitesimal
// rotations about each aggregate's centroid, translations only for aggregates of fewer than 4
// vertices). Aggregates are built once per model from the Hessian's block graph (greedy: a vertex
// whose neighbours are all free of an aggregate founds one with them; the rest join a neighbour's),
// repeated `rounds` times on the graph of aggregates. The coarse matrix is assembled block by block
// from H's 3x3 blocks into a pattern and symbolic factorisation fixed per model.
#pragma once

#include "pliant/mesh.hpp"

#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>

#include <cstdint>
#include <vector>

namespace pliant::detail {

// The inverse of a 3x3 diagonal block of the Hessian, or of its diagonal where the block is not
// positive definite (as the exact Hessian's may not be).
Eigen::Matrix3d invert_block(const Eigen::Matrix3d& b);

class TwoLevelPreconditioner {
 public:
  // The Hessian's block graph: block column q holds the 3x3 blocks of block rows
  // block_row[block_begin[q] ..] (q itself included); `position` per block (the rotations are
  // taken about the aggregates' centroids of these). Clears any refreshed state.
  void build(const std::vector<int32_t>& block_begin, const std::vector<int32_t>& block_row,
             const std::vector<Vec3>& position, int rounds);
  // The block inverses for H (stored with both triangles in full 3x3 blocks on build's graph).
  void update_blocks(const Eigen::SparseMatrix<double>& H);
  // The coarse operator P^T H P and its factorisation. False when it is not positive definite
  // (apply() is then block Jacobi alone).
  bool refresh_coarse(const Eigen::SparseMatrix<double>& H);
  // z = M^-1 r.
  void apply(const Eigen::VectorXd& r, Eigen::VectorXd& z) const;

  int aggregates() const { return int(agg_first_.size()); }
  int coarse_dofs() const { return coarse_dofs_; }

 private:
  std::vector<int32_t> block_begin_, block_row_;
  std::vector<int32_t> aggregate_;  // per block: its aggregate
  std::vector<int32_t> agg_first_;  // per aggregate: its first coarse dof
  std::vector<int8_t> agg_modes_;   // per aggregate: 3 or 6
  int coarse_dofs_ = 0;
  // Per block of H (index into block_row): the offset of its row aggregate's rows within each
  // column of its column aggregate in coarse_ (all columns of an aggregate share one pattern).
  std::vector<int32_t> block_target_;
  // Per block: its lever arm about its aggregate's centroid over the aggregate's radius.
  std::vector<Vec3> arm_;
  Eigen::SparseMatrix<double> coarse_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> coarse_solver_;
  bool analysed_ = false, coarse_ok_ = false;
  std::vector<Eigen::Matrix3d> block_inverse_;
  mutable Eigen::VectorXd coarse_r_, coarse_z_;
};

}  // namespace pliant::detail
