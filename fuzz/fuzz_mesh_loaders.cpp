// SPDX-License-Identifier: Apache-2.0
// libFuzzer harness for the tet-mesh loaders (TetGen .node/.ele, Gmsh .msh, VTK legacy .vtk,
// VTK XML .vtu). The first byte picks the format; the rest is the file (TetGen: the .node
// file, a NUL byte, then the .ele file). A loader may refuse its input with MeshError; any
// crash, sanitizer report, other exception, leak or hang is a finding.
#include "pliant/mesh_io.hpp"

#include <spdlog/spdlog.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>

namespace fs = std::filesystem;

namespace {

fs::path work_dir() {
  static const fs::path dir = [] {
    const fs::path base = fs::exists("/dev/shm") ? fs::path("/dev/shm") : fs::temp_directory_path();
    fs::path d = base / ("pliant_fuzz_mesh_" + std::to_string(::getpid()));
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

void write(const fs::path& p, const uint8_t* data, size_t size) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  spdlog::set_level(spdlog::level::off);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const int format = data[0] % 4;
  ++data;
  --size;
  const fs::path dir = work_dir();
  fs::path file;
  switch (format) {
    case 0: {
      const uint8_t* nul = static_cast<const uint8_t*>(std::memchr(data, 0, size));
      const size_t node_size = nul ? static_cast<size_t>(nul - data) : size;
      write(dir / "m.node", data, node_size);
      write(dir / "m.ele", nul ? nul + 1 : data + size, nul ? size - node_size - 1 : 0);
      file = dir / "m.node";
      break;
    }
    case 1: file = dir / "m.msh"; break;
    case 2: file = dir / "m.vtk"; break;
    default: file = dir / "m.vtu"; break;
  }
  if (format != 0) write(file, data, size);
  try {
    pliant::MeshLoadResult r = pliant::load_mesh_with_report(file.string());
    // What a loader accepts is a usable mesh: indices in range.
    const size_t nv = r.mesh.vertices.size();
    for (const auto& t : r.mesh.tets)
      for (int k = 0; k < 4; ++k)
        if (t[k] < 0 || static_cast<size_t>(t[k]) >= nv) __builtin_trap();
  } catch (const pliant::MeshError&) {
  }
  return 0;
}
