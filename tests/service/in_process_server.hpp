// SPDX-License-Identifier: Apache-2.0
// The in-process server the service tests share: a PliantServer on 127.0.0.1 (a free port
// unless one is given), started by the constructor (a failed start fails the test), and
// clients for it.
#pragma once

#include "pliant/client/client.hpp"
#include "pliant/server/server.hpp"

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <chrono>
#include <memory>
#include <string>
#include <utility>

namespace pliant::test {

// gRPC status codes as client::Status carries them.
namespace grpc_codes {
inline constexpr int kInvalidArgument = 3, kDeadlineExceeded = 4, kNotFound = 5, kAlreadyExists = 6,
                     kResourceExhausted = 8, kFailedPrecondition = 9, kUnavailable = 14, kUnauthenticated = 16;
}  // namespace grpc_codes

// Keeps the test output readable: the in-process servers log warnings and errors only.
inline const bool quiet_server_logs = [] {
  spdlog::set_level(spdlog::level::warn);
  return true;
}();

// How the fixture's clients connect: unary calls' and Step's timeouts, the access token.
struct ClientSettings {
  ClientSettings(std::chrono::milliseconds timeout_ = std::chrono::seconds(30),
                 std::chrono::milliseconds step_timeout_ = std::chrono::minutes(10), std::string token_ = {})
      : timeout(timeout_), step_timeout(step_timeout_), token(std::move(token_)) {}
  std::chrono::milliseconds timeout;
  std::chrono::milliseconds step_timeout;
  std::string token;
};

struct InProcessServer {
  std::unique_ptr<server::PliantServer> server;
  std::string address;     // 127.0.0.1:<port>
  ClientSettings clients;  // what client() connects with
  server::Error started;   // what start() answered

  // options.listen is replaced by 127.0.0.1:<port> (0: a free port).
  explicit InProcessServer(server::ServerOptions options = {}, ClientSettings client_settings = {}, int port = 0)
      : clients(std::move(client_settings)) {
    options.listen = "127.0.0.1:" + std::to_string(port);
    server = std::make_unique<server::PliantServer>(options);
    started = server->start();
    EXPECT_TRUE(started.ok()) << started.message;
    address = "127.0.0.1:" + std::to_string(server->port());
  }

  int port() const { return server->port(); }
  server::SceneRegistry& registry() const { return server->registry(); }

  client::ConnectOptions connect_options(const std::string& token) const {
    client::ConnectOptions c;
    c.address = address;
    c.token = token;
    c.timeout = clients.timeout;
    c.step_timeout = clients.step_timeout;
    return c;
  }
  client::ConnectOptions connect_options() const { return connect_options(clients.token); }
  client::Client client() const { return client::Client(connect_options()); }
  client::Client client(const std::string& token) const { return client::Client(connect_options(token)); }
};

}  // namespace pliant::test
