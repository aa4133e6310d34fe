// SPDX-License-Identifier: Apache-2.0
// Frame and haptic streams at scale and under slow readers: open streams cost no thread each (the server
// counts its threads in /proc/self/task), a reader that stops reading gets the newest frame
// when it reads again (after at most the one frame its transport held), told how many it
// skipped, and idle streams end when their scene is deleted.
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/wait_until.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <filesystem>
#include <iostream>
#include <thread>

using namespace pliant;
using client::Client;

namespace {

using namespace test::grpc_codes;

int thread_count() {
  int n = 0;
  for ([[maybe_unused]] const auto& e : std::filesystem::directory_iterator("/proc/self/task")) ++n;
  return n;
}

// Many streams on a loaded machine: clients wait up to 60 s, a Step up to 120 s.
struct Fixture : test::InProcessServer {
  explicit Fixture(server::ServerOptions o = {})
      : InProcessServer(std::move(o), {std::chrono::seconds(60), std::chrono::seconds(120)}) {}
};

v1::CreateSceneRequest lockstep_beam(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_solver()->set_substeps(1);
  r.mutable_spec()->mutable_solver()->set_iterations(1);
  r.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  return r;
}

}  // namespace

// A reader that stops reading while the scene runs N ticks gets, when it reads again, a frame
// within a few ticks of the scene's tick (not the backlog from when it stopped; at most one
// older frame, already in its transport, comes first), and the count of frames it skipped. Frames of every size: all positions, and solver figures only (small
// frames were the ones that queued up by the hundred in transport buffers).
TEST(StreamScale, SlowReaderGetsTheNewestFrame) {
  Fixture fx;
  Client c = fx.client();
  ASSERT_TRUE(c.create_scene(lockstep_beam("slow")).ok());
  ASSERT_TRUE(c.step("slow", 1).ok());
  for (bool small : {false, true}) {
    SCOPED_TRACE(small ? "solver figures only" : "all positions");
    v1::StreamFramesRequest q;
    q.set_scene_id("slow");
    if (small) q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
    auto stream = c.stream_frames(q);
    v1::Frame f;
    ASSERT_TRUE(stream->next(&f));
    constexpr uint32_t kTicks = 900;  // 15 s of a 60 Hz scene
    auto st = c.step("slow", kTicks);
    ASSERT_TRUE(st.ok()) << st.status.to_string();
    const uint64_t now = st->tick();
    // The client's transport may hold the one frame that was on its way when the reader
    // stopped; the read after it is the newest frame, with the count of frames skipped.
    int reads = 0;
    uint64_t first_tick = 0;
    while (f.tick() + 3 < now && reads < 50) {
      ASSERT_TRUE(stream->next(&f));
      if (++reads == 1) first_tick = f.tick();
    }
    std::cout << "[ slow reader ] " << (small ? "small" : "positions") << " frames (" << f.ByteSizeLong()
              << " bytes): scene at tick " << now << ", first read tick " << first_tick << ", read " << reads
              << " frame(s) to tick " << f.tick() << " with skipped_frames " << f.skipped_frames() << "\n";
    EXPECT_LE(reads, 2) << "frames queued up for the paused reader";
    EXPECT_GE(f.tick() + 3, now);
    EXPECT_GT(f.skipped_frames(), 0u);
    stream->cancel();
    stream->finish();
  }
}

constexpr int kStreams = 1000, kChannels = 4;

// A server that admits a thousand streams, and kChannels clients of it (the streams are spread
// over several connections, as many users' would be).
struct IdleScene {
  static server::ServerOptions options() {
    server::ServerOptions o;
    o.max_streams = kStreams + 10;
    o.max_streams_per_scene = kStreams + 10;
    return o;
  }
  Fixture fx{options()};
  std::vector<Client> clients;
  IdleScene() {
    for (int i = 0; i < kChannels; ++i) clients.push_back(fx.client());
  }
};

// A thousand open, idle streams (their first frame read) add fewer than 20 threads to the
// process (server and the test's client together), and all end when the scene is deleted.
TEST(StreamScale, ThousandIdleStreamsCostFewThreadsAndEndWithTheirScene) {
  IdleScene idle;
  std::vector<Client>& clients = idle.clients;
  ASSERT_TRUE(clients[0].create_scene(lockstep_beam("idle")).ok());
  ASSERT_TRUE(clients[0].step("idle", 1).ok());
  v1::StreamFramesRequest q;
  q.set_scene_id("idle");
  q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  v1::Frame f;
  {  // warm up every channel (connections, gRPC's own threads)
    for (auto& c : clients) {
      auto s = c.stream_frames(q);
      ASSERT_TRUE(s->next(&f));
      s->cancel();
      s->finish();
    }
  }
  const int before = thread_count();
  std::vector<std::unique_ptr<client::FrameStream>> streams;
  for (int i = 0; i < kStreams; ++i) {
    streams.push_back(clients[i % kChannels].stream_frames(q));
    ASSERT_TRUE(streams.back()->next(&f)) << "stream " << i;
  }
  const int after = thread_count();
  std::cout << "[ idle streams ] " << kStreams << " open streams: threads " << before << " -> " << after << " (+"
            << after - before << ")\n";
  RecordProperty("threads_added", after - before);
  EXPECT_LT(after - before, 20);

  // They all end with NOT_FOUND when the scene goes.
  ASSERT_TRUE(clients[0].delete_scene("idle").ok());
  int not_found = 0;
  for (auto& s : streams) {
    while (s->next(&f)) {
    }
    if (s->finish().code == kNotFound) ++not_found;
  }
  EXPECT_EQ(not_found, kStreams);
}

// The same for haptic streams: a thousand open HapticStream calls, each with its tool attached
// (its first pose taken) and no tick to answer, add fewer than 20 threads, and all end with
// NOT_FOUND when their scene is deleted.
TEST(StreamScale, ThousandIdleHapticStreamsCostFewThreadsAndEndWithTheirScene) {
  IdleScene idle;
  Fixture& fx = idle.fx;
  std::vector<Client>& clients = idle.clients;
  ASSERT_TRUE(clients[0].create_scene(lockstep_beam("idle")).ok());
  ASSERT_TRUE(clients[0].step("idle", 1).ok());
  v1::ToolPose pose;
  pose.set_scene_id("idle");
  pose.set_shape(v1::TOOL_SHAPE_SPHERE);
  pose.set_radius(0.01);
  pose.mutable_position()->set_x(5);  // far from the beam
  auto open_streams = [&] {
    int total = 0;
    fx.server->registry().stream_counts(&total);
    return total;
  };
  {  // warm up every channel (connections, gRPC's own threads)
    for (auto& c : clients) {
      auto s = c.haptic_stream();
      ASSERT_TRUE(s->send(pose));
      ASSERT_TRUE(test::wait_until([&] { return open_streams() == 1; }, test::kPatience, "the warm-up stream"));
      ASSERT_TRUE(s->finish().ok());
      ASSERT_TRUE(test::wait_until([&] { return open_streams() == 0; }, test::kPatience, "the warm-up stream's end"));
    }
  }
  const int before = thread_count();
  std::vector<std::unique_ptr<client::HapticStream>> streams;
  for (int i = 0; i < kStreams; ++i) {
    streams.push_back(clients[i % kChannels].haptic_stream());
    pose.set_seq(1);
    ASSERT_TRUE(streams.back()->send(pose)) << "stream " << i;
  }
  ASSERT_TRUE(test::wait_until([&] { return open_streams() == kStreams; }, test::kPatience,
                               std::to_string(kStreams) + " attached haptic streams"));
  const int after = thread_count();
  std::cout << "[ idle haptic streams ] " << kStreams << " open streams: threads " << before << " -> " << after
            << " (+" << after - before << ")\n";
  RecordProperty("threads_added", after - before);
  EXPECT_LT(after - before, 20);

  // They all end with NOT_FOUND when the scene goes, and free their places in the limits.
  ASSERT_TRUE(clients[0].delete_scene("idle").ok());
  int not_found = 0;
  v1::ToolFeedback f;
  for (auto& s : streams) {
    while (s->next(&f)) {
    }
    if (s->finish().code == kNotFound) ++not_found;
  }
  EXPECT_EQ(not_found, kStreams);
  EXPECT_TRUE(test::wait_until([&] { return open_streams() == 0; }, test::kPatience, "every stream's place freed"));
}
