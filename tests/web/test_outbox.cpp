// SPDX-License-Identifier: Apache-2.0
// The socket's send slot (latest frame wins, skips counted) and the grabs a socket releases
// when it closes.
#include "grabs.hpp"
#include "outbox.hpp"
#include "wire.hpp"

#include <gtest/gtest.h>

#include <thread>
#include <vector>

namespace {

using namespace pliant;
using namespace pliant::web;
using namespace std::chrono_literals;

std::string frame(uint64_t tick, uint64_t server_skipped = 0) {
  v1::Frame f;
  f.set_tick(tick);
  f.set_skipped_frames(server_skipped);
  for (int i = 0; i < 6; ++i) f.add_positions(static_cast<float>(tick));
  return encode_frame(f, 1, Encoding::Float32, 2);
}

TEST(WebOutbox, ANewerFrameReplacesAnUnsentOneAndTheSkipIsCounted) {
  Outbox box;
  EXPECT_FALSE(box.put_frame(frame(1)));
  EXPECT_TRUE(box.put_frame(frame(2)));
  EXPECT_TRUE(box.put_frame(frame(3, 4)));  // the server had skipped 4 before tick 3
  auto m = box.take(0ms);
  ASSERT_TRUE(m);
  const FrameHeader h = decode_frame_header(m->bytes);
  EXPECT_EQ(h.tick, 3u);
  EXPECT_EQ(h.skipped_frames, 6u);  // ticks 1 and 2 dropped here, 4 by the server
  EXPECT_EQ(box.replaced_total(), 2u);
  EXPECT_FALSE(box.take(0ms));  // one pending frame at most: nothing left
  // The count starts again after a send.
  box.put_frame(frame(4));
  EXPECT_EQ(decode_frame_header(box.take(0ms)->bytes).skipped_frames, 0u);
}

TEST(WebOutbox, DroppedFramesCarryTheirOwnServerSkips) {
  Outbox box;
  box.put_frame(frame(5, 2));
  box.put_frame(frame(6, 1));
  box.put_frame(frame(7));
  // 5 and 6 dropped (2), plus the 2 + 1 the server skipped before them.
  EXPECT_EQ(decode_frame_header(box.take(0ms)->bytes).skipped_frames, 5u);
}

TEST(WebOutbox, ControlMessagesGoFirstAndInOrder) {
  Outbox box;
  box.put_frame(frame(1));
  box.push_control({false, "a"});
  box.push_control({true, "topology"});
  EXPECT_EQ(box.take(0ms)->bytes, "a");
  EXPECT_EQ(box.take(0ms)->bytes, "topology");
  EXPECT_EQ(decode_frame_header(box.take(0ms)->bytes).tick, 1u);
}

TEST(WebOutbox, ClearForgetsThePendingFrameAndItsCount) {
  Outbox box;
  box.put_frame(frame(1));
  box.put_frame(frame(2));
  box.clear_frame();
  EXPECT_FALSE(box.take(0ms));
  box.put_frame(frame(3));
  EXPECT_EQ(decode_frame_header(box.take(0ms)->bytes).skipped_frames, 0u);
}

TEST(WebOutbox, AStalledReaderHoldsOneFrameWhateverTheProducerSends) {
  Outbox box;
  std::thread producer([&] {
    for (uint64_t t = 1; t <= 5000; ++t) box.put_frame(frame(t));
  });
  producer.join();
  auto m = box.take(0ms);
  ASSERT_TRUE(m);
  const FrameHeader h = decode_frame_header(m->bytes);
  EXPECT_EQ(h.tick, 5000u);
  EXPECT_EQ(h.skipped_frames, 4999u);
  EXPECT_FALSE(box.take(0ms));
}

TEST(WebOutbox, WithFlowControlAFrameWaitsForTheBrowsersGrant) {
  Outbox box;
  box.clear_frame(2);  // at most 2 frames in the browser
  box.put_frame(frame(1));
  EXPECT_EQ(decode_frame_header(box.take(0ms)->bytes).tick, 1u);
  box.put_frame(frame(2));
  EXPECT_EQ(decode_frame_header(box.take(0ms)->bytes).tick, 2u);
  box.put_frame(frame(3));
  box.push_control({false, "reply"});
  EXPECT_EQ(box.take(0ms)->bytes, "reply") << "control messages need no credit";
  EXPECT_FALSE(box.take(0ms)) << "two frames unacknowledged: the third waits";
  box.put_frame(frame(4));
  box.put_frame(frame(5));
  box.grant(1);
  const FrameHeader h = decode_frame_header(box.take(0ms)->bytes);
  EXPECT_EQ(h.tick, 5u);
  EXPECT_EQ(h.skipped_frames, 2u) << "3 and 4 were replaced while the browser was behind";
  box.grant(10);  // grants never exceed the window
  box.put_frame(frame(6));
  ASSERT_TRUE(box.take(0ms));
  box.put_frame(frame(7));
  ASSERT_TRUE(box.take(0ms));
  box.put_frame(frame(8));
  EXPECT_FALSE(box.take(0ms)) << "the window is 2 however much was granted";
}

TEST(WebOutbox, CloseWakesAWaitingWriter) {
  Outbox box;
  std::thread closer([&] {
    std::this_thread::sleep_for(20ms);
    box.close();
  });
  EXPECT_FALSE(box.take(10s));  // returns on close, not after 10 s
  closer.join();
  box.put_frame(frame(1));
  EXPECT_FALSE(box.take(0ms));  // nothing is queued once closed
}

TEST(WebGrabs, ClosingReleasesEveryGrabOnce) {
  GrabSet grabs;
  grabs.add("a", 1);
  grabs.add("a", 2);
  grabs.add("b", 7);
  EXPECT_TRUE(grabs.remove("a", 2));   // released by the page itself
  EXPECT_FALSE(grabs.remove("a", 2));
  std::vector<std::pair<std::string, uint64_t>> released;
  const size_t n = grabs.release_all([&](const std::string& s, uint64_t id) { released.emplace_back(s, id); });
  EXPECT_EQ(n, 2u);
  EXPECT_EQ(released, (std::vector<std::pair<std::string, uint64_t>>{{"a", 1}, {"b", 7}}));
  EXPECT_EQ(grabs.size(), 0u);
  EXPECT_EQ(grabs.release_all([&](const std::string&, uint64_t) { ADD_FAILURE() << "released twice"; }), 0u);
}

TEST(WebGrabs, LeavingASceneReleasesOnlyItsGrabs) {
  GrabSet grabs;
  grabs.add("a", 1);
  grabs.add("b", 2);
  std::vector<uint64_t> released;
  grabs.release_all([&](const std::string&, uint64_t id) { released.push_back(id); }, "a");
  EXPECT_EQ(released, (std::vector<uint64_t>{1}));
  EXPECT_TRUE(grabs.contains("b", 2));
}

}  // namespace
