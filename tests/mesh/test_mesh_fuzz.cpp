// SPDX-License-Identifier: Apache-2.0
// Malformed input at scale: every truncation and random byte garbage of valid files in each
// format fails cleanly with MeshError (about a thousand loads: seconds). The table of specific
// malformed cases is in test_mesh_malformed.cpp.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

using namespace pliant;
using pliant::test::ScratchDir;

namespace {

MeshLoadOptions quiet() {
  MeshLoadOptions o;
  o.validation.log = false;
  return o;
}

}  // namespace

// Truncating a valid file anywhere, or overwriting bytes with garbage, must give MeshError or a
// valid mesh: never a crash, a hang or another exception type.
TEST(MalformedFuzz, TruncationsAndGarbageFailCleanly) {
  ScratchDir dir;
  const TetMesh beam = make_beam(3, 2, 2, 0.5);
  struct Variant {
    const char* file;
    MeshWriteOptions w;
  };
  const Variant variants[] = {{"f.vtk", {false, 41, 0}}, {"fb.vtk", {true, 41, 0}},  {"f.vtu", {false, 41, 0}},
                              {"fb.vtu", {true, 41, 0}}, {"f.msh", {false, 41, 0}},  {"fb.msh", {true, 41, 0}},
                              {"f2.msh", {false, 22, 0}}, {"f2b.msh", {true, 22, 0}}, {"f.node", {false, 41, 0}}};
  std::mt19937 rng(12345);
  int loaded = 0, failed = 0;
  for (const Variant& v : variants) {
    SCOPED_TRACE(v.file);
    write_mesh(beam, dir.file(v.file), v.w);
    const std::string main = dir.file(v.file);
    const bool tetgen = std::string(v.file).ends_with(".node");
    std::string bytes;
    {
      std::ifstream in(main, std::ios::binary);
      bytes.assign(std::istreambuf_iterator<char>(in), {});
    }
    // The attempt's file: x.<the variant's extension> (built with +=: "x" + ... trips a GCC 12
    // -Wrestrict false positive here).
    std::string target_name = "x";
    target_name += tetgen ? std::string(".node") : std::string(v.file).substr(std::string(v.file).find('.'));
    const std::string target = dir.file(target_name);
    auto attempt = [&](const std::string& content) {
      {
        std::ofstream(target, std::ios::binary) << content;
      }
      if (tetgen) std::filesystem::copy_file(dir.file("f.ele"), dir.file("x.ele"), std::filesystem::copy_options::overwrite_existing);
      try {
        load_mesh(target, quiet());
        ++loaded;
      } catch (const MeshError&) {
        ++failed;
      }
    };
    const size_t step = std::max<size_t>(1, bytes.size() / 61);
    for (size_t cut = 0; cut < bytes.size(); cut += step) attempt(bytes.substr(0, cut));
    for (int k = 0; k < 60; ++k) {
      std::string g = bytes;
      const int flips = 1 + static_cast<int>(rng() % 4);
      for (int f = 0; f < flips; ++f) g[rng() % g.size()] = static_cast<char>(rng() & 0xff);
      attempt(g);
    }
    std::string noise(bytes.size(), '\0');
    for (char& ch : noise) ch = static_cast<char>(rng() & 0xff);
    attempt(noise);
  }
  EXPECT_GT(failed, 0) << "fuzz: " << loaded << " loaded, " << failed << " failed cleanly";
}
