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

}  // namespace

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
  return s;
}

std::string encode_topology(const SurfaceTopology& t, uint32_t subscription) {
  const uint32_t n = t.surface_vertex_count();
  if (t.triangles.size() % 3 || t.rest_positions.size() != 3 * size_t(n))
    throw std::invalid_argument("surface topology has inconsistent array sizes");
  Writer w(kTopologyHeaderBytes + 4 * (t.triangles.size() + n + t.fixed.size() + 3 * size_t(n)));
  w.put<uint8_t>(kKindTopology);
  w.put<uint8_t>(kWireVersion);
  w.put<uint16_t>(0);
  w.put<uint32_t>(subscription);
  w.put<uint32_t>(n);
  w.put<uint32_t>(static_cast<uint32_t>(t.triangles.size() / 3));
  w.put<uint32_t>(static_cast<uint32_t>(t.fixed.size()));
  w.put<uint32_t>(t.body_vertex_count);
  w.put_array(t.triangles.data(), t.triangles.size());
  w.put_array(t.surface_to_body.data(), n);
  w.put_array(t.fixed.data(), t.fixed.size());
  w.put_array(t.rest_positions.data(), t.rest_positions.size());
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
  return t;
}

size_t frame_bytes(uint32_t vertices, uint32_t residuals, Encoding encoding) {
  const size_t pos = encoding == Encoding::Float32 ? 12 * size_t(vertices) : (6 * size_t(vertices) + 3) / 4 * 4;
  return kFrameHeaderBytes + 4 * size_t(residuals) + pos;
}

std::string encode_frame(const v1::Frame& f, uint32_t subscription, Encoding encoding, uint32_t expected_vertices) {
  const size_t values = f.positions_size();
  if (values != 0 && values != 3 * size_t(expected_vertices))
    throw std::invalid_argument("frame has " + std::to_string(values) + " position values, expected " +
                                std::to_string(3 * size_t(expected_vertices)));
  const uint32_t n = static_cast<uint32_t>(values / 3);
  const uint32_t r = static_cast<uint32_t>(f.residuals_size());
  const float* p = f.positions().data();

  std::array<float, 3> lo{0, 0, 0}, hi{0, 0, 0};
  if (n) {
    lo = {p[0], p[1], p[2]};
    hi = lo;
    for (size_t i = 0; i < values; i += 3)
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], p[i + k]);
        hi[k] = std::max(hi[k], p[i + k]);
      }
  }

  Writer w(frame_bytes(n, r, encoding));
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
  w.put<uint32_t>(f.rolled_back() ? 1u : 0u);       // 100
  w.put_array(lo.data(), 3);                        // 104
  w.put_array(hi.data(), 3);                        // 116
  for (double res : f.residuals()) w.put<float>(static_cast<float>(res));  // 128
  if (encoding == Encoding::Float32) {
    w.put_array(p, values);
  } else {
    // q = round((x - lo) / (hi - lo) * 65535); a flat axis (hi == lo) encodes as 0.
    for (size_t i = 0; i < values; i += 3)
      for (int k = 0; k < 3; ++k) {
        const float ext = hi[k] - lo[k];
        const float u = ext > 0 ? (p[i + k] - lo[k]) / ext : 0.0f;
        w.put<uint16_t>(static_cast<uint16_t>(std::lround(std::clamp(u, 0.0f, 1.0f) * 65535.0f)));
      }
    w.pad_to_4();
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
  if (bytes.size() != frame_bytes(h.vertex_count, h.residual_count, h.encoding))
    throw std::invalid_argument("frame of " + std::to_string(bytes.size()) + " bytes, its header says " +
                                std::to_string(frame_bytes(h.vertex_count, h.residual_count, h.encoding)));
  return h;
}

std::vector<float> decode_frame_residuals(const std::string& bytes) {
  const FrameHeader h = decode_frame_header(bytes);
  return Reader(bytes).array<float>(kFrameHeaderBytes, h.residual_count);
}

std::vector<float> decode_frame_positions(const std::string& bytes) {
  const FrameHeader h = decode_frame_header(bytes);
  const size_t off = kFrameHeaderBytes + 4 * size_t(h.residual_count), values = 3 * size_t(h.vertex_count);
  Reader r(bytes);
  if (h.encoding == Encoding::Float32) return r.array<float>(off, values);
  const auto q = r.array<uint16_t>(off, values);
  std::vector<float> out(values);
  for (size_t i = 0; i < values; ++i) {
    const int k = static_cast<int>(i % 3);
    out[i] = h.bbox_min[k] + (h.bbox_max[k] - h.bbox_min[k]) * (static_cast<float>(q[i]) / 65535.0f);
  }
  return out;
}

}  // namespace pliant::web
