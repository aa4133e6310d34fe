// SPDX-License-Identifier: Apache-2.0
// Which server holds a scene: rendezvous (highest-random-weight) hashing of the scene id over an
// ordered list of servers (docs/deploy.md, "Scene placement"). The same rule, bit for bit, as the
// Python client's pliant.placement:
//
//   score(id, k) = mix64(fnv1a64(id bytes, 0x00, decimal digits of k))
//   owner(id, n) = the k in [0, n) with the highest score (the lowest k on a tie)
//
// k is the server's position in the list (a StatefulSet's ordinal), not its address, so clients
// that reach the servers under other names place scenes alike. Adding server n moves only the
// scenes it now owns; removing the last server moves only its scenes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace pliant::client {

// 64-bit FNV-1a (offset basis 0xcbf29ce484222325, prime 0x100000001b3).
uint64_t fnv1a64(std::string_view bytes);
// MurmurHash3's 64-bit finalizer.
uint64_t mix64(uint64_t h);
// The weight of server `ordinal` for `scene_id`.
uint64_t placement_score(std::string_view scene_id, std::size_t ordinal);
// The index in [0, server_count) of the server holding `scene_id`. server_count must be >= 1
// and scene_id non-empty (std::invalid_argument otherwise).
std::size_t owner_index(std::string_view scene_id, std::size_t server_count);
// The address out of `servers` (ordered, non-empty) holding `scene_id`.
const std::string& owner(std::string_view scene_id, const std::vector<std::string>& servers);
// "a:1,b:2" -> {"a:1", "b:2"}. Empty entries and duplicates are refused: returns false and
// sets *error to a message naming the value.
bool parse_servers(std::string_view text, std::vector<std::string>* servers, std::string* error);

}  // namespace pliant::client
