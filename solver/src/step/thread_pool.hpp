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

  // Chunks of the jobs so far that a worker ran (the rest ran on the calling thread).
  uint64_t chunks_run_by_workers() const { return worker_chunks_.load(std::memory_order_relaxed); }

 private:
  void worker_loop();
  // Claims the next chunk of job `generation`; -1 when that job has none left (or is over).
  int claim(uint32_t generation);
  void run_chunk(int chunk);

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_;
  const std::function<void(int, size_t, size_t)>* job_ = nullptr;
  size_t job_n_ = 0;
  // The job's generation (high 32 bits) and its next unclaimed chunk (low 32 bits).
  std::atomic<uint64_t> claim_{0};
  std::atomic<int> chunks_done_{0};
  std::atomic<uint64_t> worker_chunks_{0};
  std::atomic<bool> stop_{false};
};

}  // namespace pliant
