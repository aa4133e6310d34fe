// SPDX-License-Identifier: Apache-2.0
// Soak: the real pliant-server under a bounded mixed load on loopback. Several client threads
// create, delete, step, stream, grab and snapshot their own scenes; the server is killed (-9)
// part way and restarted from its data directory (checkpoints), and terminated (SIGTERM) and
// restarted at the end. Nothing is lost: every scene created and not deleted comes back with a
// sane tick. The server's resident memory stays flat over the second run (after warm-up vs at
// the end). PLIANT_SOAK_SECONDS sets the load's length (default 60).
#include "pliant/client/client.hpp"
#include "server_process.hpp"

#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <iostream>
#include <map>
#include <mutex>
#include <random>
#include <set>

using namespace pliant;
using client::Client;
using test::ServerProcess;
namespace fs = std::filesystem;

namespace {

// Resident set size of a process in KiB (VmRSS), or -1.
long rss_kib(pid_t pid) {
  std::ifstream f("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(f, line);)
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

double soak_seconds() {
  const char* env = std::getenv("PLIANT_SOAK_SECONDS");
  if (!env || !*env) return 60;
  char* end = nullptr;
  const double s = std::strtod(env, &end);
  if (end == env || *end != '\0' || !(s >= 5)) {
    ADD_FAILURE() << "PLIANT_SOAK_SECONDS must be a number of seconds >= 5, got '" << env << "'";
    return 60;
  }
  return s;
}

v1::CreateSceneRequest scene_request(const std::string& id, v1::TickMode mode) {
  v1::CreateSceneRequest r = test::beam1_request(id, mode);
  if (mode == v1::TICK_MODE_REALTIME) r.mutable_spec()->mutable_tick()->set_dt(1.0 / 30);
  return r;
}

// What the load left behind: each worker's live scenes and the tick each lockstep one reached
// (-1 for realtime scenes, which tick on their own).
struct Ledger {
  std::mutex mu;
  std::map<std::string, int64_t> live;
  std::atomic<uint64_t> ops{0}, failures{0};
  std::vector<std::string> failure_examples;

  void fail(const std::string& what) {
    ++failures;
    std::lock_guard lk(mu);
    if (failure_examples.size() < 10) failure_examples.push_back(what);
  }
};

// One worker: its own scenes (prefix w<i>-), so what it created and did not delete is exact.
void worker(int index, const ServerProcess& server, std::chrono::steady_clock::time_point until, Ledger& ledger,
            int generation) {
  Client c = server.client();
  std::mt19937 rng(1000 * generation + index);
  std::vector<std::string> mine;
  // The worker's prefix, built without `"literal" + std::string` (GCC 12's -Wrestrict false positive).
  std::string tag = std::to_string(index);
  tag.insert(0, "w");
  {
    std::lock_guard lk(ledger.mu);
    for (auto& [id, t] : ledger.live)
      if (id.rfind(tag + "-", 0) == 0) mine.push_back(id);
  }
  int serial = 0;
  uint32_t vertices = 2;
  if (auto probe = c.create_scene(scene_request(tag + "-probe" + std::to_string(generation),
                                               v1::TICK_MODE_LOCKSTEP));
      probe.ok()) {
    vertices = probe->vertex_count();
    c.delete_scene(probe->scene_id());
  } else {
    ledger.fail("create probe: " + probe.status.to_string());
  }
  auto pick = [&]() -> std::string { return mine[std::uniform_int_distribution<size_t>(0, mine.size() - 1)(rng)]; };
  auto is_lockstep = [&](const std::string& id) {
    std::lock_guard lk(ledger.mu);
    return ledger.live.at(id) >= 0;
  };
  while (std::chrono::steady_clock::now() < until) {
    ++ledger.ops;
    const int op = std::uniform_int_distribution<int>(0, 9)(rng);
    if (mine.empty() || (op == 0 && mine.size() < 4)) {
      // Create: mostly lockstep; one realtime scene per worker at most (CPU is shared).
      bool realtime = std::none_of(mine.begin(), mine.end(), [&](const std::string& id) { return !is_lockstep(id); }) &&
                      std::uniform_int_distribution<int>(0, 3)(rng) == 0;
      const std::string id =
          tag + "-g" + std::to_string(generation) + "-" + std::to_string(serial++);
      auto r = c.create_scene(scene_request(id, realtime ? v1::TICK_MODE_REALTIME : v1::TICK_MODE_LOCKSTEP));
      if (!r.ok()) {
        ledger.fail("create " + id + ": " + r.status.to_string());
        continue;
      }
      std::lock_guard lk(ledger.mu);
      ledger.live[id] = realtime ? -1 : 0;
      mine.push_back(id);
    } else if (op == 1 && mine.size() > 1) {
      const std::string id = pick();
      if (auto s = c.delete_scene(id); !s.ok()) {
        ledger.fail("delete " + id + ": " + s.to_string());
        continue;
      }
      std::lock_guard lk(ledger.mu);
      ledger.live.erase(id);
      mine.erase(std::find(mine.begin(), mine.end(), id));
    } else if (op <= 4) {
      const std::string id = pick();
      if (!is_lockstep(id)) continue;
      const uint32_t n = std::uniform_int_distribution<uint32_t>(1, 10)(rng);
      auto r = c.step(id, n);
      if (!r.ok()) {
        ledger.fail("step " + id + ": " + r.status.to_string());
        continue;
      }
      std::lock_guard lk(ledger.mu);
      ledger.live[id] = static_cast<int64_t>(r->tick());
    } else if (op <= 6) {
      // A stream: a few frames (stepping a lockstep scene for them), then the client leaves.
      const std::string id = pick();
      v1::StreamFramesRequest q;
      q.set_scene_id(id);
      q.set_surface_only(op == 5);
      const bool lockstep = is_lockstep(id);
      if (lockstep) {  // a frame to start from (a new lockstep scene has none until it steps)
        auto r = c.step(id, 1);
        if (!r.ok()) {
          ledger.fail("step " + id + ": " + r.status.to_string());
          continue;
        }
        std::lock_guard lk(ledger.mu);
        ledger.live[id] = static_cast<int64_t>(r->tick());
      }
      auto s = c.stream_frames(q);
      v1::Frame f;
      bool got = s->next(&f);
      if (got && lockstep) {
        auto r = c.step(id, 2);
        if (r.ok()) {
          std::lock_guard lk(ledger.mu);
          ledger.live[id] = static_cast<int64_t>(r->tick());
        }
        got = s->next(&f);
      }
      if (!got) ledger.fail("stream " + id + ": " + s->finish().to_string());
      s->cancel();
      s->finish();
    } else if (op == 7) {
      const std::string id = pick();
      v1::GrabRequest g;
      g.set_scene_id(id);
      g.set_vertex(std::uniform_int_distribution<uint32_t>(vertices / 2, vertices - 1)(rng));  // free end
      auto r = c.grab(g);
      if (!r.ok()) {
        ledger.fail("grab " + id + ": " + r.status.to_string());
        continue;
      }
      v1::MoveGrabRequest m;
      m.set_scene_id(id);
      m.set_grab_id(r->grab_id());
      m.mutable_target()->set_y(0.01);
      c.move_grab(m);
      if (auto s = c.release(id, r->grab_id()); !s.ok()) ledger.fail("release " + id + ": " + s.to_string());
    } else {
      const std::string id = pick();
      v1::SaveSnapshotRequest q;
      q.set_scene_id(id);
      if (op == 8) q.set_name("w" + std::to_string(index) + "-last");  // into the data directory
      if (auto r = c.save_snapshot(q); !r.ok()) ledger.fail("snapshot " + id + ": " + r.status.to_string());
    }
  }
}

void run_load(const ServerProcess& server, double seconds, Ledger& ledger, int generation) {
  constexpr int kWorkers = 4;
  const auto until = std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                             std::chrono::duration<double>(seconds));
  std::vector<std::thread> threads;
  for (int i = 0; i < kWorkers; ++i)
    threads.emplace_back([&, i] { worker(i, server, until, ledger, generation); });
  for (auto& t : threads) t.join();
}

// Every scene the ledger holds is on the server, none other, each with a sane tick: a lockstep
// scene at most where the load stepped it, exactly there after a clean shutdown
// (after kill -9, its last checkpoint's tick). The ledger continues from what came back.
void expect_all_back(Client& c, Ledger& ledger, bool exact, const std::string& when) {
  auto listed = c.list_scenes();
  ASSERT_TRUE(listed.ok()) << when << ": " << listed.status.to_string();
  std::set<std::string> got;
  std::lock_guard lk(ledger.mu);
  for (const auto& s : *listed) {
    got.insert(s.scene_id());
    auto it = ledger.live.find(s.scene_id());
    if (it == ledger.live.end() || it->second < 0) continue;
    if (exact) EXPECT_EQ(s.tick(), static_cast<uint64_t>(it->second)) << when << ": " << s.scene_id();
    else EXPECT_LE(s.tick(), static_cast<uint64_t>(it->second)) << when << ": " << s.scene_id();
    it->second = static_cast<int64_t>(s.tick());  // where it continues from
  }
  std::set<std::string> want;
  for (auto& [id, t] : ledger.live) want.insert(id);
  EXPECT_EQ(got, want) << when;
}

}  // namespace

TEST(Soak, MixedLoadWithRestartsLosesNothingAndKeepsMemoryFlat) {
  const double seconds = soak_seconds();
  const fs::path dir = fs::temp_directory_path() / ("pliant_soak_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path data = dir / "data";
  const std::vector<std::string> flags = {"--checkpoint-ms", "500", "--max-scenes", "64"};
  Ledger ledger;

  // Run 1 (a quarter of the time), then kill -9: scenes come back from their checkpoints.
  {
    ServerProcess s(data, dir / "server1.log", flags);
    ASSERT_GT(s.port(), 0) << s.log();
    run_load(s, seconds / 4, ledger, 1);
    // Let the last changes reach a checkpoint before the kill (created/deleted ones are at once).
    std::this_thread::sleep_for(std::chrono::milliseconds(1500));
    s.kill_now();
  }
  {
    // Run 2 (the rest): RSS after a warm-up third against RSS at the end, then SIGTERM.
    ServerProcess s(data, dir / "server2.log", flags);
    ASSERT_GT(s.port(), 0) << s.log();
    Client c = s.client();
    expect_all_back(c, ledger, false, "after kill -9");
    const double rest = seconds * 3 / 4;
    run_load(s, rest / 3, ledger, 2);
    const long warm = rss_kib(s.pid());
    run_load(s, rest * 2 / 3, ledger, 3);
    const long end = rss_kib(s.pid());
    std::cout << "[ soak ] " << seconds << " s, " << ledger.ops << " operations, " << ledger.failures
              << " failed; server RSS after warm-up " << warm / 1024 << " MiB, at the end " << end / 1024
              << " MiB\n";
    ASSERT_GT(warm, 0);
    EXPECT_LE(end, std::max(warm * 13 / 10, warm + 30 * 1024)) << "server RSS grew from " << warm << " KiB to "
                                                                << end << " KiB";
    EXPECT_EQ(s.terminate(std::chrono::seconds(60)), 0) << s.log();
  }
  {
    ServerProcess s(data, dir / "server3.log", flags);
    ASSERT_GT(s.port(), 0) << s.log();
    Client c = s.client();
    expect_all_back(c, ledger, true, "after SIGTERM");
    EXPECT_EQ(s.terminate(std::chrono::seconds(60)), 0) << s.log();
  }
  EXPECT_EQ(ledger.failures, 0u) << [&] {
    std::string all;
    for (auto& f : ledger.failure_examples) all += f + "\n";
    return all;
  }();
  EXPECT_GT(ledger.ops, 100u);
  fs::remove_all(dir);
}
