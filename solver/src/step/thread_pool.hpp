// SPDX-License-Identifier: Apache-2.0
// A small fixed pool of worker threads for data-parallel loops inside one step. A loop is cut
// into size() contiguous chunks, always the same for a given n, and fn receives the chunk's
// index: per-chunk results never depend on which thread ran a chunk or on scheduling. The
// calling thread takes part, so threads = 1 means no worker at all. Chunks are claimed: the
// caller and the workers take the next unclaimed chunk until none is left, so the caller never
// waits for a worker that has not been scheduled yet (on a loaded machine it runs that chunk
// itself), only for chunks already running. Workers spin briefly between jobs (a sweep issues
// one job per colour, microseconds apart) and sleep on a condition variable when idle longer.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace pliant {

class ThreadPool {
 public:
  explicit ThreadPool(int threads);
  ~ThreadPool();
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int size() const { return static_cast<int>(workers_.size()) + 1; }

  // Calls fn(chunk, begin, end) for the `size()` contiguous chunks of [0, n), in parallel, and
  // returns when all are done. Runs inline when n < min_parallel or the pool has one thread.
  void parallel_for(size_t n, const std::function<void(int, size_t, size_t)>& fn,
                    size_t min_parallel = 128);


 private:
  void worker_loop(int index);
  // Runs the chunks of job `generation` that thread `index` can claim, its own first.
  void run_claimed(int index, uint64_t generation);

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_;
  const std::function<void(int, size_t, size_t)>* job_ = nullptr;
  size_t job_n_ = 0;
  std::atomic<uint64_t> generation_{0};  // of the newest job
  // Per chunk, the generation of the last job that claimed it: a chunk is claimed for job g by
  // raising it from below g to g, so a worker that wakes up for a job already over claims nothing.
  std::vector<std::atomic<uint64_t>> claimed_;
  std::atomic<int> chunks_done_{0};
  std::atomic<bool> stop_{false};
};

// fn over [0, n) on `pool` (in chunks when n >= min_parallel), or whole on this thread when there
// is no pool. Either way fn is called through the same out-of-line std::function call: a copy
// of it that the compiler inlined at the caller could contract its products into FMAs
// differently, and results would then depend on the thread count.
void run_parallel(ThreadPool* pool, size_t n, const std::function<void(int, size_t, size_t)>& fn,
                  size_t min_parallel = 128);

// Calls fn(k, begin, end) for the blocks k = 0, 1, ... of `block` items of [0, n) (the last one
// shorter), blocks in parallel. The blocks do not depend on the thread count, so a sum kept per
// block and added in block order has the same bits with any number of threads (a sum per chunk
// does not).
void for_each_block(ThreadPool& pool, size_t n, size_t block, const std::function<void(size_t, size_t, size_t)>& fn);
inline size_t block_count(size_t n, size_t block) { return (n + block - 1) / block; }

// The sum over [0, n) of term_sum(begin, end) (a block's sum), formed per block of `block` items
// and added in block order: the same bits with any thread count. partial: scratch.
double block_sum(ThreadPool& pool, size_t n, size_t block, std::vector<double>& partial,
                 const std::function<double(size_t, size_t)>& term_sum);

}  // namespace pliant
