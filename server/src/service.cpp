// SPDX-License-Identifier: Apache-2.0
// gRPC glue: the pliant.v1 services over the SceneRegistry, token check, health, reflection,
// TLS and graceful shutdown.
#include "pliant/server/server.hpp"

#include "pliant/server/edge.hpp"
#include "pliant/server/metrics.hpp"
#include "pliant/server/stream_proto.hpp"
#include "pliant/server/streams.hpp"

#include "pliant/mesh_io.hpp"
#include "pliant/v1/pliant.grpc.pb.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/support/server_interceptor.h>
#include <openssl/crypto.h>
#include <openssl/sha.h>
#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <array>
#include <atomic>
#include <condition_variable>
#include <map>
#include <filesystem>
#include <fstream>
#include <future>
#include <sstream>
#include <thread>

namespace pliant::server {

using Clock = std::chrono::steady_clock;

namespace {

grpc::Status to_status(const Error& e) {
  grpc::StatusCode c = grpc::StatusCode::UNKNOWN;
  switch (e.code) {
    case Code::Ok: return grpc::Status::OK;
    case Code::InvalidArgument: c = grpc::StatusCode::INVALID_ARGUMENT; break;
    case Code::NotFound: c = grpc::StatusCode::NOT_FOUND; break;
    case Code::AlreadyExists: c = grpc::StatusCode::ALREADY_EXISTS; break;
    case Code::ResourceExhausted: c = grpc::StatusCode::RESOURCE_EXHAUSTED; break;
    case Code::FailedPrecondition: c = grpc::StatusCode::FAILED_PRECONDITION; break;
    case Code::Unauthenticated: c = grpc::StatusCode::UNAUTHENTICATED; break;
    case Code::Unavailable: c = grpc::StatusCode::UNAVAILABLE; break;
    case Code::DeadlineExceeded: c = grpc::StatusCode::DEADLINE_EXCEEDED; break;
    case Code::Cancelled: c = grpc::StatusCode::CANCELLED; break;
    case Code::Internal: c = grpc::StatusCode::INTERNAL; break;
  }
  return grpc::Status(c, cap_message(e.message));
}

using Digest = std::array<unsigned char, SHA256_DIGEST_LENGTH>;

Digest sha256(std::string_view s) {
  Digest d{};
  SHA256(reinterpret_cast<const unsigned char*>(s.data()), s.size(), d.data());
  return d;
}

// The 'authorization' header against the expected one, by their SHA-256 digests compared in
// constant time: the time depends neither on the token's content nor on its length.
grpc::Status check_token(const std::multimap<grpc::string_ref, grpc::string_ref>& md, const Digest& expected) {
  auto it = md.find("authorization");
  if (it == md.end())
    return grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                        "missing 'authorization' metadata: this server requires 'Bearer <token>'");
  const Digest presented = sha256(std::string_view(it->second.data(), it->second.size()));
  if (CRYPTO_memcmp(presented.data(), expected.data(), expected.size()) != 0)
    return grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "the access token in 'authorization' is not valid");
  return grpc::Status::OK;
}

// Shared by the services: the registry, the token's digest, and error logging.
struct ServiceContext {
  SceneRegistry* registry;
  bool token_required = false;
  Digest expected{};  // SHA-256 of "Bearer <token>"

  grpc::Status check(const grpc::ServerContextBase* ctx) const {
    if (!token_required) return grpc::Status::OK;
    return check_token(ctx->client_metadata(), expected);
  }

  grpc::Status answer(const char* rpc, const grpc::ServerContextBase* ctx, const Error& e) const {
    if (!e.ok()) spdlog::debug("{} from {}: {}", rpc, ctx->peer(), e.message);
    return to_status(e);
  }
};

// Runs `body` unless the call is unauthenticated; exceptions never escape to gRPC.
template <class F>
grpc::Status guarded(const ServiceContext& sc, const char* rpc, const grpc::ServerContextBase* ctx, F&& body) {
  if (grpc::Status s = sc.check(ctx); !s.ok()) {
    spdlog::warn("{} from {}: {}", rpc, ctx->peer(), s.error_message());
    return s;
  }
  try {
    return sc.answer(rpc, ctx, body());
  } catch (const std::exception& e) {
    spdlog::error("{}: internal error: {}", rpc, e.what());
    return grpc::Status(grpc::StatusCode::INTERNAL, std::string(rpc) + ": " + e.what());
  }
}

class SceneServiceImpl final : public v1::SceneService::Service {
 public:
  explicit SceneServiceImpl(ServiceContext sc) : sc_(std::move(sc)) {}
  grpc::Status CreateScene(grpc::ServerContext* c, const v1::CreateSceneRequest* r, v1::Scene* o) override {
    return guarded(sc_, "CreateScene", c, [&] { return reg().create(*r, o); });
  }
  grpc::Status ListScenes(grpc::ServerContext* c, const v1::ListScenesRequest*, v1::ListScenesResponse* o) override {
    return guarded(sc_, "ListScenes", c, [&] { return reg().list(o); });
  }
  grpc::Status GetScene(grpc::ServerContext* c, const v1::GetSceneRequest* r, v1::Scene* o) override {
    return guarded(sc_, "GetScene", c, [&] { return reg().get(r->scene_id(), o); });
  }
  grpc::Status UpdateScene(grpc::ServerContext* c, const v1::UpdateSceneRequest* r, v1::Scene* o) override {
    return guarded(sc_, "UpdateScene", c, [&] { return reg().update(*r, o); });
  }
  grpc::Status DeleteScene(grpc::ServerContext* c, const v1::DeleteSceneRequest* r, v1::DeleteSceneResponse*) override {
    return guarded(sc_, "DeleteScene", c, [&] { return reg().remove(r->scene_id()); });
  }
  grpc::Status ResetScene(grpc::ServerContext* c, const v1::ResetSceneRequest* r, v1::Scene* o) override {
    return guarded(sc_, "ResetScene", c, [&] { return reg().reset(r->scene_id(), o); });
  }
  grpc::Status PauseScene(grpc::ServerContext* c, const v1::PauseSceneRequest* r, v1::Scene* o) override {
    return guarded(sc_, "PauseScene", c, [&] { return reg().pause(r->scene_id(), o); });
  }
  grpc::Status ResumeScene(grpc::ServerContext* c, const v1::ResumeSceneRequest* r, v1::Scene* o) override {
    return guarded(sc_, "ResumeScene", c, [&] { return reg().resume(r->scene_id(), o); });
  }
  grpc::Status Step(grpc::ServerContext* c, const v1::StepRequest* r, v1::StepResponse* o) override {
    return guarded(sc_, "Step", c, [&] {
      // Bounded by the call's deadline, and by an hour when the client set none.
      auto deadline = Clock::now() + std::chrono::hours(1);
      auto remaining = c->deadline() - std::chrono::system_clock::now();
      if (remaining < std::chrono::hours(1))
        deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(remaining);
      return reg().step(*r, deadline, o, [c] { return c->IsCancelled(); });
    });
  }
  grpc::Status ApplyForce(grpc::ServerContext* c, const v1::ApplyForceRequest* r, v1::ApplyForceResponse* o) override {
    return guarded(sc_, "ApplyForce", c, [&] { return reg().apply_force(*r, o); });
  }

 private:
  SceneRegistry& reg() { return *sc_.registry; }
  ServiceContext sc_;
};

// A call refused before it started streaming (Reactor: the call's reactor type).
template <class Reactor>
class Refused final : public Reactor {
 public:
  explicit Refused(grpc::Status s) { this->Finish(std::move(s)); }
  void OnDone() override { delete this; }
};

// One StreamFrames call on gRPC's callback API: FrameStream (streams.hpp) decides what to send,
// this writes it as a v1::Frame message and finishes the call.
class FrameStreamReactor final : public grpc::ServerWriteReactor<v1::Frame>, public FrameStream {
 public:
  FrameStreamReactor(const ServiceContext& sc, StreamPump& pump, grpc::CallbackServerContext* ctx, Setup setup,
                     FrameSelection selection)
      : FrameStream(pump, [registry = sc.registry] { return registry->shutting_down(); }, std::move(setup)),
        peer_(ctx->peer()), selection_(std::move(selection)) {}

  void begin(std::shared_ptr<FrameStreamReactor> self) {
    spdlog::debug("StreamFrames: {} subscribed to '{}'", peer_, setup().scene->id());
    FrameStream::begin(std::move(self));
  }

  void OnWriteDone(bool ok) override { write_done(ok); }
  void OnCancel() override { cancelled(); }
  void OnDone() override {
    spdlog::debug("StreamFrames: {} left '{}'", peer_, setup().scene->id());
    done();  // may destroy this
  }

 private:
  void start_write(const Frame& frame, uint64_t skipped) override {
    msg_.Clear();
    frame_to_proto(frame, selection_, setup().scene->surface_vertices(), skipped, &msg_);
    StartWrite(&msg_);
  }

  void end_call(const Error& status) override {
    if (!status.ok() && status.code != Code::Cancelled)
      spdlog::debug("StreamFrames from {}: {}", peer_, status.message);
    Finish(to_status(status));
  }

  const std::string peer_;
  const FrameSelection selection_;
  v1::Frame msg_;  // the message being written (one per stream)
};

class FrameServiceImpl final : public v1::FrameService::WithCallbackMethod_StreamFrames<v1::FrameService::Service> {
 public:
  FrameServiceImpl(ServiceContext sc, StreamPump& pump) : sc_(std::move(sc)), pump_(pump) {}
  grpc::Status GetTopology(grpc::ServerContext* c, const v1::GetTopologyRequest* r, v1::Topology* o) override {
    return guarded(sc_, "GetTopology", c, [&] { return sc_.registry->topology(r->scene_id(), o); });
  }

  grpc::ServerWriteReactor<v1::Frame>* StreamFrames(grpc::CallbackServerContext* c,
                                                    const v1::StreamFramesRequest* r) override {
    FrameStreamReactor::Setup setup;
    FrameSelection selection;
    const grpc::Status s = guarded(sc_, "StreamFrames", c, [&] { return prepare(*r, &setup, &selection); });
    if (!s.ok()) return new Refused<grpc::ServerWriteReactor<v1::Frame>>(s);
    try {
      auto reactor = std::make_shared<FrameStreamReactor>(sc_, pump_, c, std::move(setup), std::move(selection));
      reactor->begin(reactor);
      return reactor.get();
    } catch (const std::exception& e) {
      spdlog::error("StreamFrames: internal error: {}", e.what());
      return new Refused<grpc::ServerWriteReactor<v1::Frame>>(
          grpc::Status(grpc::StatusCode::INTERNAL, std::string("StreamFrames: ") + e.what()));
    }
  }

 private:
  Error prepare(const v1::StreamFramesRequest& r, FrameStreamReactor::Setup* out, FrameSelection* selection) {
    if (Error e = sc_.registry->find(r.scene_id(), &out->scene); !e.ok()) return e;
    if (Error e = sc_.registry->open_stream(out->scene->id(), &out->slot); !e.ok()) return e;
    if (Error e = parse_stream_request(r, selection); !e.ok()) return e;
    out->every = r.every_nth_tick() <= 1 ? 1 : r.every_nth_tick();
    out->min_interval = r.max_rate_hz() > 0
        ? std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / r.max_rate_hz()))
        : Clock::duration::zero();
    return {};
  }

  ServiceContext sc_;
  StreamPump& pump_;
};

// One HapticStream call on gRPC's callback API: ToolStream (streams.hpp) takes the poses and
// decides what to send, this reads the poses and writes v1::ToolFeedback messages.
class HapticStreamReactor final : public grpc::ServerBidiReactor<v1::ToolPose, v1::ToolFeedback>,
                                  public ToolStream {
 public:
  HapticStreamReactor(const ServiceContext& sc, StreamPump& pump, grpc::CallbackServerContext* ctx)
      : ToolStream(pump, *sc.registry, ctx->peer()), peer_(ctx->peer()) {}

  // Holds itself until OnDone and waits for the first pose.
  void begin(std::shared_ptr<HapticStreamReactor> self) {
    ToolStream::begin(std::move(self));
    StartRead(&pose_);
  }

  void OnReadDone(bool ok) override {
    if (pose_read(ok, pose_)) StartRead(&pose_);
  }
  void OnWriteDone(bool ok) override { write_done(ok); }
  void OnCancel() override { cancelled(); }
  void OnDone() override { done(); }  // may destroy this

 private:
  void start_write(const Frame& frame, uint64_t tool_id, uint64_t skipped) override {
    tool_feedback_to_proto(frame, tool_id, skipped, &msg_);
    StartWrite(&msg_);
  }

  void end_call(const Error& status) override {
    if (!status.ok() && status.code != Code::Cancelled)
      spdlog::debug("HapticStream from {}: {}", peer_, status.message);
    Finish(to_status(status));
  }

  const std::string peer_;
  v1::ToolPose pose_;      // the read in flight (reads are serial)
  v1::ToolFeedback msg_;   // the message being written (one per stream)
};

class InteractionServiceImpl final
    : public v1::InteractionService::WithCallbackMethod_HapticStream<v1::InteractionService::Service> {
 public:
  InteractionServiceImpl(ServiceContext sc, StreamPump& pump) : sc_(std::move(sc)), pump_(pump) {}
  grpc::Status Grab(grpc::ServerContext* c, const v1::GrabRequest* r, v1::GrabResponse* o) override {
    return guarded(sc_, "Grab", c, [&] { return sc_.registry->grab(*r, o); });
  }
  grpc::Status MoveGrab(grpc::ServerContext* c, const v1::MoveGrabRequest* r, v1::MoveGrabResponse* o) override {
    return guarded(sc_, "MoveGrab", c, [&] { return sc_.registry->move_grab(*r, o); });
  }
  grpc::Status Release(grpc::ServerContext* c, const v1::ReleaseRequest* r, v1::ReleaseResponse*) override {
    return guarded(sc_, "Release", c, [&] { return sc_.registry->release(*r); });
  }

  grpc::ServerBidiReactor<v1::ToolPose, v1::ToolFeedback>* HapticStream(grpc::CallbackServerContext* c) override {
    using Reactor = grpc::ServerBidiReactor<v1::ToolPose, v1::ToolFeedback>;
    if (grpc::Status s = sc_.check(c); !s.ok()) {
      spdlog::warn("HapticStream from {}: {}", c->peer(), s.error_message());
      return new Refused<Reactor>(s);
    }
    try {
      auto reactor = std::make_shared<HapticStreamReactor>(sc_, pump_, c);
      reactor->begin(reactor);
      return reactor.get();
    } catch (const std::exception& e) {
      spdlog::error("HapticStream: internal error: {}", e.what());
      return new Refused<Reactor>(grpc::Status(grpc::StatusCode::INTERNAL, std::string("HapticStream: ") + e.what()));
    }
  }

 private:
  ServiceContext sc_;
  StreamPump& pump_;
};

class SnapshotServiceImpl final : public v1::SnapshotService::Service {
 public:
  explicit SnapshotServiceImpl(ServiceContext sc) : sc_(std::move(sc)) {}
  grpc::Status SaveSnapshot(grpc::ServerContext* c, const v1::SaveSnapshotRequest* r, v1::SaveSnapshotResponse* o) override {
    return guarded(sc_, "SaveSnapshot", c, [&] { return sc_.registry->save_snapshot(*r, o); });
  }
  grpc::Status RestoreSnapshot(grpc::ServerContext* c, const v1::RestoreSnapshotRequest* r, v1::Scene* o) override {
    return guarded(sc_, "RestoreSnapshot", c, [&] { return sc_.registry->restore_snapshot(*r, o); });
  }
  grpc::Status ListSnapshots(grpc::ServerContext* c, const v1::ListSnapshotsRequest*, v1::ListSnapshotsResponse* o) override {
    return guarded(sc_, "ListSnapshots", c, [&] { return sc_.registry->list_snapshots(o); });
  }

 private:
  ServiceContext sc_;
};

std::vector<std::string> split_path(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ':');)
    if (!item.empty()) out.push_back(item);
  return out;
}

Error read_file(const std::string& flag, const std::string& path, std::string* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Error::make(Code::InvalidArgument, fmt::format("--{} '{}' cannot be read", flag, path));
  std::stringstream ss;
  ss << f.rdbuf();
  *out = ss.str();
  return {};
}

// Reflection (grpc.reflection.*) under --reflection token | off: a call without the token, or
// every call, is cancelled once its metadata arrives (the plugin's handlers cannot be wrapped).
class ReflectionGate final : public grpc::experimental::Interceptor {
 public:
  ReflectionGate(grpc::experimental::ServerRpcInfo* info, const ServiceContext* sc, bool off)
      : info_(info), sc_(sc), off_(off) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(grpc::experimental::InterceptionHookPoints::POST_RECV_INITIAL_METADATA)) {
      const grpc::Status s = off_ ? grpc::Status(grpc::StatusCode::UNIMPLEMENTED, "reflection is off")
                                  : check_token(*methods->GetRecvInitialMetadata(), sc_->expected);
      if (!s.ok()) {
        spdlog::warn("{}: refused: {}", info_->method(), s.error_message());
        info_->server_context()->TryCancel();
      }
    }
    methods->Proceed();
  }

 private:
  grpc::experimental::ServerRpcInfo* info_;
  const ServiceContext* sc_;
  bool off_;
};

class ReflectionGateFactory final : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  ReflectionGateFactory(const ServiceContext* sc, bool off) : sc_(sc), off_(off) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override {
    if (std::string_view(info->method()).rfind("/grpc.reflection.", 0) != 0) return nullptr;
    return new ReflectionGate(info, sc_, off_);
  }

 private:
  const ServiceContext* sc_;
  bool off_;
};

const char* kServices[] = {"pliant.v1.SceneService", "pliant.v1.FrameService", "pliant.v1.SnapshotService",
                           "pliant.v1.InteractionService"};

}  // namespace

struct PliantServer::Impl {
  ServerOptions options;
  std::unique_ptr<SceneRegistry> registry;
  std::unique_ptr<ServiceContext> context;  // the reflection gate's
  std::unique_ptr<SceneServiceImpl> scenes;
  std::unique_ptr<FrameServiceImpl> frames;
  std::unique_ptr<SnapshotServiceImpl> snapshots;
  std::unique_ptr<InteractionServiceImpl> interaction;
  // Two threads serve every open stream; destroyed (joined) before the services.
  std::unique_ptr<StreamPump> pump;
  std::unique_ptr<grpc::Server> server;
  std::unique_ptr<MetricsEndpoint> metrics;  // --metrics-listen
  int port = 0;
  std::mutex mu;
  std::condition_variable cv;
  bool started = false;
  bool done = false;
  bool shutting_down = false;
  int written = 0;
};

PliantServer::PliantServer(ServerOptions options) : impl_(std::make_unique<Impl>()) {
  impl_->options = std::move(options);
  RegistryOptions ro;
  ro.max_scenes = impl_->options.max_scenes;
  ro.max_vertices = impl_->options.max_vertices;
  ro.max_threads = impl_->options.threads;
  ro.data_dir = impl_->options.data_dir;
  ro.max_tick_ms = impl_->options.max_tick_ms;
  ro.stuck_tick_ms = impl_->options.stuck_tick_ms;
  ro.checkpoint_ms = impl_->options.checkpoint_ms;
  ro.max_streams = impl_->options.max_streams;
  ro.max_streams_per_scene = impl_->options.max_streams_per_scene;
  ro.max_grabs_per_scene = impl_->options.max_grabs_per_scene;
  // A stuck tick turns the scene services NOT_SERVING (not during shutdown: that is final).
  ro.on_health = [impl = impl_.get()](bool serving) {
    std::lock_guard lk(impl->mu);
    if (impl->shutting_down || !impl->server) return;
    if (auto* health = impl->server->GetHealthCheckService()) {
      health->SetServingStatus(serving);
      for (const char* s : kServices) health->SetServingStatus(s, serving);
    }
  };
  // Without --model-path: $PLIANT_MODEL_PATH, then the model set (the installed
  // share/pliant/meshes next to the program, else the source tree's meshes/).
  ro.model_path = impl_->options.model_path.empty() ? default_model_path()
                                                     : split_path(impl_->options.model_path);
  {
    std::string joined;
    for (const std::string& d : ro.model_path) joined += (joined.empty() ? "" : ":") + d;
    spdlog::info("model path: {}", joined);
  }
  impl_->registry = std::make_unique<SceneRegistry>(std::move(ro));
}

PliantServer::~PliantServer() { shutdown(); }

SceneRegistry& PliantServer::registry() { return *impl_->registry; }
int PliantServer::port() const { return impl_->port; }
int PliantServer::metrics_port() const { return impl_->metrics ? impl_->metrics->port() : 0; }

Error PliantServer::start() {
  auto& o = impl_->options;
  if (!o.data_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(o.data_dir, ec);
    if (ec)
      return Error::make(Code::InvalidArgument,
                         fmt::format("--data-dir '{}' cannot be created: {}", o.data_dir, ec.message()));
    if (o.restore) {
      int n = impl_->registry->restore_from_data_dir();
      if (n > 0) spdlog::info("restored {} scene(s) from {}", n, o.data_dir);
    }
  }
  if (!o.metrics_listen.empty()) {
    if (Error e = MetricsEndpoint::start(o.metrics_listen, impl_->registry.get(), &impl_->metrics); !e.ok()) return e;
    spdlog::info("metrics on http://{}/metrics (port {})", o.metrics_listen, impl_->metrics->port());
  }
  std::shared_ptr<grpc::ServerCredentials> creds = grpc::InsecureServerCredentials();
  if (!o.tls_cert.empty()) {
    grpc::SslServerCredentialsOptions ssl;
    grpc::SslServerCredentialsOptions::PemKeyCertPair pair;
    if (Error e = read_file("tls-key", o.tls_key, &pair.private_key); !e.ok()) return e;
    if (Error e = read_file("tls-cert", o.tls_cert, &pair.cert_chain); !e.ok()) return e;
    ssl.pem_key_cert_pairs.push_back(std::move(pair));
    creds = grpc::SslServerCredentials(ssl);
  }
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  ServiceContext sc{impl_->registry.get(), !o.token.empty(), sha256("Bearer " + o.token)};
  impl_->context = std::make_unique<ServiceContext>(sc);
  impl_->scenes = std::make_unique<SceneServiceImpl>(sc);
  impl_->pump = std::make_unique<StreamPump>(2);
  impl_->frames = std::make_unique<FrameServiceImpl>(sc, *impl_->pump);
  impl_->snapshots = std::make_unique<SnapshotServiceImpl>(sc);
  impl_->interaction = std::make_unique<InteractionServiceImpl>(sc, *impl_->pump);
  grpc::ServerBuilder builder;
  if (o.reflection != "open") {
    std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> gates;
    gates.push_back(std::make_unique<ReflectionGateFactory>(impl_->context.get(), o.reflection == "off"));
    builder.experimental().SetInterceptorCreators(std::move(gates));
  }
  builder.AddListeningPort(o.listen, creds, &impl_->port);
  builder.SetMaxReceiveMessageSize(o.max_message_mb * 1024 * 1024);
  builder.SetMaxSendMessageSize(o.max_message_mb * 1024 * 1024);
  builder.RegisterService(impl_->scenes.get());
  builder.RegisterService(impl_->frames.get());
  builder.RegisterService(impl_->snapshots.get());
  builder.RegisterService(impl_->interaction.get());
  impl_->server = builder.BuildAndStart();
  if (!impl_->server || impl_->port == 0)
    return Error::make(Code::Unavailable, fmt::format("--listen '{}': cannot bind (address in use or invalid)", o.listen));
  auto* health = impl_->server->GetHealthCheckService();
  if (health) {
    health->SetServingStatus(true);
    for (const char* s : kServices) health->SetServingStatus(s, true);
  }
  {
    std::lock_guard lk(impl_->mu);
    impl_->started = true;
  }
  impl_->registry->start_background();
  spdlog::info("pliant-server listening on {} (port {}){}{}, reflection {}", o.listen, impl_->port,
               o.tls_cert.empty() ? "" : ", TLS", o.token.empty() ? "" : ", token required", o.reflection);
  return {};
}

bool PliantServer::save_failed() const { return impl_->registry->failed_saves() > 0; }

int PliantServer::shutdown() {
  {
    std::unique_lock lk(impl_->mu);
    if (impl_->done) return impl_->written;
    if (impl_->shutting_down) {
      impl_->cv.wait(lk, [&] { return impl_->done; });
      return impl_->written;
    }
    impl_->shutting_down = true;
  }
  int written = 0;
  if (impl_->server) {
    spdlog::info("shutting down: NOT_SERVING, ending streams, saving scenes");
    if (auto* health = impl_->server->GetHealthCheckService()) {
      health->SetServingStatus(false);
      for (const char* s : kServices) health->SetServingStatus(s, false);
    }
    // Every scene's tick stops at its next sweep; calls waiting for a scene answer UNAVAILABLE.
    impl_->registry->begin_shutdown();
    // In-flight calls get kShutdownGrace to finish, then are cancelled; streams notice
    // begin_shutdown() within 100 ms and end with UNAVAILABLE.
    impl_->server->Shutdown(std::chrono::system_clock::now() + kShutdownGrace);
    impl_->server->Wait();
  }
  impl_->metrics.reset();
  written = impl_->registry->shutdown();
  {
    std::lock_guard lk(impl_->mu);
    impl_->done = true;
    impl_->written = written;
  }
  impl_->cv.notify_all();
  return written;
}

void PliantServer::wait() {
  std::unique_lock lk(impl_->mu);
  impl_->cv.wait(lk, [&] { return impl_->done; });
}

}  // namespace pliant::server
