// SPDX-License-Identifier: Apache-2.0
#include "step/thread_pool.hpp"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define PLIANT_PAUSE() _mm_pause()
#else
#define PLIANT_PAUSE() std::this_thread::yield()
#endif

namespace pliant {

namespace {
constexpr int kSpinRounds = 20000;  // about 0.1 ms of pausing before a worker sleeps

void chunk_range(size_t n, int chunks, int c, size_t& begin, size_t& end) {
  begin = n * size_t(c) / size_t(chunks);
  end = n * size_t(c + 1) / size_t(chunks);
}
}  // namespace

ThreadPool::ThreadPool(int threads) {
  for (int i = 1; i < threads; ++i) workers_.emplace_back([this, i] { worker_loop(i); });
}

ThreadPool::~ThreadPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  start_cv_.notify_all();
  for (auto& t : workers_) t.join();
}

void ThreadPool::parallel_for(size_t n, const std::function<void(int, size_t, size_t)>& fn,
                              size_t min_parallel) {
  if (workers_.empty() || n < min_parallel) {
    fn(0, 0, n);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    job_ = &fn;
    job_n_ = n;
    pending_.store(static_cast<int>(workers_.size()), std::memory_order_relaxed);
    generation_.fetch_add(1, std::memory_order_release);
  }
  start_cv_.notify_all();
  size_t b, e;
  chunk_range(n, size(), 0, b, e);
  fn(0, b, e);
  // Spin briefly (workers finish within microseconds when they have a core), then yield so an
  // oversubscribed machine does not burn the waiting thread's whole time slice.
  for (int spins = 0; pending_.load(std::memory_order_acquire) != 0; ++spins) {
    if (spins < 2000) PLIANT_PAUSE();
    else std::this_thread::yield();
  }
}

void ThreadPool::worker_loop(int index) {
  unsigned seen = 0;
  for (;;) {
    int spins = 0;
    while (generation_.load(std::memory_order_acquire) == seen && !stop_.load()) {
      if (++spins < kSpinRounds) {
        if (spins < kSpinRounds / 10) PLIANT_PAUSE();
        else std::this_thread::yield();
        continue;
      }
      std::unique_lock<std::mutex> lock(mutex_);
      start_cv_.wait(lock, [&] { return stop_.load() || generation_.load() != seen; });
    }
    if (stop_.load()) return;
    const std::function<void(int, size_t, size_t)>* job;
    size_t n;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      seen = generation_.load();
      job = job_;
      n = job_n_;
    }
    size_t b, e;
    chunk_range(n, size(), index, b, e);
    (*job)(index, b, e);
    pending_.fetch_sub(1, std::memory_order_acq_rel);
  }
}

}  // namespace pliant
