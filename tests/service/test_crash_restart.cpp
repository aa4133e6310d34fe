// SPDX-License-Identifier: Apache-2.0
// Crash safety with the real pliant-server on 127.0.0.1: periodic checkpoints survive kill -9
// under load (every scene comes back, every file loads), created and deleted scenes reach the
// data directory at once, SIGTERM ends a server whose scene has a minutes-long tick, and a
// failed save at shutdown exits non-zero. Every wait is bounded.
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/server/registry.hpp"
#include "server_process.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace pliant;
using client::Client;

namespace {

using test::read_text;
using test::ServerProcess;

fs::path fresh_dir(const std::string& name) {
  fs::path p = fs::temp_directory_path() / ("pliant_crash_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  fs::create_directories(p);
  return p;
}

// Every file in <data>/scenes/ parses and passes the server's own snapshot checks; their ids.
std::set<std::string> loadable_scene_files(const fs::path& data) {
  std::set<std::string> ids;
  for (const auto& f : fs::directory_iterator(data / "scenes")) {
    if (f.path().extension() != ".snapshot") continue;
    v1::Snapshot proto;
    EXPECT_TRUE(proto.ParseFromString(read_text(f.path()))) << f.path();
    server::SceneSnapshot snap;
    server::Error e = server::snapshot_from_proto(proto, 1, 2'000'000, &snap);
    EXPECT_TRUE(e.ok()) << f.path() << ": " << e.message;
    ids.insert(proto.scene_id());
  }
  return ids;
}

// The tick stored in a scene's checkpoint file, or -1 while it cannot be read.
int64_t stored_tick(const fs::path& data, const std::string& id) {
  v1::Snapshot proto;
  if (!proto.ParseFromString(read_text(data / "scenes" / (id + ".snapshot")))) return -1;
  return static_cast<int64_t>(proto.tick());
}

}  // namespace

TEST(CrashRestart, CreatedAndDeletedScenesReachTheDataDirectoryAtOnce) {
  const fs::path dir = fresh_dir("promptly");
  // A temporary file left by a crash mid-write is removed on start.
  fs::create_directories(dir / "data" / "scenes");
  std::ofstream(dir / "data" / "scenes" / "old.snapshot.tmp.123.0") << "torn";
  ServerProcess s(dir / "data", dir / "server.log", {"--checkpoint-ms", "60000"});
  ASSERT_GT(s.port(), 0) << s.log();
  EXPECT_FALSE(fs::exists(dir / "data" / "scenes" / "old.snapshot.tmp.123.0"));
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(test::beam1_request("made", v1::TICK_MODE_LOCKSTEP)).ok());
  // Written on creation, not after the (one-minute) interval.
  int64_t tick = -1;
  for (int i = 0; i < 1000 && tick < 0; ++i) {
    tick = stored_tick(dir / "data", "made");
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_EQ(tick, 0);
  ASSERT_TRUE(c.delete_scene("made").ok());
  EXPECT_FALSE(fs::exists(dir / "data" / "scenes" / "made.snapshot"));
  EXPECT_EQ(s.terminate(std::chrono::seconds(30)), 0) << s.log();
  fs::remove_all(dir);
}

TEST(CrashRestart, KillNineUnderLoadLosesAtMostOneCheckpoint) {
  const fs::path dir = fresh_dir("kill9");
  const fs::path data = dir / "data";
  const std::set<std::string> ids = {"rt1", "rt2", "ls"};
  std::mt19937 rng(12345);
  uint64_t stepped_to = 0;
  for (int round = 0; round < 4; ++round) {
    ServerProcess s(data, dir / ("server" + std::to_string(round) + ".log"), {"--checkpoint-ms", "200"});
    ASSERT_GT(s.port(), 0) << s.log();
    Client c = s.client();
    if (round == 0) {
      ASSERT_TRUE(c.create_scene(test::beam1_request("rt1", v1::TICK_MODE_REALTIME)).ok());
      ASSERT_TRUE(c.create_scene(test::beam1_request("rt2", v1::TICK_MODE_AS_FAST_AS_POSSIBLE)).ok());
      ASSERT_TRUE(c.create_scene(test::beam1_request("ls", v1::TICK_MODE_LOCKSTEP)).ok());
    }
    // Every scene came back, the lockstep one exactly where its last checkpoint had it.
    auto listed = c.list_scenes();
    ASSERT_TRUE(listed.ok()) << listed.status.to_string();
    std::set<std::string> back;
    for (const auto& sc : *listed) back.insert(sc.scene_id());
    EXPECT_EQ(back, ids) << "round " << round;
    auto ls = c.get_scene("ls");
    ASSERT_TRUE(ls.ok());
    EXPECT_EQ(ls->tick(), stepped_to) << "round " << round;

    // Load: lockstep steps, grabs and snapshots from another thread while the others tick.
    std::atomic<bool> stop{false};
    std::thread load([&] {
      Client lc = s.client();
      for (int i = 0; i < 100000 && !stop; ++i) {
        lc.step("ls", 1);
        v1::GrabRequest g;
        g.set_scene_id("rt1");
        g.set_vertex(i % 50);
        if (auto r = lc.grab(g); r.ok()) lc.release("rt1", r->grab_id());
        v1::SaveSnapshotRequest snap;
        snap.set_scene_id("rt2");
        lc.save_snapshot(snap);
      }
    });
    std::this_thread::sleep_for(std::chrono::milliseconds(std::uniform_int_distribution<int>(300, 900)(rng)));
    stop = true;
    load.join();
    // The lockstep scene is idle now: its state reaches the disk within a checkpoint.
    auto now = c.get_scene("ls");
    ASSERT_TRUE(now.ok());
    stepped_to = now->tick();
    int64_t on_disk = -1;
    for (int i = 0; i < 1000 && on_disk != static_cast<int64_t>(stepped_to); ++i) {
      on_disk = stored_tick(data, "ls");
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    EXPECT_EQ(on_disk, static_cast<int64_t>(stepped_to));
    // The others keep ticking while the process dies at a random moment.
    std::this_thread::sleep_for(std::chrono::milliseconds(std::uniform_int_distribution<int>(0, 400)(rng)));
    s.kill_now();
    EXPECT_EQ(loadable_scene_files(data), ids) << "round " << round;
  }
  fs::remove_all(dir);
}

TEST(CrashRestart, SigtermEndsAServerWithAMinutesLongTick) {
  const fs::path dir = fresh_dir("sigterm");
  ServerProcess s(dir / "data", dir / "server.log", {"--max-tick-ms", "0", "--stuck-tick-ms", "0"});
  ASSERT_GT(s.port(), 0) << s.log();
  Client c = s.client();
  // A 2,875-tet beam at the sweep limit: minutes per tick.
  v1::CreateSceneRequest r;
  r.set_scene_id("slow");
  const TetMesh mesh = make_beam(24, 6, 6, 0.01);
  auto* d = r.mutable_spec()->mutable_mesh()->mutable_data();
  for (const Vec3& p : mesh.vertices)
    for (int k = 0; k < 3; ++k) d->add_positions(p[k]);
  for (const auto& t : mesh.tets)
    for (int k = 0; k < 4; ++k) d->add_tets(t[k]);
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_solver()->set_substeps(2000);
  r.mutable_spec()->mutable_solver()->set_iterations(100);
  ASSERT_TRUE(c.create_scene(r).ok());
  std::this_thread::sleep_for(std::chrono::milliseconds(500));  // into its first tick
  EXPECT_EQ(s.terminate(std::chrono::seconds(30)), 0) << s.log();
  EXPECT_EQ(stored_tick(dir / "data", "slow"), 0);
  fs::remove_all(dir);
}

TEST(CrashRestart, AFailedSaveAtShutdownExitsNonZero) {
  const fs::path dir = fresh_dir("failsave");
  fs::create_directories(dir / "data");
  std::ofstream(dir / "data" / "scenes") << "a file where the scenes directory should be\n";
  ServerProcess s(dir / "data", dir / "server.log");
  ASSERT_GT(s.port(), 0) << s.log();
  Client c = s.client();
  ASSERT_TRUE(c.create_scene(test::beam1_request("doomed", v1::TICK_MODE_LOCKSTEP)).ok());
  EXPECT_EQ(s.terminate(std::chrono::seconds(30)), 1) << s.log();
  EXPECT_NE(s.log().find("shutdown snapshot failed"), std::string::npos) << s.log();
  fs::remove_all(dir);
}
