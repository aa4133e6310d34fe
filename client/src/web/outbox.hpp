// SPDX-License-Identifier: Apache-2.0
// What one browser socket has still to send: control messages (JSON replies, topology) in
// order, and at most one frame. A newer frame replaces an unsent one; the frames dropped that
// way (and those the server had already skipped for them) are added to the skipped_frames of
// the frame that is sent, so the page can show them. Memory per socket is bounded by one frame
// plus the (small) control messages.
//
// With flow control on (the page asks for it), a frame is sent only while the browser has
// credit: it grants one per frame it handled, so at most `window` frames wait in the browser
// and a page that falls behind sees the latest frame and the skip count, not a growing queue.
#pragma once

#include "wire.hpp"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <mutex>
#include <optional>
#include <string>

namespace pliant::web {

struct OutMessage {
  bool binary = false;
  std::string bytes;
};

class Outbox {
 public:
  // Control messages are sent before any frame still pending.
  void push_control(OutMessage m) {
    {
      std::lock_guard lock(mu_);
      if (closed_) return;
      control_.push_back(std::move(m));
    }
    cv_.notify_one();
  }

  // Puts an encoded frame in the slot; returns true when it replaced one not yet sent.
  bool put_frame(std::string frame) {
    bool replaced = false;
    {
      std::lock_guard lock(mu_);
      if (closed_) return false;
      if (frame_) {
        replaced = true;
        dropped_ += 1 + skipped_of(*frame_);
        ++replaced_total_;
      }
      frame_ = std::move(frame);
    }
    cv_.notify_one();
    return replaced;
  }

  // Forgets a pending frame and the drop count (a new subscription starts afresh); sets the
  // flow control for the frames to come: window 0 sends whenever a frame is there, else at most
  // `window` frames without a grant.
  void clear_frame(uint32_t window = 0) {
    {
      std::lock_guard lock(mu_);
      frame_.reset();
      dropped_ = 0;
      window_ = window;
      credits_ = window;
    }
    cv_.notify_one();
  }

  // The browser handled n frames: as many more may be sent (never more than the window).
  void grant(uint32_t n) {
    {
      std::lock_guard lock(mu_);
      if (window_ == 0) return;
      credits_ = std::min<uint64_t>(window_, uint64_t(credits_) + n);
    }
    cv_.notify_one();
  }

  // The next message to send, waiting at most `timeout`; nullopt on timeout or once closed.
  std::optional<OutMessage> take(std::chrono::milliseconds timeout) {
    std::unique_lock lock(mu_);
    cv_.wait_for(lock, timeout, [&] { return closed_ || !control_.empty() || frame_ready(); });
    if (closed_) return std::nullopt;
    if (!control_.empty()) {
      OutMessage m = std::move(control_.front());
      control_.pop_front();
      return m;
    }
    if (!frame_ready()) return std::nullopt;
    OutMessage m{true, std::move(*frame_)};
    frame_.reset();
    if (window_ > 0) --credits_;
    add_skipped(m.bytes, dropped_);
    dropped_ = 0;
    return m;
  }

  void close() {
    {
      std::lock_guard lock(mu_);
      closed_ = true;
      control_.clear();
      frame_.reset();
    }
    cv_.notify_all();
  }

  // Frames replaced before they were sent, since the outbox was made.
  uint64_t replaced_total() const {
    std::lock_guard lock(mu_);
    return replaced_total_;
  }

 private:
  bool frame_ready() const { return frame_ && (window_ == 0 || credits_ > 0); }

  static uint32_t skipped_of(const std::string& frame) {
    uint32_t s = 0;
    if (frame.size() >= kFrameSkippedOffset + 4) std::memcpy(&s, frame.data() + kFrameSkippedOffset, 4);
    return s;
  }
  static void add_skipped(std::string& frame, uint64_t extra) {
    if (frame.size() < kFrameSkippedOffset + 4 || extra == 0) return;
    const uint64_t total = std::min<uint64_t>(skipped_of(frame) + extra, UINT32_MAX);
    const uint32_t s = static_cast<uint32_t>(total);
    std::memcpy(frame.data() + kFrameSkippedOffset, &s, 4);
  }

  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<OutMessage> control_;
  std::optional<std::string> frame_;
  uint64_t dropped_ = 0;
  uint64_t replaced_total_ = 0;
  uint32_t window_ = 0;   // 0: no flow control
  uint32_t credits_ = 0;  // frames that may be sent before the next grant
  bool closed_ = false;
};

}  // namespace pliant::web
