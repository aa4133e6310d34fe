// SPDX-License-Identifier: Apache-2.0
// pliant-server: hosts soft-body scenes over gRPC until SIGTERM/SIGINT, then saves them.
#include "pliant/server/server.hpp"
#include "pliant/version.hpp"

#include <spdlog/spdlog.h>

#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <thread>
#include <pthread.h>

int main(int argc, char** argv) {
  using namespace pliant::server;
  // Block the stop signals in every thread; main waits for them with sigwait below.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  ServerOptions options;
  bool help = false, version = false;
  std::vector<std::string> args(argv + 1, argv + argc);
  if (Error e = parse_server_options(args, process_env(), &options, &help, &version); !e.ok()) {
    std::fprintf(stderr, "pliant-server: %s\n", e.message.c_str());
    return 2;
  }
  if (version) {
    std::printf("%s\n", pliant::kVersion);
    return 0;
  }
  if (help) {
    std::fputs(server_usage().c_str(), stdout);
    return 0;
  }
  spdlog::set_level(spdlog::level::from_str(options.log_level));
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  if (!options.config.empty()) spdlog::info("settings read from {}", options.config);

  PliantServer server(options);
  if (Error e = server.start(); !e.ok()) {
    spdlog::critical("{}", e.message);
    return 1;
  }
  int sig = 0;
  sigwait(&stop_signals, &sig);
  spdlog::info("received {}: stopping within {} s plus the time to save the scenes", sig == SIGTERM ? "SIGTERM" : "SIGINT",
               kShutdownGrace.count());
  // A second SIGTERM/SIGINT during the shutdown ends the process at once, unsaved.
  std::thread([stop_signals] {
    int again = 0;
    sigwait(&stop_signals, &again);
    spdlog::critical("received a second stop signal during shutdown: exiting without saving");
    std::_Exit(3);
  }).detach();
  int written = server.shutdown();
  if (server.save_failed()) {
    spdlog::critical("stopped, but some scene snapshots could not be written ({} written)", written);
    return 1;
  }
  spdlog::info("stopped ({} scene snapshot(s) written)", written);
  return 0;
}
