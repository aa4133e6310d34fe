// SPDX-License-Identifier: Apache-2.0
// The test support library's wait: succeeds as soon as the condition holds, and fails at the
// deadline with a message naming what it waited for.
#include "pliant/test/wait_until.hpp"

#include <gtest/gtest.h>

#include <chrono>
#include <string>

using pliant::test::wait_until;

TEST(WaitUntil, ReturnsOnceTheConditionHolds) {
  int checks = 0;
  EXPECT_TRUE(wait_until([&] { return ++checks == 3; }, std::chrono::seconds(30), "the third check"));
  EXPECT_EQ(checks, 3);
}

TEST(WaitUntil, FailsAtTheDeadlineNamingWhatItWaitedFor) {
  const auto start = std::chrono::steady_clock::now();
  const ::testing::AssertionResult r = wait_until([] { return false; }, std::chrono::milliseconds(20), "a frame past tick 7");
  EXPECT_GE(std::chrono::steady_clock::now() - start, std::chrono::milliseconds(20));
  ASSERT_FALSE(r);
  const std::string message = r.message();
  EXPECT_NE(message.find("timed out after"), std::string::npos) << message;
  EXPECT_NE(message.find("waiting for a frame past tick 7"), std::string::npos) << message;
}
