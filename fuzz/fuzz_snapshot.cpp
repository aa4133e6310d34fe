// SPDX-License-Identifier: Apache-2.0
// libFuzzer harness for snapshot parsing: the bytes as a serialized pliant.v1.Snapshot (the seed
// corpus holds real ones, so mutations reach the field checks), through the server's
// snapshot_from_proto. What it accepts must serialise again and be accepted again.
#include "pliant/server/registry.hpp"

#include <spdlog/spdlog.h>

#include <cstdint>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  spdlog::set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  pliant::v1::Snapshot proto;
  if (!proto.ParseFromArray(data, static_cast<int>(size))) return 0;
  pliant::server::SceneSnapshot snap;
  // A small vertex limit keeps every input cheap (the limit itself is checked first).
  if (!pliant::server::snapshot_from_proto(proto, 2, 5000, &snap).ok()) return 0;
  pliant::v1::Snapshot again;
  pliant::server::snapshot_to_proto(snap, &again);
  pliant::server::SceneSnapshot snap2;
  if (!pliant::server::snapshot_from_proto(again, 2, 5000, &snap2).ok()) __builtin_trap();
  if (snap2.state.x.size() != snap.state.x.size() || snap2.tick != snap.tick) __builtin_trap();
  return 0;
}
