// SPDX-License-Identifier: Apache-2.0
// Scene placement (pliant/client/placement.hpp): the published FNV-1a vectors, the golden
// vectors shared with the Python client, and the properties rendezvous hashing promises.
#include "pliant/client/placement.hpp"
#include "pliant/test/paths.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <map>
#include <sstream>
#include <stdexcept>

namespace pc = pliant::client;

TEST(Placement, Fnv1a64MatchesThePublishedVectors) {
  EXPECT_EQ(pc::fnv1a64(""), 0xcbf29ce484222325ULL);
  EXPECT_EQ(pc::fnv1a64("a"), 0xaf63dc4c8601ec8cULL);
  EXPECT_EQ(pc::fnv1a64("foobar"), 0x85944171f73967e8ULL);
}

TEST(Placement, GoldenVectorsSharedWithPython) {
  const std::string path = pliant::test::source_path("tests/client/placement_golden.tsv");
  std::ifstream in(path);
  ASSERT_TRUE(in) << path;
  std::string line;
  int rows = 0;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream f(line);
    std::string id, n, k, score;
    ASSERT_TRUE(std::getline(f, id, '\t') && std::getline(f, n, '\t') && std::getline(f, k, '\t') &&
                std::getline(f, score, '\t'))
        << "malformed row: " << line;
    const std::size_t count = std::stoul(n), want = std::stoul(k);
    EXPECT_EQ(pc::owner_index(id, count), want) << "id '" << id << "' over " << count << " servers";
    EXPECT_EQ(pc::placement_score(id, want), std::stoull(score, nullptr, 16)) << "id '" << id << "'";
    ++rows;
  }
  EXPECT_GE(rows, 100) << "golden file " << path << " has too few rows";
}

TEST(Placement, SpreadsIdsEvenlyAndMovesFewWhenAServerIsAdded) {
  std::map<std::size_t, int> per_server;
  int moved = 0;
  const int ids = 6000;
  for (int i = 0; i < ids; ++i) {
    const std::string id = "scene-" + std::to_string(i);
    const std::size_t three = pc::owner_index(id, 3), four = pc::owner_index(id, 4);
    ++per_server[three];
    if (three != four) {
      ++moved;
      EXPECT_EQ(four, 3u) << id << " moved between old servers";
    }
  }
  for (auto [k, c] : per_server) EXPECT_NEAR(c, ids / 3, ids / 30) << "server " << k;
  EXPECT_NEAR(moved, ids / 4, ids / 30) << "scenes moved to the fourth server";
}

TEST(Placement, RefusesEmptyInput) {
  EXPECT_THROW(pc::owner_index("", 3), std::invalid_argument);
  EXPECT_THROW(pc::owner_index("a", 0), std::invalid_argument);
  EXPECT_THROW(pc::owner("a", {}), std::invalid_argument);
  std::vector<std::string> s;
  std::string err;
  EXPECT_TRUE(pc::parse_servers("a:1, b:2,c:3", &s, &err)) << err;
  EXPECT_EQ(s, (std::vector<std::string>{"a:1", "b:2", "c:3"}));
  EXPECT_FALSE(pc::parse_servers("a:1,,b:2", &s, &err));
  EXPECT_NE(err.find("a:1,,b:2"), std::string::npos) << err;
  EXPECT_FALSE(pc::parse_servers("a:1,a:1", &s, &err));
  EXPECT_NE(err.find("twice"), std::string::npos) << err;
  EXPECT_FALSE(pc::parse_servers("", &s, &err));
  EXPECT_EQ(pc::owner("x", {"only:1"}), "only:1");
}
