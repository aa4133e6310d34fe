// SPDX-License-Identifier: Apache-2.0
// Fixed-radius neighbour search on a uniform grid of cell h: cells hashed into a table of
// buckets filled by a counting sort, then every particle's neighbours (distance < h, itself
// excluded) gathered from the 27 cells around it into one compressed list. The lists are in
// a fixed order (cells in z, y, x order, particles by index) whatever the number of threads.
#pragma once

#include "pliant/mesh.hpp"

#include <array>
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

  size_t size() const { return offset_.empty() ? 0 : offset_.size() - 1; }
  std::span<const uint32_t> neighbours(size_t i) const {
    return {list_.data() + offset_[i], list_.data() + offset_[i + 1]};
  }
  size_t pairs() const { return list_.size(); }  // directed pairs (each pair counted twice)

  // The permutation that orders points by grid cell (z, then y, then x; ties by index):
  // order[k] = the point that goes to place k.
  static std::vector<uint32_t> cell_order(std::span<const Vec3> x, double h);

 private:
  std::vector<std::array<int32_t, 3>> cell_;
  std::vector<uint32_t> bucket_;
  std::vector<uint32_t> bucket_start_;
  std::vector<uint32_t> sorted_;
  std::vector<uint32_t> offset_;
  std::vector<uint32_t> list_;
  std::vector<std::vector<uint32_t>> chunk_list_;
  std::vector<uint32_t> chunk_first_;
};

}  // namespace pliant::fluid
