// SPDX-License-Identifier: Apache-2.0
// Particle bodies (ropes, cloth, fluids) in a server scene: created with the scene, stepped by
// its tick under gravity, carried by frames, topology and GetScene, grabbed through the
// InteractionService, kept bit for bit by snapshots and across a restart, and refused with the
// field named when their spec is bad.
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/segment_distance.hpp"
#include "pliant/test/wait_until.hpp"

#include "body_scenes.hpp"
#include "feedback_log.hpp"
#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <algorithm>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <iostream>
#include <mutex>
#include <thread>
#include <unistd.h>

using namespace pliant;
using client::Client;
namespace fs = std::filesystem;

namespace {

using namespace test::grpc_codes;

using test::BodiesServer;
using test::beam_scene;
using test::latest_frame;
using test::set;
using test::set_container;

// beam1 clamped at x <= 0.01 beside a rope pinned at one end (21 particles), a cloth pinned at
// two corners (8 x 8) and a fluid block in a container (4 x 4 x 4), lockstep.
v1::CreateSceneRequest bodies_request(const std::string& id) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  s->mutable_solver()->set_method(v1::METHOD_XPBD);
  s->mutable_solver()->set_substeps(2);
  s->mutable_solver()->set_iterations(2);

  auto* rope = s->add_bodies();
  rope->set_name("rope");
  auto* rs = rope->mutable_rope();
  set(rs->add_points(), 0, 2, 0);
  set(rs->add_points(), 1, 2, 0);
  rs->set_segments(20);
  rs->set_substeps(8);
  rs->mutable_pins()->add_indices(0);

  auto* cloth = s->add_bodies();
  cloth->set_name("cloth");
  auto* cs = cloth->mutable_cloth();
  auto* g = cs->mutable_grid();
  g->set_resolution_x(8);
  g->set_resolution_y(8);
  g->set_size_x(0.4);
  g->set_size_y(0.4);
  set(g->mutable_origin(), 3, 2, 0);
  cs->set_substeps(8);
  cs->set_self_collision(false);
  cs->mutable_pins()->add_indices(0);
  cs->mutable_pins()->add_indices(7);

  auto* fluid = s->add_bodies();
  fluid->set_name("water");
  auto* fs_ = fluid->mutable_fluid();
  fs_->set_spacing(0.05);
  auto* blk = fs_->add_blocks();
  set(blk->mutable_min(), -3.1, 0.0, -0.1);
  set(blk->mutable_max(), -2.9, 0.2, 0.1);
  set_container(fs_, -3, 0.2, 0, 0.3, 0.3, 0.3);
  return r;
}

v1::Snapshot snapshot_of(Client& c, const std::string& id) {
  v1::SaveSnapshotRequest req;
  req.set_scene_id(id);
  auto s = c.save_snapshot(req);
  EXPECT_TRUE(s.ok()) << s.status.to_string();
  return s->snapshot();
}

template <class R>
bool bit_equal(const R& a, const R& b) {
  if (a.size() != b.size()) return false;
  return a.size() == 0 || std::memcmp(a.data(), b.data(), sizeof(a[0]) * a.size()) == 0;
}

double y_of(const google::protobuf::RepeatedField<float>& p, int i) { return p[3 * i + 1]; }

fs::path temp_dir(const std::string& name) {
  fs::path p = fs::temp_directory_path() / ("pliant_bodies_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

TEST(Bodies, SceneCarriesItsBodiesWhichFallUnderGravityWhilePinsHold) {
  BodiesServer srv;
  Client c = srv.client();
  auto created = c.create_scene(bodies_request("b"));
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  ASSERT_EQ(created->bodies_size(), 3);
  EXPECT_EQ(created->bodies(0).name(), "rope");
  EXPECT_EQ(created->bodies(0).kind(), "rope");
  EXPECT_EQ(created->bodies(0).particle_count(), 21u);
  EXPECT_EQ(created->bodies(0).pinned_count(), 1u);
  EXPECT_EQ(created->bodies(1).kind(), "cloth");
  EXPECT_EQ(created->bodies(1).particle_count(), 64u);
  EXPECT_EQ(created->bodies(1).pinned_count(), 2u);
  EXPECT_GT(created->bodies(1).triangle_count(), 0u);
  EXPECT_EQ(created->bodies(2).kind(), "fluid");
  EXPECT_EQ(created->bodies(2).particle_count(), 64u);
  // The effective spec echoes every body with its values in use.
  ASSERT_EQ(created->spec().bodies_size(), 3);
  EXPECT_EQ(created->spec().bodies(0).rope().segments(), 20u);
  EXPECT_EQ(created->spec().bodies(0).rope().substeps(), 8);
  EXPECT_DOUBLE_EQ(created->spec().bodies(2).fluid().rest_density(), 1000.0);

  auto topo = c.topology("b");
  ASSERT_TRUE(topo.ok()) << topo.status.to_string();
  ASSERT_EQ(topo->bodies_size(), 3);
  const auto& rope_topo = topo->bodies(0);
  EXPECT_EQ(rope_topo.rest_positions_size(), 3 * 21);
  ASSERT_EQ(rope_topo.pinned_size(), 1);
  EXPECT_EQ(rope_topo.pinned(0), 0u);
  EXPECT_EQ(topo->bodies(1).triangles_size() % 3, 0);
  EXPECT_GT(topo->bodies(1).triangles_size(), 0);
  EXPECT_EQ(topo->bodies(2).triangles_size(), 0);

  ASSERT_TRUE(c.step("b", 30).ok());
  const v1::Frame f = latest_frame(c, "b");
  EXPECT_EQ(f.tick(), 30u);
  ASSERT_EQ(f.bodies_size(), 3);
  for (int b = 0; b < 3; ++b) {
    EXPECT_EQ(f.bodies(b).name(), topo->bodies(b).name());
    EXPECT_EQ(f.bodies(b).positions_size(), topo->bodies(b).rest_positions_size());
  }
  // Rope: the pinned end stays where it was built, the free end fell.
  const auto& rope = f.bodies(0).positions();
  for (int k = 0; k < 3; ++k) EXPECT_EQ(rope[k], rope_topo.rest_positions(k));
  EXPECT_LT(y_of(rope, 20), y_of(rope_topo.rest_positions(), 20) - 0.1);
  // Cloth: both pinned corners stay, the far corner fell.
  const auto& cloth = f.bodies(1).positions();
  for (int i : {0, 7})
    for (int k = 0; k < 3; ++k) EXPECT_EQ(cloth[3 * i + k], topo->bodies(1).rest_positions(3 * i + k));
  EXPECT_LT(y_of(cloth, 63), y_of(topo->bodies(1).rest_positions(), 63) - 0.05);
  // Fluid: the block sank toward its container's floor (y = -0.1) and stays inside it.
  double mean_now = 0, mean_rest = 0, min_y = 1e9;
  for (int i = 0; i < 64; ++i) {
    mean_now += y_of(f.bodies(2).positions(), i) / 64;
    mean_rest += y_of(topo->bodies(2).rest_positions(), i) / 64;
    min_y = std::min(min_y, y_of(f.bodies(2).positions(), i));
  }
  EXPECT_LT(mean_now, mean_rest - 0.02);
  EXPECT_GE(min_y, -0.1 - 1e-3);

  // Reset puts every body back where it was built.
  ASSERT_TRUE(c.reset_scene("b").ok());
  ASSERT_TRUE(c.step("b", 1).ok());
  auto snap = snapshot_of(c, "b");
  ASSERT_EQ(snap.bodies_size(), 3);
  EXPECT_EQ(snap.bodies(0).steps(), 1u);
  EXPECT_NEAR(snap.bodies(0).x(3 * 20 + 1), 2.0, 0.01);

  // Frames without positions carry no bodies.
  v1::StreamFramesRequest q;
  q.set_scene_id("b");
  q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  auto s = c.stream_frames(q);
  v1::Frame g;
  ASSERT_TRUE(s->next(&g));
  s->cancel();
  EXPECT_EQ(g.bodies_size(), 0);
  EXPECT_EQ(g.positions_size(), 0);
  // Their solver stats say what each body's step cost and reached.
  ASSERT_EQ(g.solver().bodies_size(), 3);
  for (int b = 0; b < 3; ++b) {
    SCOPED_TRACE(g.solver().bodies(b).name());
    EXPECT_EQ(g.solver().bodies(b).name(), created->bodies(b).name());
    EXPECT_GT(g.solver().bodies(b).step_wall_ms(), 0);
    EXPECT_GE(g.solver().bodies(b).substeps(), 1);
    EXPECT_GE(g.solver().bodies(b).constraint_error(), 0);
    EXPECT_GE(g.solver().bodies(b).max_constraint_error(), g.solver().bodies(b).constraint_error());
  }
  EXPECT_EQ(g.solver().bodies(0).substeps(), 8);  // the rope's spec
}

TEST(Bodies, TheHapticToolFeelsTheClothItCatches) {
  // A 10 cm sphere held (one pose over the haptic stream) 5 cm under the middle of the cloth,
  // away from the beam: the falling cloth lands on it, and the tool's feedback carries the
  // cloth's push (down) while the cloth's stats count the particles it pushed.
  BodiesServer srv;
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(bodies_request("t")).ok());
  test::FeedbackLog log(c);
  v1::ToolPose pose;
  pose.set_scene_id("t");
  pose.set_shape(v1::TOOL_SHAPE_SPHERE);
  pose.set_radius(0.1);
  pose.set_seq(1);
  set(pose.mutable_position(), 3.2, 1.85, 0.2);
  ASSERT_TRUE(log.stream->send(pose));
  double lowest = 0;
  auto pushed_down = [&] {
    for (const auto& f : log.all()) lowest = std::min(lowest, f.force().y());
    return lowest < 0;
  };
  ASSERT_TRUE(test::wait_until([&] { return c.step("t", 1).ok() && pushed_down(); }, test::kPatience,
                               "feedback with the cloth's push on the tool"));
  v1::StreamFramesRequest q;
  q.set_scene_id("t");
  q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  auto s = c.stream_frames(q);
  v1::Frame f;
  ASSERT_TRUE(s->next(&f));
  s->cancel();
  EXPECT_TRUE(log.close());
  ASSERT_EQ(f.solver().bodies_size(), 3);
  EXPECT_EQ(f.solver().bodies(1).name(), "cloth");
  EXPECT_GT(f.solver().bodies(1).tool_contacts(), 0u);
  EXPECT_EQ(f.solver().bodies(0).tool_contacts(), 0u);  // the rope is elsewhere
  EXPECT_EQ(f.solver().bodies(2).tool_contacts(), 0u);  // so is the water
  // The cloth weighs 0.2 kg/m^2 x 0.16 m^2: a push of the order of its weight (0.31 N), and
  // nothing from the beam, which the tool does not touch.
  EXPECT_LT(lowest, -0.01);
  EXPECT_GT(lowest, -100.0);
}

TEST(Bodies, AFastToolCatchesTheRopeItSweepsThroughInOneTick) {
  // A rope of 20 links hanging 20 cm from a pin at (5, 2, 0), away from the beam, and a 1 cm sphere
  // held 2.5 cm to its left at half its length, then moved 5 cm to its right in one tick (3 m/s):
  // the tool meets the rope inside the rope's substeps and carries its middle along, and the
  // feedback of that tick pushes back against the motion. (Met only where the tick ends, the tool
  // would be past the rope and the rope untouched.)
  BodiesServer srv;
  Client c = srv.client();
  v1::CreateSceneRequest req = beam_scene("s");
  auto* rope = req.mutable_spec()->add_bodies();
  rope->set_name("rope");
  auto* rs = rope->mutable_rope();
  set(rs->add_points(), 5, 2, 0);
  set(rs->add_points(), 5, 1.8, 0);
  rs->set_segments(20);
  rs->set_thickness(0.002);
  rs->mutable_pins()->add_indices(0);
  ASSERT_TRUE(c.create_scene(req).ok());
  test::FeedbackLog log(c);
  v1::ToolPose pose;
  pose.set_scene_id("s");
  pose.set_shape(v1::TOOL_SHAPE_SPHERE);
  pose.set_radius(0.01);
  pose.set_seq(1);
  set(pose.mutable_position(), 4.975, 1.9, 0);
  ASSERT_TRUE(log.stream->send(pose));
  ASSERT_TRUE(test::wait_until([&] { return c.step("s", 1).ok() && log.used(1); }, test::kPatience,
                               "the first pose used"));
  pose.set_seq(2);
  set(pose.mutable_position(), 5.025, 1.9, 0);
  ASSERT_TRUE(log.stream->send(pose));
  ASSERT_TRUE(test::wait_until([&] { return c.step("s", 1).ok() && log.used(2); }, test::kPatience,
                               "the second pose used"));
  const v1::Snapshot snap = snapshot_of(c, "s");
  EXPECT_TRUE(log.close());
  ASSERT_EQ(snap.bodies_size(), 1);
  double ahead = -1e9;
  for (int i = 0; i < snap.bodies(0).x_size() / 3; ++i) ahead = std::max(ahead, snap.bodies(0).x(3 * i));
  EXPECT_GT(ahead, 5.025 + 0.006) << "the rope's middle stayed behind the tool";
  double push = 0;
  for (const auto& f : log.all())
    if (f.pose_seq() == 2) {
      push = f.force().x();
      break;
    }
  EXPECT_LT(push, 0.0) << "the tool felt nothing of the rope it swept";
}

namespace {

// A 0.6 m cloth (1 kg/m^2 unless given) pinned at its corners (y = 2, centred on x = 5) and a cube
// of water particles 2 cm apart (`side` a side: 27 unless given) 15 cm above its middle, away from
// the clamped beam1; lockstep.
v1::CreateSceneRequest hammock_request(const std::string& id, bool water_contact, double mass_per_area = 1.0,
                                       int side = 3) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  auto* cloth = s->add_bodies();
  cloth->set_name("hammock");
  auto* cs = cloth->mutable_cloth();
  auto* g = cs->mutable_grid();
  g->set_resolution_x(16);
  g->set_resolution_y(16);
  g->set_size_x(0.6);
  g->set_size_y(0.6);
  cs->set_mass_per_area(mass_per_area);
  set(g->mutable_origin(), 4.7, 2, -0.3);
  cs->set_self_collision(false);
  cs->set_damping(1.0);
  for (uint32_t corner : {0u, 15u, 240u, 255u}) cs->mutable_pins()->add_indices(corner);
  auto* fluid = s->add_bodies();
  fluid->set_name("water");
  if (!water_contact) fluid->set_body_contact(false);
  auto* fs_ = fluid->mutable_fluid();
  fs_->set_spacing(0.02);
  auto* blk = fs_->add_blocks();
  const double half = 0.01 * side;
  set(blk->mutable_min(), 5 - half, 2.15, -half);
  set(blk->mutable_max(), 5 + half, 2.15 + 2 * half, half);
  return r;
}

}  // namespace

TEST(Bodies, WaterPouredIntoAClothHammockStaysInIt) {
  BodiesServer srv;
  Client c = srv.client();
  for (bool contact : {true, false}) {
    SCOPED_TRACE(contact ? "body_contact on" : "water's body_contact off");
    const std::string id = contact ? "on" : "off";
    auto created = c.create_scene(hammock_request(id, contact));
    ASSERT_TRUE(created.ok()) << created.status.to_string();
    EXPECT_EQ(created->spec().bodies(1).body_contact(), contact);
    EXPECT_EQ(created->spec().bodies(0).body_contact(), true);
    ASSERT_TRUE(c.step(id, 90).ok());
    v1::StreamFramesRequest q;
    q.set_scene_id(id);
    q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
    auto fs = c.stream_frames(q);
    v1::Frame f;
    ASSERT_TRUE(fs->next(&f));
    fs->cancel();
    const v1::Snapshot snap = snapshot_of(c, id);
    ASSERT_EQ(snap.bodies_size(), 2);
    double cloth_lowest = 1e300, water_lowest = 1e300;
    for (int i = 0; i < snap.bodies(0).x_size() / 3; ++i) cloth_lowest = std::min(cloth_lowest, snap.bodies(0).x(3 * i + 1));
    for (int i = 0; i < snap.bodies(1).x_size() / 3; ++i) water_lowest = std::min(water_lowest, snap.bodies(1).x(3 * i + 1));
    if (contact) {
      EXPECT_GT(water_lowest, cloth_lowest) << "the water stays in the hammock";
      EXPECT_LT(water_lowest, 2.0) << "resting in its sag";
    } else {
      EXPECT_LT(water_lowest, cloth_lowest - 1.0) << "without the contact the water falls through";
      EXPECT_EQ(f.solver().bodies(1).body_contacts(), 0u);
    }
  }
  // Over a second the hammock's stats count the water's contacts.
  uint32_t touched = 0;
  for (int k = 0; k < 60; ++k) {
    ASSERT_TRUE(c.step("on", 1).ok());
    v1::StreamFramesRequest q;
    q.set_scene_id("on");
    q.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
    auto fs = c.stream_frames(q);
    v1::Frame f;
    ASSERT_TRUE(fs->next(&f));
    fs->cancel();
    touched += f.solver().bodies(1).body_contacts();
    EXPECT_EQ(f.solver().bodies(0).body_contacts(), 0u);  // the cloth's own particles touch no other cloth
  }
  EXPECT_GT(touched, 0u);
}

// A load of water 14 times the cloth's mass (125 particles, 1 kg, on 72 g): the scene steps the
// two bodies in parts with their contact after each part, and the hammock holds all of it. With
// the contact once per tick the cloth, which learned of the load only after its whole step,
// dipped and let it spill over its edges and through it: here 5 of 125 were left after 10 s and
// one was under the cloth after 5 s (checked), in `build/bench/pliant_hammock --one-part` 9 and 2
// (docs/cloth.md, "Steps in parts").
TEST(Bodies, AHammockHoldsWaterFourteenTimesItsMass) {
  BodiesServer srv;
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(hammock_request("heavy", true, 0.2, 5)).ok());
  size_t in_hammock = 0, water = 0;
  for (int second = 0; second < 10; ++second) {
    ASSERT_TRUE(c.step("heavy", 60).ok());
    const v1::Snapshot snap = snapshot_of(c, "heavy");
    ASSERT_EQ(snap.bodies_size(), 2);
    double cloth_lowest = 1e300;
    for (int i = 0; i < snap.bodies(0).x_size() / 3; ++i) cloth_lowest = std::min(cloth_lowest, snap.bodies(0).x(3 * i + 1));
    water = size_t(snap.bodies(1).x_size() / 3);
    size_t under = 0;
    in_hammock = 0;
    for (size_t i = 0; i < water; ++i) {
      const double x = snap.bodies(1).x(3 * i) - 5, y = snap.bodies(1).x(3 * i + 1), z = snap.bodies(1).x(3 * i + 2);
      under += y < cloth_lowest - 0.01 && std::abs(x) < 0.25 && std::abs(z) < 0.25;
      in_hammock += y > cloth_lowest - 0.05 && std::abs(x) < 0.3 && std::abs(z) < 0.3;
    }
    EXPECT_EQ(under, 0u) << "after " << second + 1 << " s";
  }
  EXPECT_EQ(water, 125u);
  EXPECT_EQ(in_hammock, water) << "all the water in the hammock after 10 s";
  // In two parts each body still runs its own substeps a tick, and counts one step a tick.
  const v1::Frame f = latest_frame(c, "heavy");
  ASSERT_EQ(f.solver().bodies_size(), 2);
  EXPECT_EQ(f.solver().bodies(0).substeps(), 16);
  EXPECT_EQ(f.solver().bodies(1).substeps(), 2);
  EXPECT_EQ(f.solver().bodies(0).step_parts(), 2u);
  EXPECT_EQ(f.solver().bodies(1).step_parts(), 2u);
  EXPECT_GT(f.solver().bodies(1).body_contacts(), 0u);
  const v1::Snapshot snap = snapshot_of(c, "heavy");
  EXPECT_EQ(snap.bodies(0).steps(), 600u);
  EXPECT_EQ(snap.bodies(1).steps(), 600u);
  EXPECT_NEAR(snap.bodies(1).time(), 10.0, 1e-9);
}

TEST(Bodies, GrabOnARopeParticleHoldsItsWeightAndMovesIt) {
  BodiesServer srv;
  Client c = srv.client();
  v1::CreateSceneRequest r;
  r.set_scene_id("g");
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*s, 0.01);
  s->mutable_solver()->set_method(v1::METHOD_XPBD);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  auto* rope = s->add_bodies();
  rope->set_name("rope");
  auto* rs = rope->mutable_rope();
  set(rs->add_points(), 0, 3, 0);
  set(rs->add_points(), 0, 2, 0);  // hanging straight down, 1 m
  rs->set_segments(10);
  rs->set_linear_density(0.2);     // 0.2 kg in all: weight 1.962 N
  rs->set_damping(5.0);
  ASSERT_TRUE(c.create_scene(r).ok());

  v1::GrabRequest grab;
  grab.set_scene_id("g");
  grab.set_body("rope");
  grab.set_vertex(0);  // the top particle, held where it is
  auto granted = c.grab(grab);
  ASSERT_TRUE(granted.ok()) << granted.status.to_string();
  ASSERT_TRUE(c.step("g", 120).ok());

  v1::MoveGrabRequest move;
  move.set_scene_id("g");
  move.set_grab_id(granted->grab_id());
  set(move.mutable_target(), 0.3, 3, 0);
  auto moved = c.move_grab(move);
  ASSERT_TRUE(moved.ok()) << moved.status.to_string();
  // The grab holds the whole rope: its force on the body is the rope's weight, upward.
  const double weight = 0.2 * 9.81;
  EXPECT_NEAR(moved->force().y(), weight, 0.05 * weight);
  EXPECT_NEAR(moved->force().x(), 0.0, 0.05 * weight);

  ASSERT_TRUE(c.step("g", 60).ok());
  const v1::Frame f = latest_frame(c, "g");
  ASSERT_EQ(f.bodies_size(), 1);
  EXPECT_NEAR(f.bodies(0).positions(0), 0.3, 1e-3);
  EXPECT_NEAR(f.bodies(0).positions(1), 3.0, 1e-3);
  EXPECT_GT(f.bodies(0).positions(3 * 10), 0.05);  // the bottom follows

  // Release: the rope falls.
  ASSERT_TRUE(c.release("g", granted->grab_id()).ok());
  ASSERT_TRUE(c.step("g", 30).ok());
  const v1::Frame after = latest_frame(c, "g");
  EXPECT_LT(after.bodies(0).positions(1), 3.0 - 0.3);

  // Bad grabs: an unknown body, a particle out of range, a tet point on a body.
  grab.set_body("nope");
  EXPECT_EQ(c.grab(grab).status.code, kNotFound);
  grab.set_body("rope");
  grab.set_vertex(11);
  auto bad = c.grab(grab);
  EXPECT_EQ(bad.status.code, kInvalidArgument);
  EXPECT_NE(bad.status.message.find("vertex 11"), std::string::npos) << bad.status.message;
  grab.mutable_tet_point()->set_tet(0);
  EXPECT_EQ(c.grab(grab).status.code, kInvalidArgument);
}

TEST(Bodies, ABodyThatBlowsUpIsRolledBackWithTheScene) {
  BodiesServer srv;
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(bodies_request("nan")).ok());
  ASSERT_TRUE(c.step("nan", 3).ok());
  const v1::Snapshot before = snapshot_of(c, "nan");
  // A hard grab to a finite but absurd target: the rope's velocities overflow.
  v1::GrabRequest grab;
  grab.set_scene_id("nan");
  grab.set_body("rope");
  grab.set_vertex(20);
  set(grab.mutable_target(), 1e300, 0, 0);
  auto granted = c.grab(grab);
  ASSERT_TRUE(granted.ok()) << granted.status.to_string();
  auto st = c.step("nan", 1);
  ASSERT_TRUE(st.ok()) << st.status.to_string();
  EXPECT_EQ(st->rollbacks(), 1u);
  const v1::Frame f = latest_frame(c, "nan");
  EXPECT_TRUE(f.rolled_back());
  EXPECT_NE(f.rollback_reason().find("body 'rope'"), std::string::npos) << f.rollback_reason();
  // Every body and the tet body are as they were before the tick.
  const v1::Snapshot after = snapshot_of(c, "nan");
  EXPECT_TRUE(bit_equal(before.x(), after.x()));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(bit_equal(before.bodies(i).x(), after.bodies(i).x())) << before.bodies(i).name();
    EXPECT_TRUE(bit_equal(before.bodies(i).v(), after.bodies(i).v())) << before.bodies(i).name();
  }
  // Without the grab the scene steps on.
  ASSERT_TRUE(c.release("nan", granted->grab_id()).ok());
  st = c.step("nan", 1);
  ASSERT_TRUE(st.ok());
  EXPECT_EQ(st->rollbacks(), 0u);
}

TEST(Bodies, SnapshotRestoreContinuesBitIdentically) {
  BodiesServer srv;
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(bodies_request("orig")).ok());
  v1::GrabRequest grab;
  grab.set_scene_id("orig");
  grab.set_body("rope");
  grab.set_vertex(20);
  set(grab.mutable_target(), 1, 1.5, 0);
  grab.set_compliance(1e-3);
  ASSERT_TRUE(c.grab(grab).ok());
  ASSERT_TRUE(c.step("orig", 10).ok());
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = snapshot_of(c, "orig");
  restore.set_scene_id("copy");
  auto copy = c.restore_snapshot(restore);
  ASSERT_TRUE(copy.ok()) << copy.status.to_string();
  ASSERT_EQ(copy->bodies_size(), 3);
  ASSERT_TRUE(c.step("orig", 10).ok());
  ASSERT_TRUE(c.step("copy", 10).ok());
  const v1::Snapshot a = snapshot_of(c, "orig"), b = snapshot_of(c, "copy");
  EXPECT_TRUE(bit_equal(a.x(), b.x()));
  ASSERT_EQ(a.bodies_size(), 3);
  ASSERT_EQ(b.bodies_size(), 3);
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE(a.bodies(i).name());
    EXPECT_EQ(a.bodies(i).steps(), 20u);
    EXPECT_TRUE(bit_equal(a.bodies(i).x(), b.bodies(i).x()));
    EXPECT_TRUE(bit_equal(a.bodies(i).v(), b.bodies(i).v()));
    EXPECT_TRUE(bit_equal(a.bodies(i).lambda(), b.bodies(i).lambda()));
    EXPECT_EQ(a.bodies(i).time(), b.bodies(i).time());
  }
  ASSERT_EQ(b.bodies(0).grabs_size(), 1);
  // The fluid re-sorts its particles (sort_interval 10 by default, 2 substeps a tick): its order
  // and substep count travel with the snapshot, which is what keeps it bit for bit.
  ASSERT_EQ(a.bodies(2).solver_order_size() * 3, a.bodies(2).x_size());
  EXPECT_TRUE(std::equal(a.bodies(2).solver_order().begin(), a.bodies(2).solver_order().end(),
                         b.bodies(2).solver_order().begin()));
  EXPECT_EQ(a.bodies(2).substeps(), b.bodies(2).substeps());
  EXPECT_GT(a.bodies(2).substeps(), 0u);

  // A snapshot whose body state does not fit its spec is refused, naming it.
  v1::Snapshot broken = a;
  broken.mutable_bodies(1)->mutable_x()->RemoveLast();
  broken.mutable_bodies(1)->mutable_x()->RemoveLast();
  broken.mutable_bodies(1)->mutable_x()->RemoveLast();
  broken.mutable_bodies(1)->mutable_v()->RemoveLast();
  broken.mutable_bodies(1)->mutable_v()->RemoveLast();
  broken.mutable_bodies(1)->mutable_v()->RemoveLast();
  *restore.mutable_snapshot() = broken;
  restore.set_scene_id("broken");
  auto refused = c.restore_snapshot(restore);
  EXPECT_EQ(refused.status.code, kInvalidArgument);
  EXPECT_NE(refused.status.message.find("snapshot.bodies[1]"), std::string::npos) << refused.status.message;
  broken = a;
  broken.mutable_bodies(2)->set_x(4, NAN);
  *restore.mutable_snapshot() = broken;
  refused = c.restore_snapshot(restore);
  EXPECT_EQ(refused.status.code, kInvalidArgument);
  EXPECT_NE(refused.status.message.find("snapshot.bodies[2]"), std::string::npos) << refused.status.message;
  broken = a;
  broken.mutable_bodies(2)->set_solver_order(1, broken.bodies(2).solver_order(0));
  *restore.mutable_snapshot() = broken;
  refused = c.restore_snapshot(restore);
  EXPECT_EQ(refused.status.code, kInvalidArgument);
  EXPECT_NE(refused.status.message.find("snapshot.bodies[2].solver_order[1]"), std::string::npos)
      << refused.status.message;
}

TEST(Bodies, UpdatedGravityActsOnTheBodiesAndSurvivesARestore) {
  BodiesServer srv;
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(bodies_request("up")).ok());
  auto topo = c.topology("up");
  ASSERT_TRUE(topo.ok()) << topo.status.to_string();
  v1::UpdateSceneRequest update;
  update.set_scene_id("up");
  set(update.mutable_gravity(), 0, 9.81, 0);  // upward
  auto updated = c.update_scene(update);
  ASSERT_TRUE(updated.ok()) << updated.status.to_string();
  EXPECT_DOUBLE_EQ(updated->spec().gravity().y(), 9.81);
  ASSERT_TRUE(c.step("up", 30).ok());
  const v1::Frame f = latest_frame(c, "up");
  ASSERT_EQ(f.bodies_size(), 3);
  // Every body rose: the rope's and the cloth's free ends, the fluid's mean height.
  EXPECT_GT(y_of(f.bodies(0).positions(), 20), y_of(topo->bodies(0).rest_positions(), 20) + 0.1);
  EXPECT_GT(y_of(f.bodies(1).positions(), 63), y_of(topo->bodies(1).rest_positions(), 63) + 0.05);
  double mean_now = 0, mean_rest = 0;
  for (int i = 0; i < 64; ++i) {
    mean_now += y_of(f.bodies(2).positions(), i) / 64;
    mean_rest += y_of(topo->bodies(2).rest_positions(), i) / 64;
  }
  EXPECT_GT(mean_now, mean_rest + 0.02);
  // A copy restored from a snapshot keeps the updated gravity for its bodies too.
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = snapshot_of(c, "up");
  restore.set_scene_id("up-copy");
  ASSERT_TRUE(c.restore_snapshot(restore).ok());
  ASSERT_TRUE(c.step("up", 10).ok());
  ASSERT_TRUE(c.step("up-copy", 10).ok());
  const v1::Snapshot a = snapshot_of(c, "up"), b = snapshot_of(c, "up-copy");
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE(a.bodies(i).name());
    EXPECT_TRUE(bit_equal(a.bodies(i).x(), b.bodies(i).x()));
  }
}

TEST(Bodies, RestartKeepsTheBodies) {
  const fs::path dir = temp_dir("restart");
  server::ServerOptions o;
  o.data_dir = dir.string();
  v1::Snapshot before;
  {
    BodiesServer a(o);
    Client c = a.client();
    ASSERT_TRUE(c.create_scene(bodies_request("keep")).ok());
    ASSERT_TRUE(c.step("keep", 7).ok());
    before = snapshot_of(c, "keep");
    EXPECT_EQ(a.server->shutdown(), 1);
  }
  {
    BodiesServer b(o);
    Client c = b.client();
    auto got = c.get_scene("keep");
    ASSERT_TRUE(got.ok()) << got.status.to_string();
    ASSERT_EQ(got->bodies_size(), 3);
    const v1::Snapshot after = snapshot_of(c, "keep");
    ASSERT_EQ(after.bodies_size(), 3);
    for (int i = 0; i < 3; ++i) {
      EXPECT_TRUE(bit_equal(before.bodies(i).x(), after.bodies(i).x()));
      EXPECT_TRUE(bit_equal(before.bodies(i).v(), after.bodies(i).v()));
    }
  }
  fs::remove_all(dir);
}

// beam1 beside a container with no water in it and a tap above: a disc of 13 lattice points
// (radius 2 spacings) pouring downwards at 1.5 m/s, 10 layers at most.
v1::CreateSceneRequest tap_request(const std::string& id) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  auto* fluid = s->add_bodies();
  fluid->set_name("tap");
  auto* f = fluid->mutable_fluid();
  f->set_spacing(0.05);
  set_container(f, -3, 0.5, 0, 0.4, 0.5, 0.4);
  auto* e = f->add_emitters();
  set(e->mutable_center(), -3, 0.8, 0);
  set(e->mutable_direction(), 0, -2, 0);  // normalised by the server
  e->set_speed(1.5);
  e->set_radius(0.1);
  e->set_max_particles(130);
  return r;
}

TEST(Bodies, AnEmitterPoursWaterThatFramesSnapshotsAndGrabsFollow) {
  BodiesServer srv;
  Client c = srv.client();
  auto created = c.create_scene(tap_request("tap"));
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  ASSERT_EQ(created->bodies_size(), 1);
  EXPECT_EQ(created->bodies(0).particle_count(), 0u);
  EXPECT_EQ(created->bodies(0).max_particle_count(), 130u);
  // The spec comes back with the values in use.
  ASSERT_EQ(created->spec().bodies(0).fluid().emitters_size(), 1);
  const v1::FluidEmitter& echoed = created->spec().bodies(0).fluid().emitters(0);
  EXPECT_EQ(echoed.direction().y(), -1.0);
  EXPECT_EQ(echoed.radius(), 0.1);
  EXPECT_EQ(echoed.max_particles(), 130u);
  // The topology says what the body may grow to.
  auto topo = c.topology("tap");
  ASSERT_TRUE(topo.ok()) << topo.status.to_string();
  ASSERT_EQ(topo->bodies_size(), 1);
  EXPECT_EQ(topo->bodies(0).particle_count(), 0u);
  EXPECT_EQ(topo->bodies(0).max_particle_count(), 130u);

  // A layer every spacing / speed = 1/30 s, that is every 4 substeps of 1/120 s (2 a tick; a
  // fifth when the sum rounds below): after 7 ticks, 14 substeps, three layers of 13.
  ASSERT_TRUE(c.step("tap", 7).ok());
  v1::Frame f = latest_frame(c, "tap");
  ASSERT_EQ(f.bodies_size(), 1);
  const int early = f.bodies(0).positions_size() / 3;
  EXPECT_EQ(early, 39);
  EXPECT_EQ(echoed.speed(), 1.5);
  auto got = c.get_scene("tap");
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(static_cast<int>(got->bodies(0).particle_count()), early);
  // A particle the tap has not poured yet cannot be grabbed; one beyond the tap's total is
  // refused before it reaches the scene.
  v1::GrabRequest grab;
  grab.set_scene_id("tap");
  grab.set_body("tap");
  grab.set_vertex(100);
  auto refused = c.grab(grab);
  EXPECT_EQ(refused.status.code, kInvalidArgument);
  EXPECT_NE(refused.status.message.find("particles now"), std::string::npos) << refused.status.message;
  grab.set_vertex(130);
  refused = c.grab(grab);
  EXPECT_EQ(refused.status.code, kInvalidArgument);
  EXPECT_NE(refused.status.message.find("130 particles at most"), std::string::npos) << refused.status.message;

  // A snapshot between two layers continues bit for bit in a copy, emissions included.
  const v1::Snapshot mid = snapshot_of(c, "tap");
  ASSERT_EQ(mid.bodies(0).emitters_size(), 1);
  EXPECT_EQ(static_cast<int>(mid.bodies(0).emitters(0).emitted()), early);
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = mid;
  restore.set_scene_id("copy");
  auto copy = c.restore_snapshot(restore);
  ASSERT_TRUE(copy.ok()) << copy.status.to_string();
  EXPECT_EQ(static_cast<int>(copy->bodies(0).particle_count()), early);
  ASSERT_TRUE(c.step("tap", 20).ok());
  ASSERT_TRUE(c.step("copy", 20).ok());
  const v1::Snapshot a = snapshot_of(c, "tap"), b = snapshot_of(c, "copy");
  EXPECT_GT(a.bodies(0).x_size(), 3 * early);
  EXPECT_TRUE(bit_equal(a.bodies(0).x(), b.bodies(0).x()));
  EXPECT_TRUE(bit_equal(a.bodies(0).v(), b.bodies(0).v()));
  EXPECT_EQ(a.bodies(0).emitters(0).emitted(), b.bodies(0).emitters(0).emitted());
  EXPECT_EQ(a.bodies(0).emitters(0).travelled(), b.bodies(0).emitters(0).travelled());
  // Progress that does not fit the positions is refused, naming the body.
  v1::Snapshot broken = mid;
  broken.mutable_bodies(0)->mutable_emitters(0)->set_emitted(static_cast<uint64_t>(early) + 13);
  *restore.mutable_snapshot() = broken;
  restore.set_scene_id("broken");
  auto not_restored = c.restore_snapshot(restore);
  EXPECT_EQ(not_restored.status.code, kInvalidArgument);
  EXPECT_NE(not_restored.status.message.find("snapshot.bodies[0]"), std::string::npos)
      << not_restored.status.message;

  // A particle that exists now can be grabbed; after a second the tap has poured its 130
  // particles and stopped; all of them are in the container, below the tap.
  grab.set_vertex(early - 1);
  EXPECT_TRUE(c.grab(grab).ok());
  ASSERT_TRUE(c.step("tap", 40).ok());
  f = latest_frame(c, "tap");
  ASSERT_EQ(f.bodies(0).positions_size(), 3 * 130);
  for (int i = 0; i < 130; ++i) {
    const float* p = f.bodies(0).positions().data() + 3 * i;
    EXPECT_LT(std::abs(p[0] + 3), 0.4f) << i;
    EXPECT_GT(p[1], -1e-3f) << i;
    EXPECT_LT(p[1], 0.8f) << i;
  }
  // Reset: the fluid is as created, empty, and pours again.
  auto reset = c.reset_scene("tap");
  ASSERT_TRUE(reset.ok()) << reset.status.to_string();
  EXPECT_EQ(reset->bodies(0).particle_count(), 0u);
  ASSERT_TRUE(c.step("tap", 7).ok());
  f = latest_frame(c, "tap");
  EXPECT_EQ(f.bodies(0).positions_size() / 3, early);
}

TEST(Bodies, BadSpecsAreRefusedNamingTheField) {
  BodiesServer srv;
  Client c = srv.client();
  struct Case {
    std::function<void(v1::SceneSpec*)> edit;
    int code;
    std::string field, value;
  };
  const std::vector<Case> cases = {
      {[](v1::SceneSpec* s) { s->mutable_bodies(1)->mutable_cloth()->mutable_grid()->set_resolution_x(1); },
       kInvalidArgument, "spec.bodies[1].cloth.grid.resolution_x", "got 1"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(1)->set_name("rope"); }, kInvalidArgument, "spec.bodies[1].name",
       "rope"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(0)->set_name(""); }, kInvalidArgument, "spec.bodies[0].name",
       "empty"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(0)->mutable_rope()->set_segments(0); }, kInvalidArgument,
       "spec.bodies[0].rope.segments", "got 0"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(0)->mutable_rope()->set_bend_compliance(-1); }, kInvalidArgument,
       "spec.bodies[0].rope.bend_compliance", "got -1"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(0)->mutable_rope()->mutable_pins()->add_indices(21); },
       kInvalidArgument, "spec.bodies[0]", "21"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(2)->mutable_fluid()->set_spacing(-0.5); }, kInvalidArgument,
       "spec.bodies[2].fluid.spacing", "got -0.5"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(2)->mutable_fluid()->clear_blocks(); }, kInvalidArgument,
       "spec.bodies[2].fluid.blocks", "empty"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(2)->mutable_fluid()->mutable_container()->mutable_sphere()->set_radius(1); },
       kInvalidArgument, "spec.bodies[2].fluid.container", "box"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(2)->mutable_fluid()->set_substeps(0); }, kInvalidArgument,
       "spec.bodies[2].fluid.substeps", "got 0"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(2)->mutable_fluid()->add_emitters()->set_radius(0.1); },
       kInvalidArgument, "spec.bodies[2].fluid.emitters[0].speed", "got 0"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(2)->mutable_fluid()->add_emitters()->set_speed(1); },
       kInvalidArgument, "spec.bodies[2].fluid.emitters[0]", "radius, rectangle"},
      {[](v1::SceneSpec* s) {
         auto* e = s->mutable_bodies(2)->mutable_fluid()->add_emitters();
         e->set_speed(1);
         e->mutable_rectangle()->set_half_u(0.1);
         e->mutable_rectangle()->set_half_v(-0.1);
       },
       kInvalidArgument, "spec.bodies[2].fluid.emitters[0].rectangle.half_v", "got -0.1"},
      {[](v1::SceneSpec* s) {  // 161 x 161 lattice points across, 10,000 particles in all
         auto* e = s->mutable_bodies(2)->mutable_fluid()->add_emitters();
         e->set_speed(1);
         e->set_radius(4);
       },
       kInvalidArgument, "spec.bodies[2].fluid.emitters[0]", "max_particles 10000"},
      {[](v1::SceneSpec* s) {
         auto* e = s->mutable_bodies(2)->mutable_fluid()->add_emitters();
         e->set_speed(1);
         e->set_radius(0.1);
         set(e->mutable_direction(), 0, 0, 0);
       },
       kInvalidArgument, "spec.bodies[2].fluid.emitters[0].direction", "non-zero"},
      {[](v1::SceneSpec* s) {  // the emitters' totals count toward the scene's particles
         auto* f = s->mutable_bodies(2)->mutable_fluid();
         for (int i = 0; i < 2; ++i) {
           auto* e = f->add_emitters();
           e->set_speed(1);
           e->set_radius(0.1);
           e->set_max_particles(100000);
         }
       },
       kResourceExhausted, "spec.bodies[2]", "200000"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(1)->mutable_cloth()->set_mass_per_area(0); }, kInvalidArgument,
       "spec.bodies[1].cloth.mass_per_area", "got 0"},
      {[](v1::SceneSpec* s) { s->mutable_bodies(1)->mutable_cloth()->set_model_path("../etc/passwd"); },
       kInvalidArgument, "spec.bodies[1].cloth.model_path", ""},
      {[](v1::SceneSpec* s) { s->mutable_bodies(1)->clear_cloth(); }, kInvalidArgument, "spec.bodies[1]",
       "fluid, cloth, rope"},
      {[](v1::SceneSpec* s) {  // 501 x 501 = 251,001 particles
         auto* g = s->mutable_bodies(1)->mutable_cloth()->mutable_grid();
         g->set_resolution_x(501);
         g->set_resolution_y(501);
       },
       kResourceExhausted, "spec.bodies[1]", "200000"},
      {[](v1::SceneSpec* s) {
         for (int i = 0; i < 14; ++i) *s->add_bodies() = s->bodies(0);
       },
       kResourceExhausted, "spec.bodies", "16 bodies"},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    SCOPED_TRACE(cases[i].field);
    auto req = bodies_request("bad");
    cases[i].edit(req.mutable_spec());
    auto got = c.create_scene(req);
    EXPECT_EQ(got.status.code, cases[i].code) << got.status.to_string();
    EXPECT_NE(got.status.message.find(cases[i].field), std::string::npos) << got.status.message;
    EXPECT_NE(got.status.message.find(cases[i].value), std::string::npos) << got.status.message;
  }
  // Nothing was created by the refused requests.
  auto list = c.list_scenes();
  ASSERT_TRUE(list.ok());
  EXPECT_TRUE(list->empty());
}

}  // namespace

namespace {

// beam1 (E 10 MPa, the Newton step, 2 iterations per tick, lockstep) clamped at x <= 1 cm, and
// one rope body `name` with friction 1 against it (the contact off when `contact` is false):
// returns the rope's spec for the caller to lay out.
v1::RopeSpec* beam1_with_rope(v1::CreateSceneRequest& r, const std::string& id, const std::string& name, bool contact) {
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*s, 0.01);
  s->mutable_material()->set_young_modulus(1e7);
  s->mutable_solver()->set_method(v1::METHOD_NEWTON);
  s->mutable_solver()->set_substeps(1);
  s->mutable_solver()->set_iterations(2);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  auto* rope = s->add_bodies();
  rope->set_name(name);
  if (!contact) rope->set_soft_body_contact(false);
  rope->set_soft_body_friction(1.0);
  return rope->mutable_rope();
}

}  // namespace

TEST(Bodies, ARopeLaidOnTheBeamRestsOnItAndBendsIt) {
  // beam1 (E 10 MPa, the Newton step, 2 iterations per tick) clamped at x <= 1 cm (top face
  // y = 1 cm, z in [0, 1 cm]); a 7 cm rope of 1.4 g dropped onto its top from 5 mm above, along
  // it. With the soft-body
  // contact (the default) the rope lands on the beam and its weight bends the beam further down
  // (a rope does not resist compression: it bunches up as it lands, and its far end may slide
  // over the side); without it the rope falls through.
  BodiesServer srv;
  Client c = srv.client();
  auto request = [](const std::string& id, bool contact) {
    v1::CreateSceneRequest r;
    auto* rs = beam1_with_rope(r, id, "rope", contact);
    set(rs->add_points(), 0.02, 0.015, 0.005);
    set(rs->add_points(), 0.09, 0.015, 0.005);
    rs->set_linear_density(0.02);
    rs->set_segments(35);
    rs->set_thickness(0.002);
    return r;
  };
  ASSERT_TRUE(c.create_scene(request("on", true)).ok());
  ASSERT_TRUE(c.create_scene(request("off", false)).ok());
  auto bare = request("bare", true);
  bare.mutable_spec()->clear_bodies();
  ASSERT_TRUE(c.create_scene(bare).ok());
  for (const char* id : {"on", "off", "bare"}) ASSERT_TRUE(c.step(id, 90).ok()) << id;
  const v1::Frame on = latest_frame(c, "on"), off = latest_frame(c, "off"), alone = latest_frame(c, "bare");
  ASSERT_EQ(on.bodies_size(), 1);
  ASSERT_EQ(on.bodies(0).positions_size(), 3 * 36);
  // The rope's first half: resting on the beam's top, its thickness above it, or 90 ticks into
  // free fall.
  for (int i = 0; i < 18; ++i) {
    EXPECT_NEAR(y_of(on.bodies(0).positions(), i), 0.012, 0.001) << i;
    EXPECT_LT(y_of(off.bodies(0).positions(), i), -1.0) << i;
  }
  // The beam's tip (the vertex of largest x, then y): lower with the rope on it than alone, and
  // alone the same whether a rope fell through or not.
  auto topo = c.topology("bare");
  ASSERT_TRUE(topo.ok());
  int tip = 0;
  for (uint32_t i = 1; i < topo->vertex_count(); ++i) {
    const auto& r = topo->rest_positions();
    if (r[3 * i] > r[3 * tip] + 1e-9 || (std::abs(r[3 * i] - r[3 * tip]) <= 1e-9 && r[3 * i + 1] > r[3 * tip + 1]))
      tip = int(i);
  }
  const double y_on = y_of(on.positions(), tip), y_off = y_of(off.positions(), tip), y_alone = y_of(alone.positions(), tip);
  EXPECT_EQ(y_off, y_alone);
  EXPECT_LT(y_on, y_alone - 1e-4) << "tip " << y_on << " with the rope, " << y_alone << " without";
}

TEST(Bodies, ALineOverTheBeamRestsOnItAlongALink) {
  // beam1 as above (top face y = 1 cm, z in [0, 1 cm]); a line of 7 links of 3 cm and 2 mm
  // thickness pinned at both ends at the beam's bottom height, 21 cm apart across it, laid as a
  // tent whose middle link is 5 mm over the beam: that link's particles (z = -1 and 2 cm) are
  // either side of the beam, none over it. Free, the line would sag 1.4 cm below its pins. The
  // links keep the contact along their length, so the line falls onto the beam and rests on it
  // across that link (with the particles alone the link passed through the beam and the line
  // sagged below it, as the line without contact does).
  BodiesServer srv;
  Client c = srv.client();
  auto request = [](const std::string& id, bool contact) {
    v1::CreateSceneRequest r;
    auto* rs = beam1_with_rope(r, id, "line", contact);
    set(rs->add_points(), 0.06, 0.0, -0.1);
    set(rs->add_points(), 0.06, 0.015, -0.01);
    set(rs->add_points(), 0.06, 0.015, 0.02);
    set(rs->add_points(), 0.06, 0.0, 0.11);
    rs->set_linear_density(0.02);
    rs->set_segments(7);
    rs->set_thickness(0.002);
    rs->set_damping(5);
    rs->mutable_pins()->add_indices(0);
    rs->mutable_pins()->add_indices(7);
    return r;
  };
  ASSERT_TRUE(c.create_scene(request("on", true)).ok());
  ASSERT_TRUE(c.create_scene(request("off", false)).ok());
  for (const char* id : {"on", "off"}) ASSERT_TRUE(c.step(id, 120).ok()) << id;
  const v1::Frame on = latest_frame(c, "on"), off = latest_frame(c, "off");
  ASSERT_EQ(on.bodies(0).positions_size(), 3 * 8);
  const auto& p = on.bodies(0).positions();
  auto at = [&](int i) { return Vec3(p[3 * i], p[3 * i + 1], p[3 * i + 2]); };
  // The middle link's particles either side of the beam, near the top face's height.
  EXPECT_LT(at(3).z(), 0.0);
  EXPECT_GT(at(4).z(), 0.01);
  for (int i : {3, 4}) {
    EXPECT_GT(at(i).y(), 0.006) << i;
    EXPECT_LT(y_of(off.bodies(0).positions(), i), 0.0) << i;  // sagged below the beam
  }
  // Every point of every link clear of the beam's cross-section (the square y, z in [0, 1 cm];
  // the beam bends by micrometres under the line) by most of the thickness.
  for (int link = 0; link < 7; ++link)
    for (int k = 0; k <= 100; ++k) {
      const Vec3 q = at(link) + (k / 100.0) * (at(link + 1) - at(link));
      const double dy = std::max({-q.y(), q.y() - 0.01, 0.0}), dz = std::max({-q.z(), q.z() - 0.01, 0.0});
      EXPECT_GT(std::hypot(dy, dz), 0.0015) << "link " << link << " point " << k;
    }
  // Frames count the points the contact pushed (the resting link's, each tick).
  EXPECT_GT(on.solver().bodies(0).soft_body_contacts(), 0u);
  EXPECT_EQ(off.solver().bodies(0).soft_body_contacts(), 0u);
}

TEST(Bodies, AnOverstretchedClothSaysInItsFramesThatItLeftSelfCollisionOut) {
  // A 32 x 32 cloth, 0.3 m wide, hung from two corners away from the beam: with 4 substeps of
  // one iteration its hanging chains of 31 links stretch far past twice their length, so its
  // steps leave self-collision out and the frames say so; with 64 they stay within bounds.
  BodiesServer srv;
  Client c = srv.client();
  auto request = [](const std::string& id, int substeps) {
    v1::CreateSceneRequest r = beam_scene(id);
    auto* cloth = r.mutable_spec()->add_bodies();
    cloth->set_name("sheet");
    auto* cs = cloth->mutable_cloth();
    auto* g = cs->mutable_grid();
    g->set_resolution_x(32);
    g->set_resolution_y(32);
    g->set_size_x(0.3);
    g->set_size_y(0.3);
    set(g->mutable_origin(), 3, 2, 0);
    cs->set_substeps(substeps);
    cs->set_thickness(0.003);
    cs->mutable_pins()->add_indices(0);
    cs->mutable_pins()->add_indices(31);
    return r;
  };
  ASSERT_TRUE(c.create_scene(request("coarse", 4)).ok());
  ASSERT_TRUE(c.create_scene(request("fine", 64)).ok());
  for (const char* id : {"coarse", "fine"}) ASSERT_TRUE(c.step(id, 30).ok()) << id;
  const v1::Frame coarse = latest_frame(c, "coarse"), fine = latest_frame(c, "fine");
  ASSERT_EQ(coarse.solver().bodies_size(), 1);
  EXPECT_GT(coarse.solver().bodies(0).max_constraint_error(), 1.0);
  EXPECT_TRUE(coarse.solver().bodies(0).self_collision_suspended());
  EXPECT_LT(fine.solver().bodies(0).max_constraint_error(), 1.0);
  EXPECT_FALSE(fine.solver().bodies(0).self_collision_suspended());
}

// A rope stretched between two pins and a little block of water just above its middle, in a
// container far from the beam.
v1::CreateSceneRequest line_request(const std::string& id, bool rope_contact) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  auto* line = s->add_bodies();
  line->set_name("line");
  line->set_body_contact(rope_contact);
  auto* rs = line->mutable_rope();
  set(rs->add_points(), -3.3, 0.5, 0);
  set(rs->add_points(), -2.7, 0.5, 0);
  rs->set_segments(30);
  rs->set_substeps(32);
  rs->set_iterations(4);
  rs->set_damping(20);  // settles before the water arrives
  rs->mutable_pins()->add_indices(0);
  rs->mutable_pins()->add_indices(30);
  auto* water = s->add_bodies();
  water->set_name("drop");
  auto* f = water->mutable_fluid();
  f->set_spacing(0.02);
  auto* blk = f->add_blocks();
  set(blk->mutable_min(), -3.04, 0.9, -0.02);
  set(blk->mutable_max(), -2.96, 0.94, 0.02);
  set_container(f, -3, 0.5, 0, 0.4, 0.5, 0.4);
  return r;
}

TEST(Bodies, ARopeIsAnObstacleToWaterFallingOnIt) {
  // 16 particles of water, 2 cm apart, fall 40 cm onto the rope's middle, 1 cm either side of
  // its axis. With the contact they hit it, push it down and slide off around it: after every
  // tick no particle is within the contact radius (particle radius 1 cm + thickness 5 mm) of a
  // segment, and they leave wider apart. Without it (the control) they fall straight through.
  BodiesServer srv;
  Client c = srv.client();
  const double radius = 0.015;
  struct Run {
    double rope_lowest = INFINITY;  // the middle bead's lowest y
    double closest = INFINITY;      // the closest any particle came to the rope after a tick
    double spread = 0;              // the largest |z| of a particle at the end
    uint64_t contacts = 0;
  };
  auto run = [&](const std::string& id, bool contact) {
    Run out;
    EXPECT_TRUE(c.create_scene(line_request(id, contact)).ok());
    for (int k = 0; k < 30; ++k) {
      EXPECT_TRUE(c.step(id, 1).ok());
      const v1::Frame f = latest_frame(c, id);
      if (f.bodies_size() != 2 || f.solver().bodies_size() != 2) {
        ADD_FAILURE() << "frame without the bodies";
        return out;
      }
      const auto& rope = f.bodies(0).positions();
      const auto& water = f.bodies(1).positions();
      out.rope_lowest = std::min(out.rope_lowest, double(rope[3 * 15 + 1]));
      out.contacts += f.solver().bodies(1).body_contacts();
      for (int i = 0; i < water.size() / 3; ++i) {
        const Vec3 p(water[3 * i], water[3 * i + 1], water[3 * i + 2]);
        for (int j = 0; j + 1 < rope.size() / 3; ++j) {
          const Vec3 a(rope[3 * j], rope[3 * j + 1], rope[3 * j + 2]);
          const Vec3 b(rope[3 * j + 3], rope[3 * j + 4], rope[3 * j + 5]);
          const double t = std::clamp((p - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
          out.closest = std::min(out.closest, (p - (a + t * (b - a))).norm());
        }
        if (k == 29) out.spread = std::max(out.spread, std::abs(p.z()));
      }
    }
    return out;
  };
  const Run held = run("held", true), through = run("through", false);
  EXPECT_GT(held.contacts, 0u);
  EXPECT_EQ(through.contacts, 0u);
  EXPECT_GT(held.closest, radius - 1e-4) << "m; the control came to " << through.closest;
  EXPECT_LT(through.closest, radius) << "the control's water passes the rope";
  EXPECT_LT(held.rope_lowest, through.rope_lowest - 1e-3) << "the water pushes the rope down";
  EXPECT_GT(held.spread, through.spread + 0.005) << "the water slides off around the rope";
}

// A bar (a rope of 10 cm links pinned at both ends, 6 segments along x at y = 0.5) and a short
// rope of three 10 cm links dropped across its middle from 10 cm above: the dropped rope's beads
// come no nearer than 5 cm to the bar, only its middle link crosses it.
v1::CreateSceneRequest crossing_ropes_request(const std::string& id, bool contact) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  auto* bar = s->add_bodies();
  bar->set_name("bar");
  bar->set_body_contact(contact);
  auto* b = bar->mutable_rope();
  set(b->add_points(), -3.3, 0.5, 0);
  set(b->add_points(), -2.7, 0.5, 0);
  b->set_segments(6);
  b->mutable_pins()->add_indices(0);
  b->mutable_pins()->add_indices(6);
  auto* drop = s->add_bodies();
  drop->set_name("drop");
  drop->set_body_contact(contact);
  auto* d = drop->mutable_rope();
  set(d->add_points(), -3.0, 0.6, -0.15);
  set(d->add_points(), -3.0, 0.6, 0.15);
  d->set_segments(3);
  d->set_damping(5);
  return r;
}

TEST(Bodies, ARopeDroppedAcrossAnotherHangsOnItByItsLink) {
  // With contact between the two, the dropped rope's middle link lands on the bar and the rope
  // hangs over it: after every tick the two ropes' links stay apart by nearly the contact
  // radius (thickness 5 mm each: 1 cm; the points along a link are at most a radius apart, so
  // sqrt(3)/2 of it where links cross square), and after a second the middle link is still on
  // the bar (its midpoint above the bar's middle bead). Without (the control) it falls through.
  BodiesServer srv;
  Client c = srv.client();
  const double radius = 0.01;
  struct Run {
    double closest = INFINITY;  // the closest the two ropes' links came after a tick
    double above = 0;           // the dropped rope's middle above the bar's middle bead at the end
    uint64_t contacts = 0;
  };
  auto rope_of = [](const v1::Frame& f, int b) {
    std::vector<Vec3> x;
    const auto& p = f.bodies(b).positions();
    for (int i = 0; i + 2 < p.size(); i += 3) x.emplace_back(p[i], p[i + 1], p[i + 2]);
    return x;
  };
  auto run = [&](const std::string& id, bool contact) {
    Run out;
    EXPECT_TRUE(c.create_scene(crossing_ropes_request(id, contact)).ok());
    for (int k = 0; k < 60; ++k) {
      EXPECT_TRUE(c.step(id, 1).ok());
      const v1::Frame f = latest_frame(c, id);
      if (f.bodies_size() != 2 || f.solver().bodies_size() != 2) {
        ADD_FAILURE() << "frame without the bodies";
        return out;
      }
      const std::vector<Vec3> bar = rope_of(f, 0), drop = rope_of(f, 1);
      out.contacts += f.solver().bodies(1).body_contacts();
      for (size_t i = 0; i + 1 < drop.size(); ++i)
        for (size_t j = 0; j + 1 < bar.size(); ++j)
          out.closest = std::min(out.closest, test::segment_distance(drop[i], drop[i + 1], bar[j], bar[j + 1]));
      out.above = 0.5 * (drop[1].y() + drop[2].y()) - bar[3].y();
    }
    return out;
  };
  const Run held = run("held", true), through = run("through", false);
  EXPECT_GT(held.contacts, 0u);
  EXPECT_EQ(through.contacts, 0u);
  EXPECT_GT(held.closest, std::sqrt(3.0) / 2 * radius - 1e-4) << "m; the control came to " << through.closest;
  EXPECT_GT(held.above, std::sqrt(3.0) / 2 * radius - 1e-4) << "m; the dropped rope hangs on the bar";
  EXPECT_LT(through.above, -0.2) << "the control falls through";
}

TEST(Bodies, ARopeUnderAFallingClothRunsItsFiveSeconds) {
  // The browser test's scene (body_scenes.hpp): a cloth falls onto a rope beside beam1's tip
  // and wraps it, water pours beside them. Over 5 s the scene steps every tick, and the cloth
  // reaches the rope. Whether the rope stays whole depends on the configuration (the scene is
  // chaotic, and the builds' rounding picks which configurations explode), so that is asked of a
  // grid of 40 of them (BodyEnsembles, the physics label); this one configuration
  // runs here, under the sanitizers too. It asks for every tick, not for their speed: where the
  // rope explodes, the contacts between the stretched rope and cloth make a tick up to a hundred
  // times longer, which under AddressSanitizer passed the server's 10 s guard; the guard is a
  // minute here.
  server::ServerOptions o;
  o.max_tick_ms = 60'000;
  BodiesServer srv(o);
  Client c = srv.client();
  const test::RopeRun run = test::run_rope_under_cloth(c, 0.06, 0.0075, 300);
  EXPECT_EQ(run.ticks, 300);
  EXPECT_GT(run.contacts, 0u) << "the cloth reaches the rope";
  std::cout << "[ wrap ] the rope's RMS stretch: mean " << run.mean << ", largest " << run.worst << "\n";
}

TEST(Bodies, ARopeAndAClothMeetAsOftenAsTheirSubstepsAllowBesideAFluidOfFewer) {
  // The wrap scene without the soft body's contacts: a cloth of 16 substeps falls onto a rope of
  // 16, and water of 2 substeps pours far from them, paired with both (body_contact). The scene's
  // parts are the 2 every paired body shares; within them the rope and the cloth still step
  // substep by substep with their contact after each, as they do with no water in the scene: the
  // same positions to the bit. (When the water's 2 substeps cut the whole scene's contacts to
  // two a tick, the rope wrapped in the cloth stayed agitated: docs/cloth.md, "Steps in parts".)
  auto request = [](const std::string& id, bool water) {
    v1::CreateSceneRequest r = test::rope_under_cloth_request(id);
    auto* bodies = r.mutable_spec()->mutable_bodies();
    for (auto& b : *bodies) b.set_soft_body_contact(false);
    if (!water) bodies->RemoveLast();
    return r;
  };
  BodiesServer srv;
  Client c = srv.client();
  ASSERT_TRUE(c.create_scene(request("with", true)).ok());
  ASSERT_TRUE(c.create_scene(request("without", false)).ok());
  uint64_t contacts = 0;
  for (int k = 0; k < 60; ++k) {
    ASSERT_TRUE(c.step("with", 1).ok());
    ASSERT_TRUE(c.step("without", 1).ok());
    const v1::Frame f = latest_frame(c, "with");
    ASSERT_EQ(f.solver().bodies_size(), 3);
    contacts += f.solver().bodies(0).body_contacts() + f.solver().bodies(1).body_contacts();
    if (k == 0) {
      EXPECT_EQ(f.solver().bodies(0).step_parts(), 16u) << "the rope";
      EXPECT_EQ(f.solver().bodies(1).step_parts(), 16u) << "the cloth";
      EXPECT_EQ(f.solver().bodies(2).step_parts(), 2u) << "the water";
    }
  }
  EXPECT_GT(contacts, 0u) << "the cloth reaches the rope";
  const v1::Snapshot with = snapshot_of(c, "with"), without = snapshot_of(c, "without");
  ASSERT_EQ(with.bodies_size(), 3);
  ASSERT_EQ(without.bodies_size(), 2);
  for (int b = 0; b < 2; ++b) {
    EXPECT_TRUE(bit_equal(with.bodies(b).x(), without.bodies(b).x())) << with.bodies(b).name();
    EXPECT_TRUE(bit_equal(with.bodies(b).v(), without.bodies(b).v())) << with.bodies(b).name();
  }
}

// beam1 clamped at x <= 0.01, soft (100 kPa) so it sags far, over a drape of two triangles
// pinned at its four corners 2 cm below it: no cloth particle is anywhere near the beam.
v1::CreateSceneRequest drape_request(const std::string& id, bool soft_body_contact, v1::Method method) {
  v1::CreateSceneRequest r = beam_scene(id);
  auto* s = r.mutable_spec();
  s->mutable_material()->set_young_modulus(1e5);
  s->mutable_solver()->set_method(method);
  auto* body = s->add_bodies();
  body->set_name("drape");
  body->set_soft_body_contact(soft_body_contact);
  auto* cl = body->mutable_cloth();
  auto* g = cl->mutable_grid();
  g->set_resolution_x(2);
  g->set_resolution_y(2);
  g->set_size_x(0.4);
  g->set_size_y(0.4);
  set(g->mutable_origin(), -0.1, -0.02, -0.2);
  cl->set_thickness(0.004);
  for (uint32_t i = 0; i < 4; ++i) cl->mutable_pins()->add_indices(i);
  return r;
}

TEST(Bodies, ASoftBodyRestsOnADrapesTrianglesBetweenItsParticles) {
  // With the contact the sagging beam lies on the drape, inside vertices included: none below
  // its plane plus the thickness. Without it (the control) the beam falls through the triangles.
  BodiesServer srv;
  Client c = srv.client();
  auto lowest = [&](const std::string& id) {
    v1::SaveSnapshotRequest q;
    q.set_scene_id(id);
    auto s = c.save_snapshot(q);
    EXPECT_TRUE(s.ok());
    double y = INFINITY;
    for (int i = 1; i < s->snapshot().x_size(); i += 3) y = std::min(y, s->snapshot().x(i));
    return y;
  };
  for (v1::Method method : {v1::METHOD_XPBD, v1::METHOD_VBD}) {
    SCOPED_TRACE(v1::Method_Name(method));
    const std::string held_id = "held" + std::to_string(int(method)), through_id = "through" + std::to_string(int(method));
    ASSERT_TRUE(c.create_scene(drape_request(held_id, true, method)).ok());
    ASSERT_TRUE(c.create_scene(drape_request(through_id, false, method)).ok());
    ASSERT_TRUE(c.step(held_id, 90).ok());
    ASSERT_TRUE(c.step(through_id, 90).ok());
    EXPECT_GT(lowest(held_id), -0.02 + 0.004 - 2e-4) << "the beam's lowest vertex, m";
    EXPECT_LT(lowest(through_id), -0.025) << "the control: without the contact the beam passes the drape";
    const v1::Frame f = latest_frame(c, held_id);
    ASSERT_EQ(f.bodies(0).positions_size(), 12);
    EXPECT_FLOAT_EQ(f.bodies(0).positions(1), -0.02f);  // the pinned corners stay
  }
}

namespace {

// A pool of water (5 mm spacing, 4 cm deep) on a 6 x 6 cm slab of soft tissue (E 100 kPa, 2 cm
// thick, fixed at its bottom, XPBD 64 x 1) in a container over the slab's top; or, for
// `floor`, the same pool on the container's floor at the slab's top height (the slab out of
// the way below). The walls and the slab's surface count as fluid at rest beyond them (the
// defaults), so the two pools are alike.
v1::CreateSceneRequest pool_request(const std::string& id, int fluid_substeps, bool floor) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  const double drop = floor ? -0.5 : 0.0;
  const TetMesh slab = make_beam(7, 3, 7, 0.01);
  auto* d = s->mutable_mesh()->mutable_data();
  for (const Vec3& p : slab.vertices)
    for (double v : {p.x(), p.y() + drop, p.z()}) d->add_positions(v);
  for (const auto& t : slab.tets)
    for (int32_t v : t) d->add_tets(v);
  auto* fixed = s->mutable_fixed()->add_boxes();
  set(fixed->mutable_min(), -1, -1, -1);
  set(fixed->mutable_max(), 1, drop + 0.001, 1);
  s->mutable_material()->set_young_modulus(1e5);
  s->mutable_solver()->set_method(v1::METHOD_XPBD);
  s->mutable_solver()->set_substeps(64);
  s->mutable_solver()->set_iterations(1);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  auto* b = s->add_bodies();
  b->set_name("water");
  auto* f = b->mutable_fluid();
  f->set_spacing(0.005);
  f->set_substeps(fluid_substeps);
  auto* blk = f->add_blocks();
  set(blk->mutable_min(), 0.0025, 0.0225, 0.0025);
  set(blk->mutable_max(), 0.0575, 0.0625, 0.0575);
  // Up to 12 cm; down to the slab's bottom, or to the floor at the slab's top (2 cm).
  if (floor) set_container(f, 0.03, 0.07, 0.03, 0.03, 0.05, 0.03);
  else set_container(f, 0.03, 0.06, 0.03, 0.03, 0.06, 0.03);
  return r;
}

}  // namespace

TEST(Bodies, APoolOnASoftSlabSettlesNearItsDepthOnAFloor) {
  // The water and the slab step together in parts (the fluid's substeps, a factor of the slab's
  // 64), the water meeting the slab's surface inside its density iterations as it meets the
  // floor, the surface counted as fluid beyond it as the floor is. The pool settles on the soft
  // slab at the depth it has on the floor and rests as still: 1.00 of the depth at 0.0105 m/s
  // RMS (0.0104 on the floor) with the default 2 fluid substeps, 0.99 at 0.016 (0.019) with 8.
  // With the contact after each part instead (and no wall counted), the bottom layer was pressed
  // into the next one: 0.87 and 0.08 m/s (0.005 on the floor) with 2; with it once per tick,
  // after the water's whole step, 0.72 and 0.21 m/s, and boiling at 0.56 m/s, 1.7 times as deep,
  // with 8.
  BodiesServer srv;
  Client c = srv.client();
  struct Pool {
    double depth = 0;      // the particles' mean height over the slab's top (2 cm), last 0.5 s of 1.5
    double rms_speed = 0;  // from the moves between ticks over the last 0.5 s
  };
  int particles = 0;
  auto run = [&](const std::string& id, int substeps, bool floor) {
    Pool out;
    EXPECT_TRUE(c.create_scene(pool_request(id, substeps, floor)).ok()) << id;
    std::vector<float> prev;
    double sq = 0;
    int samples = 0;
    for (int k = 0; k < 90; ++k) {
      EXPECT_TRUE(c.step(id, 1).ok());
      const v1::Frame f = latest_frame(c, id);
      if (f.bodies_size() != 1) {
        ADD_FAILURE() << "a frame without the water";
        return out;
      }
      const auto& p = f.bodies(0).positions();
      particles = p.size() / 3;
      // The water in parts with the slab (its substeps, a factor of the slab's 64), touching or not.
      EXPECT_EQ(f.solver().bodies(0).step_parts(), uint32_t(substeps));
      if (k >= 60) {
        for (int i = 0; i < p.size(); ++i) sq += std::pow((p[i] - prev[i]) * 60.0, 2);
        for (int i = 0; i < p.size() / 3; ++i) out.depth += p[3 * i + 1] - 0.02;
        samples += p.size() / 3;
      }
      prev.assign(p.begin(), p.end());
    }
    out.depth /= samples;
    out.rms_speed = std::sqrt(sq / samples);
    return out;
  };
  for (int substeps : {2, 8}) {
    SCOPED_TRACE(std::to_string(substeps) + " fluid substeps");
    const std::string n = std::to_string(substeps);
    const Pool slab = run("slab" + n, substeps, false), floor = run("floor" + n, substeps, true);
    std::cout << "[ pool ] " << particles << " particles, " << substeps << " fluid substeps: " << slab.depth << " m deep on the slab, " << floor.depth
              << " on the floor; " << slab.rms_speed << " m/s RMS on the slab, " << floor.rms_speed << " on the floor\n";
    const std::string depths = std::to_string(slab.depth) + " m on the slab, " + std::to_string(floor.depth) + " on the floor";
    EXPECT_NEAR(slab.depth / floor.depth, 1.0, 0.04) << depths;
    EXPECT_LT(slab.rms_speed, 3 * floor.rms_speed + 0.002) << "on the floor: " << floor.rms_speed << " m/s";
  }
}

