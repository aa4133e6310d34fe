// SPDX-License-Identifier: Apache-2.0
#include "gateway.hpp"

#include "grabs.hpp"
#include "outbox.hpp"
#include "wire.hpp"

#include <civetweb.h>
#include <nlohmann/json.hpp>
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <mutex>
#include <stdexcept>
#include <thread>
#include <vector>

namespace pliant::web {

using nlohmann::json;

namespace {

constexpr int kProtocolVersion = 1;
// Frames a page that acknowledges frames may have unacknowledged (one drawn, one arriving).
constexpr uint32_t kAckWindow = 2;

const char* state_name(int s) {
  switch (s) {
    case v1::SCENE_STATE_RUNNING: return "running";
    case v1::SCENE_STATE_PAUSED: return "paused";
    case v1::SCENE_STATE_LOCKSTEP: return "lockstep";
    default: return "unspecified";
  }
}

json scene_json(const v1::Scene& s) {
  const double dt = s.spec().tick().dt();
  return json{{"id", s.scene_id()},
              {"state", state_name(s.state())},
              {"tick", s.tick()},
              {"sim_time", s.sim_time()},
              {"vertices", s.vertex_count()},
              {"tets", s.tet_count()},
              {"surface_triangles", s.surface_triangle_count()},
              {"ticks_per_second", s.ticks_per_second()},
              {"rate_hz", dt > 0 ? 1.0 / dt : 0.0},
              {"late_ticks", s.late_ticks()},
              {"pause_reason", s.pause_reason()}};
}

json error_json(const std::string& request, const std::string& code, const std::string& message) {
  return json{{"type", "error"}, {"request", request}, {"code", code}, {"message", message}};
}

// A request field that must be there with the right type; throws a message naming it.
struct BadRequest : std::runtime_error {
  using std::runtime_error::runtime_error;
};

uint64_t uint_field(const json& m, const char* name) {
  auto it = m.find(name);
  if (it == m.end()) throw BadRequest(std::string("missing field '") + name + "'");
  if (!it->is_number_unsigned()) throw BadRequest(std::string("field '") + name + "' must be a non-negative integer, got " + it->dump());
  return it->get<uint64_t>();
}

v1::Vec3 vec3_field(const json& m, const char* name) {
  auto it = m.find(name);
  if (it == m.end()) throw BadRequest(std::string("missing field '") + name + "'");
  if (!it->is_array() || it->size() != 3 || !(*it)[0].is_number() || !(*it)[1].is_number() || !(*it)[2].is_number())
    throw BadRequest(std::string("field '") + name + "' must be [x, y, z] in metres, got " + it->dump());
  v1::Vec3 v;
  v.set_x((*it)[0].get<double>());
  v.set_y((*it)[1].get<double>());
  v.set_z((*it)[2].get<double>());
  if (!std::isfinite(v.x()) || !std::isfinite(v.y()) || !std::isfinite(v.z()))
    throw BadRequest(std::string("field '") + name + "' must be finite, got " + it->dump());
  return v;
}

const char* body_kind_name(BodyKind k) {
  switch (k) {
    case BodyKind::Fluid: return "fluid";
    case BodyKind::Cloth: return "cloth";
    case BodyKind::Rope: return "rope";
    default: return "other";
  }
}

json vec3_json(const v1::Vec3& v) { return json::array({v.x(), v.y(), v.z()}); }

bool query_token_matches(const mg_connection* conn, const std::string& expected) {
  const mg_request_info* ri = mg_get_request_info(conn);
  if (!ri || !ri->query_string) return false;
  std::vector<char> buf(expected.size() + 2);
  const int n = mg_get_var(ri->query_string, std::strlen(ri->query_string), "token", buf.data(), buf.size());
  if (n < 0 || static_cast<size_t>(n) != expected.size()) return false;
  unsigned diff = 0;  // constant time in the token's length
  for (size_t i = 0; i < expected.size(); ++i) diff |= static_cast<unsigned char>(buf[i] ^ expected[i]);
  return diff == 0;
}

}  // namespace

// One browser socket: a gRPC session on the server, its grabs, its outbox and the threads that
// read frames from the server and write messages to the browser.
class Session {
 public:
  Session(Gateway::Impl& gw, client::Client& client, mg_connection* conn) : gw_(gw), client_(client), conn_(conn) {}
  ~Session() { close(); }

  void start() {
    writer_ = std::thread([this] { writer_loop(); });
    reply(json{{"type", "hello"}, {"version", kProtocolVersion}, {"server", client_.options().address}});
  }

  // One JSON control message from the browser.
  void on_text(std::string_view text);

  // Stops reading and writing and releases the socket's grabs. Called once the socket closed.
  void close();

 private:
  void reply(const json& j) { outbox_.push_control({false, j.dump()}); }
  void handle(const std::string& type, const json& m);
  void subscribe(const json& m);
  void unsubscribe();
  void stream_loop(std::shared_ptr<client::FrameStream> stream, uint32_t subscription, std::string scene,
                   uint32_t vertices, Encoding encoding, std::vector<ParticleBody> bodies);
  void writer_loop();
  std::string scene_of(const json& m) const {
    auto it = m.find("scene");
    if (it != m.end() && it->is_string()) return it->get<std::string>();
    std::lock_guard lock(mu_);
    if (scene_.empty()) throw BadRequest("no 'scene' given and no scene subscribed");
    return scene_;
  }
  void release_grab(const std::string& scene, uint64_t id);

  Gateway::Impl& gw_;
  client::Client& client_;
  mg_connection* conn_;
  Outbox outbox_;
  GrabSet grabs_;
  std::thread writer_;
  std::atomic<bool> closed_{false};

  mutable std::mutex mu_;  // the subscription below
  std::string scene_;
  uint32_t subscription_ = 0;
  std::thread stream_thread_;
  std::shared_ptr<client::FrameStream> stream_;
};

struct Gateway::Impl {
  GatewayOptions options;
  std::unique_ptr<client::Client> client;
  mg_context* ctx = nullptr;
  int port = 0;
  std::mutex mu;
  std::vector<Session*> sessions;  // open sockets (owned through the connection's user data)
  std::atomic<uint64_t> sockets_total{0}, sockets_refused{0}, frames_sent{0}, frames_replaced{0},
      grabs_released_on_close{0};

  static int on_connect(const mg_connection* conn, void* self) {
    auto* gw = static_cast<Impl*>(self);
    if (!gw->options.web_token.empty() && !query_token_matches(conn, gw->options.web_token)) {
      ++gw->sockets_refused;
      const mg_request_info* ri = mg_get_request_info(conn);
      spdlog::warn("web: refused a socket from {}: missing or wrong web token", ri ? ri->remote_addr : "?");
      return 1;  // civetweb answers and closes
    }
    return 0;
  }
  static void on_ready(mg_connection* conn, void* self) {
    auto* gw = static_cast<Impl*>(self);
    auto* s = new Session(*gw, *gw->client, conn);
    mg_set_user_connection_data(conn, s);
    {
      std::lock_guard lock(gw->mu);
      gw->sessions.push_back(s);
    }
    ++gw->sockets_total;
    const mg_request_info* ri = mg_get_request_info(conn);
    spdlog::info("web: socket open from {}", ri ? ri->remote_addr : "?");
    s->start();
  }
  static int on_data(mg_connection* conn, int flags, char* data, size_t len, void*) {
    auto* s = static_cast<Session*>(mg_get_user_connection_data(conn));
    const int opcode = flags & 0x0f;
    if (opcode == MG_WEBSOCKET_OPCODE_CONNECTION_CLOSE) return 0;
    if (s && opcode == MG_WEBSOCKET_OPCODE_TEXT) s->on_text(std::string_view(data, len));
    return 1;
  }
  static void on_close(const mg_connection* conn, void* self) {
    auto* gw = static_cast<Impl*>(self);
    auto* s = static_cast<Session*>(mg_get_user_connection_data(conn));
    if (!s) return;
    {
      std::lock_guard lock(gw->mu);
      std::erase(gw->sessions, s);
    }
    delete s;  // closes: stops its threads, releases its grabs
    spdlog::info("web: socket closed");
  }
  static int on_log(const mg_connection*, const char* message) {
    spdlog::warn("web: civetweb: {}", message);
    return 1;
  }
};

void Session::on_text(std::string_view text) {
  json m;
  try {
    m = json::parse(text);
  } catch (const json::exception& e) {
    reply(error_json("", "INVALID_ARGUMENT", std::string("message is not JSON: ") + e.what()));
    return;
  }
  if (!m.is_object() || !m.contains("type") || !m["type"].is_string()) {
    reply(error_json("", "INVALID_ARGUMENT", "message needs a string field 'type'"));
    return;
  }
  const std::string type = m["type"];
  try {
    handle(type, m);
  } catch (const BadRequest& e) {
    reply(error_json(type, "INVALID_ARGUMENT", e.what()));
  } catch (const json::exception& e) {
    reply(error_json(type, "INVALID_ARGUMENT", e.what()));
  }
}

void Session::handle(const std::string& type, const json& m) {
  auto fail = [&](const client::Status& st) { reply(error_json(type, st.code_name(), st.message)); };
  if (type == "list") {
    auto r = client_.list_scenes();
    if (!r.ok()) return fail(r.status);
    json scenes = json::array();
    for (const auto& s : *r) scenes.push_back(scene_json(s));
    reply(json{{"type", "scenes"}, {"scenes", scenes}});
  } else if (type == "subscribe") {
    subscribe(m);
  } else if (type == "unsubscribe") {
    unsubscribe();
    reply(json{{"type", "unsubscribed"}});
  } else if (type == "grab") {
    const std::string scene = scene_of(m);
    v1::GrabRequest req;
    req.set_scene_id(scene);
    const uint64_t vertex = uint_field(m, "vertex");
    if (vertex > INT32_MAX) throw BadRequest("field 'vertex' out of range: " + std::to_string(vertex));
    req.set_vertex(static_cast<int32_t>(vertex));
    // A particle body's name: `vertex` is then one of its particles (the server checks both).
    std::string body;
    if (m.contains("body")) {
      if (!m["body"].is_string()) throw BadRequest("field 'body' must be a particle body's name, got " + m["body"].dump());
      body = m["body"].get<std::string>();
      req.set_body(body);
    }
    if (m.contains("target")) *req.mutable_target() = vec3_field(m, "target");
    if (m.contains("compliance")) {
      if (!m["compliance"].is_number() || m["compliance"].get<double>() < 0)
        throw BadRequest("field 'compliance' must be a number >= 0 (m/N), got " + m["compliance"].dump());
      req.set_compliance(m["compliance"].get<double>());
    }
    auto r = client_.grab(req);
    if (!r.ok()) return fail(r.status);
    grabs_.add(scene, r->grab_id());
    json grabbed{{"type", "grabbed"}, {"scene", scene}, {"grab_id", r->grab_id()}, {"vertex", vertex},
                 {"first_tick", r->first_tick()}};
    if (!body.empty()) grabbed["body"] = body;
    reply(grabbed);
  } else if (type == "move") {
    const std::string scene = scene_of(m);
    v1::MoveGrabRequest req;
    req.set_scene_id(scene);
    req.set_grab_id(uint_field(m, "grab_id"));
    *req.mutable_target() = vec3_field(m, "target");
    auto r = client_.move_grab(req);
    if (!r.ok()) return fail(r.status);
    reply(json{{"type", "moved"}, {"grab_id", req.grab_id()}, {"first_tick", r->first_tick()},
               {"force", vec3_json(r->force())}});
  } else if (type == "release") {
    const std::string scene = scene_of(m);
    const uint64_t id = uint_field(m, "grab_id");
    auto st = client_.release(scene, id);
    grabs_.remove(scene, id);
    if (!st.ok()) return fail(st);
    reply(json{{"type", "released"}, {"grab_id", id}});
  } else if (type == "pause" || type == "resume" || type == "reset") {
    const std::string scene = scene_of(m);
    auto r = type == "pause" ? client_.pause_scene(scene)
             : type == "resume" ? client_.resume_scene(scene)
                                : client_.reset_scene(scene);
    if (!r.ok()) return fail(r.status);
    reply(json{{"type", "scene"}, {"scene", scene_json(*r)}});
  } else if (type == "ack") {
    uint64_t n = 1;
    if (m.contains("frames")) n = uint_field(m, "frames");
    outbox_.grant(static_cast<uint32_t>(std::min<uint64_t>(n, kAckWindow)));
  } else if (type == "ping") {
    reply(json{{"type", "pong"}});
  } else {
    reply(error_json(type, "INVALID_ARGUMENT",
                     "unknown message type '" + type +
                         "' (list, subscribe, unsubscribe, ack, grab, move, release, pause, resume, reset, ping)"));
  }
}

void Session::subscribe(const json& m) {
  auto it = m.find("scene");
  if (it == m.end() || !it->is_string() || it->get<std::string>().empty())
    throw BadRequest("subscribe needs a string field 'scene'");
  const std::string scene = *it;
  double rate = 60;
  if (m.contains("max_rate_hz")) {
    if (!m["max_rate_hz"].is_number() || m["max_rate_hz"].get<double>() < 0)
      throw BadRequest("field 'max_rate_hz' must be a number >= 0 (0: every frame), got " + m["max_rate_hz"].dump());
    rate = m["max_rate_hz"].get<double>();
  }
  Encoding encoding = Encoding::Float32;
  if (m.contains("encoding")) {
    const json& e = m["encoding"];
    if (e == "float32") encoding = Encoding::Float32;
    else if (e == "uint16") encoding = Encoding::Quantized16;
    else throw BadRequest("field 'encoding' must be \"float32\" or \"uint16\", got " + e.dump());
  }

  bool ack = false;
  if (m.contains("ack")) {
    if (!m["ack"].is_boolean()) throw BadRequest("field 'ack' must be true or false, got " + m["ack"].dump());
    ack = m["ack"];
  }

  unsubscribe();
  outbox_.clear_frame(ack ? kAckWindow : 0);
  auto topo = client_.topology(scene);
  if (!topo.ok()) {
    reply(error_json("subscribe", topo.status.code_name(), topo.status.message));
    return;
  }
  SurfaceTopology surface;
  try {
    surface = surface_topology(*topo);
  } catch (const std::invalid_argument& e) {
    reply(error_json("subscribe", "INTERNAL", e.what()));
    return;
  }
  if (!surface.bodies.empty()) {
    // Sizes for drawing (fluid spacing, cloth and rope thickness) come from the spec in use.
    auto sc = client_.get_scene(scene);
    if (sc.ok()) set_body_sizes(surface, sc->spec());
    else spdlog::warn("web: scene '{}': no spec for the bodies' sizes: {}", scene, sc.status.to_string());
  }
  json bodies = json::array();
  for (const auto& b : surface.bodies)
    bodies.push_back(json{{"name", b.name}, {"kind", body_kind_name(b.kind)}, {"particles", b.particle_count()},
                          {"max_particles", std::max(b.max_particles, b.particle_count())},
                          {"triangles", b.triangles.size() / 3}, {"pinned", b.pinned.size()},
                          // the float's value to 7 digits (0.005, not 0.004999999888)
                          {"size", std::stod(fmt::format("{:.7g}", b.size))}});
  std::lock_guard lock(mu_);
  const uint32_t sub = ++subscription_;
  scene_ = scene;
  const uint32_t n = surface.surface_vertex_count();
  reply(json{{"type", "subscribed"},
             {"scene", scene},
             {"subscription", sub},
             {"surface_vertices", n},
             {"surface_triangles", surface.triangles.size() / 3},
             {"body_vertices", surface.body_vertex_count},
             {"encoding", encoding == Encoding::Float32 ? "float32" : "uint16"},
             {"max_rate_hz", rate},
             {"ack", ack},
             {"bodies", bodies}});
  outbox_.push_control({true, encode_topology(surface, sub)});

  v1::StreamFramesRequest req;
  req.set_scene_id(scene);
  req.set_surface_only(true);
  req.set_max_rate_hz(rate);
  stream_ = client_.stream_frames(req);
  std::vector<ParticleBody> frame_bodies = surface.bodies;
  for (auto& b : frame_bodies) {  // the frame encoder needs names and counts only
    b.triangles.clear();
    b.pinned.clear();
  }
  stream_thread_ = std::thread([this, stream = stream_, sub, scene, n, encoding, fb = std::move(frame_bodies)]() mutable {
    stream_loop(stream, sub, scene, n, encoding, std::move(fb));
  });
  spdlog::info("web: subscribed to '{}' ({} surface vertices, {} particle bodies, {}, at most {} Hz)", scene, n,
               surface.bodies.size(), encoding == Encoding::Float32 ? "float32" : "uint16", rate);
}

void Session::unsubscribe() {
  std::thread t;
  std::string scene;
  {
    std::lock_guard lock(mu_);
    if (stream_) stream_->cancel();
    t = std::move(stream_thread_);
    scene = scene_;
    scene_.clear();
  }
  if (t.joinable()) t.join();
  {
    std::lock_guard lock(mu_);
    stream_.reset();
  }
  outbox_.clear_frame();
  if (!scene.empty()) grabs_.release_all([this](const std::string& s, uint64_t id) { release_grab(s, id); }, scene);
}

void Session::stream_loop(std::shared_ptr<client::FrameStream> stream, uint32_t subscription, std::string scene,
                          uint32_t vertices, Encoding encoding, std::vector<ParticleBody> bodies) {
  v1::Frame frame;
  while (stream->next(&frame)) {
    try {
      if (outbox_.put_frame(encode_frame(frame, subscription, encoding, vertices, bodies))) ++gw_.frames_replaced;
    } catch (const std::invalid_argument& e) {
      spdlog::error("web: scene '{}': {}", scene, e.what());
      break;
    }
  }
  const client::Status st = stream->finish();
  if (closed_ || stream->cancelled()) return;  // we unsubscribed or the socket closed
  spdlog::info("web: stream of '{}' ended: {}", scene, st.to_string());
  reply(json{{"type", "ended"},
             {"scene", scene},
             {"subscription", subscription},
             {"code", st.code_name()},
             {"message", st.ok() ? "the stream ended" : st.message}});
}

void Session::writer_loop() {
  while (!closed_) {
    auto m = outbox_.take(std::chrono::milliseconds(200));
    if (!m) continue;
    const int opcode = m->binary ? MG_WEBSOCKET_OPCODE_BINARY : MG_WEBSOCKET_OPCODE_TEXT;
    if (mg_websocket_write(conn_, opcode, m->bytes.data(), m->bytes.size()) <= 0) {
      // The browser went away or stopped reading past the timeout: nothing more is sent; the
      // socket's close releases the rest.
      spdlog::warn("web: a socket write failed; dropping what is left for it");
      outbox_.close();
      break;
    }
    if (m->binary && !m->bytes.empty() && m->bytes[0] == static_cast<char>(kKindFrame)) ++gw_.frames_sent;
  }
}

void Session::release_grab(const std::string& scene, uint64_t id) {
  const client::Status st = client_.release(scene, id);
  if (st.ok()) spdlog::info("web: released grab {} on '{}'", id, scene);
  else if (st.code != 5) spdlog::warn("web: releasing grab {} on '{}': {}", id, scene, st.to_string());
}

void Session::close() {
  if (closed_.exchange(true)) return;
  outbox_.close();
  unsubscribe();
  if (writer_.joinable()) writer_.join();
  const size_t n = grabs_.release_all([this](const std::string& s, uint64_t id) { release_grab(s, id); });
  gw_.grabs_released_on_close += n;
}

Gateway::Gateway(GatewayOptions options) : impl_(std::make_unique<Impl>()) { impl_->options = std::move(options); }

Gateway::~Gateway() { stop(); }

void Gateway::start() {
  auto& o = impl_->options;
  // The features that initialised: Debian 12's civetweb 1.15 loads OpenSSL at run time through
  // the 1.1 API, which OpenSSL 3 lacks (SSL_get_peer_certificate), so TLS is usually missing.
  static const unsigned init = mg_init_library(MG_FEATURES_WEBSOCKET | MG_FEATURES_SSL);
  if (!(init & MG_FEATURES_WEBSOCKET)) throw std::runtime_error("this civetweb was built without WebSockets");
  if (!o.tls_cert.empty() && !(init & MG_FEATURES_SSL))
    throw std::runtime_error("--tls-cert: this civetweb could not load OpenSSL (Debian 12's civetweb 1.15 needs "
                             "OpenSSL 1.1); terminate TLS in a reverse proxy in front of pliant-web (docs/deploy.md)");
  if (!o.tls_cert.empty() && !std::filesystem::is_regular_file(o.tls_cert))
    throw std::runtime_error("--tls-cert '" + o.tls_cert + "' is not a readable file");
  namespace fs = std::filesystem;
  if (o.web_root.empty() || !fs::is_regular_file(fs::path(o.web_root) / "index.html"))
    throw std::runtime_error("--web-root '" + o.web_root + "' has no index.html");
  if (!fs::is_regular_file(fs::path(o.three_dir) / "three.module.js"))
    throw std::runtime_error("--three-dir '" + o.three_dir + "' has no three.module.js (Debian package libjs-three)");
  const auto colon = o.listen.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == o.listen.size())
    throw std::runtime_error("--listen must be HOST:PORT, got '" + o.listen + "'");

  impl_->client = std::make_unique<client::Client>(o.server);
  const std::string ports = o.listen + (o.tls_cert.empty() ? "" : "s");
  const std::string rewrite = "/three=" + fs::absolute(o.three_dir).string();
  const std::string root = fs::absolute(o.web_root).string();
  const std::string threads = std::to_string(o.threads);
  std::vector<const char*> opts = {"listening_ports", ports.c_str(),
                                   "document_root", root.c_str(),
                                   "url_rewrite_patterns", rewrite.c_str(),
                                   "num_threads", threads.c_str(),
                                   "enable_directory_listing", "no",
                                   "enable_websocket_ping_pong", "yes",
                                   "websocket_timeout_ms", "10000",
                                   // civetweb writes a WebSocket frame's header and payload in
                                   // two writes; with Nagle's algorithm the payload waits for the
                                   // peer's ACK of the header, which an acknowledging page's
                                   // kernel delays (about 40 ms) to piggyback on its next ack.
                                   "tcp_nodelay", "1"};
  if (!o.tls_cert.empty()) {
    opts.push_back("ssl_certificate");
    opts.push_back(o.tls_cert.c_str());
  }
  opts.push_back(nullptr);
  mg_callbacks cb{};
  cb.log_message = &Impl::on_log;
  impl_->ctx = mg_start(&cb, impl_.get(), opts.data());
  if (!impl_->ctx) throw std::runtime_error("cannot listen on " + ports + " (port in use, or bad address)");
  mg_set_websocket_handler(impl_->ctx, "/ws", &Impl::on_connect, &Impl::on_ready, &Impl::on_data, &Impl::on_close,
                           impl_.get());
  mg_server_port sp[4];
  const int n = mg_get_server_ports(impl_->ctx, 4, sp);
  impl_->port = n > 0 ? sp[0].port : 0;
  spdlog::info("web: page on {}://{}:{}/ (socket /ws{}), pliant-server at {}", o.tls_cert.empty() ? "http" : "https",
               o.listen.substr(0, colon), impl_->port, o.web_token.empty() ? "" : ", web token required",
               o.server.address);
}

void Gateway::stop() {
  if (!impl_->ctx) return;
  mg_stop(impl_->ctx);  // closes every socket: on_close runs for each
  impl_->ctx = nullptr;
}

int Gateway::port() const { return impl_->port; }
bool Gateway::tls() const { return !impl_->options.tls_cert.empty(); }

GatewayStats Gateway::stats() const {
  GatewayStats s;
  {
    std::lock_guard lock(impl_->mu);
    s.sockets_open = impl_->sessions.size();
  }
  s.sockets_total = impl_->sockets_total;
  s.sockets_refused = impl_->sockets_refused;
  s.frames_sent = impl_->frames_sent;
  s.frames_replaced = impl_->frames_replaced;
  s.grabs_released_on_close = impl_->grabs_released_on_close;
  return s;
}

}  // namespace pliant::web
