// SPDX-License-Identifier: Apache-2.0
// Waiting on a condition with a deadline instead of sleeping a fixed time: as fast as the
// condition allows on a quiet machine, patient on a loaded one, and a clear message on failure.
#pragma once

#include <gtest/gtest.h>

#include <chrono>
#include <functional>
#include <string_view>

namespace pliant::test {

// How long a test waits for something that takes milliseconds on a quiet machine: generous,
// since the suites run beside builds on 2 cores. Only a broken condition waits this long.
inline constexpr std::chrono::seconds kPatience{30};

// Checks `condition` at once, then polls it (every 1 ms, backing off to 10 ms) until it holds
// or `deadline` has passed. Fails with "timed out after <s> s waiting for <description>";
// use as ASSERT_TRUE(wait_until(...)) << extra context.
::testing::AssertionResult wait_until(const std::function<bool()>& condition, std::chrono::milliseconds deadline,
                                      std::string_view description);

}  // namespace pliant::test
