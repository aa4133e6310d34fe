// SPDX-License-Identifier: Apache-2.0
// The gRPC server around a SceneRegistry: pliant.v1 services, grpc.health.v1, reflection,
// token check, TLS, and graceful shutdown (NOT_SERVING, streams end with UNAVAILABLE, then
// every scene is written to the data directory). Used by pliant-server and the tests.
#pragma once

#include "pliant/server/options.hpp"
#include "pliant/server/registry.hpp"

#include <chrono>
#include <memory>

namespace pliant::server {

// How long in-flight calls may run on after shutdown begins before they are cancelled.
constexpr std::chrono::seconds kShutdownGrace{2};

class PliantServer {
 public:
  explicit PliantServer(ServerOptions options);
  ~PliantServer();

  // Restores scenes (unless disabled), binds and starts serving.
  Error start();
  // The bound port (useful with --listen HOST:0).
  int port() const;
  // The bound port of the /metrics endpoint (0: --metrics-listen not given).
  int metrics_port() const;
  SceneRegistry& registry();
  // Graceful stop; safe to call twice. Returns the number of scene snapshots written.
  // Takes at most kShutdownGrace plus the time to write the snapshots.
  int shutdown();
  // True when shutdown() could not write a scene's snapshot.
  bool save_failed() const;
  // Blocks until shutdown() has completed.
  void wait();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pliant::server
