// SPDX-License-Identifier: Apache-2.0
// Static colliders in a scene's spec: a body dropped on a plane or a box comes to rest on it,
// GetScene and snapshots carry the colliders, and bad values are refused with the field named.
#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <functional>
#include <cmath>

using namespace pliant;
using client::Client;

namespace {

using namespace test::grpc_codes;

// Colliders make ticks slower: clients wait up to 60 s.
struct ColliderServer : test::InProcessServer {
  ColliderServer() : InProcessServer({}, {std::chrono::seconds(60)}) {}
};

void set(v1::Vec3* v, double x, double y, double z) {
  v->set_x(x);
  v->set_y(y);
  v->set_z(z);
}

// beam1, nothing fixed, lockstep, gravity -y.
v1::CreateSceneRequest free_beam(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  s->mutable_solver()->set_method(v1::METHOD_XPBD);
  s->mutable_solver()->set_substeps(16);
  s->mutable_solver()->set_iterations(2);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  s->mutable_tick()->set_dt(1.0 / 60);
  return r;
}

struct Extent {
  double min_y, max_y;
};

Extent rest_extent(Client& c, const std::string& id) {
  auto topo = c.topology(id);
  EXPECT_TRUE(topo.ok()) << topo.status.to_string();
  Extent e{1e300, -1e300};
  for (int i = 1; i < topo->rest_positions_size(); i += 3) {
    e.min_y = std::min<double>(e.min_y, topo->rest_positions(i));
    e.max_y = std::max<double>(e.max_y, topo->rest_positions(i));
  }
  return e;
}

// Steps the scene and returns (lowest y, fastest speed) at the end, from a snapshot.
std::pair<double, double> drop(Client& c, const std::string& id, uint32_t ticks) {
  auto st = c.step(id, ticks);
  EXPECT_TRUE(st.ok()) << st.status.to_string();
  v1::SaveSnapshotRequest req;
  req.set_scene_id(id);
  auto snap = c.save_snapshot(req);
  EXPECT_TRUE(snap.ok()) << snap.status.to_string();
  double min_y = 1e300, speed = 0;
  const auto& x = snap->snapshot().x();
  const auto& v = snap->snapshot().v();
  for (int i = 0; i + 2 < x.size(); i += 3) {
    min_y = std::min(min_y, x[i + 1]);
    speed = std::max(speed, std::sqrt(v[i] * v[i] + v[i + 1] * v[i + 1] + v[i + 2] * v[i + 2]));
  }
  return {min_y, speed};
}

TEST(Colliders, BodyDroppedOnAPlaneComesToRestOnIt) {
  ColliderServer srv;
  Client c = srv.client();
  auto probe = free_beam("probe");
  ASSERT_TRUE(c.create_scene(probe).ok());
  const Extent e = rest_extent(c, "probe");
  const double floor_y = e.min_y - 0.02;  // 2 cm below the body

  auto req = free_beam("plane");
  auto* col = req.mutable_spec()->add_colliders();
  set(col->mutable_plane()->mutable_point(), 0, floor_y, 0);
  set(col->mutable_plane()->mutable_normal(), 0, 2, 0);  // not unit: the server normalises it
  auto created = c.create_scene(req);
  ASSERT_TRUE(created.ok()) << created.status.to_string();
  const auto [min_y, speed] = drop(c, "plane", 120);  // 2 s: the fall takes ~0.064 s
  EXPECT_GE(min_y, floor_y - 1e-3) << "the body went through the plane";
  EXPECT_LE(min_y, floor_y + 2e-3) << "the body did not reach the plane";
  EXPECT_LT(speed, 0.05) << "the body is not at rest on the plane";

  // Without the plane the same body falls far below it in the same time.
  auto free_fall = drop(c, "probe", 120);
  EXPECT_LT(free_fall.first, floor_y - 1.0);
}

TEST(Colliders, BodyDroppedOnABoxComesToRestOnItsTop) {
  ColliderServer srv;
  Client c = srv.client();
  auto probe = free_beam("probe");
  ASSERT_TRUE(c.create_scene(probe).ok());
  const Extent e = rest_extent(c, "probe");
  const double top = e.min_y - 0.02;
  auto req = free_beam("box");
  auto* col = req.mutable_spec()->add_colliders();
  set(col->mutable_box()->mutable_center(), 0, top - 0.5, 0);
  set(col->mutable_box()->mutable_half_extent(), 2, 0.5, 2);
  col->set_static_friction(0.8);
  col->set_dynamic_friction(0.6);
  ASSERT_TRUE(c.create_scene(req).ok());
  const auto [min_y, speed] = drop(c, "box", 120);
  EXPECT_GE(min_y, top - 1e-3) << "the body went into the box";
  EXPECT_LE(min_y, top + 2e-3) << "the body did not reach the box";
  EXPECT_LT(speed, 0.05);
}

TEST(Colliders, GetSceneAndSnapshotsCarryTheColliders) {
  ColliderServer srv;
  Client c = srv.client();
  auto req = free_beam("s");
  auto* sphere = req.mutable_spec()->add_colliders();
  set(sphere->mutable_sphere()->mutable_center(), 0.1, -1, 0);
  sphere->mutable_sphere()->set_radius(0.25);
  sphere->set_static_friction(0.3);  // dynamic unset: the default 0.4 capped at 0.3
  auto* plane = req.mutable_spec()->add_colliders();
  set(plane->mutable_plane()->mutable_point(), 0, -2, 0);
  set(plane->mutable_plane()->mutable_normal(), 0, 0, 3);
  ASSERT_TRUE(c.create_scene(req).ok());
  auto got = c.get_scene("s");
  ASSERT_TRUE(got.ok());
  ASSERT_EQ(got->spec().colliders_size(), 2);
  const auto& s0 = got->spec().colliders(0);
  ASSERT_TRUE(s0.has_sphere());
  EXPECT_DOUBLE_EQ(s0.sphere().radius(), 0.25);
  EXPECT_DOUBLE_EQ(s0.sphere().center().y(), -1);
  EXPECT_DOUBLE_EQ(s0.static_friction(), 0.3);
  EXPECT_DOUBLE_EQ(s0.dynamic_friction(), 0.3);
  const auto& p1 = got->spec().colliders(1);
  ASSERT_TRUE(p1.has_plane());
  EXPECT_DOUBLE_EQ(p1.plane().normal().z(), 1.0);
  EXPECT_DOUBLE_EQ(p1.static_friction(), 0.5);
  EXPECT_DOUBLE_EQ(p1.dynamic_friction(), 0.4);

  v1::SaveSnapshotRequest save;
  save.set_scene_id("s");
  auto snap = c.save_snapshot(save);
  ASSERT_TRUE(snap.ok());
  ASSERT_EQ(snap->snapshot().spec().colliders_size(), 2);
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = snap->snapshot();
  restore.set_scene_id("copy");
  auto copy = c.restore_snapshot(restore);
  ASSERT_TRUE(copy.ok()) << copy.status.to_string();
  ASSERT_EQ(copy->spec().colliders_size(), 2);
  EXPECT_EQ(copy->spec().colliders(0).SerializeAsString(), s0.SerializeAsString());
  EXPECT_EQ(copy->spec().colliders(1).SerializeAsString(), p1.SerializeAsString());
}

TEST(Colliders, BadValuesAreRefusedNamingFieldAndValue) {
  ColliderServer srv;
  Client c = srv.client();
  struct Case {
    std::function<void(v1::Collider*)> make;
    std::string field, value;
  };
  const std::vector<Case> cases = {
      {[](v1::Collider* k) { set(k->mutable_plane()->mutable_normal(), 0, 0, 0); },
       "spec.colliders[0].plane.normal", "(0, 0, 0)"},
      {[](v1::Collider* k) {
         set(k->mutable_plane()->mutable_point(), 0, NAN, 0);
         set(k->mutable_plane()->mutable_normal(), 0, 1, 0);
       },
       "spec.colliders[0].plane.point", "nan"},
      {[](v1::Collider* k) { k->mutable_sphere()->set_radius(-1); }, "spec.colliders[0].sphere.radius", "-1"},
      {[](v1::Collider* k) { set(k->mutable_box()->mutable_half_extent(), 1, 0, 1); },
       "spec.colliders[0].box.half_extent", "(1, 0, 1)"},
      {[](v1::Collider* k) {
         k->mutable_sphere()->set_radius(1);
         k->set_static_friction(-0.5);
       },
       "spec.colliders[0].static_friction", "-0.5"},
      {[](v1::Collider* k) {
         k->mutable_sphere()->set_radius(1);
         k->set_static_friction(0.2);
         k->set_dynamic_friction(0.7);
       },
       "spec.colliders[0].dynamic_friction", "0.7"},
      {[](v1::Collider* k) { k->set_static_friction(0.2); }, "spec.colliders[0]", "plane, sphere, box"},
  };
  for (const Case& cs : cases) {
    auto req = free_beam("bad");
    cs.make(req.mutable_spec()->add_colliders());
    auto r = c.create_scene(req);
    ASSERT_FALSE(r.ok()) << cs.field;
    EXPECT_EQ(r.status.code, kInvalidArgument) << r.status.to_string();
    EXPECT_NE(r.status.message.find(cs.field), std::string::npos) << r.status.message;
    EXPECT_NE(r.status.message.find(cs.value), std::string::npos) << r.status.message;
  }
}

}  // namespace
