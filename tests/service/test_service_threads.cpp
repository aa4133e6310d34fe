// SPDX-License-Identifier: Apache-2.0
// The server's own threads racing, without gRPC: client calls on the scene registry from several
// threads at once (create, delete, update, pause, resume, reset, step, forces, grabs, snapshots),
// frame streams and haptic tool streams (the same FrameStream and ToolStream the gRPC service
// runs, over a transport whose writes complete on another thread, as gRPC's do), the checkpoint
// writer and the watchdog. Every synchronisation involved is Pliant's own, so ThreadSanitizer sees
// all of it: CI runs these tests under TSan (docs/service.md, "Fuzzing and sanitizers"); the gRPC
// tests cannot be checked so.
#include "pliant/server/registry.hpp"
#include "pliant/server/streams.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;
using namespace pliant;
using server::Code;
using Clock = std::chrono::steady_clock;

namespace {

// beam1, clamped at x = 0, cheap ticks, 500 of them a second when realtime (frames to skip).
v1::CreateSceneRequest beam_request(const std::string& id, v1::TickMode mode) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  s->mutable_mesh()->set_builtin("beam1");
  auto* box = s->mutable_fixed()->add_boxes();
  box->mutable_min()->set_x(-1e9);
  box->mutable_min()->set_y(-1e9);
  box->mutable_min()->set_z(-1e9);
  box->mutable_max()->set_x(1e-3);
  box->mutable_max()->set_y(1e9);
  box->mutable_max()->set_z(1e9);
  s->mutable_solver()->set_substeps(2);
  s->mutable_solver()->set_iterations(2);
  s->mutable_tick()->set_mode(mode);
  s->mutable_tick()->set_dt(0.002);
  return r;
}

// What one stream received, in order.
struct Received {
  uint64_t seq;
  uint64_t skipped;
};

// The transport side of a test stream, as gRPC's callback API behaves: one write at a time, whose
// completion (run by the caller on the `network` pump) fails once the call was cancelled; done()
// once the call has ended (never with a write in flight), on the network pump like OnDone.
template <class Stream, class Message>
class FakeTransport : public Stream {
 public:
  template <class... Args>
  explicit FakeTransport(server::StreamPump& network, Args&&... args)
      : Stream(std::forward<Args>(args)...), network_(network) {}

  std::vector<Message> received() const {
    std::lock_guard lk(t_mu_);
    return received_;
  }
  bool ended(server::Error* status = nullptr) const {
    std::lock_guard lk(t_mu_);
    if (status) *status = status_;
    return ended_;
  }
  bool is_done() const { return done_.load(); }
  // The reader goes away (gRPC: OnCancel).
  void cancel() {
    {
      std::lock_guard lk(t_mu_);
      cancelled_ = true;
    }
    this->cancelled();
  }

 protected:
  // Records `message` as written; returns the write's completion.
  std::function<void()> record_write(const Message& message) {
    std::lock_guard lk(t_mu_);
    EXPECT_FALSE(in_flight_) << "two writes in flight";
    EXPECT_FALSE(ended_) << "a write after the call ended";
    in_flight_ = true;
    received_.push_back(message);
    return [this, keep = this->shared_from_this()] {
      bool ok;
      {
        std::lock_guard lk2(t_mu_);
        in_flight_ = false;
        ok = !cancelled_;
      }
      this->write_done(ok);
    };
  }

  void end_call(const server::Error& status) override {
    {
      std::lock_guard lk(t_mu_);
      EXPECT_FALSE(ended_) << "the call ended twice";
      EXPECT_FALSE(in_flight_) << "the call ended with a write in flight";
      ended_ = true;
      status_ = status;
    }
    network_.post([this, keep = this->shared_from_this()] {
      if (!done_.exchange(true)) this->done();
    });
  }

  server::StreamPump& network_;
  mutable std::mutex t_mu_;

 private:
  bool cancelled_ = false;
  bool in_flight_ = false;
  bool ended_ = false;
  server::Error status_;
  std::vector<Message> received_;
  std::atomic<bool> done_{false};
};

// A frame stream whose writes complete after `delay`, or for a stalled reader when open_gate()
// is called.
class TestStream final : public FakeTransport<server::FrameStream, Received> {
 public:
  TestStream(server::StreamPump& pump, server::StreamPump& network, server::SceneRegistry* reg, Setup setup,
             std::chrono::milliseconds delay, bool gated)
      : FakeTransport(network, pump, [reg] { return reg && reg->shutting_down(); }, std::move(setup)),
        delay_(delay), gated_(gated) {}

  // Completes the write held back by the gate, and every later one at once.
  void open_gate() {
    std::function<void()> held;
    {
      std::lock_guard lk(t_mu_);
      gated_ = false;
      held = std::move(held_);
      held_ = nullptr;
    }
    if (held) network_.post(std::move(held));
  }

 private:
  void start_write(const server::Frame& frame, uint64_t skipped) override {
    auto complete = record_write({frame.seq, skipped});
    std::lock_guard lk(t_mu_);
    if (gated_) held_ = std::move(complete);
    else network_.post_at(Clock::now() + delay_, std::move(complete));
  }

  const std::chrono::milliseconds delay_;
  bool gated_;  // under t_mu_
  std::function<void()> held_;
};

std::shared_ptr<TestStream> open_stream(server::SceneRegistry& reg, server::StreamPump& pump,
                                        server::StreamPump& network, const std::string& id, uint64_t every,
                                        Clock::duration min_interval, std::chrono::milliseconds delay,
                                        bool gated, server::Error* error) {
  server::FrameStream::Setup setup;
  *error = reg.find(id, &setup.scene);
  if (!error->ok()) return nullptr;
  *error = reg.open_stream(id, &setup.slot);
  if (!error->ok()) return nullptr;
  setup.every = every;
  setup.min_interval = min_interval;
  auto s = std::make_shared<TestStream>(pump, network, &reg, std::move(setup), delay, gated);
  s->begin(s);
  return s;
}

// One feedback message as a haptic client would read it.
struct Feedback {
  uint64_t tick;
  uint64_t pose_seq;
  uint64_t skipped;
};

// A tool stream whose writes complete at once on the network pump.
class TestToolStream final : public FakeTransport<server::ToolStream, Feedback> {
 public:
  TestToolStream(server::StreamPump& pump, server::StreamPump& network, server::SceneRegistry& reg)
      : FakeTransport(network, pump, reg, "test") {}

 private:
  void start_write(const server::Frame& frame, uint64_t tool_id, uint64_t skipped) override {
    uint64_t pose = 0;
    for (const server::FrameTool& t : frame.tools)
      if (t.tool_id == tool_id) pose = t.pose_seq;
    network_.post(record_write({frame.tick, pose, skipped}));
  }
};

bool wait_for(const std::function<bool()>& cond, std::chrono::seconds limit = std::chrono::seconds(30)) {
  const auto end = Clock::now() + limit;
  while (!cond()) {
    if (Clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

// spdlog's registry is made on first use; made here, on the test's thread before any other starts
// (as pliant-server's main does), so that its construction inside the uninstrumented libspdlog
// is ordered before every thread that logs. Warnings and errors only.
void set_up_logging() { spdlog::set_level(spdlog::level::warn); }

fs::path temp_dir(const std::string& stem) {
  const fs::path d = fs::temp_directory_path() / (stem + "_" + std::to_string(::getpid()));
  fs::remove_all(d);
  return d;
}

}  // namespace

// A call waiting for the tick boundary of a scene that is deleted meanwhile answers Unavailable
// when the scene stops, not DeadlineExceeded at its own deadline.
TEST(ServiceThreads, ACallWaitingOnADeletedSceneAnswersWhenItStops) {
  set_up_logging();
  server::RegistryOptions o;
  o.max_tick_ms = 0;
  o.stuck_tick_ms = 0;
  server::SceneRegistry reg(o);
  auto req = beam_request("slow", v1::TICK_MODE_REALTIME);
  req.mutable_spec()->mutable_solver()->set_substeps(2000);  // seconds per tick: the grab waits
  req.mutable_spec()->mutable_solver()->set_iterations(100);
  req.mutable_spec()->mutable_tick()->clear_dt();
  v1::Scene out;
  ASSERT_TRUE(reg.create(req, &out).ok());
  std::shared_ptr<server::Scene> scene;
  ASSERT_TRUE(reg.find("slow", &scene).ok());
  ASSERT_TRUE(wait_for([&] { return scene->tick_running_for() > Clock::duration::zero(); }));
  v1::GrabRequest g;
  g.set_scene_id("slow");
  g.set_vertex(int32_t(out.vertex_count()) - 1);
  v1::GrabResponse gr;
  server::Error grabbed;
  std::thread caller([&] { grabbed = reg.grab(g, &gr); });
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  ASSERT_TRUE(reg.remove("slow").ok());
  caller.join();
  EXPECT_EQ(grabbed.code, Code::Unavailable) << grabbed.message;
}

// A reader that stalls gets the newest frame when it reads again, told how many it skipped;
// a deleted scene ends its streams with NotFound, a closing server with Unavailable.
TEST(ServiceThreads, AStalledStreamGetsTheNewestFrameAndWhatItSkipped) {
  set_up_logging();
  server::SceneRegistry reg({});
  v1::Scene out;
  ASSERT_TRUE(reg.create(beam_request("lock", v1::TICK_MODE_LOCKSTEP), &out).ok());
  server::StreamPump pump(2), network(1);
  server::Error e;
  auto s = open_stream(reg, pump, network, "lock", 1, {}, std::chrono::milliseconds(0), true, &e);
  ASSERT_TRUE(s) << e.message;

  v1::StepRequest step;
  step.set_scene_id("lock");
  step.set_ticks(1);
  v1::StepResponse stepped;
  ASSERT_TRUE(reg.step(step, Clock::now() + std::chrono::seconds(30), &stepped).ok());
  ASSERT_TRUE(wait_for([&] { return s->received().size() == 1; }));  // held at the gate
  const uint64_t first = s->received()[0].seq;
  step.set_ticks(5);
  ASSERT_TRUE(reg.step(step, Clock::now() + std::chrono::seconds(30), &stepped).ok());
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(s->received().size(), 1u);  // nothing queued behind the write in flight
  s->open_gate();
  ASSERT_TRUE(wait_for([&] { return s->received().size() == 2; }));
  EXPECT_EQ(s->received()[1].seq, first + 5);
  EXPECT_EQ(s->received()[1].skipped, 4u);

  ASSERT_TRUE(reg.remove("lock").ok());
  ASSERT_TRUE(wait_for([&] { return s->is_done(); }));
  server::Error status;
  ASSERT_TRUE(s->ended(&status));
  EXPECT_EQ(status.code, Code::NotFound) << status.message;

  ASSERT_TRUE(reg.create(beam_request("rt", v1::TICK_MODE_REALTIME), &out).ok());
  auto r = open_stream(reg, pump, network, "rt", 1, {}, std::chrono::milliseconds(1), false, &e);
  ASSERT_TRUE(r) << e.message;
  ASSERT_TRUE(wait_for([&] { return r->received().size() >= 3; }));
  reg.begin_shutdown();
  ASSERT_TRUE(wait_for([&] { return r->is_done(); }));
  ASSERT_TRUE(r->ended(&status));
  EXPECT_EQ(status.code, Code::Unavailable) << status.message;
  reg.shutdown();
}

// Client calls, frame streams, tool streams, the checkpoint writer and the watchdog, all at once
// for a few seconds on four scenes (two realtime, two lockstep): every call answers ok or a
// refusal that the race explains, every frame stream gets strictly newer frames with consistent
// skip counts, tool feedback never goes back to an older pose, no tool outlives its stream, and
// after shutdown the data directory holds exactly the scenes left, each at its last tick.
TEST(ServiceThreads, ClientsStreamsAndCheckpointsRaceWithoutLosingAScene) {
  set_up_logging();
  const fs::path data = temp_dir("pliant_threads");
  server::RegistryOptions o;
  o.data_dir = data.string();
  o.checkpoint_ms = 20;
  o.max_streams_per_scene = 4;
  o.max_grabs_per_scene = 3;
  std::vector<std::string> ids = {"rt0", "rt1", "ls0", "ls1"};
  auto mode_of = [](const std::string& id) {
    return id.rfind("rt", 0) == 0 ? v1::TICK_MODE_REALTIME : v1::TICK_MODE_LOCKSTEP;
  };
  std::map<std::string, uint64_t> ticks_before;
  {
    server::SceneRegistry reg(o);
    reg.start_background();
    v1::Scene out;
    for (const auto& id : ids) ASSERT_TRUE(reg.create(beam_request(id, mode_of(id)), &out).ok());
    const int32_t free_vertex = int32_t(out.vertex_count()) - 1;  // at the beam's far end

    server::StreamPump pump(2), network(1);
    std::atomic<bool> stop{false};
    std::atomic<int> calls{0}, refusals{0}, frames{0}, streams{0};
    std::mutex failures_mu;
    std::vector<std::string> failures;
    auto fail = [&](const std::string& what) {
      std::lock_guard lk(failures_mu);
      if (failures.size() < 20) failures.push_back(what);
    };
    // Refusals a race explains: the scene is gone or not there yet, taken, in the other tick
    // mode, at a limit, or stopping under the call.
    auto check = [&](const char* call, const std::string& id, const server::Error& e) {
      ++calls;
      if (e.ok()) return;
      ++refusals;
      switch (e.code) {
        case Code::NotFound:
        case Code::AlreadyExists:
        case Code::FailedPrecondition:
        case Code::ResourceExhausted:
        case Code::Unavailable:
          return;
        default:
          fail(std::string(call) + " on " + id + ": " + e.message);
      }
    };

    auto client = [&](unsigned seed) {
      std::mt19937 rng(seed);
      std::map<std::string, std::vector<uint64_t>> grabs;
      while (!stop.load()) {
        const std::string& id = ids[rng() % ids.size()];
        v1::Scene sc;
        switch (rng() % 12) {
          case 0: check("delete", id, reg.remove(id)); break;
          case 1: check("create", id, reg.create(beam_request(id, mode_of(id)), &sc)); break;
          case 2: {
            v1::UpdateSceneRequest u;
            u.set_scene_id(id);
            u.mutable_solver()->set_iterations(1 + int(rng() % 3));
            check("update", id, reg.update(u, &sc));
            break;
          }
          case 3: check("pause", id, reg.pause(id, &sc)); break;
          case 4: check("resume", id, reg.resume(id, &sc)); break;
          case 5: check("reset", id, reg.reset(id, &sc)); break;
          case 6: {
            v1::StepRequest st;
            st.set_scene_id(id);
            st.set_ticks(1 + rng() % 3);
            v1::StepResponse sr;
            check("step", id, reg.step(st, Clock::now() + std::chrono::seconds(30), &sr));
            break;
          }
          case 7: {
            v1::ApplyForceRequest f;
            f.set_scene_id(id);
            f.add_vertices(free_vertex);
            f.mutable_force()->set_y(-0.01);
            f.set_ticks(2);
            v1::ApplyForceResponse fr;
            check("force", id, reg.apply_force(f, &fr));
            break;
          }
          case 8: {
            v1::GrabRequest g;
            g.set_scene_id(id);
            g.set_vertex(free_vertex);
            g.mutable_target()->set_x(0.1);
            v1::GrabResponse gr;
            const server::Error e = reg.grab(g, &gr);
            check("grab", id, e);
            if (e.ok()) grabs[id].push_back(gr.grab_id());
            break;
          }
          case 9: {
            auto& mine = grabs[id];
            if (mine.empty()) break;
            const uint64_t gid = mine.back();
            if (rng() % 2) {
              v1::MoveGrabRequest m;
              m.set_scene_id(id);
              m.set_grab_id(gid);
              m.mutable_target()->set_y(-0.01);
              v1::MoveGrabResponse mr;
              check("move grab", id, reg.move_grab(m, &mr));
            } else {
              v1::ReleaseRequest rl;
              rl.set_scene_id(id);
              rl.set_grab_id(gid);
              check("release", id, reg.release(rl));
              mine.pop_back();
            }
            break;
          }
          case 10: {
            v1::SaveSnapshotRequest sv;
            sv.set_scene_id(id);
            v1::SaveSnapshotResponse sr;
            const server::Error e = reg.save_snapshot(sv, &sr);
            check("save", id, e);
            if (e.ok() && rng() % 2) {
              v1::RestoreSnapshotRequest rs;
              *rs.mutable_snapshot() = sr.snapshot();
              rs.set_scene_id(id);
              rs.set_replace(true);
              check("restore", id, reg.restore_snapshot(rs, &sc));
            }
            break;
          }
          default: {
            v1::ListScenesResponse l;
            check("list", id, reg.list(&l));
            check("get", id, reg.get(id, &sc));
            break;
          }
        }
      }
    };

    auto reader = [&](unsigned seed) {
      std::mt19937 rng(seed);
      while (!stop.load()) {
        const std::string& id = ids[rng() % ids.size()];
        const uint64_t every = 1 + rng() % 2;
        const bool limited = rng() % 3 == 0;
        server::Error e;
        auto s = open_stream(reg, pump, network, id, every,
                             limited ? std::chrono::milliseconds(10) : std::chrono::milliseconds(0),
                             std::chrono::milliseconds(rng() % 4), false, &e);
        if (!s) {
          check("stream", id, e);
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
          continue;
        }
        ++streams;
        std::this_thread::sleep_for(std::chrono::milliseconds(5 + rng() % 40));
        s->cancel();
        if (!wait_for([&] { return s->is_done(); })) {
          fail("a stream on " + id + " did not end after its cancellation");
          continue;
        }
        const auto got = s->received();
        frames += int(got.size());
        for (size_t k = 1; k < got.size(); ++k) {
          // A restore or reset publishes on: seq never goes back, whatever happens to the scene.
          if (got[k].seq <= got[k - 1].seq)
            fail("stream on " + id + ": frame seq went from " + std::to_string(got[k - 1].seq) + " to " +
                 std::to_string(got[k].seq));
          if (every == 1 && !limited && got[k].skipped != got[k].seq - got[k - 1].seq - 1)
            fail("stream on " + id + ": skipped " + std::to_string(got[k].skipped) + " between seq " +
                 std::to_string(got[k - 1].seq) + " and " + std::to_string(got[k].seq));
        }
      }
    };

    // A haptic device: a tool stream (the same ToolStream the gRPC service runs) fed poses at
    // about 1 kHz, ended by the client closing its side or cancelling; its feedback must come
    // from ever later ticks with poses that never go back.
    std::atomic<int> poses{0}, feedback{0};
    auto haptic = [&](unsigned seed) {
      std::mt19937 rng(seed);
      while (!stop.load()) {
        const std::string& id = ids[rng() % ids.size()];
        auto s = std::make_shared<TestToolStream>(pump, network, reg);
        s->begin(s);
        bool reading = true;
        for (uint64_t seq = 1; seq <= 40 && reading && !stop.load(); ++seq) {
          v1::ToolPose pose;
          if (seq == 1) pose.set_scene_id(id);
          pose.set_seq(seq);
          pose.set_client_time_ns(int64_t(seq));
          pose.mutable_position()->set_x(0.05 + 1e-4 * double(seq));
          pose.set_radius(0.004);
          reading = s->pose_read(true, pose);
          if (reading) ++poses;
          std::this_thread::sleep_for(std::chrono::milliseconds(1));
        }
        if (reading) {
          if (rng() % 2) s->pose_read(false, v1::ToolPose{});  // the client closes its side
          else s->cancel();
        }
        if (!wait_for([&] { return s->is_done(); })) {
          fail("a tool stream on " + id + " did not end");
          continue;
        }
        server::Error status;
        s->ended(&status);
        if (!status.ok() && status.code != Code::Cancelled && status.code != Code::NotFound &&
            status.code != Code::ResourceExhausted && status.code != Code::Unavailable)
          fail("tool stream on " + id + " ended with: " + status.message);
        const auto got = s->received();
        feedback += int(got.size());
        for (size_t k = 1; k < got.size(); ++k) {
          if (got[k].pose_seq < got[k - 1].pose_seq)
            fail("tool stream on " + id + ": pose went from " + std::to_string(got[k - 1].pose_seq) + " to " +
                 std::to_string(got[k].pose_seq));
        }
      }
    };

    std::vector<std::thread> threads;
    for (unsigned t = 0; t < 4; ++t) threads.emplace_back(client, 17 + t);
    threads.emplace_back(haptic, 7);
    for (unsigned t = 0; t < 2; ++t) threads.emplace_back(reader, 91 + t);
    threads.emplace_back([&] {
      while (!stop.load()) {
        reg.checkpoint();
        std::this_thread::sleep_for(std::chrono::milliseconds(3));
      }
    });
    std::this_thread::sleep_for(std::chrono::seconds(3));
    stop = true;
    for (auto& t : threads) t.join();
    {
      std::lock_guard lk(failures_mu);
      for (const auto& f : failures) ADD_FAILURE() << f;
    }
    EXPECT_GT(calls.load(), 100);
    EXPECT_GT(streams.load(), 10);
    EXPECT_GT(frames.load(), 0);
    EXPECT_GT(poses.load(), 0);
    EXPECT_GT(feedback.load(), 0);
    RecordProperty("calls", calls.load());
    RecordProperty("refused", refusals.load());
    RecordProperty("streams", streams.load());
    RecordProperty("frames", frames.load());
    RecordProperty("poses", poses.load());
    RecordProperty("feedback", feedback.load());

    // Every tool stream has ended, so the next tick of every scene has no tool in it.
    v1::ListScenesResponse left;
    ASSERT_TRUE(reg.list(&left).ok());
    for (const auto& sc : left.scenes()) {
      std::shared_ptr<server::Scene> scene;
      ASSERT_TRUE(reg.find(sc.scene_id(), &scene).ok());
      const auto before = scene->latest_frame();
      if (mode_of(sc.scene_id()) == v1::TICK_MODE_LOCKSTEP) {
        v1::StepRequest st;
        st.set_scene_id(sc.scene_id());
        v1::StepResponse sr;
        ASSERT_TRUE(reg.step(st, Clock::now() + std::chrono::seconds(30), &sr).ok());
      } else if (sc.state() != v1::SCENE_STATE_RUNNING) {
        continue;
      }
      auto next = scene->wait_frame(before ? before->seq : 0, Clock::now() + std::chrono::seconds(30));
      ASSERT_TRUE(next) << sc.scene_id();
      EXPECT_TRUE(next->tools.empty()) << sc.scene_id() << ": " << next->tools.size() << " tools left";
    }

    // Nothing steps the lockstep scenes now, so their ticks are final; realtime ones run on.
    ASSERT_TRUE(reg.list(&left).ok());
    for (const auto& s : left.scenes()) ticks_before[s.scene_id()] = s.tick();
    EXPECT_EQ(reg.shutdown(), int(ticks_before.size()));
    EXPECT_EQ(reg.failed_saves(), 0);
  }

  std::set<std::string> files;
  for (const auto& f : fs::directory_iterator(data / "scenes")) files.insert(f.path().filename().string());
  std::set<std::string> expected;
  for (const auto& [id, tick] : ticks_before) expected.insert(id + ".snapshot");
  EXPECT_EQ(files, expected);

  server::SceneRegistry again(o);
  EXPECT_EQ(again.restore_from_data_dir(), int(ticks_before.size()));
  for (const auto& [id, tick] : ticks_before) {
    v1::Scene sc;
    ASSERT_TRUE(again.get(id, &sc).ok()) << id;
    if (mode_of(id) == v1::TICK_MODE_LOCKSTEP) EXPECT_EQ(sc.tick(), tick) << id;
    else EXPECT_GE(sc.tick(), tick) << id;
  }
  again.shutdown();
  fs::remove_all(data);
}
