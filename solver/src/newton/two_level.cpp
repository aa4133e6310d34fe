// SPDX-License-Identifier: Apache-2.0
#include "newton/two_level.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

namespace pliant::detail {

namespace {

// Greedy aggregation of a graph (node i's neighbours: row[begin[i] .. begin[i + 1]], itself
// included): a node whose neighbours all have no aggregate founds one with them; then each node
// left joins the aggregate most of its neighbours belong to; a node with no aggregated neighbour
// founds one with its unaggregated neighbours. Returns the aggregate of each node.
std::vector<int32_t> aggregate_graph(const std::vector<int32_t>& begin, const std::vector<int32_t>& row,
                                     int32_t& count) {
  const size_t n = begin.size() - 1;
  std::vector<int32_t> label(n, -1);
  count = 0;
  for (size_t i = 0; i < n; ++i) {
    bool free = true;
    for (int32_t k = begin[i]; k < begin[i + 1] && free; ++k) free = label[size_t(row[size_t(k)])] < 0;
    if (!free) continue;
    for (int32_t k = begin[i]; k < begin[i + 1]; ++k) label[size_t(row[size_t(k)])] = count;
    ++count;
  }
  std::vector<int32_t> joined = label;
  std::vector<std::pair<int32_t, int32_t>> votes;
  for (size_t i = 0; i < n; ++i) {
    if (label[i] >= 0) continue;
    votes.clear();
    for (int32_t k = begin[i]; k < begin[i + 1]; ++k) {
      const int32_t l = label[size_t(row[size_t(k)])];
      if (l < 0) continue;
      auto it = std::find_if(votes.begin(), votes.end(), [&](const auto& v) { return v.first == l; });
      if (it == votes.end()) votes.emplace_back(l, 1);
      else it->second++;
    }
    if (votes.empty()) continue;
    joined[i] = std::max_element(votes.begin(), votes.end(),
                                 [](const auto& a, const auto& b) { return a.second < b.second; })->first;
  }
  label.swap(joined);
  for (size_t i = 0; i < n; ++i) {
    if (label[i] >= 0) continue;
    for (int32_t k = begin[i]; k < begin[i + 1]; ++k)
      if (label[size_t(row[size_t(k)])] < 0) label[size_t(row[size_t(k)])] = count;
    ++count;
  }
  return label;
}

// The graph of the aggregates `label` (count of them) of the graph (begin, row): an aggregate
// neighbours every aggregate one of its nodes neighbours (itself included), ascending.
void aggregate_graph_of(const std::vector<int32_t>& begin, const std::vector<int32_t>& row,
                        const std::vector<int32_t>& label, int32_t count, std::vector<int32_t>& out_begin,
                        std::vector<int32_t>& out_row) {
  std::vector<std::vector<int32_t>> members(static_cast<size_t>(count));
  for (size_t i = 0; i < label.size(); ++i) members[size_t(label[i])].push_back(int32_t(i));
  out_begin.assign(size_t(count) + 1, 0);
  out_row.clear();
  std::vector<int32_t> seen(size_t(count), -1);
  std::vector<int32_t> list;
  for (int32_t a = 0; a < count; ++a) {
    list.clear();
    for (const int32_t i : members[size_t(a)])
      for (int32_t k = begin[size_t(i)]; k < begin[size_t(i) + 1]; ++k) {
        const int32_t b = label[size_t(row[size_t(k)])];
        if (seen[size_t(b)] != a) {
          seen[size_t(b)] = a;
          list.push_back(b);
        }
      }
    std::sort(list.begin(), list.end());
    out_row.insert(out_row.end(), list.begin(), list.end());
    out_begin[size_t(a) + 1] = int32_t(out_row.size());
  }
}

Eigen::Matrix3d cross_matrix(const Vec3& a) {
  Eigen::Matrix3d c;
  c << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
  return c;
}

}  // namespace

Eigen::Matrix3d invert_block(const Eigen::Matrix3d& b) {
  Eigen::LLT<Eigen::Matrix3d> llt(b);
  if (llt.info() == Eigen::Success) return llt.solve(Eigen::Matrix3d::Identity());
  Eigen::Matrix3d inv = Eigen::Matrix3d::Zero();
  for (int i = 0; i < 3; ++i) inv(i, i) = 1.0 / std::max(std::abs(b(i, i)), 1e-300);
  return inv;
}

void TwoLevelPreconditioner::build(const std::vector<int32_t>& block_begin, const std::vector<int32_t>& block_row,
                                   const std::vector<Vec3>& position, int rounds) {
  block_begin_ = block_begin;
  block_row_ = block_row;
  const size_t nb = block_begin.size() - 1;
  int32_t count = 0;
  aggregate_ = aggregate_graph(block_begin, block_row, count);
  for (int r = 1; r < rounds; ++r) {
    std::vector<int32_t> gb, gr;
    aggregate_graph_of(block_begin, block_row, aggregate_, count, gb, gr);
    int32_t next = 0;
    const std::vector<int32_t> up = aggregate_graph(gb, gr, next);
    for (int32_t& a : aggregate_) a = up[size_t(a)];
    count = next;
  }
  std::vector<int32_t> size(size_t(count), 0);
  for (const int32_t a : aggregate_) size[size_t(a)]++;
  agg_first_.assign(size_t(count), 0);
  agg_modes_.assign(size_t(count), 3);
  coarse_dofs_ = 0;
  for (int32_t a = 0; a < count; ++a) {
    agg_modes_[size_t(a)] = size[size_t(a)] >= 4 ? 6 : 3;
    agg_first_[size_t(a)] = coarse_dofs_;
    coarse_dofs_ += agg_modes_[size_t(a)];
  }
  // The coarse pattern: dense blocks for every pair of aggregates that H couples, both triangles.
  std::vector<int32_t> gb, gr;
  aggregate_graph_of(block_begin, block_row, aggregate_, count, gb, gr);
  std::vector<Eigen::Triplet<double>> trip;
  for (int32_t b = 0; b < count; ++b)
    for (int32_t k = gb[size_t(b)]; k < gb[size_t(b) + 1]; ++k) {
      const int32_t a = gr[size_t(k)];
      for (int j = 0; j < agg_modes_[size_t(b)]; ++j)
        for (int i = 0; i < agg_modes_[size_t(a)]; ++i)
          trip.emplace_back(agg_first_[size_t(a)] + i, agg_first_[size_t(b)] + j, 0.0);
    }
  coarse_.resize(coarse_dofs_, coarse_dofs_);
  coarse_.setFromTriplets(trip.begin(), trip.end());
  coarse_.makeCompressed();
  // Where each H block lands: the offset of its row aggregate's rows within its column
  // aggregate's columns (the same for every column of that aggregate: they share one pattern).
  block_target_.assign(block_row.size(), 0);
  for (size_t q = 0; q < nb; ++q) {
    const int32_t b = aggregate_[q];
    const int col = agg_first_[size_t(b)];
    const int* rows = coarse_.innerIndexPtr() + coarse_.outerIndexPtr()[col];
    const int* rows_end = coarse_.innerIndexPtr() + coarse_.outerIndexPtr()[col + 1];
    for (int32_t k = block_begin[q]; k < block_begin[q + 1]; ++k) {
      const int32_t a = aggregate_[size_t(block_row[size_t(k)])];
      block_target_[size_t(k)] = int32_t(std::lower_bound(rows, rows_end, agg_first_[size_t(a)]) - rows);
    }
  }
  analysed_ = coarse_ok_ = false;
  const size_t na = size_t(count);
  arm_.assign(nb, Vec3::Zero());
  // Lever arms about each aggregate's centroid, scaled by its radius (the rotations' columns then
  // weigh like the translations').
  std::vector<Vec3> centroid(na, Vec3::Zero());
  std::vector<double> radius(na, 0.0);
  for (size_t q = 0; q < nb; ++q) centroid[size_t(aggregate_[q])] += position[q];
  for (size_t a = 0; a < na; ++a) centroid[a] /= std::max(1, size[a]);
  for (size_t q = 0; q < nb; ++q) {
    const size_t a = size_t(aggregate_[q]);
    radius[a] = std::max(radius[a], (position[q] - centroid[a]).norm());
  }
  for (size_t q = 0; q < nb; ++q) {
    const size_t a = size_t(aggregate_[q]);
    arm_[q] = radius[a] > 0 ? Vec3((position[q] - centroid[a]) / radius[a]) : Vec3::Zero();
  }
  block_inverse_.assign(nb, Eigen::Matrix3d::Identity());
}

void TwoLevelPreconditioner::update_blocks(const Eigen::SparseMatrix<double>& H) {
  const size_t nb = block_begin_.size() - 1;
  const int* outer = H.outerIndexPtr();
  const double* values = H.valuePtr();
  for (size_t q = 0; q < nb; ++q) {
    Eigen::Matrix3d b;
    const int32_t first = block_begin_[q];
    int32_t self = first;
    while (block_row_[size_t(self)] != int32_t(q)) ++self;
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i) b(i, j) = values[outer[3 * q + j] + 3 * (self - first) + i];
    block_inverse_[q] = invert_block(b);
  }
}

bool TwoLevelPreconditioner::refresh_coarse(const Eigen::SparseMatrix<double>& H) {
  const size_t nb = block_begin_.size() - 1;
  const int* outer = H.outerIndexPtr();
  const double* values = H.valuePtr();
  // P_p^T H_pq P_q into the pair's block, P_q = [I, -[arm_q]x] (its first 3 or 6 columns).
  double* cv = coarse_.valuePtr();
  const int* couter = coarse_.outerIndexPtr();
  std::fill(cv, cv + coarse_.nonZeros(), 0.0);
  Eigen::Matrix<double, 3, 6> Pp, Pq;
  for (size_t q = 0; q < nb; ++q) {
    const size_t b = size_t(aggregate_[q]);
    const int mb = agg_modes_[b];
    Pq.leftCols<3>().setIdentity();
    Pq.rightCols<3>() = -cross_matrix(arm_[q]);
    const int32_t first = block_begin_[q];
    for (int32_t k = first; k < block_begin_[q + 1]; ++k) {
      const size_t p = size_t(block_row_[size_t(k)]);
      const size_t a = size_t(aggregate_[p]);
      const int ma = agg_modes_[a];
      Eigen::Matrix3d Hpq;
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i) Hpq(i, j) = values[outer[3 * q + j] + 3 * (k - first) + i];
      Pp.leftCols<3>().setIdentity();
      Pp.rightCols<3>() = -cross_matrix(arm_[p]);
      const Eigen::Matrix<double, 6, 6> c = Pp.transpose() * Hpq * Pq;
      const int32_t at = block_target_[size_t(k)];
      for (int j = 0; j < mb; ++j) {
        double* col = cv + couter[agg_first_[b] + j] + at;
        for (int i = 0; i < ma; ++i) col[i] += c(i, j);
      }
    }
  }
  if (!analysed_) {
    coarse_solver_.analyzePattern(coarse_);
    analysed_ = true;
  }
  coarse_solver_.factorize(coarse_);
  coarse_ok_ = coarse_solver_.info() == Eigen::Success && coarse_solver_.vectorD().minCoeff() > 0;
  return coarse_ok_;
}

void TwoLevelPreconditioner::apply(const Eigen::VectorXd& r, Eigen::VectorXd& z) const {
  const size_t nb = block_begin_.size() - 1;
  z.resize(r.size());
  for (size_t q = 0; q < nb; ++q) z.segment<3>(Eigen::Index(3 * q)) = block_inverse_[q] * r.segment<3>(Eigen::Index(3 * q));
  if (!coarse_ok_) return;
  coarse_r_.setZero(coarse_dofs_);
  for (size_t q = 0; q < nb; ++q) {
    const size_t a = size_t(aggregate_[q]);
    const Vec3 rq = r.segment<3>(Eigen::Index(3 * q));
    double* c = coarse_r_.data() + agg_first_[a];
    c[0] += rq.x();
    c[1] += rq.y();
    c[2] += rq.z();
    if (agg_modes_[a] == 6) {
      const Vec3 m = arm_[q].cross(rq);
      c[3] += m.x();
      c[4] += m.y();
      c[5] += m.z();
    }
  }
  coarse_z_ = coarse_solver_.solve(coarse_r_);
  for (size_t q = 0; q < nb; ++q) {
    const size_t a = size_t(aggregate_[q]);
    const double* c = coarse_z_.data() + agg_first_[a];
    Vec3 d(c[0], c[1], c[2]);
    if (agg_modes_[a] == 6) d += Vec3(c[3], c[4], c[5]).cross(arm_[q]);
    z.segment<3>(Eigen::Index(3 * q)) += d;
  }
}

}  // namespace pliant::detail
