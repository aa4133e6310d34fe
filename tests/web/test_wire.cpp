// SPDX-License-Identifier: Apache-2.0
// The wire format against golden bytes (tests/web/golden/*.hex, also decoded by the page's
// decoder in wire.test.mjs), the quantisation error bound, and the topology's surface view.
#include "wire.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <cstdio>
#include <cstdlib>
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

// PLIANT_WEB_WRITE_GOLDEN=1 rewrites a golden file from the encoder (after a deliberate,
// documented format change; wire.test.mjs must then still decode it).
std::string golden(const std::string& name, const std::string& fresh = {}) {
  if (std::getenv("PLIANT_WEB_WRITE_GOLDEN") && !fresh.empty())
    std::ofstream(std::string(PLIANT_WEB_GOLDEN_DIR) + "/" + name) << fresh;
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

// The same scene with three particle bodies: a rope of 3 particles (first pinned), a cloth of
// 4 (2 triangles, 2 pinned) and a fluid of 2.
v1::Topology sample_topology_with_bodies() {
  v1::Topology t = sample_topology();
  auto add = [&](const char* name, const char* kind, std::vector<float> rest, std::vector<uint32_t> tris,
                 std::vector<uint32_t> pinned) {
    auto* b = t.add_bodies();
    b->set_name(name);
    b->set_kind(kind);
    b->set_particle_count(static_cast<uint32_t>(rest.size() / 3));
    for (float v : rest) b->add_rest_positions(v);
    for (uint32_t v : tris) b->add_triangles(v);
    for (uint32_t v : pinned) b->add_pinned(v);
  };
  add("rope", "rope", {0.1f, 0, 0, 0.2f, 0, 0, 0.3f, 0, 0}, {}, {0});
  add("sheet", "cloth", {0, 0.1f, 0, 0.1f, 0.1f, 0, 0, 0.1f, 0.1f, 0.1f, 0.1f, 0.1f}, {0, 1, 2, 1, 3, 2}, {0, 1});
  add("water", "fluid", {0.5f, 0, 0, 0.52f, 0, 0}, {}, {});
  return t;
}

v1::SceneSpec sample_body_spec() {
  v1::SceneSpec spec;
  auto* rope = spec.add_bodies();
  rope->set_name("rope");
  rope->mutable_rope()->set_thickness(0.005);
  auto* sheet = spec.add_bodies();
  sheet->set_name("sheet");
  sheet->mutable_cloth()->set_thickness(0.002);
  auto* water = spec.add_bodies();
  water->set_name("water");
  water->mutable_fluid()->set_spacing(0.02);
  return spec;
}

// The sample frame with the bodies' positions; the rope's free end hangs below the surface and
// the fluid lies beyond it, so the bounding box is the bodies'.
v1::Frame sample_frame_with_bodies() {
  v1::Frame f = sample_frame();
  auto add = [&](const char* name, std::vector<float> x) {
    auto* b = f.add_bodies();
    b->set_name(name);
    for (float v : x) b->add_positions(v);
  };
  add("rope", {0.1f, 0, 0, 0.18f, -0.05f, 0, 0.2f, -0.12f, 0});
  add("sheet", {0, 0.1f, 0, 0.1f, 0.1f, 0, 0, 0.08f, 0.1f, 0.1f, 0.07f, 0.1f});
  add("water", {0.5f, -0.02f, 0, 0.52f, -0.02f, 0.01f});
  return f;
}

SurfaceTopology sample_surface_with_bodies() {
  SurfaceTopology s = surface_topology(sample_topology_with_bodies());
  set_body_sizes(s, sample_body_spec());
  return s;
}

TEST(WebWire, TopologyWithBodiesMatchesGoldenBytes) {
  const SurfaceTopology s = sample_surface_with_bodies();
  const std::string bytes = encode_topology(s, 9);
  // The surface-only topology, then per body 20 bytes, the name padded to 4, triangles, pinned
  // particles and rest positions.
  const size_t surface = 24u + 4u * (12 + 4 + 1 + 12);
  EXPECT_EQ(bytes.size(), surface + (20 + 4 + 0 + 4 + 36) + (20 + 8 + 24 + 8 + 48) + (20 + 8 + 0 + 0 + 24));
  EXPECT_EQ(bytes.substr(0, 2), encode_topology(surface_topology(sample_topology()), 9).substr(0, 2));
  EXPECT_EQ(bytes.substr(4, surface - 4), encode_topology(surface_topology(sample_topology()), 9).substr(4));
  uint16_t count;
  std::memcpy(&count, bytes.data() + 2, 2);
  EXPECT_EQ(count, 3u);
  // The first record: kind 3 (rope), name length 4, 3 particles, 0 triangles, 1 pinned, 5 mm.
  EXPECT_EQ(bytes[surface], 3);
  EXPECT_EQ(bytes[surface + 1], 4);
  float size;
  std::memcpy(&size, bytes.data() + surface + 16, 4);
  EXPECT_EQ(size, 0.005f);
  EXPECT_EQ(bytes.substr(surface + 20, 4), "rope");
  EXPECT_EQ(hex(bytes), golden("topology_bodies.hex", hex(bytes)));

  const SurfaceTopology d = decode_topology(bytes);
  ASSERT_EQ(d.bodies.size(), 3u);
  EXPECT_EQ(d.bodies[1].name, "sheet");
  EXPECT_EQ(d.bodies[1].kind, BodyKind::Cloth);
  EXPECT_EQ(d.bodies[1].triangles, (std::vector<uint32_t>{0, 1, 2, 1, 3, 2}));
  EXPECT_EQ(d.bodies[1].pinned, (std::vector<uint32_t>{0, 1}));
  EXPECT_EQ(d.bodies[1].size, 0.002f);
  EXPECT_EQ(d.bodies[2].kind, BodyKind::Fluid);
  EXPECT_EQ(d.bodies[2].size, 0.02f);
  EXPECT_EQ(d.bodies[2].rest_positions, s.bodies[2].rest_positions);
}

TEST(WebWire, FrameWithBodiesMatchesGoldenBytesInBothEncodings) {
  const SurfaceTopology s = sample_surface_with_bodies();
  const v1::Frame f = sample_frame_with_bodies();
  const std::vector<uint32_t> counts{3, 4, 2};
  for (Encoding e : {Encoding::Float32, Encoding::Quantized16}) {
    const bool f32 = e == Encoding::Float32;
    const std::string bytes = encode_frame(f, 9, e, 3, s.bodies);
    ASSERT_EQ(bytes.size(), frame_bytes(3, 2, e, counts));
    // After the surface: the body count, then per body its particle count and positions.
    EXPECT_EQ(bytes.size(), f32 ? 128u + 8 + 36 + 4 + (4 + 36) + (4 + 48) + (4 + 24)
                                : 128u + 8 + 20 + 4 + (4 + 20) + (4 + 24) + (4 + 12));
    EXPECT_EQ(hex(bytes), golden(f32 ? "frame_bodies_float32.hex" : "frame_bodies_uint16.hex", hex(bytes)));

    const FrameHeader h = decode_frame_header(bytes);
    EXPECT_EQ(h.flags, kFlagRolledBack | kFlagBodies);
    EXPECT_EQ(h.bbox_min[1], -0.12f);  // the rope's end
    EXPECT_EQ(h.bbox_max[0], 0.52f);   // the fluid
    const auto bodies = decode_frame_bodies(bytes);
    ASSERT_EQ(bodies.size(), 3u);
    const auto surface = decode_frame_positions(bytes);
    ASSERT_EQ(surface.size(), 9u);
    for (int b = 0; b < 3; ++b) {
      const auto& want = f.bodies(b).positions();
      ASSERT_EQ(bodies[b].size(), static_cast<size_t>(want.size())) << "body " << b;
      for (int i = 0; i < want.size(); ++i) {
        const int k = i % 3;
        const float tol = f32 ? 0.0f : 0.5f * (h.bbox_max[k] - h.bbox_min[k]) / 65535.0f + 1e-7f;
        EXPECT_LE(std::abs(bodies[b][i] - want[i]), tol) << "body " << b << " value " << i;
      }
    }
    for (int i = 0; i < 9; ++i) {
      const int k = i % 3;
      const float tol = f32 ? 0.0f : 0.5f * (h.bbox_max[k] - h.bbox_min[k]) / 65535.0f + 1e-7f;
      EXPECT_LE(std::abs(surface[i] - f.positions(i)), tol) << "surface value " << i;
    }
  }
  // Without bodies in the topology the frame is exactly the surface-only one.
  EXPECT_EQ(encode_frame(f, 9, Encoding::Float32, 3), encode_frame(sample_frame(), 9, Encoding::Float32, 3));
}

TEST(WebWire, FrameBodiesThatDoNotMatchTheTopologyAreRejected) {
  const SurfaceTopology s = sample_surface_with_bodies();
  v1::Frame f = sample_frame_with_bodies();
  f.mutable_bodies(1)->add_positions(0.0f);  // 13 values for the cloth's 4 particles
  try {
    encode_frame(f, 1, Encoding::Float32, 3, s.bodies);
    FAIL() << "accepted a cloth with a wrong number of positions";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'sheet'"), std::string::npos) << e.what();
  }
  f = sample_frame_with_bodies();
  f.mutable_bodies()->RemoveLast();
  EXPECT_THROW(encode_frame(f, 1, Encoding::Float32, 3, s.bodies), std::invalid_argument);
  v1::Topology t = sample_topology_with_bodies();
  t.mutable_bodies(1)->set_triangles(5, 4);  // particle 4 of 4
  try {
    surface_topology(t);
    FAIL() << "accepted a cloth triangle past the particles";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("particle 4 of 4"), std::string::npos) << e.what();
  }
  std::string b = encode_frame(sample_frame_with_bodies(), 1, Encoding::Float32, 3, s.bodies);
  b.resize(b.size() - 4);
  EXPECT_THROW(decode_frame_header(b), std::invalid_argument);
}

// The sample frame with bodies plus each body's step statistics (the frame's solver stats).
v1::Frame sample_frame_with_body_stats() {
  v1::Frame f = sample_frame_with_bodies();
  const struct {
    const char* name;
    double error, max_error, ms;
    int substeps, iterations;
    uint32_t contacts, tools, bodies, soft_body;
    bool suspended;
  } stats[] = {{"rope", 0.0125, 0.05, 0.25, 16, 1, 2, 0, 1, 5, false},
               {"sheet", 0.003, 0.0078125, 0.5, 16, 1, 0, 1, 0, 0, true},
               {"water", 0.015625, 0.125, 1.75, 2, 4, 7, 0, 3, 11, false}};
  for (const auto& st : stats) {
    auto* b = f.mutable_solver()->add_bodies();
    b->set_name(st.name);
    b->set_constraint_error(st.error);
    b->set_max_constraint_error(st.max_error);
    b->set_step_wall_ms(st.ms);
    b->set_substeps(st.substeps);
    b->set_iterations(st.iterations);
    b->set_contacts(st.contacts);
    b->set_tool_contacts(st.tools);
    b->set_body_contacts(st.bodies);
    b->set_soft_body_contacts(st.soft_body);
    b->set_self_collision_suspended(st.suspended);
  }
  return f;
}

TEST(WebWire, BodyStatisticsFollowTheBodiesAndMatchGoldenBytes) {
  const SurfaceTopology s = sample_surface_with_bodies();
  const v1::Frame f = sample_frame_with_body_stats();
  const std::vector<uint32_t> counts{3, 4, 2};
  const std::string bytes = encode_frame(f, 9, Encoding::Float32, 3, s.bodies);
  ASSERT_EQ(bytes.size(), frame_bytes(3, 2, Encoding::Float32, counts, true, true));
  EXPECT_EQ(bytes.size(),
            frame_bytes(3, 2, Encoding::Float32, counts) + 4 + 3 * kBodyStatsBytes + 4 + 3 * kBodyContactsBytes);
  EXPECT_EQ(hex(bytes), golden("frame_body_stats_float32.hex", hex(bytes)));
  const FrameHeader h = decode_frame_header(bytes);
  EXPECT_EQ(h.flags, kFlagRolledBack | kFlagBodies | kFlagBodyStats | kFlagBodyContacts);
  // The positions read as without the statistics.
  EXPECT_EQ(decode_frame_bodies(bytes), decode_frame_bodies(encode_frame(sample_frame_with_bodies(), 9,
                                                                         Encoding::Float32, 3, s.bodies)));
  const auto st = decode_frame_body_stats(bytes);
  ASSERT_EQ(st.size(), 3u);
  EXPECT_EQ(st[0].constraint_error, 0.0125f);
  EXPECT_EQ(st[1].max_constraint_error, 0.0078125f);
  EXPECT_EQ(st[2].step_ms, 1.75f);
  EXPECT_EQ(st[2].substeps, 2u);
  EXPECT_EQ(st[2].iterations, 4u);
  EXPECT_EQ(st[2].contacts, 7u);
  EXPECT_EQ(st[1].tool_contacts, 1u);
  EXPECT_EQ(st[2].body_contacts, 3u);
  EXPECT_EQ(st[0].soft_body_contacts, 5u);
  EXPECT_EQ(st[2].soft_body_contacts, 11u);
  EXPECT_FALSE(st[0].self_collision_suspended);
  EXPECT_TRUE(st[1].self_collision_suspended);
  // Statistics that do not list the topology's bodies (another order) are left out.
  v1::Frame other = f;
  other.mutable_solver()->mutable_bodies(0)->set_name("sheet");
  const std::string without = encode_frame(other, 9, Encoding::Float32, 3, s.bodies);
  EXPECT_EQ(decode_frame_header(without).flags & (kFlagBodyStats | kFlagBodyContacts), 0u);
  EXPECT_TRUE(decode_frame_body_stats(without).empty());
  // Cut short, the frame is refused; a contacts block for another number of bodies too.
  EXPECT_THROW(decode_frame_header(bytes.substr(0, bytes.size() - 4)), std::invalid_argument);
  std::string bad = bytes;
  bad[bytes.size() - 3 * kBodyContactsBytes - 4] = 2;
  EXPECT_THROW(decode_frame_body_stats(bad), std::invalid_argument);
}

TEST(WebWire, AFluidWithEmittersMayGrowUpToItsMostAndOthersMayNot) {
  // The water may reach 4 particles (BodyTopology.max_particle_count); the cloth keeps its 4.
  v1::Topology t = sample_topology_with_bodies();
  t.mutable_bodies(2)->set_max_particle_count(4);
  t.mutable_bodies(1)->set_max_particle_count(9);  // ignored: a cloth's count is fixed
  SurfaceTopology s = surface_topology(t);
  set_body_sizes(s, sample_body_spec());
  EXPECT_EQ(s.bodies[2].max_particles, 4u);
  v1::Frame f = sample_frame_with_bodies();
  for (float v : {0.54f, -0.02f, 0.0f}) f.mutable_bodies(2)->add_positions(v);  // 3 particles now
  const std::string b = encode_frame(f, 1, Encoding::Float32, 3, s.bodies);
  const auto bodies = decode_frame_bodies(b);
  ASSERT_EQ(bodies.size(), 3u);
  ASSERT_EQ(bodies[2].size(), 9u);
  EXPECT_EQ(bodies[2][6], 0.54f);
  const std::vector<uint32_t> counts{3, 4, 3};
  EXPECT_EQ(b.size(), frame_bytes(3, static_cast<uint32_t>(f.residuals_size()), Encoding::Float32, counts));
  for (float v : {0.56f, -0.02f, 0.0f, 0.58f, -0.02f, 0.0f}) f.mutable_bodies(2)->add_positions(v);  // 5
  try {
    encode_frame(f, 1, Encoding::Float32, 3, s.bodies);
    FAIL() << "accepted a fluid beyond its most particles";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("'water' with 6 (up to 12)"), std::string::npos) << e.what();
  }
  f = sample_frame_with_bodies();
  for (float v : {0.0f, 0.2f, 0.0f}) f.mutable_bodies(1)->add_positions(v);  // a fifth cloth particle
  EXPECT_THROW(encode_frame(f, 1, Encoding::Float32, 3, s.bodies), std::invalid_argument);
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
