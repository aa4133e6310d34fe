// SPDX-License-Identifier: Apache-2.0
// The binary messages pliant-web sends to the browser (docs/web.md, "Binary messages"): the
// topology once per subscription and one frame per tick shown. Little-endian, every array
// 4-byte aligned so the page views positions in place (Float32Array over the message).
#pragma once

#include "pliant/v1/pliant.pb.h"

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace pliant::web {

inline constexpr uint8_t kWireVersion = 1;
inline constexpr uint8_t kKindTopology = 1;
inline constexpr uint8_t kKindFrame = 2;
inline constexpr size_t kTopologyHeaderBytes = 24;
inline constexpr size_t kFrameHeaderBytes = 128;
// Byte offset of the frame header's skipped_frames (u32): the socket's send slot adds the
// frames it dropped there when it sends (see Outbox).
inline constexpr size_t kFrameSkippedOffset = 48;
// Frame header flags (offset 100).
inline constexpr uint32_t kFlagRolledBack = 1u << 0;
inline constexpr uint32_t kFlagBodies = 1u << 1;  // particle bodies follow the surface positions
inline constexpr uint32_t kFlagBodyStats = 1u << 2;  // each body's step statistics follow the bodies
inline constexpr size_t kBodyStatsBytes = 32;         // one body's statistics record
// Each body's contacts with the soft body and its step's flags follow the statistics.
inline constexpr uint32_t kFlagBodyContacts = 1u << 3;
inline constexpr size_t kBodyContactsBytes = 8;  // u32 soft-body contacts, u32 flags
inline constexpr uint32_t kBodySelfCollisionSuspended = 1u << 0;  // its flags: self-collision left out
// A particle body's record in the topology: 20 fixed bytes, then its name padded to 4.
inline constexpr size_t kBodyRecordBytes = 20;

// Particle body kinds on the wire (BodyTopology.kind).
enum class BodyKind : uint8_t { Other = 0, Fluid = 1, Cloth = 2, Rope = 3 };
BodyKind body_kind(const std::string& name);

enum class Encoding : uint8_t { Float32 = 0, Quantized16 = 1 };

// A particle body as the page draws it (fluid, cloth or rope: docs/web.md, "Topology").
struct ParticleBody {
  std::string name;
  BodyKind kind = BodyKind::Other;
  float size = 0;                       // m: a fluid's spacing, a cloth's or rope's thickness; 0 unknown
  std::vector<uint32_t> triangles;      // cloth: 3 particle indices per triangle
  std::vector<uint32_t> pinned;         // ascending particle indices
  std::vector<float> rest_positions;    // 3 per particle (at creation)
  uint32_t max_particles = 0;           // a fluid with emitters grows up to it; 0: the creation count

  uint32_t particle_count() const { return static_cast<uint32_t>(rest_positions.size() / 3); }
  // How many positions a frame of this body may carry: its creation count, or for a growing
  // fluid any count up to max_particles.
  bool frame_count_ok(uint32_t count) const {
    return count == particle_count() || (kind == BodyKind::Fluid && count <= max_particles);
  }
};

// The surface of a body as the page draws it: triangles index the surface vertices, which map
// to body vertices (for grabs); fixed vertices are surface-local indices.
struct SurfaceTopology {
  uint32_t body_vertex_count = 0;
  std::vector<uint32_t> triangles;         // 3 per triangle, surface-local
  std::vector<uint32_t> surface_to_body;   // surface vertex -> body vertex
  std::vector<uint32_t> fixed;             // surface-local indices of fixed vertices
  std::vector<float> rest_positions;       // 3 per surface vertex
  std::vector<ParticleBody> bodies;        // the scene's particle bodies, in the server's order

  uint32_t surface_vertex_count() const { return static_cast<uint32_t>(surface_to_body.size()); }
};

// Builds the surface view of a server topology. Throws std::invalid_argument when a triangle
// uses a vertex that is not in surface_vertices or an index is out of range.
// The particle bodies are checked the same way (counts, indices below the particle count).
SurfaceTopology surface_topology(const v1::Topology& topology);
// Fills each body's size from the scene's spec (GetScene echoes the values in use): a fluid's
// spacing, a cloth's or rope's thickness. Bodies the spec does not name keep size 0.
void set_body_sizes(SurfaceTopology& topology, const v1::SceneSpec& spec);

std::string encode_topology(const SurfaceTopology& topology, uint32_t subscription);
SurfaceTopology decode_topology(const std::string& bytes, uint32_t* subscription = nullptr);

// The fixed frame header, as decoded (and as the page reads it).
struct FrameHeader {
  Encoding encoding = Encoding::Float32;
  uint8_t state = 0;  // v1::SceneState
  uint32_t subscription = 0;
  uint32_t vertex_count = 0;
  uint32_t residual_count = 0;
  uint64_t tick = 0;
  double sim_time = 0;
  uint64_t late_ticks = 0;
  uint64_t skipped_ticks = 0;
  uint32_t skipped_frames = 0;
  uint32_t iterations = 0;
  double ticks_per_second = 0;
  double residual = 0;
  double step_ms = 0;
  double lateness_ms = 0;
  int64_t published_unix_ns = 0;
  uint32_t rollbacks = 0;
  uint32_t flags = 0;  // bit 0: this tick was rolled back; bit 1: particle bodies follow; bit 2: their stats
  std::array<float, 3> bbox_min{};
  std::array<float, 3> bbox_max{};
};

// Encodes a surface-only frame (positions in surface_vertices order), then the particle
// bodies' positions when `bodies` (the topology's) is not empty, and their statistics when the
// frame's solver stats list the same bodies. Throws std::invalid_argument
// when positions is not 3 x expected_vertices floats (0 allowed: a frame without positions),
// or the frame's bodies differ from `bodies` in order, names or particle counts.
std::string encode_frame(const v1::Frame& frame, uint32_t subscription, Encoding encoding,
                         uint32_t expected_vertices, std::span<const ParticleBody> bodies = {});

FrameHeader decode_frame_header(const std::string& bytes);
// Residuals and positions of an encoded frame (16-bit positions dequantised).
std::vector<float> decode_frame_residuals(const std::string& bytes);
std::vector<float> decode_frame_positions(const std::string& bytes);
// Each particle body's positions (dequantised), in the topology's order; empty without bodies.
std::vector<std::vector<float>> decode_frame_bodies(const std::string& bytes);

// One particle body's step in the frame's tick (v1::BodyStepStats), as the page reads it.
struct BodyStats {
  float constraint_error = 0;      // a fluid's mean relative density error, a cloth's or rope's RMS stretch
  float max_constraint_error = 0;
  float step_ms = 0;               // its step and contacts, wall time
  uint32_t substeps = 0;
  uint32_t iterations = 0;         // per substep
  uint32_t contacts = 0;           // particle-collider contacts in the last substep
  uint32_t tool_contacts = 0;      // particles the tools pushed
  uint32_t body_contacts = 0;      // particles and points along links the cloths and ropes pushed
  // With kFlagBodyContacts (else 0 / false):
  uint32_t soft_body_contacts = 0;       // particles and points along links the soft body pushed
  bool self_collision_suspended = false;  // a cloth's tick left self-collision out (over-stretched)
};
// Each body's statistics, in the topology's order; empty when the frame has none.
std::vector<BodyStats> decode_frame_body_stats(const std::string& bytes);

// Bytes of one frame with n surface vertices and r residuals (and these particle bodies, with
// their statistics when body_stats and their contacts when body_contacts).
size_t frame_bytes(uint32_t vertices, uint32_t residuals, Encoding encoding);
size_t frame_bytes(uint32_t vertices, uint32_t residuals, Encoding encoding,
                   std::span<const uint32_t> body_particles, bool body_stats = false, bool body_contacts = false);

}  // namespace pliant::web
