// SPDX-License-Identifier: Apache-2.0
// The client library over the generated stubs.
#include "pliant/client/client.hpp"

#include "grpc/health/v1/health.grpc.pb.h"
#include "pliant/v1/pliant.grpc.pb.h"

#include <grpcpp/grpcpp.h>

#include <atomic>
#include <fstream>
#include <mutex>
#include <sstream>

namespace pliant::client {

void clamp_below_x(v1::SceneSpec& spec, double x_max) {
  auto* box = spec.mutable_fixed()->add_boxes();
  box->mutable_min()->set_x(-1e9);
  box->mutable_min()->set_y(-1e9);
  box->mutable_min()->set_z(-1e9);
  box->mutable_max()->set_x(x_max);
  box->mutable_max()->set_y(1e9);
  box->mutable_max()->set_z(1e9);
}


namespace {

const char* kCodeNames[] = {"OK", "CANCELLED", "UNKNOWN", "INVALID_ARGUMENT", "DEADLINE_EXCEEDED",
                            "NOT_FOUND", "ALREADY_EXISTS", "PERMISSION_DENIED", "RESOURCE_EXHAUSTED",
                            "FAILED_PRECONDITION", "ABORTED", "OUT_OF_RANGE", "UNIMPLEMENTED",
                            "INTERNAL", "UNAVAILABLE", "DATA_LOSS", "UNAUTHENTICATED"};

Status from_grpc(const grpc::Status& s) { return Status{static_cast<int>(s.error_code()), s.error_message()}; }

}  // namespace

std::string Status::code_name() const {
  if (code >= 0 && code <= 16) return kCodeNames[code];
  return "CODE_" + std::to_string(code);
}

std::string Status::to_string() const { return ok() ? "OK" : code_name() + ": " + message; }

std::string_view to_string(Health h) {
  switch (h) {
    case Health::Serving: return "SERVING";
    case Health::NotServing: return "NOT_SERVING";
    case Health::ServiceUnknown: return "SERVICE_UNKNOWN";
    default: return "UNKNOWN";
  }
}

struct Client::Impl {
  ConnectOptions options;
  std::shared_ptr<grpc::Channel> channel;
  std::shared_ptr<grpc::Channel> frame_channel;  // FrameService's (its own flow-control window)
  std::unique_ptr<v1::SceneService::Stub> scenes;
  std::unique_ptr<v1::FrameService::Stub> frames;
  std::unique_ptr<v1::SnapshotService::Stub> snapshots;
  std::unique_ptr<v1::InteractionService::Stub> interaction;
  std::unique_ptr<grpc::health::v1::Health::Stub> health;

  void prepare(grpc::ClientContext& ctx, std::chrono::milliseconds timeout) const {
    if (!options.token.empty()) ctx.AddMetadata("authorization", "Bearer " + options.token);
    if (timeout.count() > 0) ctx.set_deadline(std::chrono::system_clock::now() + timeout);
  }

  template <class Req, class Resp, class Stub, class Method>
  Result<Resp> unary(Stub* stub, Method method, const Req& req, std::chrono::milliseconds timeout) {
    grpc::ClientContext ctx;
    prepare(ctx, timeout);
    Result<Resp> r;
    r.status = from_grpc((stub->*method)(&ctx, req, &r.value));
    return r;
  }
  template <class Req, class Resp, class Stub, class Method>
  Result<Resp> unary(Stub* stub, Method method, const Req& req) {
    return unary<Req, Resp>(stub, method, req, options.timeout);
  }
};

struct FrameStream::Impl {
  grpc::ClientContext ctx;
  std::unique_ptr<grpc::ClientReader<v1::Frame>> reader;
  bool finished = false;
  std::atomic<bool> cancelled{false};  // cancel() was called here
  Status status;
};

FrameStream::FrameStream(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
FrameStream::~FrameStream() {
  if (impl_ && !impl_->finished) {
    impl_->ctx.TryCancel();
    finish();
  }
}
bool FrameStream::next(v1::Frame* frame) { return !impl_->finished && impl_->reader->Read(frame); }
void FrameStream::cancel() {
  impl_->cancelled = true;
  impl_->ctx.TryCancel();
}
bool FrameStream::cancelled() const { return impl_->cancelled; }
Status FrameStream::finish() {
  if (!impl_->finished) {
    // Drain what is in flight so Finish() does not wait on unread messages.
    v1::Frame f;
    while (impl_->reader->Read(&f)) {
    }
    impl_->status = from_grpc(impl_->reader->Finish());
    impl_->finished = true;
  }
  return impl_->status;
}

struct HapticStream::Impl {
  grpc::ClientContext ctx;
  std::unique_ptr<grpc::ClientReaderWriter<v1::ToolPose, v1::ToolFeedback>> stream;
  std::mutex write_mu;
  bool closed = false;
  bool finished = false;
  Status status;
};

HapticStream::HapticStream(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
HapticStream::~HapticStream() {
  if (impl_ && !impl_->finished) {
    impl_->ctx.TryCancel();
    finish();
  }
}
bool HapticStream::send(const v1::ToolPose& pose) {
  std::lock_guard lk(impl_->write_mu);
  if (impl_->closed) return false;
  return impl_->stream->Write(pose);
}
bool HapticStream::next(v1::ToolFeedback* feedback) { return !impl_->finished && impl_->stream->Read(feedback); }
void HapticStream::close() {
  std::lock_guard lk(impl_->write_mu);
  if (!impl_->closed) impl_->stream->WritesDone();
  impl_->closed = true;
}
void HapticStream::cancel() { impl_->ctx.TryCancel(); }
Status HapticStream::finish() {
  if (!impl_->finished) {
    close();
    v1::ToolFeedback f;
    while (impl_->stream->Read(&f)) {
    }
    impl_->status = from_grpc(impl_->stream->Finish());
    impl_->finished = true;
  }
  return impl_->status;
}

Client::Client(ConnectOptions options) : impl_(std::make_unique<Impl>()) {
  impl_->options = std::move(options);
  const auto& o = impl_->options;
  std::shared_ptr<grpc::ChannelCredentials> creds = grpc::InsecureChannelCredentials();
  if (o.tls || !o.tls_ca_file.empty()) {
    grpc::SslCredentialsOptions ssl;
    if (!o.tls_ca_file.empty()) {
      std::ifstream f(o.tls_ca_file);
      std::stringstream ss;
      ss << f.rdbuf();
      ssl.pem_root_certs = ss.str();
      // Never fall back to the system roots: with roots that cannot be read, no server is trusted.
      // (the CLI refuses such a file up front; calls then fail with UNAVAILABLE).
      if (!f || ssl.pem_root_certs.find("-----BEGIN") == std::string::npos) ssl.pem_root_certs = "unreadable";
    }
    creds = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(o.max_message_mb * 1024 * 1024);
  args.SetMaxSendMessageSize(o.max_message_mb * 1024 * 1024);
  impl_->channel = grpc::CreateCustomChannel(o.address, creds, args);
  impl_->frame_channel = impl_->channel;
  if (o.frame_window_bytes > 0) {
    // Frames on a connection of their own whose receive window stays small: a reader that stops
    // reading leaves at most about one frame in its transport, so its next reads reach the
    // newest frame (the server keeps only the newest unsent one). Whole messages still get the
    // window they need when read.
    grpc::ChannelArguments frame_args = args;
    frame_args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
    frame_args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, o.frame_window_bytes);
    impl_->frame_channel = grpc::CreateCustomChannel(o.address, creds, frame_args);
  }
  impl_->scenes = v1::SceneService::NewStub(impl_->channel);
  impl_->frames = v1::FrameService::NewStub(impl_->frame_channel);
  impl_->snapshots = v1::SnapshotService::NewStub(impl_->channel);
  impl_->interaction = v1::InteractionService::NewStub(impl_->channel);
  impl_->health = grpc::health::v1::Health::NewStub(impl_->channel);
}
Client::~Client() = default;
Client::Client(Client&&) noexcept = default;
Client& Client::operator=(Client&&) noexcept = default;

const ConnectOptions& Client::options() const { return impl_->options; }

bool Client::wait_connected(std::chrono::milliseconds timeout) {
  return impl_->channel->WaitForConnected(std::chrono::system_clock::now() + timeout);
}

using SS = v1::SceneService::Stub;

Result<v1::Scene> Client::create_scene(const v1::CreateSceneRequest& r) {
  return impl_->unary<v1::CreateSceneRequest, v1::Scene>(impl_->scenes.get(), &SS::CreateScene, r);
}
Result<std::vector<v1::Scene>> Client::list_scenes() {
  auto r = impl_->unary<v1::ListScenesRequest, v1::ListScenesResponse>(impl_->scenes.get(), &SS::ListScenes,
                                                                         v1::ListScenesRequest{});
  Result<std::vector<v1::Scene>> out;
  out.status = r.status;
  out.value.assign(r.value.scenes().begin(), r.value.scenes().end());
  return out;
}
Result<v1::Scene> Client::get_scene(const std::string& id) {
  v1::GetSceneRequest r;
  r.set_scene_id(id);
  return impl_->unary<v1::GetSceneRequest, v1::Scene>(impl_->scenes.get(), &SS::GetScene, r);
}
Result<v1::Scene> Client::update_scene(const v1::UpdateSceneRequest& r) {
  return impl_->unary<v1::UpdateSceneRequest, v1::Scene>(impl_->scenes.get(), &SS::UpdateScene, r);
}
Status Client::delete_scene(const std::string& id) {
  v1::DeleteSceneRequest r;
  r.set_scene_id(id);
  return impl_->unary<v1::DeleteSceneRequest, v1::DeleteSceneResponse>(impl_->scenes.get(), &SS::DeleteScene, r)
      .status;
}
Result<v1::Scene> Client::reset_scene(const std::string& id) {
  v1::ResetSceneRequest r;
  r.set_scene_id(id);
  return impl_->unary<v1::ResetSceneRequest, v1::Scene>(impl_->scenes.get(), &SS::ResetScene, r);
}
Result<v1::Scene> Client::pause_scene(const std::string& id) {
  v1::PauseSceneRequest r;
  r.set_scene_id(id);
  return impl_->unary<v1::PauseSceneRequest, v1::Scene>(impl_->scenes.get(), &SS::PauseScene, r);
}
Result<v1::Scene> Client::resume_scene(const std::string& id) {
  v1::ResumeSceneRequest r;
  r.set_scene_id(id);
  return impl_->unary<v1::ResumeSceneRequest, v1::Scene>(impl_->scenes.get(), &SS::ResumeScene, r);
}
Result<v1::StepResponse> Client::step(const std::string& id, uint32_t ticks) {
  v1::StepRequest r;
  r.set_scene_id(id);
  r.set_ticks(ticks);
  return impl_->unary<v1::StepRequest, v1::StepResponse>(impl_->scenes.get(), &SS::Step, r,
                                                         impl_->options.step_timeout);
}
Result<v1::ApplyForceResponse> Client::apply_force(const v1::ApplyForceRequest& r) {
  return impl_->unary<v1::ApplyForceRequest, v1::ApplyForceResponse>(impl_->scenes.get(), &SS::ApplyForce, r);
}

using IS = v1::InteractionService::Stub;

Result<v1::GrabResponse> Client::grab(const v1::GrabRequest& r) {
  return impl_->unary<v1::GrabRequest, v1::GrabResponse>(impl_->interaction.get(), &IS::Grab, r);
}
Result<v1::MoveGrabResponse> Client::move_grab(const v1::MoveGrabRequest& r) {
  return impl_->unary<v1::MoveGrabRequest, v1::MoveGrabResponse>(impl_->interaction.get(), &IS::MoveGrab, r);
}
Status Client::release(const std::string& scene_id, uint64_t grab_id) {
  v1::ReleaseRequest r;
  r.set_scene_id(scene_id);
  r.set_grab_id(grab_id);
  return impl_->unary<v1::ReleaseRequest, v1::ReleaseResponse>(impl_->interaction.get(), &IS::Release, r).status;
}
std::unique_ptr<HapticStream> Client::haptic_stream() {
  auto impl = std::make_unique<HapticStream::Impl>();
  impl_->prepare(impl->ctx, std::chrono::milliseconds(0));
  impl->stream = impl_->interaction->HapticStream(&impl->ctx);
  return std::unique_ptr<HapticStream>(new HapticStream(std::move(impl)));
}

Result<v1::Topology> Client::topology(const std::string& id) {
  v1::GetTopologyRequest r;
  r.set_scene_id(id);
  return impl_->unary<v1::GetTopologyRequest, v1::Topology>(impl_->frames.get(), &v1::FrameService::Stub::GetTopology, r);
}

std::unique_ptr<FrameStream> Client::stream_frames(const v1::StreamFramesRequest& r) {
  auto impl = std::make_unique<FrameStream::Impl>();
  impl_->prepare(impl->ctx, std::chrono::milliseconds(0));
  impl->reader = impl_->frames->StreamFrames(&impl->ctx, r);
  return std::unique_ptr<FrameStream>(new FrameStream(std::move(impl)));
}

Status Client::stream_frames(const v1::StreamFramesRequest& r,
                             const std::function<bool(const v1::Frame&)>& on_frame) {
  auto stream = stream_frames(r);
  v1::Frame f;
  while (stream->next(&f)) {
    if (!on_frame(f)) {
      stream->cancel();
      stream->finish();
      return {};
    }
  }
  return stream->finish();
}

Result<v1::SaveSnapshotResponse> Client::save_snapshot(const v1::SaveSnapshotRequest& r) {
  return impl_->unary<v1::SaveSnapshotRequest, v1::SaveSnapshotResponse>(
      impl_->snapshots.get(), &v1::SnapshotService::Stub::SaveSnapshot, r);
}
Result<v1::Scene> Client::restore_snapshot(const v1::RestoreSnapshotRequest& r) {
  return impl_->unary<v1::RestoreSnapshotRequest, v1::Scene>(impl_->snapshots.get(),
                                                             &v1::SnapshotService::Stub::RestoreSnapshot, r);
}
Result<std::vector<std::string>> Client::list_snapshots() {
  auto r = impl_->unary<v1::ListSnapshotsRequest, v1::ListSnapshotsResponse>(
      impl_->snapshots.get(), &v1::SnapshotService::Stub::ListSnapshots, v1::ListSnapshotsRequest{});
  Result<std::vector<std::string>> out;
  out.status = r.status;
  out.value.assign(r.value.names().begin(), r.value.names().end());
  return out;
}

Result<Health> Client::health(const std::string& service) {
  grpc::health::v1::HealthCheckRequest req;
  req.set_service(service);
  auto r = impl_->unary<grpc::health::v1::HealthCheckRequest, grpc::health::v1::HealthCheckResponse>(
      impl_->health.get(), &grpc::health::v1::Health::Stub::Check, req);
  Result<Health> out;
  out.status = r.status;
  switch (r.value.status()) {
    case grpc::health::v1::HealthCheckResponse::SERVING: out.value = Health::Serving; break;
    case grpc::health::v1::HealthCheckResponse::NOT_SERVING: out.value = Health::NotServing; break;
    case grpc::health::v1::HealthCheckResponse::SERVICE_UNKNOWN: out.value = Health::ServiceUnknown; break;
    default: out.value = Health::Unknown; break;
  }
  return out;
}

}  // namespace pliant::client
