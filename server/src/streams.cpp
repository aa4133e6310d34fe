// SPDX-License-Identifier: Apache-2.0
#include "pliant/server/streams.hpp"

#include "pliant/server/edge.hpp"
#include "pliant/server/stream_proto.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <utility>

namespace pliant::server {

StreamPump::StreamPump(int threads) {
  for (int i = 0; i < threads; ++i) threads_.emplace_back([this] { run(); });
}

StreamPump::~StreamPump() {
  {
    std::lock_guard lk(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  for (auto& t : threads_) t.join();
}

void StreamPump::post(std::function<void()> fn) {
  {
    std::lock_guard lk(mu_);
    ready_.push_back(std::move(fn));
  }
  cv_.notify_one();
}

void StreamPump::post_at(Clock::time_point when, std::function<void()> fn) {
  {
    std::lock_guard lk(mu_);
    timers_.emplace(when, std::move(fn));
  }
  cv_.notify_one();
}

void StreamPump::run() {
  std::unique_lock lk(mu_);
  while (true) {
    const auto now = Clock::now();
    while (!timers_.empty() && timers_.begin()->first <= now) {
      ready_.push_back(std::move(timers_.begin()->second));
      timers_.erase(timers_.begin());
    }
    if (!ready_.empty()) {
      auto fn = std::move(ready_.front());
      ready_.pop_front();
      lk.unlock();
      try {
        fn();
      } catch (const std::exception& e) {
        spdlog::error("stream pump: internal error: {}", e.what());
      }
      fn = nullptr;  // drops what it holds outside the lock
      lk.lock();
      continue;
    }
    if (stop_) return;
    if (timers_.empty()) {
      cv_.wait(lk);
    } else {
      // A copy: while this thread waits, another can take that timer and free its node.
      const Clock::time_point next = timers_.begin()->first;
      cv_.wait_until(lk, next);
    }
  }
}

// ---------------------------------------------------------------------------------------------

void PumpedStream::listen(const std::shared_ptr<Scene>& scene) {
  std::weak_ptr<PumpedStream> weak = self_;
  listener_ = scene->add_frame_listener([weak] {
    if (auto s = weak.lock()) s->wake();
  });
  listened_ = scene;
}

void PumpedStream::done() {
  if (listened_) listened_->remove_frame_listener(listener_);
  listened_.reset();
  auto keep = std::move(self_);  // may destroy this at the end of the scope
  std::shared_ptr<void> slot;
  {
    std::lock_guard lk(mu_);
    slot = std::move(slot_);
  }
  slot.reset();  // frees the stream's place in the limits (takes the registry's lock: not under mu_)
}

void PumpedStream::write_done(bool ok) {
  std::optional<Error> status;
  bool ending = false;  // this completion ends the call: the client is gone
  {
    std::lock_guard lk(mu_);
    writing_ = false;
    if (finished_) {
      status = std::exchange(due_, std::nullopt);
    } else if (!ok) {
      finished_ = ending = true;
      status = Error{};
    }
  }
  if (ending) on_finish();
  if (status) return end_call(*status);
  look();  // returns at once when the call has ended
}

void PumpedStream::cancelled() { finish(Error::make(Code::Cancelled, "the call was cancelled")); }

void PumpedStream::finish(const Error& status) {
  bool now;
  {
    std::lock_guard lk(mu_);
    if (finished_) return;
    finished_ = true;
    now = !writing_;
    if (!now) due_ = status;  // the write's completion ends the call
  }
  on_finish();
  if (now) end_call(status);
}

void PumpedStream::wake() {
  std::lock_guard lk(mu_);
  if (finished_ || writing_ || scheduled_) return;
  schedule_locked(Clock::time_point{});
}

void PumpedStream::schedule_locked(Clock::time_point when) {
  scheduled_ = true;
  auto fn = [s = shared_from_this()] {
    {
      std::lock_guard lk2(s->mu_);
      s->scheduled_ = false;
    }
    s->look();
  };
  if (when == Clock::time_point{}) pump_.post(std::move(fn));
  else pump_.post_at(when, std::move(fn));
}

// ---------------------------------------------------------------------------------------------

FrameStream::FrameStream(StreamPump& pump, std::function<bool()> server_closing, Setup setup)
    : PumpedStream(pump), server_closing_(std::move(server_closing)), setup_(std::move(setup)),
      next_allowed_(Clock::now()) {
  slot_ = std::move(setup_.slot);
  auto latest = setup_.scene->latest_frame();
  after_ = latest ? latest->seq - 1 : 0;
}

void FrameStream::begin(std::shared_ptr<FrameStream> self) {
  hold(std::move(self));
  listen(setup_.scene);
  wake();
}

void FrameStream::look() {
  std::unique_lock lk(mu_);
  if (finished_ || writing_ || scheduled_) return;
  if (server_closing_ && server_closing_()) {
    lk.unlock();
    return finish(Error::make(Code::Unavailable, "the server is shutting down"));
  }
  Scene& scene = *setup_.scene;
  auto frame = scene.latest_frame();
  bool due = frame && frame->seq > after_;
  if (due && have_last_ && frame->seq < last_sent_ + setup_.every) {  // decimation
    after_ = frame->seq;
    due = false;
  }
  if (!due) {
    if (scene.stopped()) {
      lk.unlock();
      return finish(Error::make(Code::NotFound, fmt::format("scene_id '{}' was deleted", scene.id())));
    }
    return;
  }
  const bool limited = setup_.min_interval > Clock::duration::zero();
  const auto now = Clock::now();
  if (limited && now < next_allowed_) {
    // Rate limit: look again when the slot opens, and send whatever is newest then.
    schedule_locked(next_allowed_);
    return;
  }
  uint64_t skipped = 0;
  if (have_last_ && !limited) skipped = (frame->seq - last_sent_) / setup_.every - 1;
  // Keep the decimation's phase when a late reader sends an off-phase frame.
  last_sent_ = have_last_ ? frame->seq - (frame->seq - last_sent_) % setup_.every : frame->seq;
  have_last_ = true;
  after_ = frame->seq;
  if (limited) {
    next_allowed_ += setup_.min_interval;
    if (next_allowed_ < now) next_allowed_ = now;
  }
  writing_ = true;
  lk.unlock();
  start_write(*frame, skipped);
}

// ---------------------------------------------------------------------------------------------

ToolStream::ToolStream(StreamPump& pump, SceneRegistry& registry, std::string peer)
    : PumpedStream(pump), registry_(registry), peer_(std::move(peer)) {}

bool ToolStream::pose_read(bool ok, const v1::ToolPose& pose) {
  if (!ok) {
    finish(Error{});  // the client closed its side (or went away)
    return false;
  }
  const Error e = attached_ ? next_pose(pose) : first_pose(pose);
  if (!e.ok()) {
    finish(e);
    return false;
  }
  std::lock_guard lk(mu_);
  return !finished_;  // ended meanwhile (scene gone, cancelled): read no more
}

Error ToolStream::first_pose(const v1::ToolPose& pose) {
  std::shared_ptr<Scene> scene;
  if (Error e = registry_.find(pose.scene_id(), &scene); !e.ok()) return e;
  std::shared_ptr<void> slot;
  if (Error e = registry_.open_stream(scene->id(), &slot); !e.ok()) return e;
  RigidTool tool;
  if (Error e = parse_tool_pose(pose, nullptr, &tool); !e.ok()) return e;
  {
    std::lock_guard lk(mu_);
    if (finished_) return Error::make(Code::Cancelled, "the call was cancelled");  // attach nothing
    scene_ = scene;
    slot_ = std::move(slot);
    tool_ = tool;
    tool_id_ = scene->new_tool_id();
    scene->set_tool(tool_id_, tool_, pose.seq(), pose.client_time_ns());
    auto latest = scene->latest_frame();
    after_ = latest ? latest->seq : 0;
  }
  attached_ = true;
  spdlog::debug("HapticStream: {} attached tool {} to '{}'", peer_, tool_id_, scene->id());
  listen(scene);
  wake();  // a scene stopped meanwhile ends the stream now
  return {};
}

Error ToolStream::next_pose(const v1::ToolPose& pose) {
  if (!pose.scene_id().empty() && pose.scene_id() != scene_->id())
    return Error::make(Code::InvalidArgument, fmt::format("scene_id {} differs from the stream's scene '{}'",
                                                          echo(pose.scene_id()), scene_->id()));
  RigidTool next;
  if (Error e = parse_tool_pose(pose, &tool_, &next); !e.ok()) return e;
  tool_ = next;
  std::lock_guard lk(mu_);
  if (!finished_) scene_->set_tool(tool_id_, tool_, pose.seq(), pose.client_time_ns());
  return {};
}

void ToolStream::look() {
  std::unique_lock lk(mu_);
  if (finished_ || writing_ || scheduled_ || !scene_) return;
  if (registry_.shutting_down()) {
    lk.unlock();
    return finish(Error::make(Code::Unavailable, "the server is shutting down"));
  }
  auto frame = scene_->latest_frame();
  if (!frame || frame->seq <= after_) {
    if (scene_->stopped()) {
      const std::string id = scene_->id();
      lk.unlock();
      return finish(Error::make(Code::NotFound, fmt::format("scene_id '{}' was deleted", id)));
    }
    return;
  }
  const uint64_t skipped = after_ > 0 && frame->seq > after_ + 1 ? frame->seq - after_ - 1 : 0;
  after_ = frame->seq;
  bool has_tool = false;
  for (const FrameTool& t : frame->tools) has_tool = has_tool || t.tool_id == tool_id_;
  if (!has_tool) return;  // its first pose is not in a tick yet
  writing_ = true;
  const uint64_t tool_id = tool_id_;
  lk.unlock();
  start_write(*frame, tool_id, skipped);
}

void ToolStream::on_finish() {
  std::shared_ptr<Scene> scene;
  uint64_t tool_id;
  {
    std::lock_guard lk(mu_);
    scene = scene_;
    tool_id = tool_id_;
  }
  if (!scene) return;  // never attached
  scene->remove_tool(tool_id);
  spdlog::debug("HapticStream: {} detached tool {} from '{}'", peer_, tool_id, scene->id());
}

}  // namespace pliant::server
