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

int32_t cell_coord(double v, double inv_h) {
  double c = std::floor(v * inv_h);
  if (!(c > -kCellLimit)) c = -kCellLimit;  // NaN lands here too
  if (!(c < kCellLimit)) c = kCellLimit;
  return static_cast<int32_t>(c);
}

uint32_t cell_hash(int32_t x, int32_t y, int32_t z, uint32_t mask) {
  return ((static_cast<uint32_t>(x) * 73856093u) ^ (static_cast<uint32_t>(y) * 19349663u) ^
          (static_cast<uint32_t>(z) * 83492791u)) &
         mask;
}

void run(ThreadPool* pool, size_t n, const std::function<void(int, size_t, size_t)>& fn) {
  if (pool)
    pool->parallel_for(n, fn, 256);
  else
    fn(0, 0, n);
}

}  // namespace

void NeighbourGrid::build(std::span<const Vec3> x, double h, ThreadPool* pool) {
  const size_t n = x.size();
  const double inv_h = 1.0 / h;
  const double h2 = h * h;
  cell_.resize(n);
  bucket_.resize(n);
  size_t table = 64;
  while (table < 2 * n) table *= 2;
  const uint32_t mask = static_cast<uint32_t>(table - 1);
  run(pool, n, [&](int, size_t b, size_t e) {
    for (size_t i = b; i < e; ++i) {
      const std::array<int32_t, 3> c{cell_coord(x[i].x(), inv_h), cell_coord(x[i].y(), inv_h),
                                     cell_coord(x[i].z(), inv_h)};
      cell_[i] = c;
      bucket_[i] = cell_hash(c[0], c[1], c[2], mask);
    }
  });
  // Counting sort of the points by bucket (stable: by index within a bucket).
  bucket_start_.assign(table + 1, 0);
  for (size_t i = 0; i < n; ++i) ++bucket_start_[bucket_[i] + 1];
  for (size_t b = 0; b < table; ++b) bucket_start_[b + 1] += bucket_start_[b];
  sorted_.resize(n);
  {
    std::vector<uint32_t> fill(bucket_start_.begin(), bucket_start_.end() - 1);
    for (size_t i = 0; i < n; ++i) sorted_[fill[bucket_[i]]++] = static_cast<uint32_t>(i);
  }

  const int chunks = pool ? pool->size() : 1;
  chunk_list_.resize(chunks);
  for (auto& l : chunk_list_) l.clear();  // a small n runs as one chunk
  chunk_first_.assign(chunks + 1, 0);
  offset_.assign(n + 1, 0);
  run(pool, n, [&](int chunk, size_t b, size_t e) {
    std::vector<uint32_t>& out = chunk_list_[chunk];
    out.clear();
    for (size_t i = b; i < e; ++i) {
      const std::array<int32_t, 3> ci = cell_[i];
      const Vec3 xi = x[i];
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            const std::array<int32_t, 3> c{ci[0] + dx, ci[1] + dy, ci[2] + dz};
            const uint32_t bucket = cell_hash(c[0], c[1], c[2], mask);
            for (uint32_t s = bucket_start_[bucket]; s < bucket_start_[bucket + 1]; ++s) {
              const uint32_t j = sorted_[s];
              if (j == i || cell_[j] != c) continue;
              if ((x[j] - xi).squaredNorm() < h2) out.push_back(j);
            }
          }
      offset_[i + 1] = static_cast<uint32_t>(out.size());  // chunk-relative for now
    }
  });
  // Rebase the chunk-relative offsets (parallel_for splits [0, n) the same way every time).
  uint32_t base = 0;
  for (int c = 0; c < chunks; ++c) {
    chunk_first_[c] = base;
    base += static_cast<uint32_t>(chunk_list_[c].size());
  }
  chunk_first_[chunks] = base;
  list_.resize(base);
  run(pool, n, [&](int chunk, size_t b, size_t e) {
    const uint32_t first = chunk_first_[chunk];
    std::copy(chunk_list_[chunk].begin(), chunk_list_[chunk].end(), list_.begin() + first);
    for (size_t i = b; i < e; ++i) offset_[i + 1] += first;
  });
}

std::vector<uint32_t> NeighbourGrid::cell_order(std::span<const Vec3> x, double h) {
  const double inv_h = 1.0 / h;
  const int64_t off = 1 << 19;  // keys of 21 bits per axis
  std::vector<uint64_t> key(x.size());
  for (size_t i = 0; i < x.size(); ++i) {
    const uint64_t cx = static_cast<uint64_t>(cell_coord(x[i].x(), inv_h) + off);
    const uint64_t cy = static_cast<uint64_t>(cell_coord(x[i].y(), inv_h) + off);
    const uint64_t cz = static_cast<uint64_t>(cell_coord(x[i].z(), inv_h) + off);
    key[i] = (cz << 42) | (cy << 21) | cx;
  }
  std::vector<uint32_t> order(x.size());
  std::iota(order.begin(), order.end(), 0u);
  std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key[a] < key[b]; });
  return order;
}

}  // namespace pliant::fluid
