// SPDX-License-Identifier: Apache-2.0
// pliant-web end to end: the real pliant-server and pliant-web on free loopback ports, a
// lockstep scene, and a small WebSocket client (civetweb's) speaking docs/web.md: the topology
// comes first, then every stepped tick arrives or is counted as skipped; a grab pulls the body;
// a socket that closes releases its grabs; a wrong web token is refused; particle bodies (a rope
// and a cloth) travel in the topology and every frame, and a grab by body name pulls a particle.
#include "pliant/client/client.hpp"
#include "wire.hpp"

#include <civetweb.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <csignal>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <regex>
#include <sstream>
#include <sys/wait.h>
#include <thread>
#include <unistd.h>

namespace fs = std::filesystem;
using nlohmann::json;
using namespace std::chrono_literals;

namespace {

std::string read_text(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// A program in a child process, its output in a log file; the port is read from its
// "listening on ... (port N)" line.
class Process {
 public:
  Process(std::vector<std::string> args, fs::path log) : log_(std::move(log)) {
    pid_ = fork();
    if (pid_ == 0) {
      FILE* f = std::fopen(log_.c_str(), "w");
      dup2(fileno(f), 1);
      dup2(fileno(f), 2);
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(argv[0], argv.data());
      _exit(127);
    }
    const std::regex port_re(R"(listening on .*\(port (\d+)\))");
    for (int i = 0; i < 1500 && port_ == 0; ++i) {
      std::smatch m;
      const std::string text = read_text(log_);
      if (std::regex_search(text, m, port_re)) port_ = std::stoi(m[1]);
      else std::this_thread::sleep_for(10ms);
    }
  }
  ~Process() {
    if (pid_ > 0) {
      kill(pid_, SIGTERM);
      waitpid(pid_, nullptr, 0);
    }
  }
  int port() const { return port_; }
  std::string log() const { return read_text(log_); }

 private:
  fs::path log_;
  pid_t pid_ = -1;
  int port_ = 0;
};

// A WebSocket client that queues what it receives.
class Socket {
 public:
  struct Message {
    bool binary;
    std::string data;
  };

  Socket(int port, const std::string& path) {
    static const unsigned features = mg_init_library(MG_FEATURES_WEBSOCKET);
    (void)features;
    char err[256] = {0};
    conn_ = mg_connect_websocket_client("127.0.0.1", port, 0, err, sizeof err, path.c_str(), nullptr, &on_data,
                                        &on_close, this);
    error_ = err;
  }
  ~Socket() { close(); }
  bool ok() const { return conn_ != nullptr; }
  const std::string& error() const { return error_; }

  void send(const json& j) {
    const std::string s = j.dump();
    mg_websocket_client_write(conn_, MG_WEBSOCKET_OPCODE_TEXT, s.data(), s.size());
  }
  // The next message within the timeout, or nullopt.
  std::optional<Message> next(std::chrono::milliseconds timeout = 5000ms) {
    std::unique_lock lock(mu_);
    cv_.wait_for(lock, timeout, [&] { return !queue_.empty(); });
    if (queue_.empty()) return std::nullopt;
    Message m = std::move(queue_.front());
    queue_.pop_front();
    return m;
  }
  // The next JSON reply of this type (other messages before it are dropped).
  std::optional<json> next_json(const std::string& type, std::chrono::milliseconds timeout = 5000ms) {
    const auto until = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < until) {
      auto m = next(std::chrono::duration_cast<std::chrono::milliseconds>(until - std::chrono::steady_clock::now()));
      if (!m) break;
      if (m->binary) continue;
      json j = json::parse(m->data);
      if (j["type"] == type) return j;
      if (j["type"] == "error") ADD_FAILURE() << "error while waiting for " << type << ": " << j.dump();
    }
    return std::nullopt;
  }
  void close() {
    if (conn_) mg_close_connection(conn_);
    conn_ = nullptr;
  }
  bool closed_by_peer() const { return closed_; }

 private:
  static int on_data(mg_connection*, int flags, char* data, size_t len, void* self) {
    auto* s = static_cast<Socket*>(self);
    const int op = flags & 0x0f;
    if (op == MG_WEBSOCKET_OPCODE_TEXT || op == MG_WEBSOCKET_OPCODE_BINARY) {
      std::lock_guard lock(s->mu_);
      s->queue_.push_back({op == MG_WEBSOCKET_OPCODE_BINARY, std::string(data, len)});
      s->cv_.notify_all();
    }
    return 1;
  }
  static void on_close(const mg_connection*, void* self) { static_cast<Socket*>(self)->closed_ = true; }

  mg_connection* conn_ = nullptr;
  std::string error_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Message> queue_;
  std::atomic<bool> closed_{false};
};

// beam1 clamped at x <= 1 mm, lockstep, 2 substeps x 4 iterations.
pliant::v1::CreateSceneRequest lockstep_beam(const std::string& id) {
  pliant::v1::CreateSceneRequest req;
  req.set_scene_id(id);
  auto* spec = req.mutable_spec();
  spec->mutable_mesh()->set_builtin("beam1");
  pliant::client::clamp_below_x(*spec, 0.001);
  spec->mutable_tick()->set_mode(pliant::v1::TICK_MODE_LOCKSTEP);
  spec->mutable_solver()->set_substeps(2);
  spec->mutable_solver()->set_iterations(4);
  return req;
}

class WebGateway : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("pliant_web_" + std::to_string(getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_ / "data");
    server_ = std::make_unique<Process>(
        std::vector<std::string>{PLIANT_SERVER_BIN, "--listen", "127.0.0.1:0", "--data-dir", (dir_ / "data").string(),
                                 "--log-level", "info"},
        dir_ / "server.log");
    ASSERT_GT(server_->port(), 0) << server_->log();
    address_ = "127.0.0.1:" + std::to_string(server_->port());
    web_ = std::make_unique<Process>(
        std::vector<std::string>{PLIANT_WEB_BIN, "--listen", "127.0.0.1:0", "--address", address_, "--web-token",
                                 "sesame", "--web-root", PLIANT_WEB_ROOT},
        dir_ / "web.log");
    ASSERT_GT(web_->port(), 0) << web_->log();

    pliant::client::ConnectOptions o;
    o.address = address_;
    client_ = std::make_unique<pliant::client::Client>(o);
    auto r = client_->create_scene(lockstep_beam("web"));
    ASSERT_TRUE(r.ok()) << r.status.to_string();
  }
  void TearDown() override {
    web_.reset();
    server_.reset();
    fs::remove_all(dir_);
  }

  fs::path dir_;
  std::unique_ptr<Process> server_, web_;
  std::string address_;
  std::unique_ptr<pliant::client::Client> client_;
};

TEST_F(WebGateway, TopologyFirstThenEveryTickOrACountedSkip) {
  Socket ws(web_->port(), "/ws?token=sesame");
  ASSERT_TRUE(ws.ok()) << ws.error();
  ASSERT_TRUE(ws.next_json("hello"));
  ws.send({{"type", "subscribe"}, {"scene", "web"}, {"max_rate_hz", 0}});
  auto sub = ws.next_json("subscribed");
  ASSERT_TRUE(sub);
  auto topo_msg = ws.next();
  ASSERT_TRUE(topo_msg && topo_msg->binary) << "the topology follows the subscribe reply";
  uint32_t subscription = 0;
  const auto topo = pliant::web::decode_topology(topo_msg->data, &subscription);
  EXPECT_EQ(subscription, (*sub)["subscription"].get<uint32_t>());
  const auto server_topo = client_->topology("web");
  ASSERT_TRUE(server_topo.ok());
  EXPECT_EQ(topo.surface_vertex_count(), static_cast<uint32_t>(server_topo->surface_vertices_size()));
  EXPECT_EQ(topo.triangles.size(), static_cast<size_t>(server_topo->surface_triangles_size()));
  EXPECT_FALSE(topo.fixed.empty()) << "the clamped end is on the surface";

  // The tip: the surface vertex farthest along x.
  uint32_t tip = 0;
  for (uint32_t i = 0; i < topo.surface_vertex_count(); ++i)
    if (topo.rest_positions[3 * i] > topo.rest_positions[3 * tip]) tip = i;
  const float tip_rest_y = topo.rest_positions[3 * tip + 1];

  constexpr int kTicks = 40;
  for (int i = 0; i < kTicks; ++i) ASSERT_TRUE(client_->step("web", 1).ok());
  std::vector<pliant::web::FrameHeader> frames;
  std::vector<float> last_positions;
  while (frames.empty() || frames.back().tick < kTicks) {
    auto m = ws.next();
    ASSERT_TRUE(m) << "no frame for tick " << kTicks << " (last " << (frames.empty() ? 0 : frames.back().tick) << ")";
    if (!m->binary) continue;
    frames.push_back(pliant::web::decode_frame_header(m->data));
    last_positions = pliant::web::decode_frame_positions(m->data);
    EXPECT_EQ(frames.back().vertex_count, topo.surface_vertex_count());
  }
  for (size_t i = 1; i < frames.size(); ++i)
    EXPECT_EQ(frames[i].tick - frames[i - 1].tick, 1 + frames[i].skipped_frames)
        << "frame " << i << ": tick " << frames[i].tick << " after " << frames[i - 1].tick;
  EXPECT_EQ(frames.back().state, pliant::v1::SCENE_STATE_LOCKSTEP);
  EXPECT_GT(frames.back().iterations, 0u);
  EXPECT_LT(last_positions[3 * tip + 1], tip_rest_y - 1e-4f) << "the free end sags under gravity";

  // Pull the tip 2 cm above its rest position: it rises above it within a few ticks.
  const uint32_t body_tip = topo.surface_to_body[tip];
  ws.send({{"type", "grab"},
           {"vertex", body_tip},
           {"target", {topo.rest_positions[3 * tip], tip_rest_y + 0.02, topo.rest_positions[3 * tip + 2]}}});
  auto grabbed = ws.next_json("grabbed");
  ASSERT_TRUE(grabbed);
  const uint64_t grab_id = (*grabbed)["grab_id"];
  for (int i = 0; i < 20; ++i) ASSERT_TRUE(client_->step("web", 1).ok());
  uint64_t tick = 0;
  while (tick < kTicks + 20) {
    auto m = ws.next();
    ASSERT_TRUE(m) << "no frame after the grab";
    if (!m->binary) continue;
    tick = pliant::web::decode_frame_header(m->data).tick;
    last_positions = pliant::web::decode_frame_positions(m->data);
  }
  EXPECT_GT(last_positions[3 * tip + 1], tip_rest_y + 0.01f) << "the grab pulls the tip up";
  ws.send({{"type", "move"}, {"grab_id", grab_id}, {"target", {0.1, 0.0, 0.0}}});
  auto moved = ws.next_json("moved");
  ASSERT_TRUE(moved);
  EXPECT_GT((*moved)["force"][1].get<double>(), 0.0) << "the grab held the tip up: its force on the body is +y";

  // Closing the socket releases the grab: the server then no longer knows it.
  ws.close();
  pliant::v1::MoveGrabRequest mv;
  mv.set_scene_id("web");
  mv.set_grab_id(grab_id);
  mv.mutable_target()->set_x(0.1);
  int code = 0;
  for (int i = 0; i < 100 && code != 5; ++i) {
    code = client_->move_grab(mv).status.code;
    if (code != 5) std::this_thread::sleep_for(50ms);
  }
  EXPECT_EQ(code, 5) << "grab " << grab_id << " should be released (NOT_FOUND) once its socket closed";
}

// A lockstep scene with the beam, a rope hanging off its pinned first particle and a cloth
// pinned along one edge: the topology lists both, every frame carries their positions, the
// rope's free end falls under gravity, and a grab by body name pulls a rope particle.
TEST_F(WebGateway, ParticleBodiesTravelInTheTopologyAndEveryFrame) {
  pliant::v1::CreateSceneRequest req = lockstep_beam("bodies");
  auto* spec = req.mutable_spec();
  auto* rope = spec->add_bodies();
  rope->set_name("rope");
  for (double x : {0.13, 0.33}) {
    auto* pt = rope->mutable_rope()->add_points();
    pt->set_x(x);
    pt->set_y(0.0075);
    pt->set_z(0.0075);
  }
  rope->mutable_rope()->set_segments(10);
  rope->mutable_rope()->mutable_pins()->add_indices(0);
  auto* cloth = spec->add_bodies();
  cloth->set_name("sheet");
  auto* grid = cloth->mutable_cloth()->mutable_grid();
  grid->set_resolution_x(5);
  grid->set_resolution_y(4);
  grid->set_size_x(0.1);
  grid->set_size_y(0.08);
  grid->mutable_origin()->set_x(0.05);
  grid->mutable_origin()->set_y(0.1);
  for (uint32_t i = 0; i < 5; ++i) cloth->mutable_cloth()->mutable_pins()->add_indices(i);  // the first row
  auto created = client_->create_scene(req);
  ASSERT_TRUE(created.ok()) << created.status.to_string();

  Socket ws(web_->port(), "/ws?token=sesame");
  ASSERT_TRUE(ws.ok()) << ws.error();
  ws.send({{"type", "subscribe"}, {"scene", "bodies"}, {"max_rate_hz", 0}, {"encoding", "uint16"}});
  auto sub = ws.next_json("subscribed");
  ASSERT_TRUE(sub);
  ASSERT_EQ((*sub)["bodies"].size(), 2u) << sub->dump();
  EXPECT_EQ((*sub)["bodies"][0]["name"], "rope");
  EXPECT_EQ((*sub)["bodies"][0]["particles"], 11);
  EXPECT_EQ((*sub)["bodies"][0]["kind"], "rope");
  EXPECT_EQ((*sub)["bodies"][0]["pinned"], 1);
  EXPECT_EQ((*sub)["bodies"][0]["size"], 0.005) << "the default thickness in use, as the spec gives it";
  EXPECT_EQ((*sub)["bodies"][1]["name"], "sheet");
  EXPECT_EQ((*sub)["bodies"][1]["kind"], "cloth");
  auto topo_msg = ws.next();
  ASSERT_TRUE(topo_msg && topo_msg->binary);
  const auto topo = pliant::web::decode_topology(topo_msg->data);
  ASSERT_EQ(topo.bodies.size(), 2u);
  const auto& r = topo.bodies[0];
  const auto& c = topo.bodies[1];
  EXPECT_EQ(r.name, "rope");
  EXPECT_EQ(r.kind, pliant::web::BodyKind::Rope);
  EXPECT_EQ(r.particle_count(), 11u);
  EXPECT_EQ(r.pinned, (std::vector<uint32_t>{0}));
  EXPECT_TRUE(r.triangles.empty());
  EXPECT_GT(r.size, 0.0f) << "the rope's thickness in use (GetScene)";
  EXPECT_EQ(c.name, "sheet");
  EXPECT_EQ(c.kind, pliant::web::BodyKind::Cloth);
  EXPECT_EQ(c.particle_count(), 20u);
  EXPECT_EQ(c.triangles.size(), 3u * 2 * 4 * 3) << "two triangles per grid cell";
  EXPECT_EQ(c.pinned.size(), 5u);
  const float end_rest_y = r.rest_positions[3 * 10 + 1];
  const float end_rest_x = r.rest_positions[3 * 10];
  EXPECT_NEAR(end_rest_x, 0.33f, 1e-4f);

  constexpr int kTicks = 30;
  std::vector<std::vector<float>> last;
  uint64_t tick = 0, frames = 0;
  float lowest_end = end_rest_y;  // the rope's free end, over the frames
  for (uint64_t i = 1; i <= kTicks; ++i) {
    ASSERT_TRUE(client_->step("bodies", 1).ok());
    while (tick < i) {  // this tick's frame (a slow reader may be sent only the latest)
      auto m = ws.next();
      ASSERT_TRUE(m) << "no frame for tick " << i << " (last " << tick << ")";
      if (!m->binary) continue;
      const auto h = pliant::web::decode_frame_header(m->data);
      EXPECT_TRUE(h.flags & pliant::web::kFlagBodies);
      tick = h.tick;
      last = pliant::web::decode_frame_bodies(m->data);
      ASSERT_EQ(last.size(), 2u);
      ASSERT_EQ(last[0].size(), 33u);
      ASSERT_EQ(last[1].size(), 60u);
      lowest_end = std::min(lowest_end, last[0][3 * 10 + 1]);
      ++frames;
    }
  }
  EXPECT_GT(frames, 0u);
  // 30 ticks at 60 Hz (0.5 s): the free end falls (about g t^2 / 2 if the rope did not
  // hold it; the pinned end holds it to a swing, which passes the beam's tip, so it is well
  // below its start at the bottom of the swing, not at every tick).
  EXPECT_LT(lowest_end, end_rest_y - 0.02f) << "the rope's free end falls under gravity";
  EXPECT_NEAR(last[0][1], r.rest_positions[1], 1e-3f) << "the pinned end stays";
  EXPECT_NEAR(last[1][1], c.rest_positions[1], 1e-3f) << "the cloth's pinned row stays";
  EXPECT_LT(last[1][3 * 19 + 1], c.rest_positions[3 * 19 + 1] - 0.01f) << "the cloth's free corner falls";

  // Grab the rope's free end by body name and hold it 5 cm above where it started.
  ws.send({{"type", "grab"}, {"body", "rope"}, {"vertex", 10}, {"target", {end_rest_x - 0.05, end_rest_y + 0.05, 0.0075}}});
  auto grabbed = ws.next_json("grabbed");
  ASSERT_TRUE(grabbed);
  EXPECT_EQ((*grabbed)["body"], "rope");
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(client_->step("bodies", 1).ok());
  while (tick < kTicks + 10) {
    auto m = ws.next();
    ASSERT_TRUE(m) << "no frame after the grab";
    if (!m->binary) continue;
    tick = pliant::web::decode_frame_header(m->data).tick;
    last = pliant::web::decode_frame_bodies(m->data);
  }
  EXPECT_GT(last[0][3 * 10 + 1], end_rest_y + 0.03f) << "the grab pulls the rope's end up";

  // A body the scene does not have: the server's error, passed on.
  ws.send({{"type", "grab"}, {"body", "nope"}, {"vertex", 0}});
  auto e = ws.next_json("error");
  ASSERT_TRUE(e);
  EXPECT_NE((*e)["message"].get<std::string>().find("nope"), std::string::npos) << e->dump();
  ws.send({{"type", "grab"}, {"body", 3}, {"vertex", 0}});
  e = ws.next_json("error");
  ASSERT_TRUE(e);
  EXPECT_EQ((*e)["code"], "INVALID_ARGUMENT");
  EXPECT_NE((*e)["message"].get<std::string>().find("'body'"), std::string::npos) << e->dump();
}

TEST_F(WebGateway, AnAcknowledgingPageGetsTheLatestFrameNotAQueue) {
  Socket ws(web_->port(), "/ws?token=sesame");
  ASSERT_TRUE(ws.ok()) << ws.error();
  ws.send({{"type", "subscribe"}, {"scene", "web"}, {"max_rate_hz", 0}, {"ack", true}});
  ASSERT_TRUE(ws.next_json("subscribed"));
  auto topo = ws.next();
  ASSERT_TRUE(topo && topo->binary);
  // Step one tick at a time until the two frames the window allows have arrived.
  std::vector<pliant::web::FrameHeader> got;
  for (int i = 0; i < 50 && got.size() < 2; ++i) {
    ASSERT_TRUE(client_->step("web", 1).ok());
    if (auto m = ws.next(200ms); m && m->binary) got.push_back(pliant::web::decode_frame_header(m->data));
  }
  ASSERT_EQ(got.size(), 2u);
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(client_->step("web", 1).ok());
  const uint64_t last_tick = client_->get_scene("web")->tick();
  EXPECT_FALSE(ws.next(500ms)) << "no frame goes out while two are unacknowledged";
  ws.send({{"type", "ack"}});
  auto m = ws.next();
  ASSERT_TRUE(m && m->binary) << "an ack lets the latest frame go";
  const auto h = pliant::web::decode_frame_header(m->data);
  EXPECT_EQ(h.tick, last_tick);
  EXPECT_EQ(h.tick - got.back().tick, 1 + h.skipped_frames) << "the frames it replaced are counted";
}

TEST_F(WebGateway, ControlErrorsNameTheField) {
  Socket ws(web_->port(), "/ws?token=sesame");
  ASSERT_TRUE(ws.ok()) << ws.error();
  ws.send({{"type", "grab"}, {"scene", "web"}, {"vertex", -3}});
  auto e = ws.next_json("error");
  ASSERT_TRUE(e);
  EXPECT_EQ((*e)["code"], "INVALID_ARGUMENT");
  EXPECT_NE((*e)["message"].get<std::string>().find("vertex"), std::string::npos) << e->dump();
  ws.send({{"type", "subscribe"}, {"scene", "nope"}});
  e = ws.next_json("error");
  ASSERT_TRUE(e);
  EXPECT_EQ((*e)["code"], "NOT_FOUND") << e->dump();
  ws.send({{"type", "list"}});
  auto scenes = ws.next_json("scenes");
  ASSERT_TRUE(scenes);
  ASSERT_EQ((*scenes)["scenes"].size(), 1u);
  EXPECT_EQ((*scenes)["scenes"][0]["id"], "web");
}

TEST_F(WebGateway, ADeletedSceneEndsTheSubscriptionWithNotFound) {
  Socket ws(web_->port(), "/ws?token=sesame");
  ASSERT_TRUE(ws.ok()) << ws.error();
  ws.send({{"type", "subscribe"}, {"scene", "web"}});
  auto sub = ws.next_json("subscribed");
  ASSERT_TRUE(sub);
  ASSERT_TRUE(client_->delete_scene("web").ok());
  auto ended = ws.next_json("ended");
  ASSERT_TRUE(ended) << "the page is told when its scene goes away";
  EXPECT_EQ((*ended)["code"], "NOT_FOUND") << ended->dump();
  EXPECT_EQ((*ended)["scene"], "web");
  EXPECT_EQ((*ended)["subscription"], (*sub)["subscription"]);
}

TEST_F(WebGateway, AServerThatStopsEndsTheSubscriptionWithUnavailable) {
  Socket ws(web_->port(), "/ws?token=sesame");
  ASSERT_TRUE(ws.ok()) << ws.error();
  ws.send({{"type", "subscribe"}, {"scene", "web"}});
  ASSERT_TRUE(ws.next_json("subscribed"));
  // A frame from the server shows its stream is open (the gateway answers "subscribed" before
  // the server has seen the call; a call that reaches a stopping server is cancelled instead).
  bool streaming = false;
  for (int i = 0; i < 20 && !streaming; ++i) {
    ASSERT_TRUE(client_->step("web", 1).ok());
    for (auto m = ws.next(500ms); m && !streaming; m = ws.next(100ms))
      streaming = m->binary && !m->data.empty() && m->data[0] == static_cast<char>(pliant::web::kKindFrame);
  }
  ASSERT_TRUE(streaming) << "no frame reached the page";
  server_.reset();  // SIGTERM: the server ends its streams with UNAVAILABLE
  // Generous: a sanitized server on a busy machine takes several seconds to shut down.
  auto ended = ws.next_json("ended", 30000ms);
  ASSERT_TRUE(ended) << "the page is told when the server goes away\n" << web_->log();
  EXPECT_EQ((*ended)["code"], "UNAVAILABLE") << ended->dump();
  ws.send({{"type", "list"}});
  auto e = ws.next_json("error");
  ASSERT_TRUE(e);
  EXPECT_EQ((*e)["code"], "UNAVAILABLE") << e->dump();
}

TEST_F(WebGateway, AWrongWebTokenIsRefused) {
  Socket none(web_->port(), "/ws");
  Socket wrong(web_->port(), "/ws?token=open");
  for (Socket* s : {&none, &wrong}) {
    if (!s->ok()) continue;  // refused at the handshake
    s->send({{"type", "list"}});
    auto m = s->next(1000ms);
    EXPECT_FALSE(m) << "a socket without the web token got " << (m ? m->data : "");
  }
}

}  // namespace
