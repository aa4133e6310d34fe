// SPDX-License-Identifier: Apache-2.0
// pliant-server's Prometheus endpoint (--metrics-listen): GET /metrics answers the text
// exposition format with the server-wide and per-scene series, labelled by scene, and the
// counters grow as the scenes tick; streams and grabs show while they are open.
#include "pliant/client/client.hpp"
#include "pliant/server/metrics.hpp"
#include "pliant/server/server.hpp"
#include "pliant/test/wait_until.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdlib>
#include <map>
#include <sstream>

using namespace pliant;
using client::Client;
using pliant::test::kPatience;
using pliant::test::wait_until;

namespace {

struct HttpReply {
  int status = 0;
  std::string headers, body;
};

// One HTTP/1.1 GET on 127.0.0.1:port (Connection: close), read to the end.
HttpReply http_get(int port, const std::string& path) {
  HttpReply r;
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return r;
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return r;
  }
  const std::string req = "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
  if (::send(fd, req.data(), req.size(), 0) != static_cast<ssize_t>(req.size())) {
    ::close(fd);
    return r;
  }
  std::string all;
  char buf[4096];
  for (ssize_t n; (n = ::recv(fd, buf, sizeof buf, 0)) > 0;) all.append(buf, static_cast<size_t>(n));
  ::close(fd);
  const size_t end = all.find("\r\n\r\n");
  if (all.rfind("HTTP/1.", 0) != 0 || end == std::string::npos) return r;
  r.status = std::atoi(all.c_str() + 9);
  r.headers = all.substr(0, end);
  r.body = all.substr(end + 4);
  return r;
}

// Samples by "name{labels}" (or "name" without labels). Fails the test on a line that is not
// a comment and not "NAME[{LABELS}] VALUE".
std::map<std::string, double> samples(const std::string& text) {
  std::map<std::string, double> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (line.empty() || line[0] == '#') continue;
    const size_t space = line.rfind(' ');
    EXPECT_NE(space, std::string::npos) << line;
    if (space == std::string::npos) continue;
    const std::string v = line.substr(space + 1);
    double d = 0;
    if (v == "NaN") d = std::nan("");
    else {
      char* end = nullptr;
      d = std::strtod(v.c_str(), &end);
      EXPECT_TRUE(end && *end == '\0') << line;
    }
    out[line.substr(0, space)] = d;
  }
  return out;
}

v1::CreateSceneRequest realtime_beam(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  r.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  client::clamp_below_x(*r.mutable_spec(), 1e-3);
  r.mutable_spec()->mutable_solver()->set_substeps(1);
  r.mutable_spec()->mutable_solver()->set_iterations(2);
  return r;
}

}  // namespace

TEST(Metrics, ScrapeHasTheSeriesPerSceneAndCountersGrow) {
  server::ServerOptions o;
  o.metrics_listen = "127.0.0.1:0";
  test::InProcessServer fx(o);
  ASSERT_TRUE(fx.started.ok());
  server::PliantServer& srv = *fx.server;
  ASSERT_GT(srv.metrics_port(), 0);
  Client c = fx.client();

  HttpReply r = http_get(srv.metrics_port(), "/metrics");
  ASSERT_EQ(r.status, 200) << r.headers;
  EXPECT_NE(r.headers.find("text/plain; version=0.0.4"), std::string::npos) << r.headers;
  auto s = samples(r.body);
  EXPECT_EQ(s["pliant_scenes"], 0);
  EXPECT_EQ(s["pliant_open_streams"], 0);
  EXPECT_EQ(http_get(srv.metrics_port(), "/nothing").status, 404);

  ASSERT_TRUE(c.create_scene(realtime_beam("m1")).ok());
  ASSERT_TRUE(c.create_scene(realtime_beam("m2")).ok());
  const std::string m1 = "{scene=\"m1\"}";
  double first = 0;
  ASSERT_TRUE(wait_until(
      [&] {
        s = samples(http_get(srv.metrics_port(), "/metrics").body);
        first = s["pliant_scene_ticks_total" + m1];
        return first > 0 && s.count("pliant_scene_step_seconds" + m1);
      },
      kPatience, "m1 ticking in /metrics"));
  EXPECT_EQ(s["pliant_scenes"], 2);
  for (const char* name : {"pliant_scene_ticks_total", "pliant_scene_late_ticks_total", "pliant_scene_skipped_ticks_total",
                           "pliant_scene_rollbacks_total", "pliant_scene_running", "pliant_scene_step_seconds",
                           "pliant_scene_step_seconds_mean", "pliant_scene_residual", "pliant_scene_relative_residual",
                           "pliant_scene_iterations", "pliant_scene_substeps", "pliant_scene_grabs",
                           "pliant_scene_open_streams"}) {
    EXPECT_TRUE(s.count(name + m1)) << name;
    EXPECT_NE(r.body.find(std::string("# TYPE ") + name + " "), std::string::npos) << name;
  }
  EXPECT_EQ(s["pliant_scene_running" + m1], 1);
  EXPECT_EQ(s["pliant_scene_iterations" + m1], 2);
  EXPECT_GT(s["pliant_scene_step_seconds_mean" + m1], 0);
  EXPECT_GE(s["pliant_scene_relative_residual" + m1], 0);
  EXPECT_TRUE(s.count("pliant_scene_ticks_total{scene=\"m2\"}"));
  ASSERT_TRUE(wait_until(
      [&] { return samples(http_get(srv.metrics_port(), "/metrics").body)["pliant_scene_ticks_total" + m1] > first; },
      kPatience, "the tick counter to grow"));

  // A stream and a grab show on their scene.
  v1::StreamFramesRequest sr;
  sr.set_scene_id("m1");
  auto stream = c.stream_frames(sr);
  v1::Frame f;
  ASSERT_TRUE(stream->next(&f));
  v1::GrabRequest g;
  g.set_scene_id("m1");
  g.set_vertex(int32_t(f.positions_size() / 3 - 1));
  auto grabbed = c.grab(g);
  ASSERT_TRUE(grabbed.ok()) << grabbed.status.message;
  ASSERT_TRUE(wait_until(
      [&] {
        s = samples(http_get(srv.metrics_port(), "/metrics").body);
        return s["pliant_scene_open_streams" + m1] == 1 && s["pliant_open_streams"] == 1 &&
               s["pliant_scene_grabs" + m1] == 1 && s["pliant_scene_grabs{scene=\"m2\"}"] == 0;
      },
      kPatience, "one stream and one grab on m1 in /metrics"));
  stream->cancel();
  stream->finish();
  srv.shutdown();
}

TEST(Metrics, ListenIsCheckedAndReadFromTheEnvironment) {
  server::ServerOptions o;
  bool help = false;
  server::Error e = server::parse_server_options({"--metrics-listen", "nowhere"},
                                                 [](const std::string&) { return std::nullopt; }, &o, &help);
  EXPECT_NE(e.message.find("--metrics-listen must be HOST:PORT, got 'nowhere'"), std::string::npos) << e.message;
  e = server::parse_server_options({"--metrics-listen", "127.0.0.1:70000"},
                                   [](const std::string&) { return std::nullopt; }, &o, &help);
  EXPECT_NE(e.message.find("--metrics-listen must be HOST:PORT with a port in [0, 65535]"), std::string::npos)
      << e.message;
  e = server::parse_server_options({}, [](const std::string& n) -> std::optional<std::string> {
    if (n == "PLIANT_METRICS_LISTEN") return "127.0.0.1:9464";
    return std::nullopt;
  }, &o, &help);
  EXPECT_TRUE(e.ok()) << e.message;
  EXPECT_EQ(o.metrics_listen, "127.0.0.1:9464");
}
