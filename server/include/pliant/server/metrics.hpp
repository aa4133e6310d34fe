// SPDX-License-Identifier: Apache-2.0
// Prometheus metrics of the scenes a SceneRegistry hosts: the text exposition format (0.0.4)
// rendered from the scenes' latest frames and statuses, served over HTTP at /metrics by
// civetweb on pliant-server's --metrics-listen HOST:PORT.
#pragma once

#include "pliant/server/registry.hpp"

#include <memory>
#include <string>

struct mg_context;  // civetweb

namespace pliant::server {

// The exposition text: server-wide series (scenes, open streams, build info) and per-scene
// series labelled {scene="ID"}. Reads each scene's status and latest frame (short locks, none
// on the tick path beyond the frame pointer and status reads).
std::string render_metrics(const SceneRegistry& registry);

class MetricsEndpoint {
 public:
  // Serves GET /metrics on `listen` (IPv4 HOST:PORT, [IPv6]:PORT or localhost:PORT; port 0
  // picks a free one). InvalidArgument names --metrics-listen when it cannot listen.
  static Error start(const std::string& listen, const SceneRegistry* registry,
                     std::unique_ptr<MetricsEndpoint>* out);
  ~MetricsEndpoint();
  MetricsEndpoint(const MetricsEndpoint&) = delete;
  MetricsEndpoint& operator=(const MetricsEndpoint&) = delete;

  int port() const { return port_; }

 private:
  MetricsEndpoint() = default;
  mg_context* ctx_ = nullptr;
  const SceneRegistry* registry_ = nullptr;
  int port_ = 0;
};

}  // namespace pliant::server
