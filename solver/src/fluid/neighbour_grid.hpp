// SPDX-License-Identifier: Apache-2.0
// Fixed-radius neighbour search on a uniform grid of cell h: the points sorted by cell (z, y,
// x) by counting into the box of the occupied cells (or, for points spread far apart, sorted
// and the occupied cells found through a hash table), and for every cell the points of its 27
// neighbouring cells (9 rows of three consecutive cells, each a range of sorted points)
// copied once into contiguous arrays that each of its points scans 8 candidates at a time.
// Each point's neighbours (distance < h, itself excluded) come in a fixed order (cells in z,
// y, x order, points by index within a cell) whatever the number of threads.
#pragma once

#include "pliant/mesh.hpp"

#include <cstdint>
#include <span>
#include <vector>

namespace pliant {
class ThreadPool;
}

namespace pliant::fluid {

class NeighbourGrid {
 public:
  // Neighbours within h of every point of x; the pool may be null (one thread).
  void build(std::span<const Vec3> x, double h, ThreadPool* pool);

  size_t size() const { return slot_.size(); }
  std::span<const uint32_t> neighbours(size_t i) const {
    const uint32_t s = slot_[i];
    return {list_.data() + offset_[s], list_.data() + offset_[s + 1]};
  }
  size_t pairs() const { return list_.size(); }  // directed pairs (each pair counted twice)
  // Where point i's neighbours start in the list of all pairs (per-pair data goes there).
  size_t first(size_t i) const { return offset_[slot_[i]]; }
  // The same by slot: the points in cell order (slot s holds point(s)), whose neighbour lists
  // follow each other in the list of all pairs (slot_first(size()) = pairs()).
  uint32_t point(size_t s) const { return sorted_[s].second; }
  size_t slot_first(size_t s) const { return offset_[s]; }
  std::span<const uint32_t> slot_neighbours(size_t s) const {
    return {list_.data() + offset_[s], list_.data() + offset_[s + 1]};
  }

  // The permutation that orders points by grid cell (z, then y, then x; ties by index):
  // order[k] = the point that goes to place k. The pool may be null (one thread).
  static std::vector<uint32_t> cell_order(std::span<const Vec3> x, double h, ThreadPool* pool = nullptr);

 private:
  // The box of the occupied cells with a cell of padding (two above along x), and where each of
  // its cells starts in the sorted points (start, nx ny nz + 1 entries; empty without the box).
  struct DenseBox {
    int64_t lx = 0, ly = 0, lz = 0, nx = 0, ny = 0, nz = 0;
    std::vector<uint32_t> start, fill;
    int64_t index(int64_t x, int64_t y, int64_t z) const;
  };
  static void sort_by_cell(std::span<const Vec3> x, double h, ThreadPool* pool,
                           std::vector<std::pair<uint64_t, uint32_t>>& sorted, DenseBox& box,
                           std::vector<std::pair<uint64_t, uint32_t>>& scratch);

  struct Cell {
    uint64_t key;
    uint32_t begin, end;  // in sorted_
  };
  std::vector<std::pair<uint64_t, uint32_t>> sorted_;  // (cell key, point), ascending
  std::vector<std::pair<uint64_t, uint32_t>> scratch_;  // the pairs in point order, before sorting
  DenseBox box_;
  std::vector<uint32_t> slot_;                         // point -> place in sorted_
  std::vector<Cell> cells_;
  std::vector<int32_t> table_;  // open addressing: cell key -> index in cells_ (-1 empty)
  std::vector<uint32_t> offset_;  // by place in sorted_
  std::vector<double> sx_, sy_, sz_;  // coordinates by place in sorted_
  std::vector<uint32_t> point_;       // point by place in sorted_
  std::vector<uint32_t> list_;
  std::vector<std::vector<uint32_t>> chunk_list_;  // per chunk; the first chunk_used_ are its pairs
  std::vector<size_t> chunk_used_;
  std::vector<uint32_t> chunk_first_;
};

}  // namespace pliant::fluid
