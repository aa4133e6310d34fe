// SPDX-License-Identifier: Apache-2.0
// Writers for TetGen, VTK legacy, VTU and Gmsh. Coordinates are written in the shortest form that
// reads back to the same double, so write-then-read gives the same mesh bit for bit.
#include "mesh/mesh_parse.hpp"
#include "pliant/mesh_io.hpp"

#include <cstring>

namespace pliant {

using detail::append_double;
using detail::append_int;

namespace {

void append_xyz(std::string& out, const Vec3& p) {
  for (int k = 0; k < 3; ++k) {
    out += ' ';
    append_double(out, p[k]);
  }
}

template <typename T>
void put_le(std::string& out, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  out.append(b, sizeof(T));
}
template <typename T>
void put_be(std::string& out, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  for (size_t i = 0; i < sizeof(T); ++i) out += b[sizeof(T) - 1 - i];
}

void check_writable(const TetMesh& mesh, const std::string& path) {
  if (mesh.vertices.empty() || mesh.tets.empty()) throw MeshError(path + ": refusing to write an empty mesh");
}

}  // namespace

void write_tetgen(const TetMesh& mesh, const std::string& stem, int base) {
  check_writable(mesh, stem);
  if (base != 0 && base != 1) throw MeshError("TetGen index base must be 0 or 1");
  std::string node;
  node.reserve(mesh.vertices.size() * 60);
  append_int(node, static_cast<int64_t>(mesh.vertices.size()));
  node += " 3 0 0\n";
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    append_int(node, static_cast<int64_t>(i) + base);
    append_xyz(node, mesh.vertices[i]);
    node += '\n';
  }
  node += "# written by pliant (" + mesh.name + ")\n";
  std::string ele;
  ele.reserve(mesh.tets.size() * 32);
  append_int(ele, static_cast<int64_t>(mesh.tets.size()));
  ele += " 4 0\n";
  for (size_t i = 0; i < mesh.tets.size(); ++i) {
    append_int(ele, static_cast<int64_t>(i) + base);
    for (int32_t v : mesh.tets[i]) {
      ele += ' ';
      append_int(ele, v + base);
    }
    ele += '\n';
  }
  ele += "# written by pliant (" + mesh.name + ")\n";
  detail::write_file_bytes(stem + ".node", node);
  detail::write_file_bytes(stem + ".ele", ele);
}

void write_vtk_legacy(const TetMesh& mesh, const std::string& path, bool binary) {
  check_writable(mesh, path);
  const size_t n = mesh.vertices.size(), t = mesh.tets.size();
  std::string out = "# vtk DataFile Version 3.0\n";
  out += (mesh.name.empty() ? std::string("pliant mesh") : mesh.name) + "\n";
  out += binary ? "BINARY\n" : "ASCII\n";
  out += "DATASET UNSTRUCTURED_GRID\nPOINTS " + std::to_string(n) + " double\n";
  for (const Vec3& p : mesh.vertices) {
    if (binary) {
      for (int k = 0; k < 3; ++k) put_be<double>(out, p[k]);
    } else {
      append_xyz(out, p);
      out += '\n';
    }
  }
  if (binary) out += '\n';
  out += "CELLS " + std::to_string(t) + " " + std::to_string(5 * t) + "\n";
  for (const Tet& tet : mesh.tets) {
    if (binary) {
      put_be<int32_t>(out, 4);
      for (int32_t v : tet) put_be<int32_t>(out, v);
    } else {
      out += '4';
      for (int32_t v : tet) {
        out += ' ';
        append_int(out, v);
      }
      out += '\n';
    }
  }
  if (binary) out += '\n';
  out += "CELL_TYPES " + std::to_string(t) + "\n";
  for (size_t i = 0; i < t; ++i) {
    if (binary) put_be<int32_t>(out, 10);
    else out += "10\n";
  }
  if (binary) out += '\n';
  detail::write_file_bytes(path, out);
}

void write_vtu(const TetMesh& mesh, const std::string& path, bool binary) {
  check_writable(mesh, path);
  const size_t n = mesh.vertices.size(), t = mesh.tets.size();
  const char* format = binary ? "binary" : "ascii";
  // Inline binary: base64 of (UInt64 byte count, little-endian data).
  auto block = [](const std::string& data) {
    std::string raw;
    put_le<uint64_t>(raw, data.size());
    raw += data;
    return detail::base64_encode(raw);
  };
  std::string out = "<?xml version=\"1.0\"?>\n";
  out += "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
  out += "  <UnstructuredGrid>\n";
  out += "    <Piece NumberOfPoints=\"" + std::to_string(n) + "\" NumberOfCells=\"" + std::to_string(t) + "\">\n";
  out += "      <Points>\n";
  out += std::string("        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"") + format + "\">\n";
  if (binary) {
    std::string data;
    for (const Vec3& p : mesh.vertices)
      for (int k = 0; k < 3; ++k) put_le<double>(data, p[k]);
    out += block(data) + "\n";
  } else {
    for (const Vec3& p : mesh.vertices) {
      append_xyz(out, p);
      out += '\n';
    }
  }
  out += "        </DataArray>\n      </Points>\n      <Cells>\n";
  out += std::string("        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"") + format + "\">\n";
  std::string conn, offs, types;
  for (size_t i = 0; i < t; ++i) {
    for (int32_t v : mesh.tets[i]) {
      if (binary) put_le<int64_t>(conn, v);
      else {
        append_int(conn, v);
        conn += ' ';
      }
    }
    if (binary) {
      put_le<int64_t>(offs, static_cast<int64_t>(4 * (i + 1)));
      put_le<uint8_t>(types, 10);
    } else {
      conn += '\n';
      append_int(offs, static_cast<int64_t>(4 * (i + 1)));
      offs += '\n';
      types += "10\n";
    }
  }
  out += (binary ? block(conn) + "\n" : conn);
  out += "        </DataArray>\n";
  out += std::string("        <DataArray type=\"Int64\" Name=\"offsets\" format=\"") + format + "\">\n";
  out += (binary ? block(offs) + "\n" : offs);
  out += "        </DataArray>\n";
  out += std::string("        <DataArray type=\"UInt8\" Name=\"types\" format=\"") + format + "\">\n";
  out += (binary ? block(types) + "\n" : types);
  out += "        </DataArray>\n      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n";
  detail::write_file_bytes(path, out);
}

void write_gmsh(const TetMesh& mesh, const std::string& path, int version, bool binary) {
  check_writable(mesh, path);
  if (version != 22 && version != 41) throw MeshError(path + ": Gmsh version must be 22 or 41");
  const size_t n = mesh.vertices.size(), t = mesh.tets.size();
  std::string out = "$MeshFormat\n";
  out += version == 22 ? "2.2" : "4.1";
  out += binary ? " 1 8\n" : " 0 8\n";
  if (binary) {
    put_le<int32_t>(out, 1);
    out += '\n';
  }
  out += "$EndMeshFormat\n";
  if (version == 22) {
    out += "$Nodes\n" + std::to_string(n) + "\n";
    for (size_t i = 0; i < n; ++i) {
      if (binary) {
        put_le<int32_t>(out, static_cast<int32_t>(i + 1));
        for (int k = 0; k < 3; ++k) put_le<double>(out, mesh.vertices[i][k]);
      } else {
        append_int(out, static_cast<int64_t>(i + 1));
        append_xyz(out, mesh.vertices[i]);
        out += '\n';
      }
    }
    if (binary) out += '\n';
    out += "$EndNodes\n$Elements\n" + std::to_string(t) + "\n";
    if (binary) {
      put_le<int32_t>(out, 4);
      put_le<int32_t>(out, static_cast<int32_t>(t));
      put_le<int32_t>(out, 2);
    }
    for (size_t i = 0; i < t; ++i) {
      if (binary) {
        put_le<int32_t>(out, static_cast<int32_t>(i + 1));
        put_le<int32_t>(out, 1);
        put_le<int32_t>(out, 1);
        for (int32_t v : mesh.tets[i]) put_le<int32_t>(out, v + 1);
      } else {
        append_int(out, static_cast<int64_t>(i + 1));
        out += " 4 2 1 1";
        for (int32_t v : mesh.tets[i]) {
          out += ' ';
          append_int(out, v + 1);
        }
        out += '\n';
      }
    }
    if (binary) out += '\n';
    out += "$EndElements\n";
    detail::write_file_bytes(path, out);
    return;
  }
  // 4.1: one volume entity (tag 1) holding every node and every tet.
  auto size_field = [&](uint64_t v, bool last) {
    if (binary) put_le<uint64_t>(out, v);
    else {
      append_int(out, static_cast<int64_t>(v));
      out += last ? '\n' : ' ';
    }
  };
  auto int_field = [&](int32_t v) {
    if (binary) put_le<int32_t>(out, v);
    else {
      append_int(out, v);
      out += ' ';
    }
  };
  out += "$Nodes\n";
  size_field(1, false);
  size_field(n, false);
  size_field(1, false);
  size_field(n, true);
  int_field(3);
  int_field(1);
  int_field(0);
  size_field(n, true);
  for (size_t i = 0; i < n; ++i) size_field(i + 1, true);
  for (const Vec3& p : mesh.vertices) {
    if (binary) {
      for (int k = 0; k < 3; ++k) put_le<double>(out, p[k]);
    } else {
      for (int k = 0; k < 3; ++k) {
        if (k) out += ' ';
        append_double(out, p[k]);
      }
      out += '\n';
    }
  }
  if (binary) out += '\n';
  out += "$EndNodes\n$Elements\n";
  size_field(1, false);
  size_field(t, false);
  size_field(1, false);
  size_field(t, true);
  int_field(3);
  int_field(1);
  int_field(4);
  size_field(t, true);
  for (size_t i = 0; i < t; ++i) {
    size_field(i + 1, false);
    for (int k = 0; k < 4; ++k) size_field(static_cast<uint64_t>(mesh.tets[i][k]) + 1, k == 3);
  }
  if (binary) out += '\n';
  out += "$EndElements\n";
  detail::write_file_bytes(path, out);
}

void write_mesh(const TetMesh& mesh, const std::string& path, const MeshWriteOptions& options) {
  const std::string ext = detail::lower_extension(path);
  if (ext == ".node" || ext == ".ele") write_tetgen(mesh, path.substr(0, path.size() - ext.size()), options.tetgen_index_base);
  else if (ext == ".vtk") write_vtk_legacy(mesh, path, options.binary);
  else if (ext == ".vtu") write_vtu(mesh, path, options.binary);
  else if (ext == ".msh") write_gmsh(mesh, path, options.gmsh_version, options.binary);
  else throw MeshError(path + ": unknown output format '" + ext + "' (use .node, .vtk, .vtu or .msh)");
}

}  // namespace pliant
