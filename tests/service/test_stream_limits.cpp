// SPDX-License-Identifier: Apache-2.0
// Limits on open streams (server-wide and per scene) and on grabs per scene: the call over the
// limit gets RESOURCE_EXHAUSTED naming the limit; closing a stream or releasing a grab frees
// its place.
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <thread>

using namespace pliant;
using client::Client;

namespace {

using namespace test::grpc_codes;

v1::CreateSceneRequest paused_beam(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_solver()->set_substeps(1);
  r.mutable_spec()->set_start_paused(true);
  return r;
}

// A stream on a scene that has published a frame: open once its first frame arrived.
std::unique_ptr<client::FrameStream> open(Client& c, const std::string& id) {
  v1::StreamFramesRequest r;
  r.set_scene_id(id);
  return c.stream_frames(r);
}

}  // namespace

TEST(StreamLimits, StreamsPerServerAndPerSceneAreLimited) {
  server::ServerOptions o;
  o.max_streams = 2;
  o.max_streams_per_scene = 1;
  test::InProcessServer srv(o);
  ASSERT_TRUE(srv.started.ok());
  Client c = srv.client();
  for (const char* id : {"a", "b", "c"}) {
    ASSERT_TRUE(c.create_scene(paused_beam(id)).ok());
    ASSERT_TRUE(c.step(id, 1).ok());  // a frame to stream
  }
  v1::Frame f;
  auto a1 = open(c, "a");
  ASSERT_TRUE(a1->next(&f));
  auto a2 = open(c, "a");
  EXPECT_FALSE(a2->next(&f));
  client::Status s = a2->finish();
  EXPECT_EQ(s.code, kResourceExhausted);
  EXPECT_EQ(s.message, "scene 'a' already has 1 open streams (--max-streams-per-scene 1)");
  auto b1 = open(c, "b");
  ASSERT_TRUE(b1->next(&f));
  auto c1 = open(c, "c");
  EXPECT_FALSE(c1->next(&f));
  s = c1->finish();
  EXPECT_EQ(s.code, kResourceExhausted);
  EXPECT_EQ(s.message, "this server already has 2 open streams (--max-streams 2)");
  // Closing a stream frees its place (the server notices the cancellation within 100 ms).
  a1->cancel();
  a1->finish();
  bool reopened = false;
  for (int i = 0; i < 200 && !reopened; ++i) {
    auto again = open(c, "c");
    reopened = again->next(&f);
    if (!reopened) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_TRUE(reopened);
}

TEST(StreamLimits, GrabsPerSceneAreLimited) {
  server::ServerOptions o;
  o.max_grabs_per_scene = 2;
  test::InProcessServer srv(o);
  ASSERT_TRUE(srv.started.ok());
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(paused_beam("g")).ok());
  v1::GrabRequest g;
  g.set_scene_id("g");
  g.set_vertex(10);
  auto first = c.grab(g);
  ASSERT_TRUE(first.ok()) << first.status.to_string();
  ASSERT_TRUE(c.grab(g).ok());
  auto third = c.grab(g);
  EXPECT_EQ(third.status.code, kResourceExhausted);
  EXPECT_EQ(third.status.message, "scene 'g' already has 2 grabs (--max-grabs-per-scene 2); release one first");
  ASSERT_TRUE(c.release("g", first->grab_id()).ok());
  EXPECT_TRUE(c.grab(g).ok());
}
