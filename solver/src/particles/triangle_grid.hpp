// SPDX-License-Identifier: Apache-2.0
// A uniform grid over triangles (or segments given as triangles (a, b, b)) for the contacts
// between bodies and the body's contact with a cloth: each triangle is binned by its box grown
// by the search reach (and, with `swept_from`, by where its corners were), so a point looks in
// its own cell only and a path in the cells its box touches. And the contact of a moving point
// with a moving triangle that those contacts share.
#pragma once

#include "pliant/interaction.hpp"
#include "pliant/mesh.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <span>
#include <unordered_map>
#include <utility>
#include <vector>

namespace pliant::detail {

class TriangleGrid {
 public:
  // `triangles`: 3-index arrays (the tet body's surface, a cloth's triangles) into x.
  // `region` (a box), when given: only the triangles that a query inside it can meet are binned
  // (those whose cells overlap the region's), so a small set of particles beside a large body
  // costs the triangles near it; every query inside the region finds what the whole grid finds,
  // in the same order.
  template <class Triangles>
  TriangleGrid(const Triangles& triangles, std::span<const Vec3> x, double reach,
               std::span<const Vec3> swept_from = {}, const std::pair<Vec3, Vec3>* region = nullptr) {
    double edge = 0;
    for (const auto& t : triangles) edge += (x[t[1]] - x[t[0]]).norm();
    edge = triangles.empty() ? reach : edge / double(triangles.size());
    cell_ = std::max(2 * reach, edge);
    boxes_.assign(triangles.size(), {Vec3::Constant(INFINITY), Vec3::Constant(-INFINITY)});
    std::vector<char> binned(triangles.size(), 0);
    for (size_t k = 0; k < triangles.size(); ++k) {
      const auto& t = triangles[k];
      if (!x[t[0]].allFinite() || !x[t[1]].allFinite() || !x[t[2]].allFinite()) continue;
      Vec3 lo = x[t[0]].cwiseMin(x[t[1]]).cwiseMin(x[t[2]]);
      Vec3 hi = x[t[0]].cwiseMax(x[t[1]]).cwiseMax(x[t[2]]);
      if (!swept_from.empty())
        for (int c = 0; c < 3; ++c)
          if (swept_from[t[c]].allFinite()) {
            lo = lo.cwiseMin(swept_from[t[c]]);
            hi = hi.cwiseMax(swept_from[t[c]]);
          }
      boxes_[k] = {lo, hi};
      binned[k] = 1;
    }
    // Each triangle's cells (its box grown by the reach), and the range of all of them. A few
    // triangles swept very far (a body that jumped) would span too many cells: then the cells
    // grow until the entries are at most 64 a triangle (and a million).
    std::vector<std::array<std::array<int64_t, 3>, 2>> spans(triangles.size());
    std::array<int64_t, 3> all_lo{}, all_hi{};
    double entries = 0;
    const double cap = 64.0 * double(triangles.size()) + 1e6;
    for (int attempt = 0;; ++attempt) {
      all_lo = {INT64_MAX, INT64_MAX, INT64_MAX};
      all_hi = {INT64_MIN, INT64_MIN, INT64_MIN};
      entries = 0;
      for (size_t k = 0; k < triangles.size(); ++k) {
        if (!binned[k]) continue;
        spans[k] = {cell_of(Vec3(boxes_[k].first.array() - reach)), cell_of(Vec3(boxes_[k].second.array() + reach))};
        double n = 1;
        for (int c = 0; c < 3; ++c) {
          all_lo[c] = std::min(all_lo[c], spans[k][0][c]);
          all_hi[c] = std::max(all_hi[c], spans[k][1][c]);
          n *= double(spans[k][1][c] - spans[k][0][c] + 1);
        }
        entries += n;
      }
      if (entries <= cap || attempt == 64) break;
      cell_ *= 2 * std::cbrt(entries / cap);
    }
    const auto r_lo = region ? cell_of(region->first) : all_lo, r_hi = region ? cell_of(region->second) : all_hi;
    if (r_lo[0] > all_lo[0] || r_lo[1] > all_lo[1] || r_lo[2] > all_lo[2] || r_hi[0] < all_hi[0] ||
        r_hi[1] < all_hi[1] || r_hi[2] < all_hi[2]) {
      // The cell size stays the whole set's; the triangles whose cells miss the region's go.
      all_lo = {INT64_MAX, INT64_MAX, INT64_MAX};
      all_hi = {INT64_MIN, INT64_MIN, INT64_MIN};
      entries = 0;
      for (size_t k = 0; k < triangles.size(); ++k) {
        if (!binned[k]) continue;
        double n = 1;
        for (int c = 0; c < 3 && binned[k]; ++c) {
          spans[k][0][c] = std::max(spans[k][0][c], r_lo[c]);
          spans[k][1][c] = std::min(spans[k][1][c], r_hi[c]);
          binned[k] = spans[k][0][c] <= spans[k][1][c];
          n *= double(spans[k][1][c] - spans[k][0][c] + 1);
        }
        if (!binned[k]) continue;
        for (int c = 0; c < 3; ++c) {
          all_lo[c] = std::min(all_lo[c], spans[k][0][c]);
          all_hi[c] = std::max(all_hi[c], spans[k][1][c]);
        }
        entries += n;
      }
    }
    if (entries == 0) return;
    span_lo_.resize(triangles.size());
    for (size_t k = 0; k < triangles.size(); ++k)
      if (binned[k]) span_lo_[k] = spans[k][0];
    // Dense cells over the range when it is not much larger than the entries (a body in one
    // piece), filled by counting in triangle order; a hash of the occupied cells otherwise.
    double cells = 1;
    for (int c = 0; c < 3; ++c) cells *= double(all_hi[c] - all_lo[c] + 1);
    auto each_cell = [&](auto&& fn) {
      for (size_t k = 0; k < spans.size(); ++k) {
        if (!binned[k]) continue;
        const auto& [a, b] = spans[k];
        for (int64_t i = a[0]; i <= b[0]; ++i)
          for (int64_t j = a[1]; j <= b[1]; ++j)
            for (int64_t l = a[2]; l <= b[2]; ++l) fn(std::array<int64_t, 3>{i, j, l}, int32_t(k));
      }
    };
    if (cells <= 4 * entries + 4096) {
      dense_lo_ = all_lo;
      for (int c = 0; c < 3; ++c) dense_n_[c] = all_hi[c] - all_lo[c] + 1;
      dense_start_.assign(size_t(cells) + 1, 0);
      each_cell([&](const std::array<int64_t, 3>& c, int32_t) { ++dense_start_[dense_index(c) + 1]; });
      for (size_t i = 1; i < dense_start_.size(); ++i) dense_start_[i] += dense_start_[i - 1];
      triangles_.resize(dense_start_.back());
      std::vector<uint32_t> fill(dense_start_.begin(), dense_start_.end() - 1);
      each_cell([&](const std::array<int64_t, 3>& c, int32_t k) { triangles_[fill[dense_index(c)]++] = k; });
      return;
    }
    std::vector<std::pair<uint64_t, int32_t>> sorted;
    sorted.reserve(size_t(entries));
    each_cell([&](const std::array<int64_t, 3>& c, int32_t k) { sorted.emplace_back(key(c), k); });
    std::sort(sorted.begin(), sorted.end());
    triangles_.reserve(sorted.size());
    for (size_t e = 0; e < sorted.size(); ++e) {
      if (e == 0 || sorted[e].first != sorted[e - 1].first) ranges_[sorted[e].first] = {uint32_t(e), uint32_t(e)};
      ranges_[sorted[e].first].second = uint32_t(e + 1);
      triangles_.push_back(sorted[e].second);
    }
  }

  std::span<const int32_t> near(const Vec3& p) const { return cell(cell_of(p)); }
  size_t entries() const { return triangles_.size(); }  // (cell, triangle) entries binned
  double cell_size() const { return cell_; }  // cell (i, j, k) is [i, i + 1) x ... times this
  // Triangle k's box (its corners', start and end), not grown: a bound for its points.
  const std::pair<Vec3, Vec3>& box(int32_t k) const { return boxes_[size_t(k)]; }
  // The squared distance from p to triangle k's box (0 inside): no point of it is nearer.
  double box_distance2(int32_t k, const Vec3& p) const {
    const auto& [lo, hi] = boxes_[size_t(k)];
    return (lo - p).cwiseMax(p - hi).cwiseMax(0.0).squaredNorm();
  }

  // The triangles near a segment: those of every cell its box touches, each once, in the order
  // the cells first give them; nothing when that box spans more than max_cells cells. A
  // triangle's cells and the box's cells are boxes of cells, so the first of their common cells
  // in the walk's order is the corner at the larger of their low corners: the triangle is taken
  // there only (a large triangle would otherwise be measured once per cell it shares with a long
  // path).
  void near_segment(const Vec3& a, const Vec3& b, size_t max_cells, std::vector<int32_t>& out) const {
    out.clear();
    const auto lo = cell_of(a.cwiseMin(b)), hi = cell_of(a.cwiseMax(b));
    const double cells = double(hi[0] - lo[0] + 1) * double(hi[1] - lo[1] + 1) * double(hi[2] - lo[2] + 1);
    if (cells > double(max_cells)) return;
    for (int64_t i = lo[0]; i <= hi[0]; ++i)
      for (int64_t j = lo[1]; j <= hi[1]; ++j)
        for (int64_t l = lo[2]; l <= hi[2]; ++l)
          for (int32_t k : cell({i, j, l})) {
            const auto& s = span_lo_[size_t(k)];
            if (std::max(s[0], lo[0]) == i && std::max(s[1], lo[1]) == j && std::max(s[2], lo[2]) == l) out.push_back(k);
          }
  }

  // The candidates for a point that moved from `start` to `x`: the triangles near its path, or
  // (a path too long to search) those of the cell it ended in.
  void candidates(const Vec3& start, const Vec3& x, std::vector<int32_t>& out) const {
    near_segment(start, x, 4096, out);
    if (out.empty()) {
      const auto cell = near(x);
      out.assign(cell.begin(), cell.end());
    }
  }

  // The candidates that a point moving from `start` to `x` can touch within `radius`: those of
  // candidates() whose box (the corners' start and end positions) comes within the radius of the
  // path's box, in the same order. Every contact triangle_contact finds is among them (it needs
  // the point, at the end or where it crosses the plane, within the radius of the triangle then,
  // and both lie in those boxes); a margin of 1e-3 of the radius covers rounding.
  void candidates_within(const Vec3& start, const Vec3& x, double radius, std::vector<int32_t>& out) const {
    candidates(start, x, out);
    const double r = 1.001 * radius;
    const Vec3 lo = start.cwiseMin(x).array() - r, hi = start.cwiseMax(x).array() + r;
    std::erase_if(out, [&](int32_t k) {
      const auto& [blo, bhi] = boxes_[size_t(k)];
      return !((blo.array() <= hi.array()).all() && (bhi.array() >= lo.array()).all());
    });
  }

 private:
  // The triangles binned in cell c (in triangle order).
  std::span<const int32_t> cell(const std::array<int64_t, 3>& c) const {
    if (!dense_start_.empty()) {
      for (int a = 0; a < 3; ++a)
        if (c[a] < dense_lo_[a] || c[a] >= dense_lo_[a] + dense_n_[a]) return {};
      const size_t i = dense_index(c);
      return {triangles_.data() + dense_start_[i], dense_start_[i + 1] - dense_start_[i]};
    }
    const auto it = ranges_.find(key(c));
    if (it == ranges_.end()) return {};
    return {triangles_.data() + it->second.first, it->second.second - it->second.first};
  }
  size_t dense_index(const std::array<int64_t, 3>& c) const {
    return size_t((c[0] - dense_lo_[0]) + dense_n_[0] * ((c[1] - dense_lo_[1]) + dense_n_[1] * (c[2] - dense_lo_[2])));
  }

  // Finite points only; far-away ones are clamped (their cells are never near a triangle's).
  std::array<int64_t, 3> cell_of(const Vec3& p) const {
    auto axis = [&](double v) { return int64_t(std::clamp(std::floor(v / cell_), -1e15, 1e15)); };
    return {axis(p.x()), axis(p.y()), axis(p.z())};
  }
  static uint64_t key(const std::array<int64_t, 3>& c) {
    // 21 bits per axis (cells far outside +-2^20 wrap: only a slower search, never a missed one,
    // since every candidate is measured exactly).
    return (uint64_t(c[0]) & 0x1FFFFF) | ((uint64_t(c[1]) & 0x1FFFFF) << 21) | ((uint64_t(c[2]) & 0x1FFFFF) << 42);
  }

  double cell_ = 1;
  std::vector<std::pair<Vec3, Vec3>> boxes_;  // per triangle: its corners' box (start and end), not grown
  std::vector<std::array<int64_t, 3>> span_lo_;  // per binned triangle: the low corner of its cells
  // Dense cells (first cell, counts per axis, each cell's start in triangles_), or a hash of
  // the occupied cells' ranges when the triangles are spread far apart.
  std::array<int64_t, 3> dense_lo_{}, dense_n_{};
  std::vector<uint32_t> dense_start_;
  std::unordered_map<uint64_t, std::pair<uint32_t, uint32_t>> ranges_;
  std::vector<int32_t> triangles_;
};

// A point's contact with a triangle, both moving linearly over the step: the point from `start`
// to `x`, the corners from `from` to `to` (the same for a triangle that does not move). The point
// belongs on the side of the triangle it started on (against the triangle where it started).
// A contact when it ends within `radius` of the triangle on that side, or behind its plane having
// gone through the triangle during the step: its distance to the plane goes from s0 to s1, and
// where it changes sign the point must be inside the triangle of that moment (within the
// radius) -- that catches a point crossing and a triangle springing back past a point, which
// neither the path nor the triangle at its start or end alone shows; otherwise the point is
// behind another part of the surface (around this triangle's edge). Returns whether there is a
// contact, with C (< 0: the distance along n less the radius), n (towards where the point
// belongs) and b (the barycentric weights of the closest point at the end).
inline bool triangle_contact(const Vec3& start, const Vec3& x, const std::array<Vec3, 3>& from,
                             const std::array<Vec3, 3>& to, double radius, double& C, Vec3& n,
                             std::array<double, 3>& b) {
  const Vec3 face = (to[1] - to[0]).cross(to[2] - to[0]);
  if (!(face.squaredNorm() > 0)) return false;
  std::array<double, 3> bs;
  const Vec3 qs = closest_point_on_triangle(start, from[0], from[1], from[2], bs);
  const Vec3 n_start = (from[1] - from[0]).cross(from[2] - from[0]);
  const Vec3 n_face = face.normalized();
  const Vec3 n_side = (start - qs).dot(n_start) < 0 ? Vec3(-n_face) : n_face;
  const Vec3 d = x - closest_point_on_triangle(x, to[0], to[1], to[2], b);
  const double along = d.dot(n_side);
  n = n_side;
  if (along >= 0) {
    // On its side: apart along the line to the closest point (the face normal when on it).
    const double len = d.norm();
    if (len >= radius) return false;
    if (len > 1e-12 * radius) n = d / len;
    C = len - radius;
    return true;
  }
  if (!(n_start.squaredNorm() > 0)) return false;
  const double s0 = (start - from[0]).dot(n_start.normalized()), s1 = (x - to[0]).dot(n_face);
  if (!((s0 > 0) != (s1 > 0)) || s0 == s1) return false;
  const double tc = s0 / (s0 - s1);
  const Vec3 pc = start + tc * (x - start);
  std::array<double, 3> bc;
  const Vec3 qc = closest_point_on_triangle(pc, from[0] + tc * (to[0] - from[0]), from[1] + tc * (to[1] - from[1]),
                                            from[2] + tc * (to[2] - from[2]), bc);
  if ((pc - qc).norm() > radius) return false;
  C = along - radius;
  return true;
}

}  // namespace pliant::detail
