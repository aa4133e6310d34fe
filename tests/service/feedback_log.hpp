// SPDX-License-Identifier: Apache-2.0
// A haptic stream and a thread that keeps every feedback it receives, for the service tests;
// closed (and the thread joined) at the latest when it goes, so that a failed assertion does not
// leave the thread running.
#pragma once

#include "pliant/client/client.hpp"

#include <algorithm>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace pliant::test {

struct FeedbackLog {
  explicit FeedbackLog(client::Client& c) : stream(c.haptic_stream()), reader([this] {
    v1::ToolFeedback f;
    while (stream->next(&f)) {
      std::lock_guard lk(mu);
      got.push_back(f);
    }
  }) {}
  ~FeedbackLog() {
    if (reader.joinable()) close();
  }
  // Closes the stream and waits for the reader; true when the stream finished without error.
  bool close() {
    stream->close();
    reader.join();
    return stream->finish().ok();
  }
  std::vector<v1::ToolFeedback> all() {
    std::lock_guard lk(mu);
    return got;
  }
  size_t count() {
    std::lock_guard lk(mu);
    return got.size();
  }
  // Whether a feedback has come for a tick that used pose `seq`.
  bool used(uint64_t seq) {
    std::lock_guard lk(mu);
    return std::any_of(got.begin(), got.end(), [&](const v1::ToolFeedback& f) { return f.pose_seq() == seq; });
  }
  // The latest feedback (into `out` when given) when it is of `tick` or later.
  bool latest(uint64_t tick, v1::ToolFeedback* out = nullptr) {
    std::lock_guard lk(mu);
    if (got.empty() || got.back().tick() < tick) return false;
    if (out) *out = got.back();
    return true;
  }

  std::unique_ptr<client::HapticStream> stream;
  std::mutex mu;
  std::vector<v1::ToolFeedback> got;
  std::thread reader;
};

}  // namespace pliant::test
