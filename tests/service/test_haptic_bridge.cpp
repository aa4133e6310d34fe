// SPDX-License-Identifier: Apache-2.0
// The haptic bridge: the force renderer's safety limits and extrapolation (no server), and the
// bridge against an in-process server: it feels the beam, cuts the force to zero within one
// loop period when the server goes away, and reconnects when it comes back. Waits are
// "eventually" bounds, never timing assertions.
#include "pliant/client/haptic.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/wait_until.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>


using namespace pliant;
using namespace pliant::haptic;

namespace {

ServerForce at(uint64_t tick, const Vec3& force, const Vec3& pose) {
  ServerForce s;
  s.valid = true;
  s.tick = tick;
  s.force = force;
  s.pose = pose;
  s.received = Clock::now();
  return s;
}

}  // namespace

TEST(ForceRenderer, ClampsMagnitudeAndRateAndCutsAtOnceWhenLost) {
  SafetyLimits lim;
  lim.max_force = 3;
  lim.max_force_rate = 1000;  // 1 N per 1 ms period
  ForceRenderer r(lim);
  const Vec3 p(0, 0, 0);
  Vec3 f = r.update(p, at(1, Vec3(0, 10, 0), p), false, 1e-3);
  EXPECT_NEAR(f.y(), 1.0, 1e-12);  // rate limited from 0
  for (int i = 0; i < 10; ++i) f = r.update(p, at(1, Vec3(0, 10, 0), p), false, 1e-3);
  EXPECT_NEAR(f.norm(), 3.0, 1e-12);  // clamped
  f = r.update(p, at(1, Vec3(0, 10, 0), p), true, 1e-3);
  EXPECT_EQ(f, Vec3::Zero());  // lost: zero in this very period
}

TEST(ForceRenderer, ExtrapolatesWithTheLearnedStiffnessBetweenUpdates) {
  SafetyLimits lim;
  lim.max_force_rate = 1e9;
  ForceRenderer r(lim);
  // Stiffness 1000 N/m along +y.
  // Updates alternate between 1 N at y = 0 and 2 N at y = -1 mm.
  for (int i = 0; i < 40; ++i) {
    const double y = i % 2 ? -0.001 : 0.0;
    r.update(Vec3(0, y, 0), at(1 + i, Vec3(0, i % 2 ? 2 : 1, 0), Vec3(0, y, 0)), false, 1e-3);
  }
  EXPECT_GT(r.stiffness(), 500);
  EXPECT_LT(r.stiffness(), 1001);
  // No new update while the handle goes 0.5 mm deeper: the force follows the handle.
  const ServerForce last = at(1000, Vec3(0, 2, 0), Vec3(0, -0.001, 0));
  const Vec3 f0 = r.update(Vec3(0, -0.001, 0), last, false, 1e-3);
  const Vec3 f1 = r.update(Vec3(0, -0.0015, 0), last, false, 1e-3);
  EXPECT_NEAR(f0.y(), 2.0, 1e-9);
  EXPECT_NEAR(f1.y() - f0.y(), 0.0005 * r.stiffness(), 1e-9);
  // Pulled out past the surface: never a pulling force.
  const Vec3 f2 = r.update(Vec3(0, 0.01, 0), last, false, 1e-3);
  EXPECT_GE(f2.y(), 0);
}

TEST(ForceRenderer, ExtrapolatesOverAtMostTheWindowOfAnOldPose) {
  SafetyLimits lim;
  lim.max_force_rate = 1e9;
  lim.max_force = 1e3;
  lim.extrapolate_ms = 10;
  ForceRenderer r(lim);
  for (int i = 0; i < 40; ++i) {  // learn 1000 N/m along +y, as above
    const double y = i % 2 ? -0.001 : 0.0;
    r.update(Vec3(0, y, 0), at(1 + i, Vec3(0, i % 2 ? 2 : 1, 0), Vec3(0, y, 0)), false, 1e-3);
  }
  const double k = r.stiffness();
  ASSERT_GT(k, 500);
  // The handle is 4 mm deeper than the pose the server's last answer used.
  const Vec3 handle(0, -0.005, 0);
  const Clock::time_point now = Clock::now();
  ServerForce last = at(1000, Vec3(0, 2, 0), Vec3(0, -0.001, 0));
  // A pose 5 ms old is within the window: the whole distance.
  last.pose_time = now - std::chrono::milliseconds(5);
  EXPECT_NEAR(r.update(handle, last, false, 1e-3, now).y(), 2 + 0.004 * k, 1e-9);
  // 40 ms old (a server that fell behind): a quarter of it, the last 10 ms of steady motion.
  last.pose_time = now - std::chrono::milliseconds(40);
  EXPECT_NEAR(r.update(handle, last, false, 1e-3, now).y(), 2 + 0.001 * k, 1e-9);
  // No extrapolation asked for: the server's force as it is.
  lim.extrapolate_ms = 0;
  ForceRenderer plain(lim);
  EXPECT_NEAR(plain.update(handle, last, false, 1e-3, now).y(), 2.0, 1e-12);
}

TEST(SimulatedDevice, PressesBelowTheSurfaceAndComesBack) {
  SimulatedDevice::Params p;
  p.ramp_s = 0.5;
  p.period_s = 2;
  SimulatedDevice d(p);
  EXPECT_NEAR(d.position(0).y(), p.start.y(), 1e-12);
  EXPECT_NEAR(d.position(1.0).y() - p.radius, p.surface_y - p.depth, 1e-12);  // tool bottom at depth
  EXPECT_NEAR(d.position(2.0 - 1e-9).y(), p.start.y(), 1e-6);
}

TEST(HapticBridge, FeelsTheBeamCutsToZeroWhenTheServerGoesAndReconnects) {
  auto srv = std::make_unique<test::InProcessServer>();
  ASSERT_TRUE(srv->started.ok());
  const int port = srv->port();

  SimulatedDevice::Params dp;
  dp.ramp_s = 0.2;
  dp.period_s = 1e6;  // press and hold
  auto device = std::make_shared<SimulatedDevice>(dp);
  BridgeOptions bo;
  bo.connect.address = "127.0.0.1:" + std::to_string(port);
  bo.connect.timeout = std::chrono::seconds(5);
  bo.scene_id = "bridge";
  bo.create_builtin = "beam1";
  bo.create_tick_hz = 500;  // two busy 1 kHz threads on a shared 2-core machine would be unfair to the rest
  bo.reconnect_delay = std::chrono::milliseconds(50);
  HapticBridge bridge(bo, device);
  bridge.start();

  ASSERT_TRUE(test::wait_until([&] { return device->last_force().y() > 0.005; }, std::chrono::seconds(30),
                               "the device to feel the beam (force above 5 mN)"))
      << bridge.stats().to_json();
  const BridgeStats pressed = bridge.stats();
  EXPECT_GT(pressed.feedback, 0u);
  EXPECT_GT(pressed.max_force_n, 0.005);

  // The server goes away: the force is zero from the loop period after the loss on.
  srv->server->shutdown();
  srv.reset();
  ASSERT_TRUE(test::wait_until([&] { return !bridge.connected(); }, std::chrono::seconds(10),
                               "the bridge to notice the server is gone"));
  ASSERT_TRUE(test::wait_until([&] { return bridge.zero_rendered_at_loop() >= bridge.loss_flagged_at_loop(); },
                               std::chrono::seconds(5), "a zero force rendered after the loss"));
  EXPECT_LE(bridge.zero_rendered_at_loop() - bridge.loss_flagged_at_loop(), 1u);
  // And it stays zero: 50 device loop periods later the device still feels nothing.
  const uint64_t loops = bridge.stats().loops;
  ASSERT_TRUE(test::wait_until([&] { return bridge.stats().loops >= loops + 50; }, test::kPatience,
                               "50 more device loop periods"));
  EXPECT_EQ(device->last_force(), Vec3::Zero());

  // It comes back on the same port (a fresh server: the bridge creates the scene again).
  srv = std::make_unique<test::InProcessServer>(server::ServerOptions{}, test::ClientSettings{}, port);
  ASSERT_TRUE(srv->started.ok());
  ASSERT_TRUE(test::wait_until([&] { return bridge.connected() && device->last_force().y() > 0.005; },
                               std::chrono::seconds(30), "the bridge to reconnect and feel the beam again"))
      << bridge.stats().to_json();
  EXPECT_GE(bridge.stats().reconnects, 1u);
  bridge.stop();
  srv->server->shutdown();
}
