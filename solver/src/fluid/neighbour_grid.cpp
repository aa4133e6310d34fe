// SPDX-License-Identifier: Apache-2.0
#include "fluid/neighbour_grid.hpp"

#include "step/thread_pool.hpp"

#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <array>
#include <bit>
#include <climits>
#include <cmath>
#include <limits>
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

#if defined(__AVX2__)
// For each 8-bit mask, the lanes whose bit is set, in order: the permutation that packs the
// hits of 8 candidates to the front of a vector.
struct CompressTable {
  alignas(32) uint32_t lanes[256][8] = {};
  constexpr CompressTable() {
    for (int m = 0; m < 256; ++m) {
      int k = 0;
      for (int l = 0; l < 8; ++l)
        if ((m >> l) & 1) lanes[m][k++] = static_cast<uint32_t>(l);
    }
  }
};
constexpr CompressTable kCompress;
#endif

// Appends to o the candidates q in [0, m) (m a multiple of 8) within h of (xi, yi, zi), except
// q = self, and returns how many; o has room for m + 8 entries. cx, cy, cz, id are the
// candidates' coordinates and points.
size_t collect(size_t m, const double* cx, const double* cy, const double* cz, const uint32_t* id, double xi,
               double yi, double zi, double h2, size_t self, uint32_t* o) {
  size_t hits = 0;
#if defined(__AVX2__)
  const __m256d vx = _mm256_set1_pd(xi), vy = _mm256_set1_pd(yi), vz = _mm256_set1_pd(zi), vh = _mm256_set1_pd(h2);
  auto below = [&](size_t q) {
    const __m256d dx = _mm256_sub_pd(_mm256_loadu_pd(cx + q), vx);
    const __m256d dy = _mm256_sub_pd(_mm256_loadu_pd(cy + q), vy);
    const __m256d dz = _mm256_sub_pd(_mm256_loadu_pd(cz + q), vz);
    const __m256d d2 = _mm256_fmadd_pd(dz, dz, _mm256_fmadd_pd(dy, dy, _mm256_mul_pd(dx, dx)));
    return _mm256_movemask_pd(_mm256_cmp_pd(d2, vh, _CMP_LT_OQ));
  };
  for (size_t q = 0; q < m; q += 8) {
    unsigned mask = static_cast<unsigned>(below(q) | (below(q + 4) << 4));
    if (self - q < 8) mask &= ~(1u << (self - q));
    const __m256i ids = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(id + q));
    const __m256i perm = _mm256_load_si256(reinterpret_cast<const __m256i*>(kCompress.lanes[mask]));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(o + hits), _mm256_permutevar8x32_epi32(ids, perm));
    hits += static_cast<size_t>(std::popcount(mask));
  }
#else
  // Branch-free compaction: every candidate is written, the count moves on for hits.
  for (size_t q = 0; q < m; ++q) {
    const double dx = cx[q] - xi, dy = cy[q] - yi, dz = cz[q] - zi;
    o[hits] = id[q];
    hits += static_cast<size_t>((dx * dx + dy * dy + dz * dz < h2) & (q != self));
  }
#endif
  return hits;
}

// Sorts a (distinct entries, so there is one result) with the pool: each chunk of the pool's
// split sorted on its own thread, then the sorted chunks merged.
template <class T>
void sort_parallel(std::vector<T>& a, ThreadPool* pool) {
  const size_t n = a.size();
  if (!pool || pool->size() == 1 || n < 4096) {
    std::sort(a.begin(), a.end());
    return;
  }
  std::vector<size_t> end(static_cast<size_t>(pool->size()), 0);
  pool->parallel_for(n, [&](int c, size_t b, size_t e) {
    std::sort(a.begin() + static_cast<ptrdiff_t>(b), a.begin() + static_cast<ptrdiff_t>(e));
    end[static_cast<size_t>(c)] = e;
  }, 1);
  for (size_t c = 1; c < end.size(); ++c)
    if (end[c] > end[c - 1])
      std::inplace_merge(a.begin(), a.begin() + static_cast<ptrdiff_t>(end[c - 1]),
                         a.begin() + static_cast<ptrdiff_t>(end[c]));
}

// The cell coordinates of a key.
int64_t key_x(uint64_t k) { return static_cast<int64_t>(k & 0x1FFFFF); }
int64_t key_y(uint64_t k) { return static_cast<int64_t>((k >> 21) & 0x1FFFFF); }
int64_t key_z(uint64_t k) { return static_cast<int64_t>(k >> 42); }

}  // namespace

int64_t NeighbourGrid::DenseBox::index(int64_t x, int64_t y, int64_t z) const {
  return ((z - lz) * ny + (y - ly)) * nx + (x - lx);
}

// The points' (cell key, index) pairs in ascending order. When the box of the occupied cells,
// padded for the neighbour rows, has at most kDenseCellsPerPoint cells a point, they are counted
// into its cells (a counting sort, stable by index: the order std::sort gives the pairs) and box
// keeps where each cell's points start; otherwise (points spread far apart) the pairs are
// sorted and box.start is left empty.
void NeighbourGrid::sort_by_cell(std::span<const Vec3> x, double h, ThreadPool* pool,
                                 std::vector<std::pair<uint64_t, uint32_t>>& sorted, DenseBox& box,
                                 std::vector<std::pair<uint64_t, uint32_t>>& scratch) {
  constexpr double kDenseCellsPerPoint = 8.0;
  constexpr double kDenseCellsAlways = 4096.0;  // a small cloud's box in any case
  const size_t n = x.size();
  const double inv_h = 1.0 / h;
  const int chunks = pool ? pool->size() : 1;
  // Per chunk: the lowest and highest cell coordinates (x, y, z).
  std::vector<std::array<int64_t, 6>> range(static_cast<size_t>(chunks),
                                            {INT64_MAX, INT64_MAX, INT64_MAX, INT64_MIN, INT64_MIN, INT64_MIN});
  scratch.resize(n);
  run_parallel(pool, n, [&](int c, size_t b, size_t e) {
    std::array<int64_t, 6>& r = range[static_cast<size_t>(c)];
    for (size_t i = b; i < e; ++i) {
      const uint64_t k = cell_key(x[i], inv_h);
      scratch[i] = {k, static_cast<uint32_t>(i)};
      const int64_t a[3] = {key_x(k), key_y(k), key_z(k)};
      for (int d = 0; d < 3; ++d) {
        r[size_t(d)] = std::min(r[size_t(d)], a[d]);
        r[size_t(d) + 3] = std::max(r[size_t(d) + 3], a[d]);
      }
    }
  }, 1024);
  box.start.clear();
  std::array<int64_t, 6> all = range[0];
  for (const auto& r : range)
    for (int d = 0; d < 3; ++d) {
      all[size_t(d)] = std::min(all[size_t(d)], r[size_t(d)]);
      all[size_t(d) + 3] = std::max(all[size_t(d) + 3], r[size_t(d) + 3]);
    }
  if (n > 0) {
    // One empty cell below each axis's lowest and above its highest (the rows around a cell), a
    // second above along x (a row's range ends where the cell after x + 1 starts).
    box.lx = all[0] - 1;
    box.ly = all[1] - 1;
    box.lz = all[2] - 1;
    box.nx = all[3] - all[0] + 4;
    box.ny = all[4] - all[1] + 3;
    box.nz = all[5] - all[2] + 3;
    const double cells = double(box.nx) * double(box.ny) * double(box.nz);
    if (cells <= std::max(kDenseCellsPerPoint * double(n), kDenseCellsAlways)) {
      const size_t total = static_cast<size_t>(box.nx * box.ny * box.nz);
      auto cell = [&box](uint64_t k) { return static_cast<size_t>(box.index(key_x(k), key_y(k), key_z(k))); };
      box.start.assign(total + 1, 0);
      for (const auto& e : scratch) ++box.start[cell(e.first) + 1];
      for (size_t c = 0; c < total; ++c) box.start[c + 1] += box.start[c];
      box.fill.assign(box.start.begin(), box.start.end() - 1);
      sorted.resize(n);
      for (const auto& e : scratch) sorted[box.fill[cell(e.first)]++] = e;
      return;
    }
  }
  sorted.swap(scratch);
  sort_parallel(sorted, pool);
}

void NeighbourGrid::build(std::span<const Vec3> x, double h, ThreadPool* pool) {
  const size_t n = x.size();
  const double h2 = h * h;
  sort_by_cell(x, h, pool, sorted_, box_, scratch_);
  const bool dense = !box_.start.empty();
  slot_.resize(n);
  cells_.clear();
  for (size_t s = 0; s < n; ++s) {
    slot_[sorted_[s].second] = static_cast<uint32_t>(s);
    if (cells_.empty() || cells_.back().key != sorted_[s].first)
      cells_.push_back(Cell{sorted_[s].first, static_cast<uint32_t>(s), static_cast<uint32_t>(s)});
    cells_.back().end = static_cast<uint32_t>(s + 1);
  }
  // Without the dense box, the occupied cells are found through a hash table.
  uint64_t mask = 0;
  table_.clear();
  if (!dense) {
    size_t tsize = 64;
    while (tsize < 2 * cells_.size()) tsize *= 2;
    mask = tsize - 1;
    table_.assign(tsize, -1);
    for (size_t c = 0; c < cells_.size(); ++c) {
      uint64_t slot = key_hash(cells_[c].key) & mask;
      while (table_[slot] >= 0) slot = (slot + 1) & mask;
      table_[slot] = static_cast<int32_t>(c);
    }
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
  run_parallel(pool, n, [&](int, size_t b, size_t e) {
    for (size_t s = b; s < e; ++s) {
      const Vec3& q = x[sorted_[s].second];
      sx_[s] = q.x();
      sy_[s] = q.y();
      sz_[s] = q.z();
      point_[s] = sorted_[s].second;
    }
  }, 1024);
  run_parallel(pool, ncells, [&](int chunk, size_t b, size_t e) {
    std::vector<uint32_t>& out = chunk_list_[chunk];
    size_t used = 0;
    // The candidates of one cell: the points of its 9 rows one after the other, padded to a
    // multiple of 8 with points at infinity (never within h).
    std::vector<double> bx, by, bz;
    std::vector<uint32_t> bid;
    for (size_t c = b; c < e; ++c) {
      const Cell& cell = cells_[c];
      const int64_t cx = static_cast<int64_t>(cell.key & 0x1FFFFF), cy = static_cast<int64_t>((cell.key >> 21) & 0x1FFFFF),
                    cz = static_cast<int64_t>(cell.key >> 42);
      // The 9 rows (z, then y order); in a row the cells x - 1, x, x + 1 are consecutive keys,
      // so their points are one range of slots from the first to the last that exists.
      size_t m = 0, own = 0;  // candidates; where the cell's own row starts among them
      bx.clear();
      by.clear();
      bz.clear();
      bid.clear();
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy) {
          const int64_t ay = cy + dy, az = cz + dz;
          uint32_t rb = 0, re = 0;
          if (dense) {
            // From where cell x - 1 starts to where cell x + 2 starts (empty cells start where
            // the next occupied one does).
            const size_t at = static_cast<size_t>(box_.index(cx - 1, ay, az));
            rb = box_.start[at];
            re = box_.start[at + 3];
          } else {
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
            rb = first->begin;
            re = last->end;
          }
          if (rb == re) continue;
          if (dy == 0 && dz == 0) own = m - rb;  // slot s sits at own + s
          bx.insert(bx.end(), sx_.begin() + rb, sx_.begin() + re);
          by.insert(by.end(), sy_.begin() + rb, sy_.begin() + re);
          bz.insert(bz.end(), sz_.begin() + rb, sz_.begin() + re);
          bid.insert(bid.end(), point_.begin() + rb, point_.begin() + re);
          m += re - rb;
        }
      const size_t padded = (m + 7) / 8 * 8;
      bx.resize(padded, std::numeric_limits<double>::infinity());
      by.resize(padded, std::numeric_limits<double>::infinity());
      bz.resize(padded, std::numeric_limits<double>::infinity());
      bid.resize(padded, 0);
      for (uint32_t s = cell.begin; s < cell.end; ++s) {
        if (used + padded + 8 > out.size()) out.resize(std::max(2 * out.size(), used + padded + 1024));
        used += collect(padded, bx.data(), by.data(), bz.data(), bid.data(), sx_[s], sy_[s], sz_[s], h2, own + s,
                        out.data() + used);
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
  run_parallel(pool, ncells, [&](int chunk, size_t b, size_t e) {
    const uint32_t first = chunk_first_[chunk];
    std::copy(chunk_list_[chunk].begin(), chunk_list_[chunk].begin() + static_cast<ptrdiff_t>(chunk_used_[chunk]),
              list_.begin() + first);
    if (b < e)
      for (uint32_t s = cells_[b].begin; s < cells_[e - 1].end; ++s) offset_[s + 1] += first;
  }, 64);
}

std::vector<uint32_t> NeighbourGrid::cell_order(std::span<const Vec3> x, double h, ThreadPool* pool) {
  std::vector<std::pair<uint64_t, uint32_t>> key, scratch;
  DenseBox box;
  sort_by_cell(x, h, pool, key, box, scratch);
  std::vector<uint32_t> order(x.size());
  for (size_t i = 0; i < x.size(); ++i) order[i] = key[i].second;
  return order;
}

}  // namespace pliant::fluid
