// SPDX-License-Identifier: Apache-2.0
// zlib-compressed .vtu (compressor="vtkZLibDataCompressor", as VTK and meshio write by default):
// files made here with zlib in VTK's layout (header [blocks, block size, last block size,
// compressed sizes], blocks back to back; inline base64 with header and blocks encoded
// separately, or raw appended), several blocks with a short last one, UInt32 and UInt64 headers.
// tests/files/check_files.py also reads a file VTK itself compressed.
#include "pliant/mesh_io.hpp"

#include "test_helpers.hpp"

#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <sstream>

namespace pliant::test {
namespace {

std::string b64(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8) | uint8_t(in[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += k[(v >> s) & 63];
  }
  if (i < in.size()) {
    uint32_t v = uint8_t(in[i]) << 16;
    if (i + 1 < in.size()) v |= uint8_t(in[i + 1]) << 8;
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < in.size() ? k[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

template <typename H>
void put(std::string& s, H v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof v);
}

// (header, blocks) of `raw` compressed in blocks of `block` bytes.
template <typename H>
std::pair<std::string, std::string> compress_blocks(const std::string& raw, size_t block, bool corrupt = false) {
  std::string header, data;
  const size_t blocks = (raw.size() + block - 1) / block;
  put<H>(header, H(blocks));
  put<H>(header, H(block));
  put<H>(header, H(raw.size() % block));
  for (size_t b = 0; b < blocks; ++b) {
    const size_t n = std::min(block, raw.size() - b * block);
    uLongf len = compressBound(n);
    std::string out(len, '\0');
    EXPECT_EQ(compress2(reinterpret_cast<Bytef*>(out.data()), &len, reinterpret_cast<const Bytef*>(raw.data() + b * block),
                        n, 6),
              Z_OK);
    out.resize(len);
    if (corrupt && b == 1) out[out.size() / 2] ^= 0x5a;
    put<H>(header, H(len));
    data += out;
  }
  return {header, data};
}

struct Cube {
  std::vector<double> xyz;
  std::vector<int64_t> conn, offsets;
  std::vector<uint8_t> types;
  Cube() {
    for (int i = 0; i < 8; ++i) xyz.insert(xyz.end(), {0.1 * (i & 1) + 0.01, 0.2 * ((i >> 1) & 1), 0.3 * ((i >> 2) & 1)});
    conn = {0, 1, 2, 4, 1, 3, 2, 7, 1, 2, 4, 7, 2, 4, 7, 6, 1, 4, 5, 7};
    // Positive orientation for each (the loader validates).
    for (size_t t = 0; t < 5; ++t) {
      Vec3 p[4];
      for (int k = 0; k < 4; ++k) p[k] = Vec3(xyz[3 * conn[4 * t + k]], xyz[3 * conn[4 * t + k] + 1], xyz[3 * conn[4 * t + k] + 2]);
      if (signed_tet_volume(p[0], p[1], p[2], p[3]) < 0) std::swap(conn[4 * t + 2], conn[4 * t + 3]);
      offsets.push_back(4 * int64_t(t + 1));
      types.push_back(10);
    }
  }
};

template <typename T>
std::string bytes_of(const std::vector<T>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
}

// The cube as a compressed .vtu; `appended` picks raw appended data over inline base64.
template <typename H>
std::string compressed_vtu(const Cube& c, bool appended, size_t block, bool corrupt = false,
                           const std::string& compressor = "vtkZLibDataCompressor") {
  const std::string header_type = sizeof(H) == 8 ? "UInt64" : "UInt32";
  std::ostringstream x;
  std::string blob;
  auto array = [&](const char* type, const char* name, int comps, const std::string& raw, bool may_corrupt) {
    auto [h, d] = compress_blocks<H>(raw, block, corrupt && may_corrupt);
    x << "<DataArray type=\"" << type << "\" Name=\"" << name << "\" NumberOfComponents=\"" << comps << "\"";
    if (appended) {
      x << " format=\"appended\" offset=\"" << blob.size() << "\"/>\n";
      blob += h + d;
    } else {
      x << " format=\"binary\">\n" << b64(h) << b64(d) << "\n</DataArray>\n";
    }
  };
  x << "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
    << "header_type=\"" << header_type << "\" compressor=\"" << compressor << "\">\n<UnstructuredGrid>\n"
    << "<Piece NumberOfPoints=\"8\" NumberOfCells=\"5\">\n<Points>\n";
  array("Float64", "Points", 3, bytes_of(c.xyz), true);
  x << "</Points>\n<Cells>\n";
  array("Int64", "connectivity", 1, bytes_of(c.conn), false);
  array("Int64", "offsets", 1, bytes_of(c.offsets), false);
  array("UInt8", "types", 1, bytes_of(c.types), false);
  x << "</Cells>\n</Piece>\n</UnstructuredGrid>\n";
  if (appended) x << "<AppendedData encoding=\"raw\">\n_" << blob << "\n</AppendedData>\n";
  x << "</VTKFile>\n";
  return x.str();
}

void expect_cube(const TetMesh& m, const Cube& c) {
  ASSERT_EQ(m.vertices.size(), 8u);
  ASSERT_EQ(m.tets.size(), 5u);
  for (size_t i = 0; i < 8; ++i)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(m.vertices[i][k], c.xyz[3 * i + k]);
  for (size_t t = 0; t < 5; ++t)
    for (int k = 0; k < 4; ++k) EXPECT_EQ(m.tets[t][k], c.conn[4 * t + k]);
}

TEST(VtuCompressed, InlineBase64WithUInt32HeadersAndSeveralBlocks) {
  ScratchDir dir("vtu-zlib");
  const Cube c;
  // 192 bytes of points in blocks of 40: five blocks, the last one 32 bytes.
  expect_cube(load_mesh(dir.write("inline32.vtu", compressed_vtu<uint32_t>(c, false, 40))), c);
  expect_cube(load_mesh(dir.write("inline64.vtu", compressed_vtu<uint64_t>(c, false, 64))), c);
}

TEST(VtuCompressed, AppendedRawWithUInt64Headers) {
  ScratchDir dir("vtu-zlib");
  const Cube c;
  expect_cube(load_mesh(dir.write("app64.vtu", compressed_vtu<uint64_t>(c, true, 40))), c);
  expect_cube(load_mesh(dir.write("app32.vtu", compressed_vtu<uint32_t>(c, true, 1 << 15))), c);  // one block
}

TEST(VtuCompressed, CorruptBlockAndOtherCompressorsAreRefusedWithTheReason) {
  ScratchDir dir("vtu-zlib");
  const Cube c;
  for (bool appended : {false, true}) {
    const std::string path = dir.write(appended ? "bad_app.vtu" : "bad_inline.vtu",
                                       compressed_vtu<uint64_t>(c, appended, 40, /*corrupt=*/true));
    try {
      load_mesh(path);
      FAIL() << "read a corrupt compressed block";
    } catch (const MeshError& e) {
      EXPECT_NE(std::string(e.what()).find("points: compressed block 1 does not inflate"), std::string::npos) << e.what();
    }
  }
  try {
    load_mesh(dir.write("lz4.vtu", compressed_vtu<uint64_t>(c, false, 40, false, "vtkLZ4DataCompressor")));
    FAIL() << "read an LZ4 file as zlib";
  } catch (const MeshError& e) {
    EXPECT_NE(std::string(e.what()).find("vtkLZ4DataCompressor is not supported"), std::string::npos) << e.what();
  }
  // A header claiming 8 GiB from a few bytes: refused before anything is allocated.
  {
    std::string blob;
    put<uint64_t>(blob, 1);
    put<uint64_t>(blob, uint64_t{1} << 33);
    put<uint64_t>(blob, 0);
    put<uint64_t>(blob, 10);
    blob += std::string(10, 'x');
    const std::string text =
        "<VTKFile type=\"UnstructuredGrid\" header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\">"
        "<UnstructuredGrid><Piece NumberOfPoints=\"8\" NumberOfCells=\"5\"><Points><DataArray type=\"Float64\" "
        "NumberOfComponents=\"3\" format=\"appended\" offset=\"0\"/></Points></Piece></UnstructuredGrid>"
        "<AppendedData encoding=\"raw\">_" + blob + "</AppendedData></VTKFile>";
    try {
      load_mesh(dir.write("bomb.vtu", text));
      FAIL() << "accepted a header claiming 8 GiB";
    } catch (const MeshError& e) {
      EXPECT_NE(std::string(e.what()).find("points: compressed header claims 8589934592 bytes"), std::string::npos)
          << e.what();
    }
  }
  // A header announcing more data than there is.
  std::string text = compressed_vtu<uint64_t>(c, true, 40);
  text.resize(text.size() - 60);
  EXPECT_THROW(load_mesh(dir.write("short.vtu", text)), MeshError);
}

}  // namespace
}  // namespace pliant::test
