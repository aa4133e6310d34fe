// SPDX-License-Identifier: Apache-2.0
// A small fixed pool of worker threads for data-parallel loops inside one step. The calling
// thread takes part in the work, so threads = 1 means no worker at all. Loops are split into
// contiguous chunks (one per thread) so results never depend on scheduling. Workers spin
// briefly between jobs (a sweep issues one job per colour, microseconds apart) and sleep on a
// condition variable when idle longer.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
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

  // Calls fn(chunk, begin, end) for `size()` contiguous chunks of [0, n), in parallel, and
  // returns when all are done. Runs inline when n < min_parallel or the pool has one thread.
  void parallel_for(size_t n, const std::function<void(int, size_t, size_t)>& fn,
                    size_t min_parallel = 128);

 private:
  void worker_loop(int index);

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_;
  const std::function<void(int, size_t, size_t)>* job_ = nullptr;
  size_t job_n_ = 0;
  std::atomic<unsigned> generation_{0};
  std::atomic<int> pending_{0};
  std::atomic<bool> stop_{false};
};

}  // namespace pliant
