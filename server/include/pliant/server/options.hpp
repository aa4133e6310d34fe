// SPDX-License-Identifier: Apache-2.0
// pliant-server's settings: command-line flags, an optional config file of `name = value`
// lines, and PLIANT_<NAME> environment variables. Precedence: flags, then environment, then
// the config file, then defaults.
#pragma once

#include "pliant/server/error.hpp"

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace pliant::server {

struct ServerOptions {
  std::string listen = "0.0.0.0:50051";
  std::string data_dir;          // snapshots (shutdown and named); empty: none
  std::string model_path;        // colon-separated directories for mesh files
  int max_scenes = 16;
  int64_t max_vertices = 2'000'000;
  int max_message_mb = 64;
  std::string log_level = "info";  // trace | debug | info | warn | error | critical | off
  std::string tls_cert;
  std::string tls_key;
  std::string token;             // required as "authorization: Bearer <token>" when set
  std::string token_file_token;  // read from --token-file (replaces token)
  std::string reflection = "open";  // open | token | off
  int64_t max_tick_ms = 10'000;  // RegistryOptions::max_tick_ms
  int64_t stuck_tick_ms = 15'000;
  int64_t checkpoint_ms = 5'000;
  int max_streams = 256;          // RegistryOptions::max_streams
  int max_streams_per_scene = 64;
  int max_grabs_per_scene = 64;
  int threads = 1;               // cap on each scene's solver threads
  bool restore = true;           // --no-restore: do not restore scenes from the data dir
  std::string metrics_listen;    // HOST:PORT of the Prometheus /metrics endpoint; empty: off
  std::string config;            // the config file read, if any
};

using EnvLookup = std::function<std::optional<std::string>(const std::string& name)>;

// The process environment.
EnvLookup process_env();

// Parses argv (without argv[0]) with CLI11. On --help sets *help, on --version *version (or
// *help when version is null), and returns Ok.
Error parse_server_options(const std::vector<std::string>& args, const EnvLookup& env,
                           ServerOptions* out, bool* help, bool* version = nullptr);

std::string server_usage();

}  // namespace pliant::server
