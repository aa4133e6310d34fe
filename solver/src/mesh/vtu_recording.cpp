// SPDX-License-Identifier: Apache-2.0
// Recordings for ParaView: binary .vtu frames (appended raw data, UInt64 headers) and a .pvd.
#include "pliant/vtu_recording.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <system_error>

namespace pliant {

static_assert(std::endian::native == std::endian::little, "the .vtu writer writes the host's bytes as LittleEndian");

namespace {

// The appended block: each array is a UInt64 byte count followed by its bytes.
class AppendedData {
 public:
  template <typename T>
  size_t add(const std::vector<T>& values) {
    const size_t offset = bytes_.size();
    const uint64_t n = values.size() * sizeof(T);
    append(&n, sizeof n);
    if (n) append(values.data(), n);
    return offset;
  }
  const std::string& bytes() const { return bytes_; }

 private:
  void append(const void* p, size_t n) { bytes_.append(static_cast<const char*>(p), n); }
  std::string bytes_;
};

std::string xml_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string number(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::vector<double> flatten(const std::vector<Vec3>& v, size_t n) {
  std::vector<double> out(3 * n, 0.0);
  for (size_t i = 0; i < v.size() && i < n; ++i)
    for (int k = 0; k < 3; ++k) out[3 * i + k] = v[i][k];
  return out;
}

void write_file(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) throw std::runtime_error("cannot write '" + path + "'");
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  f.close();
  if (!f) throw std::runtime_error("cannot write '" + path + "' (disk full?)");
}

}  // namespace

std::vector<double> tet_volume_ratios(const std::vector<Vec3>& rest, const std::vector<Tet>& tets,
                                      const std::vector<Vec3>& current) {
  std::vector<double> out(tets.size(), 0.0);
  for (size_t t = 0; t < tets.size(); ++t) {
    const Tet& e = tets[t];
    const double v0 = signed_tet_volume(rest[e[0]], rest[e[1]], rest[e[2]], rest[e[3]]);
    const double v = signed_tet_volume(current[e[0]], current[e[1]], current[e[2]], current[e[3]]);
    out[t] = v0 != 0 ? v / v0 : std::nan("");
  }
  return out;
}

void write_vtu_frame(const RecordingTopology& topo, const RecordingFrame& frame, const std::string& path) {
  const bool points_only = topo.point_cells && topo.tets.empty() && topo.triangles.empty() && topo.segments.empty();
  const size_t rest = topo.rest_positions.size();
  const size_t n = points_only ? frame.positions.size() : rest;
  if (frame.positions.size() != n)
    throw std::invalid_argument("frame: " + std::to_string(frame.positions.size()) + " positions, the topology has " +
                                std::to_string(n) + " vertices");
  if (!frame.velocity.empty() && frame.velocity.size() != n)
    throw std::invalid_argument("frame: " + std::to_string(frame.velocity.size()) + " velocities, expected " +
                                std::to_string(n));
  if (!topo.fixed.empty() && topo.fixed.size() != rest)
    throw std::invalid_argument("topology: " + std::to_string(topo.fixed.size()) + " fixed flags, expected " +
                                std::to_string(rest));
  auto check_index = [n](const char* what, int32_t v) {
    if (v < 0 || static_cast<size_t>(v) >= n)
      throw std::invalid_argument(std::string("topology: ") + what + " vertex index " + std::to_string(v) +
                                  " out of range [0, " + std::to_string(n) + ")");
  };
  for (const Tet& e : topo.tets)
    for (int32_t v : e) check_index("tet", v);
  for (const auto& e : topo.triangles)
    for (int32_t v : e) check_index("triangle", v);
  for (const auto& e : topo.segments)
    for (int32_t v : e) check_index("segment", v);

  std::vector<Vec3> displacement(n, Vec3::Zero());
  for (size_t i = 0; i < std::min(n, rest); ++i) displacement[i] = frame.positions[i] - topo.rest_positions[i];
  std::vector<uint8_t> fixed(n, 0);
  for (size_t i = 0; i < std::min(n, topo.fixed.size()); ++i) fixed[i] = topo.fixed[i] ? 1 : 0;
  std::vector<int64_t> connectivity, offsets;
  std::vector<uint8_t> types;
  auto cell = [&](const auto& vertices, uint8_t type) {
    for (int32_t v : vertices) connectivity.push_back(v);
    offsets.push_back(static_cast<int64_t>(connectivity.size()));
    types.push_back(type);
  };
  for (const Tet& e : topo.tets) cell(e, 10);              // VTK_TETRA
  for (const auto& e : topo.triangles) cell(e, 5);         // VTK_TRIANGLE
  for (const auto& e : topo.segments) cell(e, 3);          // VTK_LINE
  if (topo.point_cells)
    for (size_t i = 0; i < n; ++i) cell(std::array<int32_t, 1>{static_cast<int32_t>(i)}, 1);  // VTK_VERTEX
  // det F per cell only where every cell is a tet.
  const bool tets_only = !topo.tets.empty() && types.size() == topo.tets.size();

  AppendedData data;
  const size_t o_disp = data.add(flatten(displacement, n));
  const size_t o_vel = data.add(flatten(frame.velocity, n));
  const size_t o_fixed = data.add(fixed);
  const size_t o_detf = tets_only ? data.add(tet_volume_ratios(topo.rest_positions, topo.tets, frame.positions)) : 0;
  const size_t o_points = data.add(flatten(frame.positions, n));
  const size_t o_conn = data.add(connectivity);
  const size_t o_off = data.add(offsets);
  const size_t o_types = data.add(types);

  auto array = [](const char* type, const char* name, int components, size_t offset) {
    std::string s = std::string("        <DataArray type=\"") + type + "\"";
    if (name) s += std::string(" Name=\"") + name + "\"";
    if (components > 1) s += " NumberOfComponents=\"" + std::to_string(components) + "\"";
    return s + " format=\"appended\" offset=\"" + std::to_string(offset) + "\"/>\n";
  };
  std::ostringstream x;
  x << "<?xml version=\"1.0\"?>\n"
    << "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n"
    << "  <UnstructuredGrid>\n"
    << "    <FieldData>\n"
    << "      <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">"
    << number(frame.time) << "</DataArray>\n"
    << "      <DataArray type=\"Float64\" Name=\"residual\" NumberOfTuples=\"1\" format=\"ascii\">"
    << number(frame.residual) << "</DataArray>\n"
    << "    </FieldData>\n"
    << "    <Piece NumberOfPoints=\"" << n << "\" NumberOfCells=\"" << types.size() << "\">\n"
    << "      <PointData Vectors=\"displacement\" Scalars=\"fixed\">\n"
    << "  " << array("Float64", "displacement", 3, o_disp)
    << "  " << array("Float64", "velocity", 3, o_vel)
    << "  " << array("UInt8", "fixed", 1, o_fixed)
    << "      </PointData>\n"
    << (tets_only ? "      <CellData Scalars=\"det_F\">\n  " + array("Float64", "det_F", 1, o_detf) + "      </CellData>\n"
                  : std::string())
    << "      <Points>\n"
    << "  " << array("Float64", "Points", 3, o_points)
    << "      </Points>\n"
    << "      <Cells>\n"
    << "  " << array("Int64", "connectivity", 1, o_conn)
    << "  " << array("Int64", "offsets", 1, o_off)
    << "  " << array("UInt8", "types", 1, o_types)
    << "      </Cells>\n"
    << "    </Piece>\n"
    << "  </UnstructuredGrid>\n"
    << "  <AppendedData encoding=\"raw\">\n   _";
  std::string bytes = x.str();
  bytes += data.bytes();
  bytes += "\n  </AppendedData>\n</VTKFile>\n";
  write_file(path, bytes);
}

void write_pvd(const std::vector<std::pair<double, std::string>>& entries, const std::string& path) {
  std::ostringstream x;
  x << "<?xml version=\"1.0\"?>\n"
    << "<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
    << "  <Collection>\n";
  for (const auto& [time, file] : entries)
    x << "    <DataSet timestep=\"" << number(time) << "\" group=\"\" part=\"0\" file=\"" << xml_escape(file)
      << "\"/>\n";
  x << "  </Collection>\n</VTKFile>\n";
  const std::string tmp = path + ".tmp";
  write_file(tmp, x.str());
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw std::runtime_error("cannot rename '" + tmp + "' to '" + path + "': " + ec.message());
}

VtuRecorder::VtuRecorder(std::string dir, RecordingTopology topology, std::string stem, std::string pvd_stem)
    : dir_(std::move(dir)), stem_(std::move(stem)), pvd_stem_(pvd_stem.empty() ? stem_ + "s" : std::move(pvd_stem)),
      topology_(std::move(topology)) {
  std::error_code ec;
  std::filesystem::create_directories(dir_, ec);
  if (ec) throw std::runtime_error("cannot create directory '" + dir_ + "': " + ec.message());
}

std::string VtuRecorder::pvd_path() const { return (std::filesystem::path(dir_) / (pvd_stem_ + ".pvd")).string(); }

std::string VtuRecorder::write(const RecordingFrame& frame, long index) {
  char name[96];
  std::snprintf(name, sizeof name, "%s_%06ld.vtu", stem_.c_str(), index);
  const std::string path = (std::filesystem::path(dir_) / name).string();
  write_vtu_frame(topology_, frame, path);
  entries_.emplace_back(frame.time, name);
  // The .pvd grows by one line per frame: overwrite the closing tags with the new entry and the
  // closing tags again (a long recording must not rewrite the whole collection every frame).
  static const std::string kClosing = "  </Collection>\n</VTKFile>\n";
  if (!pvd_.is_open()) {
    write_pvd({}, pvd_path());
    pvd_.open(pvd_path(), std::ios::binary | std::ios::in | std::ios::out);
    if (!pvd_) throw std::runtime_error("cannot open '" + pvd_path() + "' for writing");
    pvd_.seekp(0, std::ios::end);
    pvd_tail_ = static_cast<long long>(pvd_.tellp()) - static_cast<long long>(kClosing.size());
  }
  const std::string entry = "    <DataSet timestep=\"" + number(frame.time) + "\" group=\"\" part=\"0\" file=\"" +
                            xml_escape(name) + "\"/>\n";
  pvd_.seekp(pvd_tail_);
  pvd_ << entry << kClosing;
  pvd_.flush();
  if (!pvd_) throw std::runtime_error("cannot write '" + pvd_path() + "' (disk full?)");
  pvd_tail_ += static_cast<long long>(entry.size());
  return path;
}

}  // namespace pliant
