// SPDX-License-Identifier: Apache-2.0
// A Pliant client built against the installed package (find_package(Pliant), Pliant::client):
// connects to a server, creates a lockstep scene of the builtin beam, lists the scenes, streams
// one frame while stepping the scene, prints it and deletes the scene.
//   pliant-consumer [--address HOST:PORT] [--scene ID]      (token: $PLIANT_TOKEN)
#include "pliant/client/client.hpp"

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

namespace v1 = pliant::v1;
using namespace std::chrono_literals;

int main(int argc, char** argv) {
  pliant::client::ConnectOptions options;
  if (const char* token = std::getenv("PLIANT_TOKEN")) options.token = token;
  std::string scene_id = "consumer";
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if ((arg == "--address" || arg == "--scene") && i + 1 < argc) {
      (arg == "--address" ? options.address : scene_id) = argv[++i];
    } else {
      std::fprintf(stderr, "pliant-consumer: unknown argument '%s' (usage: pliant-consumer "
                           "[--address HOST:PORT] [--scene ID])\n", arg.c_str());
      return 2;
    }
  }

  pliant::client::Client client(options);
  if (!client.wait_connected(10s)) {
    std::fprintf(stderr, "pliant-consumer: no server at %s\n", options.address.c_str());
    return 1;
  }

  v1::CreateSceneRequest create;
  create.set_scene_id(scene_id);
  create.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  create.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  pliant::client::clamp_below_x(*create.mutable_spec(), 0.001);
  auto scene = client.create_scene(create);
  if (!scene.ok()) {
    std::fprintf(stderr, "pliant-consumer: create scene: %s\n", scene.status.to_string().c_str());
    return 1;
  }
  std::printf("created %s: %u vertices, %u tets\n", scene->scene_id().c_str(), scene->vertex_count(),
              scene->tet_count());

  auto scenes = client.list_scenes();
  if (!scenes.ok()) {
    std::fprintf(stderr, "pliant-consumer: list scenes: %s\n", scenes.status.to_string().c_str());
    return 1;
  }
  std::printf("scenes:");
  for (const v1::Scene& s : *scenes) std::printf(" %s", s.scene_id().c_str());
  std::printf("\n");

  // Subscribe, then step until the first frame arrives (a lockstep scene publishes a frame
  // per tick; the subscription may start after the first step).
  v1::StreamFramesRequest watch;
  watch.set_scene_id(scene_id);
  auto stream = client.stream_frames(watch);
  std::atomic<bool> got{false};
  v1::Frame frame;
  std::thread reader([&] { got = stream->next(&frame); });
  int rc = 1;
  for (int attempt = 0; attempt < 100 && !got; ++attempt) {
    auto step = client.step(scene_id, 1);
    if (!step.ok()) {
      std::fprintf(stderr, "pliant-consumer: step: %s\n", step.status.to_string().c_str());
      break;
    }
    std::this_thread::sleep_for(50ms);
  }
  if (!got) stream->cancel();
  reader.join();
  if (got) {
    const int vertices = frame.positions_size() / 3;
    const float tip_y = vertices > 0 ? frame.positions(frame.positions_size() - 2) : 0.0f;
    std::printf("frame: tick %llu, sim_time %.4f s, %d vertex positions, last vertex y %.6f m, "
                "%d iterations, residual %.3g\n",
                static_cast<unsigned long long>(frame.tick()), frame.sim_time(), vertices, tip_y,
                frame.solver().iterations(), frame.solver().residual_final());
    rc = vertices == static_cast<int>(scene->vertex_count()) ? 0 : 1;
  } else {
    std::fprintf(stderr, "pliant-consumer: no frame arrived (%s)\n", stream->finish().to_string().c_str());
  }
  if (auto del = client.delete_scene(scene_id); !del.ok()) {
    std::fprintf(stderr, "pliant-consumer: delete scene: %s\n", del.to_string().c_str());
    rc = 1;
  }
  return rc;
}
