// SPDX-License-Identifier: Apache-2.0
// The recording writer (.vtu frames + .pvd): values written come back byte for byte from the
// appended block, the mesh reader reads the frame's geometry, det F is the volume ratio, and a
// bad frame is refused. tests/mesh/check_vtu_recording.py reads the same files with VTK itself.
#include "pliant/mesh_io.hpp"
#include "pliant/vtu_recording.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

namespace pliant::test {
namespace {

std::string read_all(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// A unit cube cut into 5 tets: enough for distinct per-tet values.
RecordingTopology cube() {
  RecordingTopology t;
  for (int i = 0; i < 8; ++i) t.rest_positions.emplace_back(i & 1, (i >> 1) & 1, (i >> 2) & 1);
  t.tets = {{0, 1, 2, 4}, {1, 3, 2, 7}, {1, 2, 4, 7}, {2, 4, 7, 6}, {1, 4, 5, 7}};
  for (auto& e : t.tets)
    if (signed_tet_volume(t.rest_positions[e[0]], t.rest_positions[e[1]], t.rest_positions[e[2]],
                          t.rest_positions[e[3]]) < 0)
      std::swap(e[2], e[3]);
  t.fixed = {1, 0, 1, 0, 0, 0, 0, 0};
  return t;
}

// The arrays of the appended block by name: header UInt64 byte count, then the bytes.
std::map<std::string, std::string> appended_arrays(const std::string& file) {
  std::map<std::string, std::string> out;
  const size_t marker = file.find("<AppendedData encoding=\"raw\">");
  EXPECT_NE(marker, std::string::npos);
  const size_t start = file.find('_', marker) + 1;
  std::regex tag(R"re(<DataArray type="(\w+)" Name="(\w+)"[^>]*format="appended" offset="(\d+)")re");
  for (auto it = std::sregex_iterator(file.begin(), file.begin() + static_cast<long>(marker), tag);
       it != std::sregex_iterator(); ++it) {
    const size_t off = start + std::stoull((*it)[3].str());
    uint64_t n = 0;
    std::memcpy(&n, file.data() + off, 8);
    out[(*it)[2].str()] = file.substr(off + 8, n);
  }
  return out;
}

template <typename T>
std::vector<T> as(const std::string& bytes) {
  std::vector<T> v(bytes.size() / sizeof(T));
  std::memcpy(v.data(), bytes.data(), v.size() * sizeof(T));
  return v;
}

TEST(VtuRecording, FrameCarriesPositionsDisplacementVelocityFixedDetFAndResidual) {
  ScratchDir dir("vtu-recording");
  const RecordingTopology topo = cube();
  RecordingFrame f;
  f.time = 0.25;
  f.residual = 3.5e-7;
  for (const Vec3& p : topo.rest_positions) {
    f.positions.push_back(Vec3(2 * p.x(), p.y(), p.z()) + Vec3(0, -0.1, 0));  // stretched 2x in x
    f.velocity.push_back(Vec3(p.x(), -1.0, 0.5));
  }
  const std::string path = dir.file("f.vtu");
  write_vtu_frame(topo, f, path);
  const std::string file = read_all(path);
  EXPECT_NE(file.find("header_type=\"UInt64\""), std::string::npos);
  EXPECT_NE(file.find("byte_order=\"LittleEndian\""), std::string::npos);
  EXPECT_NE(file.find("Name=\"residual\" NumberOfTuples=\"1\" format=\"ascii\">3.4999999999999998e-07<"), std::string::npos);
  EXPECT_NE(file.find("Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">0.25<"), std::string::npos);

  auto arrays = appended_arrays(file);
  ASSERT_EQ(arrays.size(), 8u);
  const auto disp = as<double>(arrays["displacement"]);
  const auto vel = as<double>(arrays["velocity"]);
  const auto fixed = as<uint8_t>(arrays["fixed"]);
  const auto det = as<double>(arrays["det_F"]);
  const auto points = as<double>(arrays["Points"]);
  ASSERT_EQ(disp.size(), 24u);
  ASSERT_EQ(vel.size(), 24u);
  ASSERT_EQ(points.size(), 24u);
  ASSERT_EQ(fixed.size(), 8u);
  ASSERT_EQ(det.size(), topo.tets.size());
  for (size_t i = 0; i < 8; ++i) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(points[3 * i + k], f.positions[i][k]);
      EXPECT_EQ(disp[3 * i + k], f.positions[i][k] - topo.rest_positions[i][k]);
      EXPECT_EQ(vel[3 * i + k], f.velocity[i][k]);
    }
    EXPECT_EQ(fixed[i], topo.fixed[i]);
  }
  for (double d : det) EXPECT_NEAR(d, 2.0, 1e-12);
  EXPECT_EQ(as<int64_t>(arrays["offsets"]), (std::vector<int64_t>{4, 8, 12, 16, 20}));
  EXPECT_EQ(as<uint8_t>(arrays["types"]), std::vector<uint8_t>(5, 10));

  // The mesh reader reads the frame's geometry (the current positions, the tets).
  const TetMesh back = load_mesh(path);
  ASSERT_EQ(back.vertices.size(), 8u);
  ASSERT_EQ(back.tets.size(), 5u);
  for (size_t i = 0; i < 8; ++i) EXPECT_EQ(back.vertices[i], f.positions[i]);
  for (size_t t = 0; t < 5; ++t) EXPECT_EQ(back.tets[t], topo.tets[t]);
}

TEST(VtuRecording, DetFIsTheVolumeRatioAndNegativeWhenInverted) {
  const RecordingTopology topo = cube();
  std::vector<Vec3> x = topo.rest_positions;
  for (Vec3& p : x) p.z() = -p.z();  // mirrored: every tet inverted, same volume
  for (double d : tet_volume_ratios(topo.rest_positions, topo.tets, x)) EXPECT_NEAR(d, -1.0, 1e-12);
  for (Vec3& p : x) p *= 0.5;
  for (double d : tet_volume_ratios(topo.rest_positions, topo.tets, x)) EXPECT_NEAR(d, -0.125, 1e-12);
}

TEST(VtuRecording, RecorderWritesNumberedFramesAndACollectionWithTheirTimes) {
  ScratchDir dir("vtu-recorder");
  VtuRecorder rec(dir.file("out/nested"), cube());
  RecordingFrame f;
  f.positions = rec.topology().rest_positions;
  for (int k = 0; k < 3; ++k) {
    f.time = 0.1 * k;
    rec.write(f, 10 * k);
  }
  EXPECT_EQ(rec.frames(), 3u);
  const std::string pvd = read_all(rec.pvd_path());
  EXPECT_NE(pvd.find("type=\"Collection\""), std::string::npos);
  EXPECT_NE(pvd.find("timestep=\"0\" group=\"\" part=\"0\" file=\"frame_000000.vtu\""), std::string::npos) << pvd;
  EXPECT_NE(pvd.find("timestep=\"0.10000000000000001\" group=\"\" part=\"0\" file=\"frame_000010.vtu\""),
            std::string::npos) << pvd;
  EXPECT_NE(pvd.find("file=\"frame_000020.vtu\""), std::string::npos) << pvd;
  // Grown entry by entry, it is the same file as the whole collection written at once.
  write_pvd({{0.0, "frame_000000.vtu"}, {0.1, "frame_000010.vtu"}, {0.2, "frame_000020.vtu"}}, dir.file("whole.pvd"));
  EXPECT_EQ(pvd, read_all(dir.file("whole.pvd")));
  EXPECT_TRUE(std::filesystem::exists(dir.file("out/nested/frame_000020.vtu")));
  // No velocity given: zeros.
  const auto arrays = appended_arrays(read_all(dir.file("out/nested/frame_000000.vtu")));
  for (double v : as<double>(arrays.at("velocity"))) EXPECT_EQ(v, 0.0);
}

TEST(VtuRecording, RefusesAFrameThatDoesNotMatchTheTopology) {
  ScratchDir dir("vtu-recording-bad");
  RecordingFrame f;
  f.positions.resize(7, Vec3::Zero());
  try {
    write_vtu_frame(cube(), f, dir.file("bad.vtu"));
    FAIL() << "accepted 7 positions for 8 vertices";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("7 positions"), std::string::npos) << e.what();
  }
  f.positions.resize(8, Vec3::Zero());
  EXPECT_THROW(write_vtu_frame(cube(), f, dir.file("no/such/dir/bad.vtu")), std::runtime_error);
}

TEST(VtuRecording, ParticleBodiesAreTrianglesLinesOrVertexCellsWithoutDetF) {
  ScratchDir dir("vtu-recording-bodies");
  RecordingTopology t;
  for (int i = 0; i < 4; ++i) t.rest_positions.emplace_back(i, 0, 0);
  t.triangles = {{0, 1, 2}};
  t.segments = {{2, 3}};
  t.point_cells = true;
  RecordingFrame f;
  f.positions = t.rest_positions;
  VtuRecorder rec(dir.path().string(), t, "body-sheet", "body-sheet");
  const std::string path = rec.write(f, 7);
  EXPECT_EQ(path, dir.file("body-sheet_000007.vtu"));
  EXPECT_EQ(rec.pvd_path(), dir.file("body-sheet.pvd"));
  const std::string file = read_all(path);
  EXPECT_EQ(file.find("det_F"), std::string::npos);
  EXPECT_NE(file.find("NumberOfCells=\"6\""), std::string::npos);  // 1 triangle + 1 segment + 4 vertices
  const auto arrays = appended_arrays(file);
  EXPECT_EQ(as<uint8_t>(arrays.at("types")), (std::vector<uint8_t>{5, 3, 1, 1, 1, 1}));
  EXPECT_EQ(as<int64_t>(arrays.at("connectivity")), (std::vector<int64_t>{0, 1, 2, 2, 3, 0, 1, 2, 3}));
  EXPECT_EQ(as<int64_t>(arrays.at("offsets")), (std::vector<int64_t>{3, 5, 6, 7, 8, 9}));
  t.segments = {{2, 9}};
  try {
    write_vtu_frame(t, f, dir.file("bad.vtu"));
    FAIL() << "accepted a segment to vertex 9 of 4";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("segment vertex index 9"), std::string::npos) << e.what();
  }
}

TEST(VtuRecording, APointCloudTakesFramesOfAnyCountAndOnlyIt) {
  // A fluid whose emitters add particles: 2 at the start, 3 in this frame. The new one has no
  // rest position (displacement 0) and is not fixed; a frame of another count in a topology
  // with triangles or lines is still refused.
  ScratchDir dir("vtu-recording-growing");
  RecordingTopology t;
  t.rest_positions = {Vec3(0, 0, 0), Vec3(1, 0, 0)};
  t.fixed = {1, 0};
  t.point_cells = true;
  RecordingFrame f;
  f.positions = {Vec3(0, -1, 0), Vec3(1, -1, 0), Vec3(2, 5, 0)};
  const std::string path = dir.file("water.vtu");
  write_vtu_frame(t, f, path);
  const std::string file = read_all(path);
  EXPECT_NE(file.find("NumberOfPoints=\"3\" NumberOfCells=\"3\""), std::string::npos);
  const auto arrays = appended_arrays(file);
  EXPECT_EQ(as<double>(arrays.at("displacement")), (std::vector<double>{0, -1, 0, 0, -1, 0, 0, 0, 0}));
  EXPECT_EQ(as<uint8_t>(arrays.at("fixed")), (std::vector<uint8_t>{1, 0, 0}));
  EXPECT_EQ(as<double>(arrays.at("Points")), (std::vector<double>{0, -1, 0, 1, -1, 0, 2, 5, 0}));
  t.segments = {{0, 1}};
  EXPECT_THROW(write_vtu_frame(t, f, dir.file("rope.vtu")), std::invalid_argument);
}

}  // namespace
}  // namespace pliant::test
