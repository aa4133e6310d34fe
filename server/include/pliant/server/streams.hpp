// SPDX-License-Identifier: Apache-2.0
// Open streams without a thread each, and what a frame stream sends, apart from the transport
// that carries it (gRPC's callback API in service.cpp; tests drive the same code with their own).
// A scene's tick wakes a stream through a frame listener; the pump's few threads then look at the
// scene's newest frame, at most one look queued per stream and none while a write is in flight
// (the write's completion looks again). So a stream holds at most one message, and a reader that
// falls behind gets the newest frame next, told how many it skipped.
#pragma once

#include "pliant/server/error.hpp"
#include "pliant/server/registry.hpp"
#include "pliant/server/scene.hpp"

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

namespace pliant::server {

// A few threads that run the streams' work (building a message and starting its write), now or
// at a given time. Exceptions thrown by the work are logged, not propagated.
class StreamPump {
 public:
  using Clock = std::chrono::steady_clock;
  explicit StreamPump(int threads);
  ~StreamPump();  // runs what is ready, then joins (timers not yet due are dropped)
  StreamPump(const StreamPump&) = delete;
  StreamPump& operator=(const StreamPump&) = delete;

  void post(std::function<void()> fn);
  void post_at(Clock::time_point when, std::function<void()> fn);

 private:
  void run();

  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> ready_;
  std::multimap<Clock::time_point, std::function<void()>> timers_;
  bool stop_ = false;
  std::vector<std::thread> threads_;
};

// What the streams share: held alive by itself from hold() until done(), woken by the scene's
// frame listener, looks queued on the pump, at most one write in flight, and the end of the call
// (never while a write is in flight). The transport implements end_call and reports back through
// write_done, cancelled and done.
class PumpedStream : public std::enable_shared_from_this<PumpedStream> {
 public:
  using Clock = StreamPump::Clock;
  virtual ~PumpedStream() = default;

  // From the transport: the write it was asked for completed (ok false: the client is gone).
  void write_done(bool ok);
  // From the transport: the call was cancelled.
  void cancelled();
  // From the transport: the call is over (end_call done, no write in flight); may destroy this.
  void done();

 protected:
  explicit PumpedStream(StreamPump& pump) : pump_(pump) {}

  // Keeps the stream alive until done().
  void hold(std::shared_ptr<PumpedStream> self) { self_ = std::move(self); }
  // Registers the frame listener on `scene` (once, after hold()).
  void listen(const std::shared_ptr<Scene>& scene);

  // A look now, unless one is queued or a write is in flight.
  void wake();
  // A look at `when` (mu_ held; the caller checked nothing else is queued).
  void schedule_locked(Clock::time_point when);
  // Looks at the scene: starts a write of the newest message when one is due (writing_ set under
  // mu_, the write started without it), or ends the call.
  virtual void look() = 0;

  // Ends the call with `status`: end_call now, or with a write in flight when it completes (no
  // write starts after this). Only the first call counts.
  void finish(const Error& status);
  // Runs once when the call is ended, before end_call, without the lock.
  virtual void on_finish() {}
  // Ends the call with `status` (Ok: the client went away or closed it). Called once, never while
  // a write is in flight, without the lock.
  virtual void end_call(const Error& status) = 0;

  StreamPump& pump_;
  std::mutex mu_;
  bool writing_ = false;    // a write whose completion has not been reported
  bool scheduled_ = false;  // a look is queued (now or at a later time)
  bool finished_ = false;   // the call was ended (or is, once the write in flight completes)
  std::shared_ptr<void> slot_;  // the stream's place in the registry's limits, freed by done()

 private:
  std::optional<Error> due_;  // under mu_: the status to end with once the write completes
  std::shared_ptr<Scene> listened_;
  uint64_t listener_ = 0;
  std::shared_ptr<PumpedStream> self_;  // alive until done()
};

// One frame subscription: the newest frame when the reader is ready for it, every `every`-th
// published frame (keeping that phase when a late reader gets an off-phase one), at most one per
// min_interval (then whatever is newest when the interval opens), with the count of frames
// skipped since the last one sent; ends with NotFound when the scene is deleted and Unavailable
// when the server closes. The transport implements start_write and end_call and reports back
// through write_done, cancelled and done.
class FrameStream : public PumpedStream {
 public:
  struct Setup {
    std::shared_ptr<Scene> scene;
    std::shared_ptr<void> slot;  // the stream's place in the registry's limits, freed by done()
    uint64_t every = 1;
    Clock::duration min_interval{};
  };

  FrameStream(StreamPump& pump, std::function<bool()> server_closing, Setup setup);

  // Holds itself, registers the listener and sends the first frame (or waits for it). The
  // stream starts with the scene's latest frame, so a paused scene's reader sees its state.
  void begin(std::shared_ptr<FrameStream> self);

  const Setup& setup() const { return setup_; }

 protected:
  // Starts writing `frame`, `skipped` frames after the last one written (one write at a time;
  // write_done follows). Called without the stream's lock.
  virtual void start_write(const Frame& frame, uint64_t skipped) = 0;

 private:
  void look() override;

  const std::function<bool()> server_closing_;
  Setup setup_;
  uint64_t after_ = 0;      // the newest frame seq looked at
  bool have_last_ = false;
  uint64_t last_sent_ = 0;  // decimation phase
  Clock::time_point next_allowed_;
};

// One haptic tool stream: poses read one at a time and posted to the scene (never waiting for the
// tick), the first naming the scene and attaching the tool; one feedback message per published
// tick that has the tool in it, at most one write in flight (ticks published meanwhile counted in
// the next message's skipped ticks). The tool lives as long as the stream: it is removed when the
// stream ends, whatever ends it. The transport reads poses, implements start_write and end_call,
// and reports back through pose_read, write_done, cancelled and done.
class ToolStream : public PumpedStream {
 public:
  // `peer` names the client in debug logs.
  ToolStream(StreamPump& pump, SceneRegistry& registry, std::string peer);

  // Holds itself until done(); the transport then reads the first pose.
  void begin(std::shared_ptr<ToolStream> self) { hold(std::move(self)); }

  // From the transport: a pose was read (ok false: the client closed its side or went away).
  // Returns whether to read the next one. Reads are serial.
  bool pose_read(bool ok, const v1::ToolPose& pose);

 protected:
  // Starts writing tool `tool_id`'s feedback from `frame` (which has it), `skipped` published
  // ticks after the last one looked at; write_done follows. Called without the stream's lock.
  virtual void start_write(const Frame& frame, uint64_t tool_id, uint64_t skipped) = 0;

 private:
  Error first_pose(const v1::ToolPose& pose);
  Error next_pose(const v1::ToolPose& pose);
  void look() override;
  // The tool goes when the call ends, whatever ends it.
  void on_finish() override;

  SceneRegistry& registry_;
  const std::string peer_;
  bool attached_ = false;  // the first pose was taken (read side only)
  RigidTool tool_;         // the last pose's tool (read side only)

  // Under mu_:
  std::shared_ptr<Scene> scene_;
  uint64_t tool_id_ = 0;
  uint64_t after_ = 0;  // the newest frame seq looked at
};

}  // namespace pliant::server
