// SPDX-License-Identifier: Apache-2.0
#include "pliant/test/wait_until.hpp"

#include <algorithm>
#include <string>
#include <thread>

namespace pliant::test {

::testing::AssertionResult wait_until(const std::function<bool()>& condition, std::chrono::milliseconds deadline,
                                      std::string_view description) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto end = start + deadline;
  auto pause = std::chrono::microseconds(1000);
  int checks = 0;
  while (true) {
    ++checks;
    if (condition()) return ::testing::AssertionSuccess();
    if (Clock::now() >= end) break;
    std::this_thread::sleep_for(std::min<Clock::duration>(pause, end - Clock::now()));
    pause = std::min(pause * 2, std::chrono::microseconds(10000));
  }
  const double waited = std::chrono::duration<double>(Clock::now() - start).count();
  return ::testing::AssertionFailure() << "timed out after " << waited << " s (deadline "
                                       << std::chrono::duration<double>(deadline).count() << " s, " << checks
                                       << " checks) waiting for " << std::string(description);
}

}  // namespace pliant::test
