// SPDX-License-Identifier: Apache-2.0
// pliant-web's gateway: one civetweb server that serves the page (web/) and three.js, and a
// WebSocket (/ws) per browser. Each socket is a gRPC client session of pliant-server: JSON
// control messages in, JSON replies and binary topology/frames out (docs/web.md). The
// real-time server stays pure gRPC; the gateway never slows its tick (a slow browser gets the
// latest frame and a skip count).
#pragma once

#include "pliant/client/client.hpp"

#include <cstdint>
#include <memory>
#include <string>

namespace pliant::web {

struct GatewayOptions {
  std::string listen = "127.0.0.1:8080";  // HOST:PORT; port 0 picks a free one
  client::ConnectOptions server;          // pliant-server address, token, TLS
  std::string web_token;                  // when set, sockets must present ?token=<it>
  std::string web_root;                   // the page's directory (web/)
  std::string three_dir = "/usr/share/javascript/three";  // three.js (Debian libjs-three)
  std::string tls_cert;                   // PEM with certificate and key: serve HTTPS/WSS
  int threads = 64;                       // civetweb workers; each open socket holds one
};

// Counters of the whole gateway, for logs and tests.
struct GatewayStats {
  uint64_t sockets_open = 0;
  uint64_t sockets_total = 0;
  uint64_t sockets_refused = 0;   // bad or missing web token
  uint64_t frames_sent = 0;
  uint64_t frames_replaced = 0;   // newer frame took the place of an unsent one
  uint64_t grabs_released_on_close = 0;
};

class Gateway {
 public:
  explicit Gateway(GatewayOptions options);
  ~Gateway();  // stops
  Gateway(const Gateway&) = delete;
  Gateway& operator=(const Gateway&) = delete;

  // Starts listening; throws std::runtime_error with the reason when it cannot.
  void start();
  // Closes every socket (releasing its grabs) and stops serving.
  void stop();
  int port() const;
  bool tls() const;
  GatewayStats stats() const;

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace pliant::web
