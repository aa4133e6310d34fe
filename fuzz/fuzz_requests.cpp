// SPDX-License-Identifier: Apache-2.0
// libFuzzer harness for request validation at the service's edge. The first byte picks the
// request; the rest is its serialized protobuf (the seed corpus holds valid ones):
//   0 CreateSceneRequest (the scene, if created, is deleted at once)
//   1 StreamFramesRequest   2 ToolPose   3 RestoreSnapshotRequest (inline snapshot)
//   4 a model_path name (raw bytes) resolved on the repository's meshes/ and echoed
// Every refusal must carry a message within the service's cap.
#include "pliant/server/edge.hpp"
#include "pliant/server/registry.hpp"
#include "pliant/server/stream_proto.hpp"

#include <spdlog/spdlog.h>

#include <cstdint>
#include <string>

using namespace pliant;

namespace {

server::SceneRegistry& registry() {
  static server::SceneRegistry reg([] {
    server::RegistryOptions o;
    o.max_scenes = 4;
    o.max_vertices = 3000;
    o.model_path = {PLIANT_MESH_DIR};
    return o;
  }());
  return reg;
}

void check_message(const server::Error& e) {
  if (!e.ok() && (e.message.empty() || server::cap_message(e.message).size() > server::kMaxErrorMessage))
    __builtin_trap();
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  spdlog::set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const int kind = data[0] % 5;
  const void* body = data + 1;
  const int n = static_cast<int>(size - 1);
  switch (kind) {
    case 0: {
      v1::CreateSceneRequest r;
      if (!r.ParseFromArray(body, n)) return 0;
      v1::Scene out;
      server::Error e = registry().create(r, &out);
      check_message(e);
      if (e.ok()) registry().remove(out.scene_id());
      break;
    }
    case 1: {
      v1::StreamFramesRequest r;
      if (!r.ParseFromArray(body, n)) return 0;
      server::FrameSelection sel;
      check_message(server::parse_stream_request(r, &sel));
      break;
    }
    case 2: {
      v1::ToolPose p;
      if (!p.ParseFromArray(body, n)) return 0;
      RigidTool tool;
      server::Error e = server::parse_tool_pose(p, nullptr, &tool);
      check_message(e);
      if (e.ok() && !(tool.position.allFinite() && tool.radius > 0)) __builtin_trap();
      break;
    }
    case 3: {
      v1::RestoreSnapshotRequest r;
      if (!r.ParseFromArray(body, n) || r.source_case() != v1::RestoreSnapshotRequest::kSnapshot) return 0;
      v1::Scene out;
      server::Error e = registry().restore_snapshot(r, &out);
      check_message(e);
      if (e.ok()) registry().remove(out.scene_id());
      break;
    }
    default: {
      const std::string name(static_cast<const char*>(body), static_cast<size_t>(n));
      std::string path;
      server::Error e = server::resolve_model_file("model_path", name, {PLIANT_MESH_DIR}, &path);
      check_message(e);
      if (e.ok() && path.rfind(PLIANT_MESH_DIR, 0) != 0) __builtin_trap();  // escaped meshes/
      if (server::echo(name).size() > 4 * server::kMaxEcho + 40) __builtin_trap();
      break;
    }
  }
  return 0;
}
