// SPDX-License-Identifier: Apache-2.0
#include "fluid/neighbour_grid.hpp"

#include "step/thread_pool.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <numeric>

namespace pliant::fluid {

namespace {

constexpr double kCellLimit = double(1 << 19);  // cells further out share the last one
constexpr int64_t kOffset = 1 << 19;             // keys of 21 bits per axis

int64_t cell_coord(double v, double inv_h) {
  double c = std::floor(v * inv_h);
  if (!(c > -kCellLimit)) c = -kCellLimit;  // NaN lands here too
  if (!(c < kCellLimit)) c = kCellLimit;
  return static_cast<int64_t>(c) + kOffset;
}

uint64_t cell_key(const Vec3& p, double inv_h) {
  return (static_cast<uint64_t>(cell_coord(p.z(), inv_h)) << 42) |
         (static_cast<uint64_t>(cell_coord(p.y(), inv_h)) << 21) | static_cast<uint64_t>(cell_coord(p.x(), inv_h));
}

uint64_t key_hash(uint64_t k) {
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdULL;
  k ^= k >> 33;
  return k;
}

void run(ThreadPool* pool, size_t n, const std::function<void(int, size_t, size_t)>& fn, size_t min_parallel) {
  if (pool)
    pool->parallel_for(n, fn, min_parallel);
  else
    fn(0, 0, n);
}

}  // namespace

void NeighbourGrid::build(std::span<const Vec3> x, double h, ThreadPool* pool) {
  const size_t n = x.size();
  const double inv_h = 1.0 / h;
  const double h2 = h * h;
  sorted_.resize(n);
  run(pool, n, [&](int, size_t b, size_t e) {
    for (size_t i = b; i < e; ++i) sorted_[i] = {cell_key(x[i], inv_h), static_cast<uint32_t>(i)};
  }, 1024);
  std::sort(sorted_.begin(), sorted_.end());
  slot_.resize(n);
  cells_.clear();
  for (size_t s = 0; s < n; ++s) {
    slot_[sorted_[s].second] = static_cast<uint32_t>(s);
    if (cells_.empty() || cells_.back().key != sorted_[s].first)
      cells_.push_back(Cell{sorted_[s].first, static_cast<uint32_t>(s), static_cast<uint32_t>(s)});
    cells_.back().end = static_cast<uint32_t>(s + 1);
  }
  size_t tsize = 64;
  while (tsize < 2 * cells_.size()) tsize *= 2;
  const uint64_t mask = tsize - 1;
  table_.assign(tsize, -1);
  for (size_t c = 0; c < cells_.size(); ++c) {
    uint64_t slot = key_hash(cells_[c].key) & mask;
    while (table_[slot] >= 0) slot = (slot + 1) & mask;
    table_[slot] = static_cast<int32_t>(c);
  }
  auto find = [&](uint64_t key) -> const Cell* {
    uint64_t slot = key_hash(key) & mask;
    while (table_[slot] >= 0) {
      const Cell& c = cells_[table_[slot]];
      if (c.key == key) return &c;
      slot = (slot + 1) & mask;
    }
    return nullptr;
  };

  const int chunks = pool ? pool->size() : 1;
  chunk_list_.resize(chunks);
  chunk_used_.assign(chunks, 0);  // a small n runs as one chunk
  chunk_first_.assign(chunks + 1, 0);
  offset_.assign(n + 1, 0);
  const size_t ncells = cells_.size();
  // The points' coordinates in slot order: a row of three neighbouring cells (x - 1, x,
  // x + 1) is then one contiguous range, scanned without gathering.
  sx_.resize(n);
  sy_.resize(n);
  sz_.resize(n);
  point_.resize(n);
  run(pool, n, [&](int, size_t b, size_t e) {
    for (size_t s = b; s < e; ++s) {
      const Vec3& q = x[sorted_[s].second];
      sx_[s] = q.x();
      sy_[s] = q.y();
      sz_[s] = q.z();
      point_[s] = sorted_[s].second;
    }
  }, 1024);
  run(pool, ncells, [&](int chunk, size_t b, size_t e) {
    std::vector<uint32_t>& out = chunk_list_[chunk];
    size_t used = 0;
    std::vector<double> d2;
    uint32_t row_b[9], row_e[9];
    for (size_t c = b; c < e; ++c) {
      const Cell& cell = cells_[c];
      const int64_t cx = static_cast<int64_t>(cell.key & 0x1FFFFF), cy = static_cast<int64_t>((cell.key >> 21) & 0x1FFFFF),
                    cz = static_cast<int64_t>(cell.key >> 42);
      // The 9 rows (z, then y order); in a row the cells x - 1, x, x + 1 are consecutive keys,
      // so their points are one range of slots from the first to the last that exists.
      int rows = 0;
      size_t span = 0;
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy) {
          const int64_t ay = cy + dy, az = cz + dz;
          if (ay < 0 || az < 0 || ay > 0x1FFFFF || az > 0x1FFFFF) continue;
          const Cell* first = nullptr;
          const Cell* last = nullptr;
          for (int dx = -1; dx <= 1; ++dx) {
            const int64_t ax = cx + dx;
            if (ax < 0 || ax > 0x1FFFFF) continue;
            const Cell* nb = find((static_cast<uint64_t>(az) << 42) | (static_cast<uint64_t>(ay) << 21) |
                                  static_cast<uint64_t>(ax));
            if (!nb) continue;
            if (!first) first = nb;
            last = nb;
          }
          if (!first) continue;
          row_b[rows] = first->begin;
          row_e[rows] = last->end;
          span = std::max<size_t>(span, last->end - first->begin);
          ++rows;
        }
      if (d2.size() < span) d2.resize(span);
      for (uint32_t s = cell.begin; s < cell.end; ++s) {
        const double xi = sx_[s], yi = sy_[s], zi = sz_[s];
        for (int r = 0; r < rows; ++r) {
          const size_t rb = row_b[r], nc = row_e[r] - rb;
          const double* px = sx_.data() + rb;
          const double* py = sy_.data() + rb;
          const double* pz = sz_.data() + rb;
          double* pd = d2.data();
          for (size_t q = 0; q < nc; ++q) {
            const double dx = px[q] - xi, dy = py[q] - yi, dz = pz[q] - zi;
            pd[q] = dx * dx + dy * dy + dz * dz;
          }
          // Branch-free compaction: every candidate is written, the count moves on for hits.
          if (used + nc > out.size()) out.resize(std::max(2 * out.size(), used + nc + 1024));
          uint32_t* o = out.data() + used;
          const uint32_t* ci = point_.data() + rb;
          const size_t self = s - rb;  // wraps around (no match) when s is outside the row
          size_t hits = 0;
          for (size_t q = 0; q < nc; ++q) {
            o[hits] = ci[q];
            hits += static_cast<size_t>((pd[q] < h2) & (q != self));
          }
          used += hits;
        }
        offset_[s + 1] = static_cast<uint32_t>(used);  // chunk-relative for now
      }
    }
    chunk_used_[chunk] = used;
  }, 64);
  // Rebase the chunk-relative offsets (parallel_for splits the cells the same way every time).
  uint32_t base = 0;
  for (int c = 0; c < chunks; ++c) {
    chunk_first_[c] = base;
    base += static_cast<uint32_t>(chunk_used_[c]);
  }
  chunk_first_[chunks] = base;
  list_.resize(base);
  run(pool, ncells, [&](int chunk, size_t b, size_t e) {
    const uint32_t first = chunk_first_[chunk];
    std::copy(chunk_list_[chunk].begin(), chunk_list_[chunk].begin() + static_cast<ptrdiff_t>(chunk_used_[chunk]),
              list_.begin() + first);
    if (b < e)
      for (uint32_t s = cells_[b].begin; s < cells_[e - 1].end; ++s) offset_[s + 1] += first;
  }, 64);
}

std::vector<uint32_t> NeighbourGrid::cell_order(std::span<const Vec3> x, double h) {
  const double inv_h = 1.0 / h;
  std::vector<std::pair<uint64_t, uint32_t>> key(x.size());
  for (size_t i = 0; i < x.size(); ++i) key[i] = {cell_key(x[i], inv_h), static_cast<uint32_t>(i)};
  std::sort(key.begin(), key.end());
  std::vector<uint32_t> order(x.size());
  for (size_t i = 0; i < x.size(); ++i) order[i] = key[i].second;
  return order;
}

}  // namespace pliant::fluid
