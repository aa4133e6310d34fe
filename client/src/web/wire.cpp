// SPDX-License-Identifier: Apache-2.0
#include "wire.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <unordered_map>

namespace pliant::web {

static_assert(std::endian::native == std::endian::little, "the wire format is little-endian");

namespace {

// Appends plain values to a byte string.
class Writer {
 public:
  explicit Writer(size_t reserve) { out_.reserve(reserve); }
  template <class T>
  void put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    out_.append(b, sizeof(T));
  }
  template <class T>
  void put_array(const T* data, size_t n) {
    out_.append(reinterpret_cast<const char*>(data), n * sizeof(T));
  }
  void pad_to_4() {
    while (out_.size() % 4) out_.push_back('\0');
  }
  std::string& bytes() { return out_; }

 private:
  std::string out_;
};

// Reads plain values at offsets, checking the bounds.
class Reader {
 public:
  explicit Reader(const std::string& b) : b_(b) {}
  template <class T>
  T at(size_t offset) const {
    if (offset + sizeof(T) > b_.size())
      throw std::invalid_argument("message of " + std::to_string(b_.size()) + " bytes is too short (read at " +
                                  std::to_string(offset) + ")");
    T v;
    std::memcpy(&v, b_.data() + offset, sizeof(T));
    return v;
  }
  template <class T>
  std::vector<T> array(size_t offset, size_t n) const {
    if (offset + n * sizeof(T) > b_.size())
      throw std::invalid_argument("message of " + std::to_string(b_.size()) + " bytes is too short for an array of " +
                                  std::to_string(n) + " at " + std::to_string(offset));
    std::vector<T> v(n);
    if (n) std::memcpy(v.data(), b_.data() + offset, n * sizeof(T));
    return v;
  }

 private:
  const std::string& b_;
};

void check_kind(const Reader& r, uint8_t kind) {
  const auto k = r.at<uint8_t>(0), ver = r.at<uint8_t>(1);
  if (k != kind) throw std::invalid_argument("message kind " + std::to_string(k) + ", expected " + std::to_string(kind));
  if (ver != kWireVersion) throw std::invalid_argument("wire version " + std::to_string(ver) + " not supported");
}

uint32_t saturate_u32(uint64_t v) {
  return static_cast<uint32_t>(std::min<uint64_t>(v, std::numeric_limits<uint32_t>::max()));
}

// Bytes of 3 x n positions in an encoding (16-bit padded to 4).
size_t position_bytes(uint32_t n, Encoding encoding) {
  return encoding == Encoding::Float32 ? 12 * size_t(n) : (6 * size_t(n) + 3) / 4 * 4;
}

// Writes 3 x n positions, 16-bit ones quantised against [lo, hi] per axis.
void put_positions(Writer& w, const float* p, size_t values, Encoding encoding, const std::array<float, 3>& lo,
                   const std::array<float, 3>& hi) {
  if (encoding == Encoding::Float32) {
    w.put_array(p, values);
    return;
  }
  // q = round((x - lo) / (hi - lo) * 65535); a flat axis (hi == lo) encodes as 0.
  for (size_t i = 0; i < values; i += 3)
    for (int k = 0; k < 3; ++k) {
      const float ext = hi[k] - lo[k];
      const float u = ext > 0 ? (p[i + k] - lo[k]) / ext : 0.0f;
      w.put<uint16_t>(static_cast<uint16_t>(std::lround(std::clamp(u, 0.0f, 1.0f) * 65535.0f)));
    }
  w.pad_to_4();
}

std::vector<float> read_positions(const Reader& r, size_t off, uint32_t n, const FrameHeader& h) {
  const size_t values = 3 * size_t(n);
  if (h.encoding == Encoding::Float32) return r.array<float>(off, values);
  const auto q = r.array<uint16_t>(off, values);
  std::vector<float> out(values);
  for (size_t i = 0; i < values; ++i) {
    const int k = static_cast<int>(i % 3);
    out[i] = h.bbox_min[k] + (h.bbox_max[k] - h.bbox_min[k]) * (static_cast<float>(q[i]) / 65535.0f);
  }
  return out;
}

// Offset of a frame's body section (after the surface positions).
size_t body_section_offset(const FrameHeader& h) {
  return kFrameHeaderBytes + 4 * size_t(h.residual_count) + position_bytes(h.vertex_count, h.encoding);
}

// The particle counts of a frame's bodies, walking the body section.
std::vector<uint32_t> frame_body_counts(const Reader& r, const FrameHeader& h) {
  std::vector<uint32_t> counts;
  if (!(h.flags & kFlagBodies)) return counts;
  size_t off = body_section_offset(h);
  const uint32_t b = r.at<uint32_t>(off);
  off += 4;
  for (uint32_t i = 0; i < b; ++i) {
    counts.push_back(r.at<uint32_t>(off));
    off += 4 + position_bytes(counts.back(), h.encoding);
  }
  return counts;
}

}  // namespace

BodyKind body_kind(const std::string& name) {
  if (name == "fluid") return BodyKind::Fluid;
  if (name == "cloth") return BodyKind::Cloth;
  if (name == "rope") return BodyKind::Rope;
  return BodyKind::Other;
}

SurfaceTopology surface_topology(const v1::Topology& t) {
  SurfaceTopology s;
  s.body_vertex_count = t.vertex_count();
  if (t.rest_positions_size() != 3 * static_cast<int>(t.vertex_count()))
    throw std::invalid_argument("topology rest_positions has " + std::to_string(t.rest_positions_size()) +
                                " values for " + std::to_string(t.vertex_count()) + " vertices");
  std::unordered_map<uint32_t, uint32_t> local;
  local.reserve(t.surface_vertices_size());
  for (int v : t.surface_vertices()) {
    if (v < 0 || static_cast<uint32_t>(v) >= t.vertex_count())
      throw std::invalid_argument("topology surface vertex " + std::to_string(v) + " out of range");
    local.emplace(v, static_cast<uint32_t>(s.surface_to_body.size()));
    s.surface_to_body.push_back(static_cast<uint32_t>(v));
    for (int k = 0; k < 3; ++k) s.rest_positions.push_back(t.rest_positions(3 * v + k));
  }
  s.triangles.reserve(t.surface_triangles_size());
  for (int v : t.surface_triangles()) {
    auto it = local.find(static_cast<uint32_t>(v));
    if (it == local.end())
      throw std::invalid_argument("topology surface triangle uses vertex " + std::to_string(v) +
                                  ", which is not a surface vertex");
    s.triangles.push_back(it->second);
  }
  for (int v : t.fixed_vertices()) {
    auto it = local.find(static_cast<uint32_t>(v));
    if (it != local.end()) s.fixed.push_back(it->second);
  }
  std::sort(s.fixed.begin(), s.fixed.end());
  for (const auto& b : t.bodies()) {
    const std::string what = "topology body '" + b.name() + "'";
    if (b.name().empty() || b.name().size() > 255)
      throw std::invalid_argument("topology body name must have 1 to 255 bytes, got '" + b.name() + "'");
    const uint32_t p = b.particle_count();
    if (b.rest_positions_size() != 3 * static_cast<int64_t>(p))
      throw std::invalid_argument(what + " has " + std::to_string(b.rest_positions_size()) +
                                  " rest position values for " + std::to_string(p) + " particles");
    if (b.triangles_size() % 3)
      throw std::invalid_argument(what + " has " + std::to_string(b.triangles_size()) +
                                  " triangle indices, not a multiple of 3");
    for (uint32_t v : b.triangles())
      if (v >= p)
        throw std::invalid_argument(what + " triangle uses particle " + std::to_string(v) + " of " + std::to_string(p));
    for (uint32_t v : b.pinned())
      if (v >= p)
        throw std::invalid_argument(what + " pins particle " + std::to_string(v) + " of " + std::to_string(p));
    ParticleBody pb;
    pb.name = b.name();
    pb.kind = body_kind(b.kind());
    pb.triangles.assign(b.triangles().begin(), b.triangles().end());
    pb.pinned.assign(b.pinned().begin(), b.pinned().end());
    std::sort(pb.pinned.begin(), pb.pinned.end());
    pb.rest_positions.assign(b.rest_positions().begin(), b.rest_positions().end());
    pb.max_particles = std::max(b.max_particle_count(), p);
    s.bodies.push_back(std::move(pb));
  }
  if (s.bodies.size() > std::numeric_limits<uint16_t>::max())
    throw std::invalid_argument("topology has " + std::to_string(s.bodies.size()) + " particle bodies, at most 65535");
  return s;
}

void set_body_sizes(SurfaceTopology& t, const v1::SceneSpec& spec) {
  for (const auto& b : spec.bodies()) {
    float size = 0;
    if (b.has_fluid() && b.fluid().has_spacing()) size = static_cast<float>(b.fluid().spacing());
    if (b.has_cloth() && b.cloth().has_thickness()) size = static_cast<float>(b.cloth().thickness());
    if (b.has_rope() && b.rope().has_thickness()) size = static_cast<float>(b.rope().thickness());
    for (auto& pb : t.bodies)
      if (pb.name == b.name()) pb.size = size;
  }
}

std::string encode_topology(const SurfaceTopology& t, uint32_t subscription) {
  const uint32_t n = t.surface_vertex_count();
  if (t.triangles.size() % 3 || t.rest_positions.size() != 3 * size_t(n))
    throw std::invalid_argument("surface topology has inconsistent array sizes");
  Writer w(kTopologyHeaderBytes + 4 * (t.triangles.size() + n + t.fixed.size() + 3 * size_t(n)));
  if (t.bodies.size() > std::numeric_limits<uint16_t>::max())
    throw std::invalid_argument("surface topology has more than 65535 particle bodies");
  w.put<uint8_t>(kKindTopology);
  w.put<uint8_t>(kWireVersion);
  w.put<uint16_t>(static_cast<uint16_t>(t.bodies.size()));
  w.put<uint32_t>(subscription);
  w.put<uint32_t>(n);
  w.put<uint32_t>(static_cast<uint32_t>(t.triangles.size() / 3));
  w.put<uint32_t>(static_cast<uint32_t>(t.fixed.size()));
  w.put<uint32_t>(t.body_vertex_count);
  w.put_array(t.triangles.data(), t.triangles.size());
  w.put_array(t.surface_to_body.data(), n);
  w.put_array(t.fixed.data(), t.fixed.size());
  w.put_array(t.rest_positions.data(), t.rest_positions.size());
  for (const ParticleBody& b : t.bodies) {
    if (b.name.empty() || b.name.size() > 255 || b.rest_positions.size() % 3 || b.triangles.size() % 3)
      throw std::invalid_argument("particle body '" + b.name + "' has inconsistent array sizes or name");
    w.put<uint8_t>(static_cast<uint8_t>(b.kind));
    w.put<uint8_t>(static_cast<uint8_t>(b.name.size()));
    w.put<uint16_t>(0);
    w.put<uint32_t>(b.particle_count());
    w.put<uint32_t>(static_cast<uint32_t>(b.triangles.size() / 3));
    w.put<uint32_t>(static_cast<uint32_t>(b.pinned.size()));
    w.put<float>(b.size);
    w.put_array(b.name.data(), b.name.size());
    w.pad_to_4();
    w.put_array(b.triangles.data(), b.triangles.size());
    w.put_array(b.pinned.data(), b.pinned.size());
    w.put_array(b.rest_positions.data(), b.rest_positions.size());
  }
  return std::move(w.bytes());
}

SurfaceTopology decode_topology(const std::string& bytes, uint32_t* subscription) {
  Reader r(bytes);
  check_kind(r, kKindTopology);
  if (subscription) *subscription = r.at<uint32_t>(4);
  const uint32_t n = r.at<uint32_t>(8), tris = r.at<uint32_t>(12), fixed = r.at<uint32_t>(16);
  SurfaceTopology t;
  t.body_vertex_count = r.at<uint32_t>(20);
  size_t off = kTopologyHeaderBytes;
  t.triangles = r.array<uint32_t>(off, 3 * size_t(tris));
  off += 12 * size_t(tris);
  t.surface_to_body = r.array<uint32_t>(off, n);
  off += 4 * size_t(n);
  t.fixed = r.array<uint32_t>(off, fixed);
  off += 4 * size_t(fixed);
  t.rest_positions = r.array<float>(off, 3 * size_t(n));
  off += 12 * size_t(n);
  const uint16_t bodies = r.at<uint16_t>(2);
  for (uint16_t i = 0; i < bodies; ++i) {
    ParticleBody b;
    const uint8_t kind = r.at<uint8_t>(off);
    if (kind > static_cast<uint8_t>(BodyKind::Rope)) throw std::invalid_argument("body kind " + std::to_string(kind) + " unknown");
    b.kind = static_cast<BodyKind>(kind);
    const uint8_t len = r.at<uint8_t>(off + 1);
    const uint32_t p = r.at<uint32_t>(off + 4), tris = r.at<uint32_t>(off + 8), pinned = r.at<uint32_t>(off + 12);
    b.size = r.at<float>(off + 16);
    off += kBodyRecordBytes;
    const auto name = r.array<char>(off, len);
    b.name.assign(name.begin(), name.end());
    off += (size_t(len) + 3) / 4 * 4;
    b.triangles = r.array<uint32_t>(off, 3 * size_t(tris));
    off += 12 * size_t(tris);
    b.pinned = r.array<uint32_t>(off, pinned);
    off += 4 * size_t(pinned);
    b.rest_positions = r.array<float>(off, 3 * size_t(p));
    off += 12 * size_t(p);
    t.bodies.push_back(std::move(b));
  }
  if (off != bytes.size())
    throw std::invalid_argument("topology of " + std::to_string(bytes.size()) + " bytes, its header says " +
                                std::to_string(off));
  return t;
}

size_t frame_bytes(uint32_t vertices, uint32_t residuals, Encoding encoding) {
  return kFrameHeaderBytes + 4 * size_t(residuals) + position_bytes(vertices, encoding);
}

size_t frame_bytes(uint32_t vertices, uint32_t residuals, Encoding encoding, std::span<const uint32_t> body_particles,
                   bool body_stats, bool body_contacts) {
  size_t n = frame_bytes(vertices, residuals, encoding);
  if (body_particles.empty()) return n;
  n += 4;
  for (uint32_t p : body_particles) n += 4 + position_bytes(p, encoding);
  if (body_stats) n += 4 + kBodyStatsBytes * body_particles.size();
  if (body_contacts) n += 4 + kBodyContactsBytes * body_particles.size();
  return n;
}

std::string encode_frame(const v1::Frame& f, uint32_t subscription, Encoding encoding, uint32_t expected_vertices,
                         std::span<const ParticleBody> bodies) {
  const size_t values = f.positions_size();
  if (values != 0 && values != 3 * size_t(expected_vertices))
    throw std::invalid_argument("frame has " + std::to_string(values) + " position values, expected " +
                                std::to_string(3 * size_t(expected_vertices)));
  const uint32_t n = static_cast<uint32_t>(values / 3);
  const uint32_t r = static_cast<uint32_t>(f.residuals_size());
  const float* p = f.positions().data();

  // The particle bodies travel with the positions: all of them, as in the topology, or none.
  const bool with_bodies = values != 0 && !bodies.empty();
  std::vector<uint32_t> counts;
  if (with_bodies) {
    if (f.bodies_size() != static_cast<int>(bodies.size()))
      throw std::invalid_argument("frame has " + std::to_string(f.bodies_size()) + " particle bodies, the topology " +
                                  std::to_string(bodies.size()));
    for (size_t i = 0; i < bodies.size(); ++i) {
      const auto& fb = f.bodies(static_cast<int>(i));
      const uint32_t count = static_cast<uint32_t>(fb.positions_size() / 3);
      if (fb.name() != bodies[i].name || fb.positions_size() % 3 != 0 || !bodies[i].frame_count_ok(count))
        throw std::invalid_argument("frame body " + std::to_string(i) + " is '" + fb.name() + "' with " +
                                    std::to_string(fb.positions_size()) + " position values, the topology's is '" +
                                    bodies[i].name + "' with " + std::to_string(3 * size_t(bodies[i].particle_count())) +
                                    (bodies[i].max_particles > bodies[i].particle_count()
                                         ? " (up to " + std::to_string(3 * size_t(bodies[i].max_particles)) + ")"
                                         : std::string()));
      counts.push_back(count);
    }
  }
  // The bodies' statistics travel with them when the frame's solver stats list the same bodies.
  bool with_stats = with_bodies && f.solver().bodies_size() == static_cast<int>(bodies.size());
  for (int i = 0; with_stats && i < f.solver().bodies_size(); ++i)
    with_stats = f.solver().bodies(i).name() == bodies[size_t(i)].name;

  // The bounding box of everything the frame carries (the 16-bit encoding's range).
  std::array<float, 3> lo{0, 0, 0}, hi{0, 0, 0};
  bool any = false;
  auto extend = [&](const float* x, size_t count) {
    for (size_t i = 0; i < count; i += 3) {
      if (!any) {
        lo = {x[i], x[i + 1], x[i + 2]};
        hi = lo;
        any = true;
      }
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], x[i + k]);
        hi[k] = std::max(hi[k], x[i + k]);
      }
    }
  };
  extend(p, values);
  if (with_bodies)
    for (const auto& fb : f.bodies()) extend(fb.positions().data(), fb.positions_size());

  Writer w(frame_bytes(n, r, encoding, counts, with_stats, with_stats));
  w.put<uint8_t>(kKindFrame);
  w.put<uint8_t>(kWireVersion);
  w.put<uint8_t>(static_cast<uint8_t>(encoding));
  w.put<uint8_t>(static_cast<uint8_t>(f.state()));
  w.put<uint32_t>(subscription);
  w.put<uint32_t>(n);
  w.put<uint32_t>(r);
  w.put<uint64_t>(f.tick());                        // 16
  w.put<double>(f.sim_time());                      // 24
  w.put<uint64_t>(f.late_ticks());                  // 32
  w.put<uint64_t>(f.skipped_ticks());               // 40
  w.put<uint32_t>(saturate_u32(f.skipped_frames()));  // 48
  w.put<uint32_t>(static_cast<uint32_t>(std::max(0, f.solver().iterations())));
  w.put<double>(f.ticks_per_second());              // 56
  w.put<double>(f.solver().residual_final());       // 64
  w.put<double>(f.solver().step_wall_ms());         // 72
  w.put<double>(f.lateness_ms());                   // 80
  w.put<int64_t>(f.published_unix_ns());            // 88
  w.put<uint32_t>(saturate_u32(f.rollbacks()));     // 96
  w.put<uint32_t>((f.rolled_back() ? kFlagRolledBack : 0u) | (with_bodies ? kFlagBodies : 0u) |
                  (with_stats ? kFlagBodyStats | kFlagBodyContacts : 0u));  // 100
  w.put_array(lo.data(), 3);                        // 104
  w.put_array(hi.data(), 3);                        // 116
  for (double res : f.residuals()) w.put<float>(static_cast<float>(res));  // 128
  put_positions(w, p, values, encoding, lo, hi);
  if (with_bodies) {
    w.put<uint32_t>(static_cast<uint32_t>(counts.size()));
    for (size_t i = 0; i < counts.size(); ++i) {
      w.put<uint32_t>(counts[i]);
      const auto& fb = f.bodies(static_cast<int>(i));
      put_positions(w, fb.positions().data(), fb.positions_size(), encoding, lo, hi);
    }
  }
  if (with_stats) {
    w.put<uint32_t>(static_cast<uint32_t>(counts.size()));
    for (const auto& s : f.solver().bodies()) {
      w.put<float>(static_cast<float>(s.constraint_error()));
      w.put<float>(static_cast<float>(s.max_constraint_error()));
      w.put<float>(static_cast<float>(s.step_wall_ms()));
      w.put<uint32_t>(static_cast<uint32_t>(std::max(0, s.substeps())));
      w.put<uint32_t>(static_cast<uint32_t>(std::max(0, s.iterations())));
      w.put<uint32_t>(s.contacts());
      w.put<uint32_t>(s.tool_contacts());
      w.put<uint32_t>(s.body_contacts());
    }
    w.put<uint32_t>(static_cast<uint32_t>(counts.size()));
    for (const auto& s : f.solver().bodies()) {
      w.put<uint32_t>(s.soft_body_contacts());
      w.put<uint32_t>(s.self_collision_suspended() ? kBodySelfCollisionSuspended : 0u);
    }
  }
  return std::move(w.bytes());
}

FrameHeader decode_frame_header(const std::string& bytes) {
  Reader r(bytes);
  check_kind(r, kKindFrame);
  FrameHeader h;
  const auto enc = r.at<uint8_t>(2);
  if (enc > 1) throw std::invalid_argument("frame encoding " + std::to_string(enc) + " unknown");
  h.encoding = static_cast<Encoding>(enc);
  h.state = r.at<uint8_t>(3);
  h.subscription = r.at<uint32_t>(4);
  h.vertex_count = r.at<uint32_t>(8);
  h.residual_count = r.at<uint32_t>(12);
  h.tick = r.at<uint64_t>(16);
  h.sim_time = r.at<double>(24);
  h.late_ticks = r.at<uint64_t>(32);
  h.skipped_ticks = r.at<uint64_t>(40);
  h.skipped_frames = r.at<uint32_t>(48);
  h.iterations = r.at<uint32_t>(52);
  h.ticks_per_second = r.at<double>(56);
  h.residual = r.at<double>(64);
  h.step_ms = r.at<double>(72);
  h.lateness_ms = r.at<double>(80);
  h.published_unix_ns = r.at<int64_t>(88);
  h.rollbacks = r.at<uint32_t>(96);
  h.flags = r.at<uint32_t>(100);
  for (int k = 0; k < 3; ++k) {
    h.bbox_min[k] = r.at<float>(104 + 4 * k);
    h.bbox_max[k] = r.at<float>(116 + 4 * k);
  }
  const size_t expected =
      frame_bytes(h.vertex_count, h.residual_count, h.encoding, frame_body_counts(r, h), (h.flags & kFlagBodyStats) != 0,
                  (h.flags & kFlagBodyStats) != 0 && (h.flags & kFlagBodyContacts) != 0);
  if (bytes.size() != expected)
    throw std::invalid_argument("frame of " + std::to_string(bytes.size()) + " bytes, its header says " +
                                std::to_string(expected));
  return h;
}

std::vector<float> decode_frame_residuals(const std::string& bytes) {
  const FrameHeader h = decode_frame_header(bytes);
  return Reader(bytes).array<float>(kFrameHeaderBytes, h.residual_count);
}

std::vector<float> decode_frame_positions(const std::string& bytes) {
  const FrameHeader h = decode_frame_header(bytes);
  return read_positions(Reader(bytes), kFrameHeaderBytes + 4 * size_t(h.residual_count), h.vertex_count, h);
}

std::vector<std::vector<float>> decode_frame_bodies(const std::string& bytes) {
  const FrameHeader h = decode_frame_header(bytes);
  const Reader r(bytes);
  std::vector<std::vector<float>> out;
  size_t off = body_section_offset(h) + 4;
  for (uint32_t p : frame_body_counts(r, h)) {
    out.push_back(read_positions(r, off + 4, p, h));
    off += 4 + position_bytes(p, h.encoding);
  }
  return out;
}

std::vector<BodyStats> decode_frame_body_stats(const std::string& bytes) {
  const FrameHeader h = decode_frame_header(bytes);
  std::vector<BodyStats> out;
  if (!(h.flags & kFlagBodyStats)) return out;
  const Reader r(bytes);
  const auto counts = frame_body_counts(r, h);
  size_t off = body_section_offset(h) + 4;
  for (uint32_t p : counts) off += 4 + position_bytes(p, h.encoding);
  const uint32_t b = r.at<uint32_t>(off);
  off += 4;
  for (uint32_t i = 0; i < b; ++i, off += kBodyStatsBytes) {
    BodyStats s;
    s.constraint_error = r.at<float>(off);
    s.max_constraint_error = r.at<float>(off + 4);
    s.step_ms = r.at<float>(off + 8);
    s.substeps = r.at<uint32_t>(off + 12);
    s.iterations = r.at<uint32_t>(off + 16);
    s.contacts = r.at<uint32_t>(off + 20);
    s.tool_contacts = r.at<uint32_t>(off + 24);
    s.body_contacts = r.at<uint32_t>(off + 28);
    out.push_back(s);
  }
  if (h.flags & kFlagBodyContacts) {
    const uint32_t bc = r.at<uint32_t>(off);
    if (bc != b)
      throw std::invalid_argument("frame body contacts for " + std::to_string(bc) + " bodies, statistics for " +
                                  std::to_string(b));
    off += 4;
    for (uint32_t i = 0; i < b; ++i, off += kBodyContactsBytes) {
      out[i].soft_body_contacts = r.at<uint32_t>(off);
      out[i].self_collision_suspended = (r.at<uint32_t>(off + 4) & kBodySelfCollisionSuspended) != 0;
    }
  }
  return out;
}

}  // namespace pliant::web
