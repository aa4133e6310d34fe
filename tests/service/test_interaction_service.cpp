// SPDX-License-Identifier: Apache-2.0
// InteractionService over an in-process server on 127.0.0.1 port 0: grab / move / release in a
// lockstep scene, the haptic stream's feedback (tick id, echoed pose, force and contacts; the
// friction of a tool turned between poses), and errors that name the field and the value. No
// timing assertions (bench/ measures latency).
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/wait_until.hpp"

#include "feedback_log.hpp"
#include "in_process_server.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <filesystem>
#include <cmath>
#include <iostream>
#include <mutex>
#include <thread>

#include <unistd.h>

using namespace pliant;
using client::Client;

namespace {

using namespace test::grpc_codes;

using Server = test::InProcessServer;

// beam1 (11.5 x 1 x 1 cm) clamped at x = 0, gravity off so grabs and tools are the only loads.
v1::CreateSceneRequest beam(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*s, 1e-3);
  s->mutable_gravity()->set_y(0);
  // 16 substeps: with 8 x 2 a hard grab pulling one vertex of this coarse, soft beam tangles it.
  s->mutable_solver()->set_substeps(16);
  s->mutable_solver()->set_iterations(1);
  s->mutable_solver()->set_damping_coefficient(20);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  s->mutable_tick()->set_dt(1.0 / 60);
  return r;
}

v1::Vec3 vec(double x, double y, double z) {
  v1::Vec3 v;
  v.set_x(x);
  v.set_y(y);
  v.set_z(z);
  return v;
}

// Position of vertex i from a snapshot.
std::array<double, 3> vertex_position(Client& c, const std::string& id, int i) {
  v1::SaveSnapshotRequest r;
  r.set_scene_id(id);
  auto s = c.save_snapshot(r);
  EXPECT_TRUE(s.ok()) << s.status.to_string();
  return {s->snapshot().x(3 * i), s->snapshot().x(3 * i + 1), s->snapshot().x(3 * i + 2)};
}

// The vertex nearest to p in the rest shape.
int nearest(Client& c, const std::string& id, double x, double y, double z) {
  auto t = c.topology(id);
  EXPECT_TRUE(t.ok());
  int best = 0;
  double bd = 1e300;
  for (uint32_t i = 0; i < t->vertex_count(); ++i) {
    const double dx = t->rest_positions(3 * i) - x, dy = t->rest_positions(3 * i + 1) - y,
                 dz = t->rest_positions(3 * i + 2) - z;
    if (dx * dx + dy * dy + dz * dz < bd) {
      bd = dx * dx + dy * dy + dz * dz;
      best = int(i);
    }
  }
  return best;
}

}  // namespace

TEST(InteractionService, GrabMoveReleaseDragsAVertex) {
  Server s;
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(beam("g")).ok());
  const int tip = nearest(c, "g", 0.115, 0.01, 0.01);
  const auto rest = vertex_position(c, "g", tip);

  v1::GrabRequest g;
  g.set_scene_id("g");
  g.set_vertex(tip);
  *g.mutable_target() = vec(rest[0], rest[1] + 0.003, rest[2]);
  auto grabbed = c.grab(g);
  ASSERT_TRUE(grabbed.ok()) << grabbed.status.to_string();
  EXPECT_EQ(grabbed->first_tick(), 1u);
  ASSERT_TRUE(c.step("g", 120).ok());
  auto p = vertex_position(c, "g", tip);
  EXPECT_NEAR(p[1], rest[1] + 0.003, 1e-4);

  // Move the target down: the vertex follows; the reply carries the force of the lift.
  v1::MoveGrabRequest m;
  m.set_scene_id("g");
  m.set_grab_id(grabbed->grab_id());
  *m.mutable_target() = vec(rest[0], rest[1] - 0.003, rest[2]);
  auto moved = c.move_grab(m);
  ASSERT_TRUE(moved.ok()) << moved.status.to_string();
  EXPECT_EQ(moved->first_tick(), 121u);
  EXPECT_GT(moved->force().y(), 0);  // holding the tip up pulls the body up
  ASSERT_TRUE(c.step("g", 120).ok());
  p = vertex_position(c, "g", tip);
  EXPECT_NEAR(p[1], rest[1] - 0.003, 1e-4);

  // A second grab at once, inside the last tet, held where it is.
  v1::GrabRequest g2;
  g2.set_scene_id("g");
  g2.mutable_tet_point()->set_tet(0);
  for (int k = 0; k < 4; ++k) g2.mutable_tet_point()->add_barycentric(0.25);
  auto second = c.grab(g2);
  ASSERT_TRUE(second.ok()) << second.status.to_string();
  EXPECT_NE(second->grab_id(), grabbed->grab_id());

  // Release: the beam springs back towards its rest shape (no gravity).
  ASSERT_TRUE(c.release("g", grabbed->grab_id()).ok());
  ASSERT_TRUE(c.release("g", second->grab_id()).ok());
  ASSERT_TRUE(c.step("g", 240).ok());
  p = vertex_position(c, "g", tip);
  EXPECT_NEAR(p[1], rest[1], 1e-3);
  EXPECT_EQ(c.release("g", grabbed->grab_id()).code, kNotFound);
}

TEST(InteractionService, BadGrabsNameFieldAndValue) {
  Server s;
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(beam("e")).ok());
  v1::GrabRequest g;
  g.set_scene_id("nope");
  g.set_vertex(0);
  auto r = c.grab(g);
  EXPECT_EQ(r.status.code, kNotFound);
  EXPECT_NE(r.status.message.find("nope"), std::string::npos) << r.status.message;

  g.set_scene_id("e");
  g.set_vertex(99999);
  r = c.grab(g);
  EXPECT_EQ(r.status.code, kInvalidArgument);
  EXPECT_NE(r.status.message.find("vertex = 99999"), std::string::npos) << r.status.message;

  g.clear_vertex();
  r = c.grab(g);
  EXPECT_EQ(r.status.code, kInvalidArgument);
  EXPECT_NE(r.status.message.find("point is not set"), std::string::npos) << r.status.message;

  g.mutable_tet_point()->set_tet(0);
  g.mutable_tet_point()->add_barycentric(1.0);
  r = c.grab(g);
  EXPECT_EQ(r.status.code, kInvalidArgument);
  EXPECT_NE(r.status.message.find("tet_point.barycentric must hold 4 values, got 1"), std::string::npos)
      << r.status.message;

  g.set_vertex(0);
  g.set_compliance(-1);
  r = c.grab(g);
  EXPECT_EQ(r.status.code, kInvalidArgument);
  EXPECT_NE(r.status.message.find("compliance must be finite and >= 0, got -1"), std::string::npos)
      << r.status.message;

  v1::MoveGrabRequest m;
  m.set_scene_id("e");
  m.set_grab_id(4242);
  *m.mutable_target() = vec(0, 0, 0);
  auto mr = c.move_grab(m);
  EXPECT_EQ(mr.status.code, kNotFound);
  EXPECT_NE(mr.status.message.find("grab_id 4242"), std::string::npos) << mr.status.message;
}

TEST(InteractionService, HapticStreamAnswersEveryTickWithTheToolForce) {
  Server s;
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(beam("h")).ok());
  test::FeedbackLog fr(c);
  auto& stream = fr.stream;
  auto& mu = fr.mu;
  auto& got = fr.got;
  // A 1 cm sphere lowered from 1 mm above the top face near the tip to 2 mm into it over 60
  // ticks (one pose per tick), then held. The poses reach the tick asynchronously: a tick uses
  // the latest pose the server has read, so after each step the test waits for that tick's
  // feedback (the tool is in every tick once its first pose is).
  auto feedback_count = [&] { return fr.count(); };
  auto has_feedback_of_tick = [&](uint64_t tick) { return fr.latest(tick, nullptr); };
  v1::ToolPose pose;
  pose.set_scene_id("h");
  pose.set_shape(v1::TOOL_SHAPE_SPHERE);
  pose.set_radius(0.01);
  uint64_t seq = 0;
  for (int i = 0; i < 120; ++i) {
    const double depth = -0.001 + 0.003 * std::min(1.0, i / 60.0);
    pose.set_seq(++seq);
    pose.set_client_time_ns(1000 + int64_t(seq));
    *pose.mutable_position() = vec(0.1, 0.01 + 0.01 - depth, 0.005);
    ASSERT_TRUE(stream->send(pose));
    pose.clear_scene_id();
    if (i == 0) {
      // Tick until the first pose is in a tick (the tool attached) and its feedback is back.
      ASSERT_TRUE(test::wait_until([&] { return c.step("h", 1).ok() && feedback_count() > 0; }, test::kPatience,
                                   "the first feedback (the tool's first pose in a tick)"));
      continue;
    }
    auto st = c.step("h", 1);
    ASSERT_TRUE(st.ok()) << st.status.to_string();
    const uint64_t tick = st->tick();
    ASSERT_TRUE(test::wait_until([&] { return has_feedback_of_tick(tick); }, test::kPatience,
                                 "the feedback of tick " + std::to_string(tick)));
  }
  // Tick until the last pose is in a tick, then 10 more ticks with it.
  auto ticks_with_last_pose = [&] {
    std::lock_guard lk(mu);
    size_t n = 0;
    for (auto it = got.rbegin(); it != got.rend() && it->pose_seq() == seq; ++it) ++n;
    return n;
  };
  ASSERT_TRUE(test::wait_until([&] { return c.step("h", 1).ok() && ticks_with_last_pose() > 10; }, test::kPatience,
                               "11 ticks' feedback with the last pose"));
  EXPECT_TRUE(fr.close());
  ASSERT_GE(got.size(), 100u);
  for (size_t i = 1; i < got.size(); ++i) {
    EXPECT_GT(got[i].tick(), got[i - 1].tick());
    EXPECT_GE(got[i].pose_seq(), got[i - 1].pose_seq());
  }
  const v1::ToolFeedback& last = got.back();
  EXPECT_EQ(last.pose_seq(), seq);
  EXPECT_EQ(last.pose_client_time_ns(), int64_t(1000 + seq));
  EXPECT_GT(last.force().y(), 0);  // the beam pushes the tool up
  ASSERT_GT(last.contacts_size(), 0);
  double sum = 0;
  for (const auto& cp : last.contacts()) {
    sum += cp.force().y();
    // A contact point is its vertex: on the sphere's surface for a vertex contact, a corner of
    // the touching face (at most the face's 7.1 mm diagonal away) for a triangle contact;
    // never inside the tool.
    const double dx = cp.point().x() - 0.1, dy = cp.point().y() - 0.018, dz = cp.point().z() - 0.005;
    const double dist = std::sqrt(dx * dx + dy * dy + dz * dz);
    EXPECT_GT(dist, 0.01 - 1e-4);
    EXPECT_LT(dist, 0.01 + 0.0075);
  }
  EXPECT_NEAR(sum, last.force().y(), 1e-9 + 1e-9 * std::abs(sum));

  // The tool goes with the stream: later ticks see no contact.
  auto after = c.step("h", 30);
  ASSERT_TRUE(after.ok());
}

TEST(InteractionService, AToolTurningBetweenPosesFeelsTheFrictionOfItsTurn) {
  // A capsule (4 mm radius) lying across the top face near the tip, 1 mm into it, with friction
  // 1: held still for 40 ticks, then turned about its own axis (z) by 5 rad/s x dt between one
  // pose and the next for 40 ticks. The server takes the turn between the poses a tick uses as
  // the tool's angular velocity, so friction drags the surface under it and the feedback's
  // torque about the axis opposes the turn, mu x the normal force x the radius as it slides;
  // held, the torque about the axis is about nil (a tool that only jumped between orientations
  // would feel nearly none either way: a capsule turned about its axis has the same shape).
  Server s;
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(beam("turn")).ok());
  test::FeedbackLog fr(c);
  v1::ToolPose pose;
  pose.set_scene_id("turn");
  pose.set_shape(v1::TOOL_SHAPE_CAPSULE);
  pose.set_radius(0.004);
  pose.set_half_length(0.03);
  pose.set_static_friction(1.0);
  pose.set_dynamic_friction(1.0);
  *pose.mutable_position() = vec(0.09, 0.01 + 0.004 - 0.001, 0.005);
  const double rate = 5.0, dt = 1.0 / 60;
  double angle = 0, held = 0, turning = 0, pressing = 0;
  uint64_t seq = 0;
  for (int i = 0; i < 80; ++i) {
    if (i >= 40) angle += rate * dt;
    pose.set_seq(++seq);
    auto* q = pose.mutable_orientation();
    q->set_w(std::cos(angle / 2));
    q->set_x(0);
    q->set_y(0);
    q->set_z(std::sin(angle / 2));
    ASSERT_TRUE(fr.stream->send(pose));
    pose.clear_scene_id();
    // Step until a tick has used this pose, and read that tick's feedback.
    v1::ToolFeedback f;
    ASSERT_TRUE(test::wait_until(
        [&] {
          auto st = c.step("turn", 1);
          return st.ok() && fr.latest(st->tick(), &f) && f.pose_seq() == seq;
        },
        test::kPatience, "a tick with pose " + std::to_string(seq)));
    if (i >= 20 && i < 40) held += f.torque().z() / 20;
    if (i >= 60) {
      turning += f.torque().z() / 20;
      pressing += f.force().y() / 20;
    }
  }
  EXPECT_TRUE(fr.close());
  std::cout << "[ turn ] torque about the axis " << turning << " N m turning, " << held << " held; pressing "
            << pressing << " N\n";
  // Sliding, friction is mu x the normal force at the capsule's radius: mu = 1, r = 4 mm.
  const double sliding = 1.0 * pressing * 0.004;
  ASSERT_GT(pressing, 0.0);
  EXPECT_NEAR(turning, -sliding, 0.3 * sliding) << "the body should hold the turn back by sliding friction";
  EXPECT_LT(std::abs(held), 0.2 * sliding);
}

TEST(InteractionService, HapticStreamRejectsBadPoses) {
  Server s;
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(beam("b")).ok());
  {
    auto stream = c.haptic_stream();
    v1::ToolPose pose;
    pose.set_scene_id("missing");
    *pose.mutable_position() = vec(0, 0, 0);
    stream->send(pose);
    auto st = stream->finish();
    EXPECT_EQ(st.code, kNotFound);
    EXPECT_NE(st.message.find("missing"), std::string::npos) << st.message;
  }
  {
    auto stream = c.haptic_stream();
    v1::ToolPose pose;
    pose.set_scene_id("b");
    pose.set_radius(-0.5);
    *pose.mutable_position() = vec(0, 0, 0);
    stream->send(pose);
    auto st = stream->finish();
    EXPECT_EQ(st.code, kInvalidArgument);
    EXPECT_NE(st.message.find("radius must be > 0, got -0.5"), std::string::npos) << st.message;
  }
  {
    // A good first pose, then a bad one: the stream ends with the bad one's error.
    auto stream = c.haptic_stream();
    v1::ToolPose pose;
    pose.set_scene_id("b");
    *pose.mutable_position() = vec(0.5, 0.5, 0.5);
    stream->send(pose);
    pose.clear_scene_id();
    pose.mutable_orientation()->set_w(0);
    stream->send(pose);
    auto st = stream->finish();
    EXPECT_EQ(st.code, kInvalidArgument);
    EXPECT_NE(st.message.find("orientation"), std::string::npos) << st.message;
  }
}

// Grabs are part of the scene's state: a restart (shutdown snapshot + restore) and a
// RestoreSnapshot keep them with their ids, so MoveGrab / Release with the same id go on working
// and the body stays held meanwhile. Without the grab the beam (no gravity) springs back.
TEST(InteractionService, GrabsSurviveARestartAndARestore) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("pliant-grab-restart-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  server::ServerOptions o;
  o.data_dir = dir.string();
  int tip = 0;
  uint64_t grab_id = 0;
  std::array<double, 3> rest{};
  {
    Server a(o);
    Client c = a.client();
    ASSERT_TRUE(c.create_scene(beam("g")).ok());
    tip = nearest(c, "g", 0.115, 0.01, 0.01);
    rest = vertex_position(c, "g", tip);
    v1::GrabRequest g;
    g.set_scene_id("g");
    g.set_vertex(tip);
    *g.mutable_target() = vec(rest[0], rest[1] + 0.003, rest[2]);
    g.set_compliance(1e-6);
    auto grabbed = c.grab(g);
    ASSERT_TRUE(grabbed.ok()) << grabbed.status.to_string();
    grab_id = grabbed->grab_id();
    ASSERT_TRUE(c.step("g", 120).ok());
    EXPECT_NEAR(vertex_position(c, "g", tip)[1], rest[1] + 0.003, 2e-4);
    EXPECT_EQ(a.server->shutdown(), 1);  // what SIGTERM does: one snapshot per scene
  }
  {
    Server b(o);
    Client c = b.client();
    v1::SaveSnapshotRequest sr;
    sr.set_scene_id("g");
    auto saved = c.save_snapshot(sr);
    ASSERT_TRUE(saved.ok()) << saved.status.to_string();
    ASSERT_EQ(saved->snapshot().grabs_size(), 1);
    EXPECT_EQ(saved->snapshot().grabs(0).grab_id(), grab_id);
    EXPECT_DOUBLE_EQ(saved->snapshot().grabs(0).compliance(), 1e-6);
    // Before the first tick after the restart, a grab without a target holds a point where the
    // snapshot left it, not where the rest shape has it: the lifted corner next to the tip.
    const int corner = nearest(c, "g", 0.115, 0.01, 0.0);
    const auto lifted = vertex_position(c, "g", corner);
    ASSERT_GT(lifted[1] - 0.01, 0.001);  // lifted by the grab (rest y = 0.01)
    v1::GrabRequest hold;
    hold.set_scene_id("g");
    hold.set_vertex(corner);
    auto held = c.grab(hold);
    ASSERT_TRUE(held.ok()) << held.status.to_string();
    // Still held after more ticks (a lost grab would let the tip spring back to rest).
    ASSERT_TRUE(c.step("g", 120).ok());
    EXPECT_NEAR(vertex_position(c, "g", tip)[1], rest[1] + 0.003, 2e-4);
    EXPECT_NEAR(vertex_position(c, "g", corner)[1], lifted[1], 1e-4);
    ASSERT_TRUE(c.release("g", held->grab_id()).ok());
    // The same id moves it.
    v1::MoveGrabRequest m;
    m.set_scene_id("g");
    m.set_grab_id(grab_id);
    *m.mutable_target() = vec(rest[0], rest[1] - 0.003, rest[2]);
    auto moved = c.move_grab(m);
    ASSERT_TRUE(moved.ok()) << moved.status.to_string();
    EXPECT_GT(moved->force().y(), 0);  // it was holding the tip up
    ASSERT_TRUE(c.step("g", 120).ok());
    EXPECT_NEAR(vertex_position(c, "g", tip)[1], rest[1] - 0.003, 2e-4);
    // A new grab gets a new id, not a reused one.
    v1::GrabRequest g2;
    g2.set_scene_id("g");
    g2.set_vertex(0);
    auto second = c.grab(g2);
    ASSERT_TRUE(second.ok()) << second.status.to_string();
    EXPECT_GT(second->grab_id(), grab_id);
    ASSERT_TRUE(c.release("g", second->grab_id()).ok());

    // Roll back to a snapshot taken while grabbed: releasing afterwards is undone too.
    auto before = c.save_snapshot(sr);
    ASSERT_TRUE(before.ok());
    ASSERT_TRUE(c.release("g", grab_id).ok());
    EXPECT_EQ(c.release("g", grab_id).code, kNotFound);
    v1::RestoreSnapshotRequest r;
    *r.mutable_snapshot() = before->snapshot();
    r.set_replace(true);
    ASSERT_TRUE(c.restore_snapshot(r).ok());
    *m.mutable_target() = vec(rest[0], rest[1], rest[2]);
    auto moved_again = c.move_grab(m);
    EXPECT_TRUE(moved_again.ok()) << moved_again.status.to_string();

    // A snapshot from before grabs were saved (no grabs field) restores without grabs.
    v1::RestoreSnapshotRequest old;
    *old.mutable_snapshot() = before->snapshot();
    old.mutable_snapshot()->clear_grabs();
    old.mutable_snapshot()->clear_next_grab_id();
    old.set_scene_id("old");
    ASSERT_TRUE(c.restore_snapshot(old).ok());
    m.set_scene_id("old");
    EXPECT_EQ(c.move_grab(m).status.code, kNotFound);

    // A bad grab in a snapshot is refused, naming the field and the value.
    v1::RestoreSnapshotRequest bad;
    *bad.mutable_snapshot() = before->snapshot();
    bad.mutable_snapshot()->mutable_grabs(0)->set_vertices(0, 99999);
    bad.set_scene_id("bad");
    auto refused = c.restore_snapshot(bad);
    EXPECT_EQ(refused.status.code, kInvalidArgument);
    EXPECT_NE(refused.status.message.find("snapshot.grabs[0].vertices[0] = 99999"), std::string::npos)
        << refused.status.message;
    b.server->shutdown();
  }
  fs::remove_all(dir);
}

// The inversion floor is a scene setting (spec.solver.inversion_floor), default 0.2, kept in the
// effective spec (and so in snapshots).
TEST(InteractionService, InversionFloorIsASceneSetting) {
  Server s;
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(beam("default")).ok());
  auto off = beam("off");
  off.mutable_spec()->mutable_solver()->set_inversion_floor(0);
  ASSERT_TRUE(c.create_scene(off).ok());
  auto d = c.get_scene("default"), o = c.get_scene("off");
  ASSERT_TRUE(d.ok() && o.ok());
  EXPECT_DOUBLE_EQ(d->spec().solver().inversion_floor(), 0.2);
  EXPECT_DOUBLE_EQ(o->spec().solver().inversion_floor(), 0.0);
}
