// SPDX-License-Identifier: Apache-2.0
// The wire format against golden bytes (tests/web/golden/*.hex, also decoded by the page's
// decoder in wire.test.mjs), the quantisation error bound, and the topology's surface view.
#include "wire.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <cstdio>
#include <fstream>
#include <sstream>

namespace {

using namespace pliant;
using namespace pliant::web;

std::string hex(const std::string& bytes) {
  std::string out;
  char b[4];
  for (size_t i = 0; i < bytes.size(); ++i) {
    std::snprintf(b, sizeof b, "%02x", static_cast<unsigned char>(bytes[i]));
    out += b;
    out += (i % 16 == 15) ? '\n' : ' ';
  }
  if (!out.empty() && out.back() == ' ') out.back() = '\n';
  return out;
}

std::string golden(const std::string& name) {
  std::ifstream f(std::string(PLIANT_WEB_GOLDEN_DIR) + "/" + name);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// The frame the golden files hold: 3 surface vertices, 2 residuals, every header field set.
v1::Frame sample_frame() {
  v1::Frame f;
  f.set_tick(42);
  f.set_sim_time(0.7);
  f.set_skipped_frames(3);
  for (float v : {0.0f, -0.01f, 0.005f, 0.1f, 0.0f, 0.01f, 0.05f, 0.02f, 0.0f}) f.add_positions(v);
  f.set_surface_only(true);
  f.add_residuals(0.5);
  f.add_residuals(0.125);
  f.mutable_solver()->set_iterations(8);
  f.mutable_solver()->set_residual_final(0.125);
  f.mutable_solver()->set_step_wall_ms(1.5);
  f.set_late_ticks(7);
  f.set_lateness_ms(0.25);
  f.set_ticks_per_second(60);
  f.set_rolled_back(true);
  f.set_rollbacks(2);
  f.set_published_unix_ns(1700000000123456789LL);
  f.set_state(v1::SCENE_STATE_RUNNING);
  f.set_skipped_ticks(5);
  return f;
}

// A tetrahedron's worth of topology: 5 body vertices, 4 on the surface (vertex 2 is inside).
v1::Topology sample_topology() {
  v1::Topology t;
  t.set_vertex_count(5);
  for (int v = 0; v < 5; ++v)
    for (int k = 0; k < 3; ++k) t.add_rest_positions(static_cast<float>(v) + 0.25f * static_cast<float>(k));
  for (int v : {0, 1, 3, 4}) t.add_surface_vertices(v);
  for (int v : {0, 1, 3, 0, 3, 4, 0, 4, 1, 1, 4, 3}) t.add_surface_triangles(v);
  for (int v : {1, 2}) t.add_fixed_vertices(v);  // 2 is not on the surface: not sent
  return t;
}

TEST(WebWire, FrameFloat32MatchesGoldenBytes) {
  const std::string bytes = encode_frame(sample_frame(), 9, Encoding::Float32, 3);
  ASSERT_EQ(bytes.size(), frame_bytes(3, 2, Encoding::Float32));
  EXPECT_EQ(bytes.size(), 128u + 8u + 36u);
  EXPECT_EQ(hex(bytes), golden("frame_float32.hex"));
}

TEST(WebWire, FrameUint16MatchesGoldenBytes) {
  const std::string bytes = encode_frame(sample_frame(), 9, Encoding::Quantized16, 3);
  ASSERT_EQ(bytes.size(), frame_bytes(3, 2, Encoding::Quantized16));
  EXPECT_EQ(bytes.size(), 128u + 8u + 20u);  // 18 bytes of positions padded to 20
  EXPECT_EQ(hex(bytes), golden("frame_uint16.hex"));
}

TEST(WebWire, TopologyMatchesGoldenBytes) {
  const std::string bytes = encode_topology(surface_topology(sample_topology()), 9);
  EXPECT_EQ(bytes.size(), 24u + 4u * (12 + 4 + 1 + 12));
  EXPECT_EQ(hex(bytes), golden("topology.hex"));
}

TEST(WebWire, HeaderFieldsSitAtTheDocumentedOffsets) {
  const std::string b = encode_frame(sample_frame(), 9, Encoding::Float32, 3);
  auto u64_at = [&](size_t o) {
    uint64_t v;
    std::memcpy(&v, b.data() + o, 8);
    return v;
  };
  auto f64_at = [&](size_t o) {
    double v;
    std::memcpy(&v, b.data() + o, 8);
    return v;
  };
  EXPECT_EQ(b[0], kKindFrame);
  EXPECT_EQ(b[1], 1);
  EXPECT_EQ(b[3], v1::SCENE_STATE_RUNNING);
  EXPECT_EQ(u64_at(16), 42u);
  EXPECT_EQ(f64_at(24), 0.7);
  EXPECT_EQ(u64_at(32), 7u);
  EXPECT_EQ(u64_at(40), 5u);
  EXPECT_EQ(f64_at(56), 60.0);
  EXPECT_EQ(f64_at(64), 0.125);
  EXPECT_EQ(f64_at(72), 1.5);
  EXPECT_EQ(u64_at(88), 1700000000123456789ull);
  // Positions start 4-byte aligned after the residuals.
  float x1;
  std::memcpy(&x1, b.data() + 128 + 8 + 12, 4);
  EXPECT_EQ(x1, 0.1f);
}

TEST(WebWire, FrameRoundTrips) {
  const v1::Frame f = sample_frame();
  const std::string b = encode_frame(f, 9, Encoding::Float32, 3);
  const FrameHeader h = decode_frame_header(b);
  EXPECT_EQ(h.subscription, 9u);
  EXPECT_EQ(h.tick, 42u);
  EXPECT_EQ(h.skipped_frames, 3u);
  EXPECT_EQ(h.iterations, 8u);
  EXPECT_EQ(h.rollbacks, 2u);
  EXPECT_EQ(h.flags, 1u);
  EXPECT_EQ(h.bbox_min[1], -0.01f);
  EXPECT_EQ(h.bbox_max[0], 0.1f);
  const auto r = decode_frame_residuals(b);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0], 0.5f);
  const auto p = decode_frame_positions(b);
  ASSERT_EQ(p.size(), 9u);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(p[i], f.positions(i));
}

TEST(WebWire, QuantisedPositionsAreWithinHalfAStepOfTheBox) {
  v1::Frame f = sample_frame();
  f.clear_positions();
  // 1000 vertices spread over a 13.5 cm box (the armadillo's size).
  for (int i = 0; i < 1000; ++i) {
    f.add_positions(0.135f * std::sin(0.37f * static_cast<float>(i)));
    f.add_positions(0.05f * std::cos(0.11f * static_cast<float>(i)));
    f.add_positions(0.001f * static_cast<float>(i % 7));
  }
  const std::string b = encode_frame(f, 1, Encoding::Quantized16, 1000);
  const FrameHeader h = decode_frame_header(b);
  const auto p = decode_frame_positions(b);
  ASSERT_EQ(p.size(), 3000u);
  for (int i = 0; i < 3000; ++i) {
    const int k = i % 3;
    const float step = (h.bbox_max[k] - h.bbox_min[k]) / 65535.0f;
    EXPECT_LE(std::abs(p[i] - f.positions(i)), 0.5f * step + 1e-7f) << "value " << i;
  }
  EXPECT_LT(b.size(), encode_frame(f, 1, Encoding::Float32, 1000).size() * 0.51);
}

TEST(WebWire, SurfaceTopologyIndexesTheSurface) {
  const SurfaceTopology s = surface_topology(sample_topology());
  EXPECT_EQ(s.body_vertex_count, 5u);
  EXPECT_EQ(s.surface_to_body, (std::vector<uint32_t>{0, 1, 3, 4}));
  // Triangle (0, 1, 3) in body indices is (0, 1, 2) in surface indices.
  EXPECT_EQ(std::vector<uint32_t>(s.triangles.begin(), s.triangles.begin() + 3), (std::vector<uint32_t>{0, 1, 2}));
  EXPECT_EQ(s.fixed, (std::vector<uint32_t>{1}));
  EXPECT_EQ(s.rest_positions[6], 3.0f);  // surface vertex 2 is body vertex 3
  const SurfaceTopology d = decode_topology(encode_topology(s, 4));
  EXPECT_EQ(d.triangles, s.triangles);
  EXPECT_EQ(d.rest_positions, s.rest_positions);
}

TEST(WebWire, BadInputIsRejectedWithTheReason) {
  v1::Topology t = sample_topology();
  t.set_surface_triangles(0, 2);  // vertex 2 is not on the surface
  try {
    surface_topology(t);
    FAIL() << "accepted a triangle on an inner vertex";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 2"), std::string::npos) << e.what();
  }
  EXPECT_THROW(encode_frame(sample_frame(), 1, Encoding::Float32, 4), std::invalid_argument);
  std::string b = encode_frame(sample_frame(), 1, Encoding::Float32, 3);
  b.pop_back();
  EXPECT_THROW(decode_frame_header(b), std::invalid_argument);
  EXPECT_THROW(decode_topology(b), std::invalid_argument);  // a frame is not a topology
}

}  // namespace
