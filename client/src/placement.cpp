// SPDX-License-Identifier: Apache-2.0
#include "pliant/client/placement.hpp"

#include <algorithm>
#include <stdexcept>

namespace pliant::client {

uint64_t fnv1a64(std::string_view bytes) {
  uint64_t h = 0xcbf29ce484222325ULL;
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 0x100000001b3ULL;
  }
  return h;
}

uint64_t mix64(uint64_t h) {
  h ^= h >> 33;
  h *= 0xff51afd7ed558ccdULL;
  h ^= h >> 33;
  h *= 0xc4ceb93e2d7d4a03ULL;
  h ^= h >> 33;
  return h;
}

uint64_t placement_score(std::string_view scene_id, std::size_t ordinal) {
  std::string key(scene_id);
  key.push_back('\0');
  key += std::to_string(ordinal);
  return mix64(fnv1a64(key));
}

std::size_t owner_index(std::string_view scene_id, std::size_t server_count) {
  if (scene_id.empty()) throw std::invalid_argument("scene_id must not be empty (placement needs the id)");
  if (server_count == 0) throw std::invalid_argument("server_count must be >= 1, got 0");
  std::size_t best = 0;
  uint64_t best_score = placement_score(scene_id, 0);
  for (std::size_t k = 1; k < server_count; ++k) {
    const uint64_t s = placement_score(scene_id, k);
    if (s > best_score) {
      best = k;
      best_score = s;
    }
  }
  return best;
}

const std::string& owner(std::string_view scene_id, const std::vector<std::string>& servers) {
  if (servers.empty()) throw std::invalid_argument("servers must list at least one address");
  return servers[owner_index(scene_id, servers.size())];
}

bool parse_servers(std::string_view text, std::vector<std::string>* servers, std::string* error) {
  servers->clear();
  const std::string all(text);
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = text.find(',', start);
    std::string_view item = text.substr(start, comma == std::string_view::npos ? std::string_view::npos : comma - start);
    while (!item.empty() && item.front() == ' ') item.remove_prefix(1);
    while (!item.empty() && item.back() == ' ') item.remove_suffix(1);
    if (item.empty()) {
      *error = "servers must be a comma-separated list of HOST:PORT, got '" + all + "'";
      return false;
    }
    if (std::find(servers->begin(), servers->end(), item) != servers->end()) {
      *error = "servers lists '" + std::string(item) + "' twice in '" + all + "'";
      return false;
    }
    servers->emplace_back(item);
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  return true;
}

}  // namespace pliant::client
