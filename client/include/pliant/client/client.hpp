// SPDX-License-Identifier: Apache-2.0
// The C++ client library for a Pliant server: typed calls returning values or a Status
// (never throwing for remote errors), a frame stream as an iterator or with a callback, and
// the standard health check. Messages are the pliant.v1 protobuf types.
#pragma once

#include "pliant/v1/pliant.pb.h"

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace pliant::client {

// Adds one box to spec.fixed holding every vertex with x <= x_max (a cantilever's clamp; the
// builtin beams start at x = 0).
void clamp_below_x(v1::SceneSpec& spec, double x_max);


// A gRPC status: code 0 is OK; otherwise grpc::StatusCode values (3 INVALID_ARGUMENT,
// 5 NOT_FOUND, 14 UNAVAILABLE, 16 UNAUTHENTICATED, ...) and the server's message.
struct Status {
  int code = 0;
  std::string message;
  bool ok() const { return code == 0; }
  std::string code_name() const;
  std::string to_string() const;  // "NOT_FOUND: scene_id 'x' not found"
};

template <class T>
struct Result {
  Status status;
  T value{};
  bool ok() const { return status.ok(); }
  const T& operator*() const { return value; }
  const T* operator->() const { return &value; }
};

struct ConnectOptions {
  std::string address = "localhost:50051";
  std::string token;        // sent as "authorization: Bearer <token>" when set
  bool tls = false;         // TLS with the system roots, or tls_ca_file
  std::string tls_ca_file;  // PEM roots for a private CA (implies tls)
  int max_message_mb = 64;
  std::chrono::milliseconds timeout{30000};        // unary calls
  std::chrono::milliseconds step_timeout{600000};  // Step (many ticks can take long)
  // FrameService calls use a connection of their own whose HTTP/2 lookahead is this many bytes
  // (and no BDP probing), so a reader that pauses finds about one stale frame in its transport
  // before the newest one; 0: the main connection with gRPC's defaults (64 KiB or more of
  // frames queue up for a paused reader).
  int frame_window_bytes = 1;
};

enum class Health { Unknown, Serving, NotServing, ServiceUnknown };
std::string_view to_string(Health h);

// A server stream of frames. next() blocks for the next frame and returns false at the end
// of the stream; finish() then gives the status the server ended it with.
class FrameStream {
 public:
  ~FrameStream();  // cancels a stream still open
  bool next(v1::Frame* frame);
  void cancel();   // may be called from another thread
  // True once cancel() was called on this side: a CANCELLED status then means "we ended it";
  // without it, CANCELLED came from the server (a stopping server cancels what outlives its grace).
  bool cancelled() const;
  Status finish();

 private:
  friend class Client;
  struct Impl;
  explicit FrameStream(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// The bidirectional haptic stream (InteractionService.HapticStream): send() tool poses from
// one thread while another reads feedback with next(). close() half-closes; cancel() may be
// called from any thread; finish() gives the server's status.
class HapticStream {
 public:
  ~HapticStream();  // cancels a stream still open
  bool send(const v1::ToolPose& pose);
  bool next(v1::ToolFeedback* feedback);
  void close();
  void cancel();
  Status finish();

 private:
  friend class Client;
  struct Impl;
  explicit HapticStream(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

class Client {
 public:
  explicit Client(ConnectOptions options);
  ~Client();
  Client(Client&&) noexcept;
  Client& operator=(Client&&) noexcept;

  const ConnectOptions& options() const;
  // Waits until the channel is connected (false when the deadline passes first).
  bool wait_connected(std::chrono::milliseconds timeout);

  Result<v1::Scene> create_scene(const v1::CreateSceneRequest& request);
  Result<std::vector<v1::Scene>> list_scenes();
  Result<v1::Scene> get_scene(const std::string& scene_id);
  Result<v1::Scene> update_scene(const v1::UpdateSceneRequest& request);
  Status delete_scene(const std::string& scene_id);
  Result<v1::Scene> reset_scene(const std::string& scene_id);
  Result<v1::Scene> pause_scene(const std::string& scene_id);
  Result<v1::Scene> resume_scene(const std::string& scene_id);
  Result<v1::StepResponse> step(const std::string& scene_id, uint32_t ticks = 1);
  Result<v1::ApplyForceResponse> apply_force(const v1::ApplyForceRequest& request);

  Result<v1::Topology> topology(const std::string& scene_id);
  std::unique_ptr<FrameStream> stream_frames(const v1::StreamFramesRequest& request);
  // Calls on_frame for every frame until it returns false (then cancels: Status OK) or the
  // stream ends (the server's status).
  Status stream_frames(const v1::StreamFramesRequest& request,
                       const std::function<bool(const v1::Frame&)>& on_frame);

  Result<v1::SaveSnapshotResponse> save_snapshot(const v1::SaveSnapshotRequest& request);
  Result<v1::Scene> restore_snapshot(const v1::RestoreSnapshotRequest& request);
  Result<std::vector<std::string>> list_snapshots();

  // InteractionService.
  Result<v1::GrabResponse> grab(const v1::GrabRequest& request);
  Result<v1::MoveGrabResponse> move_grab(const v1::MoveGrabRequest& request);
  Status release(const std::string& scene_id, uint64_t grab_id);
  std::unique_ptr<HapticStream> haptic_stream();

  // grpc.health.v1.Health/Check; service "" is the whole server.
  Result<Health> health(const std::string& service = "");

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pliant::client
