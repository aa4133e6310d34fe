// SPDX-License-Identifier: Apache-2.0
#include "step/thread_pool.hpp"

#include <algorithm>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define PLIANT_PAUSE() _mm_pause()
#else
#define PLIANT_PAUSE() std::this_thread::yield()
#endif

namespace pliant {

namespace {
constexpr int kSpinRounds = 20000;  // about 0.1 ms of pausing before a worker sleeps
}  // namespace

ThreadPool::ThreadPool(int threads) : claimed_(size_t(std::max(threads, 1))) {
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

void ThreadPool::run_claimed(int index, uint64_t generation) {
  const int chunks = size();
  for (int k = 0; k < chunks; ++k) {
    const int c = (index + k) % chunks;
    uint64_t last = claimed_[size_t(c)].load(std::memory_order_acquire);
    bool mine = false;
    while (last < generation && !(mine = claimed_[size_t(c)].compare_exchange_weak(last, generation, std::memory_order_acq_rel,
                                                                                   std::memory_order_acquire))) {
    }
    if (!mine) continue;
    // Claimed for this job, so the job is still running (its caller waits for every chunk).
    const size_t n = job_n_;
    (*job_)(c, n * size_t(c) / size_t(chunks), n * size_t(c + 1) / size_t(chunks));
    chunks_done_.fetch_add(1, std::memory_order_acq_rel);
  }
}

[[gnu::noinline]] void run_parallel(ThreadPool* pool, size_t n, const std::function<void(int, size_t, size_t)>& fn,
                                    size_t min_parallel) {
  if (pool)
    pool->parallel_for(n, fn, min_parallel);
  else
    fn(0, 0, n);
}

void for_each_block(ThreadPool& pool, size_t n, size_t block, const std::function<void(size_t, size_t, size_t)>& fn) {
  pool.parallel_for(block_count(n, block), [&](int, size_t first, size_t end) {
    for (size_t k = first; k < end; ++k) fn(k, k * block, std::min(n, (k + 1) * block));
  }, 2);
}

double block_sum(ThreadPool& pool, size_t n, size_t block, std::vector<double>& partial,
                 const std::function<double(size_t, size_t)>& term_sum) {
  partial.assign(block_count(n, block), 0.0);
  for_each_block(pool, n, block, [&](size_t k, size_t b, size_t e) { partial[k] = term_sum(b, e); });
  double sum = 0;
  for (double p : partial) sum += p;
  return sum;
}

void ThreadPool::parallel_for(size_t n, const std::function<void(int, size_t, size_t)>& fn,
                              size_t min_parallel) {
  if (workers_.empty() || n < min_parallel) {
    fn(0, 0, n);
    return;
  }
  uint64_t generation;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    job_ = &fn;
    job_n_ = n;
    chunks_done_.store(0, std::memory_order_relaxed);
    generation = generation_.load(std::memory_order_relaxed) + 1;
    generation_.store(generation, std::memory_order_release);
  }
  start_cv_.notify_all();
  run_claimed(0, generation);
  // Only chunks a worker has claimed and not finished are left: spin briefly (they finish
  // within microseconds when the worker has a core), then yield so that an oversubscribed
  // machine does not burn the waiting thread's whole time slice.
  for (int spins = 0; chunks_done_.load(std::memory_order_acquire) != size(); ++spins) {
    if (spins < 2000) PLIANT_PAUSE();
    else std::this_thread::yield();
  }
}

void ThreadPool::worker_loop(int index) {
  uint64_t seen = 0;
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
    // The newest job; one that ended before this worker woke up has no chunk left to claim.
    seen = generation_.load(std::memory_order_acquire);
    run_claimed(index, seen);
  }
}

}  // namespace pliant
