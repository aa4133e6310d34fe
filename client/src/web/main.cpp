// SPDX-License-Identifier: Apache-2.0
// pliant-web: the browser front end's gateway. A gRPC client of pliant-server that serves the
// page (web/) and a WebSocket per browser: live surface frames, solver plots, pick-and-drag.
// Exit codes: 0 stopped by a signal; 1 could not start; 2 usage error.
#include "cli.hpp"
#include "gateway.hpp"
#include "pliant/version.hpp"

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <thread>

namespace {

const char* kUsage = R"(usage: pliant-web [flags]

Serves the Pliant viewer (a page with the deforming body, solver plots and pick-and-drag) and
its WebSocket, as a client of pliant-server. Open http://HOST:PORT/ in a browser.

  --listen HOST:PORT   where the page is served (default $PLIANT_WEB_LISTEN or 127.0.0.1:8080;
                       0.0.0.0:8080 for every interface; port 0 picks a free one)
  --address HOST:PORT  pliant-server (default $PLIANT_ADDRESS or localhost:50051)
  --token TOKEN        the server's access token (default $PLIANT_TOKEN)
  --tls                TLS to the server with the system roots;  --tls-ca FILE: with these roots
  --web-token TOKEN    browsers must open the page as /?token=TOKEN (default $PLIANT_WEB_TOKEN;
                       empty: no check, for loopback use)
  --tls-cert FILE      PEM holding the certificate chain and private key: serve HTTPS and WSS
                       (default $PLIANT_WEB_TLS_CERT). Needs a civetweb that loads OpenSSL;
                       Debian 12's cannot (OpenSSL 3): use a TLS reverse proxy there
  --web-root DIR       the page's files (default $PLIANT_WEB_ROOT, else the installed or
                       source web/ directory)
  --three-dir DIR      three.js (default /usr/share/javascript/three, Debian libjs-three)
  --threads N          web worker threads; each open browser holds one (default 64)
  --log-level L        trace|debug|info|warn|error|critical|off (default info)
  --version            print the version and exit
)";

std::atomic<bool> g_stop{false};
void on_signal(int) { g_stop = true; }

std::string env_or(const char* name, const std::string& fallback) {
  const char* v = std::getenv(name);
  return v && *v ? v : fallback;
}

// The page's files: installed next to the program (<bin>/../share/pliant/web), else the source tree's.
std::string default_web_root(const char* argv0) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path exe = fs::canonical("/proc/self/exe", ec);
  const fs::path base = ec ? fs::path(argv0).parent_path() : exe.parent_path();
  for (const fs::path& p : {base / PLIANT_DATA_FROM_BIN / "web", fs::path(PLIANT_WEB_SOURCE_ROOT)})
    if (fs::is_regular_file(p / "index.html")) return fs::weakly_canonical(p).string();
  return PLIANT_WEB_SOURCE_ROOT;
}

}  // namespace

int main(int argc, char** argv) {
  pliant::web::GatewayOptions o;
  o.listen = env_or("PLIANT_WEB_LISTEN", o.listen);
  o.server.address = env_or("PLIANT_ADDRESS", "localhost:50051");
  o.server.token = env_or("PLIANT_TOKEN", "");
  o.server.timeout = std::chrono::seconds(5);
  o.web_token = env_or("PLIANT_WEB_TOKEN", "");
  o.tls_cert = env_or("PLIANT_WEB_TLS_CERT", "");
  o.web_root = env_or("PLIANT_WEB_ROOT", "");
  std::string log_level = "info";
  CLI::App app{"pliant-web"};
  app.set_version_flag("--version", std::string(pliant::kVersion));
  app.formatter_fn([](const CLI::App*, std::string, CLI::AppFormatMode) { return std::string(kUsage); });
  auto text = [&app](const std::string& name, std::string* into) {
    app.add_option(name, *into)->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  };
  text("--listen", &o.listen);
  text("--address", &o.server.address);
  text("--token", &o.server.token);
  app.add_flag("--tls", o.server.tls);
  app.add_option_function<std::string>("--tls-ca", [&o](const std::string& v) {
       o.server.tls_ca_file = v;
       o.server.tls = true;
     })->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  text("--web-token", &o.web_token);
  text("--tls-cert", &o.tls_cert);
  text("--web-root", &o.web_root);
  text("--three-dir", &o.three_dir);
  app.add_option_function<std::string>("--threads", [&o](const std::string& v) {
       char* end = nullptr;
       const long n = std::strtol(v.c_str(), &end, 10);
       if (end == v.c_str() || *end != '\0' || n < 2 || n > 1024)
         throw CLI::ValidationError("--threads must be an integer in [2, 1024], got '" + v + "'");
       o.threads = static_cast<int>(n);
     })->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  app.add_option("--log-level", log_level)
      ->check(pliant::cli::one_of(pliant::cli::log_levels()))
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
  if (auto rc = pliant::cli::parse_or_exit(app, argc, argv, "pliant-web")) return *rc;
  if (o.web_root.empty()) o.web_root = default_web_root(argv[0]);
  spdlog::set_default_logger(spdlog::stderr_color_mt("pliant-web"));
  spdlog::set_level(spdlog::level::from_str(log_level));

  pliant::web::Gateway gateway(o);
  try {
    gateway.start();
  } catch (const std::exception& e) {
    spdlog::error("cannot start: {}", e.what());
    return 1;
  }
  // The line scripts and tests read the port from.
  spdlog::info("listening on {} (port {})", o.listen, gateway.port());
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  while (!g_stop.load()) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  spdlog::info("stopping");
  gateway.stop();
  return 0;
}
