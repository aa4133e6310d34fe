// SPDX-License-Identifier: Apache-2.0
// The C++ side of the cross-language placement test (tests/python/test_sharded.py):
//   placement_probe --servers A,B,C [--create] ID...
// For each scene id: with --create, creates it (beam1, lockstep) on the server the placement
// rule names; then finds it there (GetScene), checks that no other server has it (NOT_FOUND),
// steps it once and reads one frame with all positions from the owner's stream. Prints
// "ID OWNER_INDEX TICK" per scene; exits 1 with a message naming the scene on any failure.
#include "pliant/client/client.hpp"
#include "pliant/client/placement.hpp"

#include <cstdio>
#include <string>
#include <vector>

namespace pc = pliant::client;
namespace v1 = pliant::v1;

int main(int argc, char** argv) {
  std::vector<std::string> servers, ids;
  bool create = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--servers" && i + 1 < argc) {
      std::string error;
      if (!pc::parse_servers(argv[++i], &servers, &error)) {
        std::fprintf(stderr, "placement_probe: --servers: %s\n", error.c_str());
        return 2;
      }
    } else if (a == "--create") {
      create = true;
    } else if (a.rfind("--", 0) == 0) {
      std::fprintf(stderr, "placement_probe: unknown flag %s\n", a.c_str());
      return 2;
    } else {
      ids.push_back(a);
    }
  }
  if (servers.empty() || ids.empty()) {
    std::fprintf(stderr, "usage: placement_probe --servers A,B,C [--create] ID...\n");
    return 2;
  }
  std::vector<pc::Client> clients;
  for (const auto& s : servers) {
    pc::ConnectOptions o;
    o.address = s;
    clients.emplace_back(o);
  }
  int failures = 0;
  auto fail = [&](const std::string& id, const std::string& what) {
    std::fprintf(stderr, "placement_probe: scene '%s': %s\n", id.c_str(), what.c_str());
    ++failures;
  };
  for (const auto& id : ids) {
    const std::size_t k = pc::owner_index(id, servers.size());
    pc::Client& owner = clients[k];
    if (create) {
      v1::CreateSceneRequest req;
      req.set_scene_id(id);
      req.mutable_spec()->mutable_mesh()->set_builtin("beam1");
      req.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
      pc::clamp_below_x(*req.mutable_spec(), 0.001);
      if (auto r = owner.create_scene(req); !r.ok()) {
        fail(id, "create on " + servers[k] + ": " + r.status.to_string());
        continue;
      }
    }
    auto scene = owner.get_scene(id);
    if (!scene.ok()) {
      fail(id, "not found on its owner " + servers[k] + ": " + scene.status.to_string());
      continue;
    }
    for (std::size_t j = 0; j < clients.size(); ++j) {
      if (j == k) continue;
      auto other = clients[j].get_scene(id);
      if (other.status.code != 5) fail(id, "server " + servers[j] + " answers " + other.status.to_string());
    }
    v1::StreamFramesRequest sreq;
    sreq.set_scene_id(id);
    auto stream = owner.stream_frames(sreq);
    if (auto st = owner.step(id, 1); !st.ok()) {
      fail(id, "step: " + st.status.to_string());
      continue;
    }
    v1::Frame frame;
    if (!stream->next(&frame)) {
      fail(id, "stream ended: " + stream->finish().to_string());
      continue;
    }
    if (frame.positions_size() != static_cast<int>(3 * scene->vertex_count()))
      fail(id, "frame has " + std::to_string(frame.positions_size()) + " coordinates for " +
                   std::to_string(scene->vertex_count()) + " vertices");
    stream->cancel();
    std::printf("%s %zu %llu\n", id.c_str(), k, static_cast<unsigned long long>(frame.tick()));
  }
  return failures == 0 ? 0 : 1;
}
