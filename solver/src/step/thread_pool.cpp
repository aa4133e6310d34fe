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

uint32_t generation_of(uint64_t claim) { return uint32_t(claim >> 32); }
uint32_t next_chunk_of(uint64_t claim) { return uint32_t(claim); }
}  // namespace

ThreadPool::ThreadPool(int threads) {
  for (int i = 1; i < threads; ++i) workers_.emplace_back([this] { worker_loop(); });
}

ThreadPool::~ThreadPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  start_cv_.notify_all();
  for (auto& t : workers_) t.join();
}

int ThreadPool::claim(uint32_t generation) {
  uint64_t cur = claim_.load(std::memory_order_acquire);
  for (;;) {
    if (generation_of(cur) != generation || next_chunk_of(cur) >= uint32_t(size())) return -1;
    if (claim_.compare_exchange_weak(cur, cur + 1, std::memory_order_acq_rel, std::memory_order_acquire))
      return int(next_chunk_of(cur));
  }
}

void ThreadPool::run_chunk(int chunk) {
  const size_t n = job_n_, chunks = size_t(size());
  (*job_)(chunk, n * size_t(chunk) / chunks, n * size_t(chunk + 1) / chunks);
  chunks_done_.fetch_add(1, std::memory_order_acq_rel);
}

void ThreadPool::parallel_for(size_t n, const std::function<void(int, size_t, size_t)>& fn,
                              size_t min_parallel) {
  if (workers_.empty() || n < min_parallel) {
    fn(0, 0, n);
    return;
  }
  uint32_t generation;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    job_ = &fn;
    job_n_ = n;
    chunks_done_.store(0, std::memory_order_relaxed);
    generation = generation_of(claim_.load(std::memory_order_relaxed)) + 1;
    claim_.store(uint64_t(generation) << 32, std::memory_order_release);
  }
  start_cv_.notify_all();
  for (int c; (c = claim(generation)) >= 0;) run_chunk(c);
  // Only chunks a worker has claimed and not finished are left: spin briefly (they finish
  // within microseconds when the worker has a core), then yield so that an oversubscribed
  // machine does not burn the waiting thread's whole time slice.
  for (int spins = 0; chunks_done_.load(std::memory_order_acquire) != size(); ++spins) {
    if (spins < 2000) PLIANT_PAUSE();
    else std::this_thread::yield();
  }
}

void ThreadPool::worker_loop() {
  uint32_t seen = 0;
  for (;;) {
    int spins = 0;
    while (generation_of(claim_.load(std::memory_order_acquire)) == seen && !stop_.load()) {
      if (++spins < kSpinRounds) {
        if (spins < kSpinRounds / 10) PLIANT_PAUSE();
        else std::this_thread::yield();
        continue;
      }
      std::unique_lock<std::mutex> lock(mutex_);
      start_cv_.wait(lock, [&] { return stop_.load() || generation_of(claim_.load()) != seen; });
    }
    if (stop_.load()) return;
    // The newest job; a job that ended before this worker woke up has no chunk left to claim.
    seen = generation_of(claim_.load(std::memory_order_acquire));
    for (int c; (c = claim(seen)) >= 0;) {
      run_chunk(c);
      worker_chunks_.fetch_add(1, std::memory_order_relaxed);
    }
  }
}

}  // namespace pliant
