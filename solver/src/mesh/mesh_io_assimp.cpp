// SPDX-License-Identifier: Apache-2.0
// Surface meshes through assimp (OBJ, STL, PLY, glTF/GLB, FBX, OFF, ...), and a tiny OFF/OBJ
// writer for handing a surface to TetGen.
#include "mesh/mesh_parse.hpp"
#include "pliant/render_mesh.hpp"

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <spdlog/spdlog.h>

#include <charconv>
#include <cmath>
#include <filesystem>
#include <functional>
#include <unordered_map>

namespace pliant {

namespace {
struct PointHash {
  size_t operator()(const Vec3& p) const {
    size_t h = 0;
    for (int k = 0; k < 3; ++k) h = h * 1000003u ^ std::hash<double>{}(p[k] == 0 ? 0.0 : p[k]);
    return h;
  }
};
struct PointEq {
  bool operator()(const Vec3& a, const Vec3& b) const { return a == b; }
};
}  // namespace

SurfaceMesh load_surface(const std::string& path, const SurfaceLoadOptions& options) {
  if (!std::filesystem::is_regular_file(path)) throw MeshError(path + ": cannot open file");
  Assimp::Importer importer;
  // Only positions matter: drop normals/UVs before joining so vertices split by them merge.
  importer.SetPropertyInteger(AI_CONFIG_PP_RVC_FLAGS, aiComponent_NORMALS | aiComponent_TEXCOORDS | aiComponent_COLORS |
                                                          aiComponent_TANGENTS_AND_BITANGENTS);
  const aiScene* scene = importer.ReadFile(
      path, aiProcess_Triangulate | aiProcess_RemoveComponent |
                aiProcess_PreTransformVertices | aiProcess_SortByPType);
  if (!scene) throw MeshError(path + ": cannot read surface: " + importer.GetErrorString());
  SurfaceMesh out;
  out.name = detail::base_name(path);
  std::unordered_map<Vec3, int32_t, PointHash, PointEq> welded;
  int64_t skipped_faces = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[m];
    if (!mesh || !mesh->mVertices) continue;
    std::vector<int32_t> map(mesh->mNumVertices);
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D& a = mesh->mVertices[v];
      const Vec3 p(double(a.x) * options.scale, double(a.y) * options.scale, double(a.z) * options.scale);
      if (!p.allFinite()) throw MeshError(path + ": mesh " + std::to_string(m) + " vertex " + std::to_string(v) + ": non-finite coordinate");
      if (options.weld) {
        auto [it, inserted] = welded.try_emplace(p, static_cast<int32_t>(out.vertices.size()));
        if (inserted) out.vertices.push_back(p);
        map[v] = it->second;
      } else {
        map[v] = static_cast<int32_t>(out.vertices.size());
        out.vertices.push_back(p);
      }
    }
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices != 3) {
        ++skipped_faces;
        continue;
      }
      Triangle t;
      for (int k = 0; k < 3; ++k) {
        if (face.mIndices[k] >= mesh->mNumVertices) throw MeshError(path + ": face index out of range");
        t[k] = map[face.mIndices[k]];
      }
      if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) {
        ++skipped_faces;
        continue;
      }
      out.triangles.push_back(t);
    }
  }
  if (out.triangles.empty()) throw MeshError(path + ": no triangles in the file");
  if (skipped_faces) spdlog::info("{}: skipped {} points/lines/degenerate faces", out.name, skipped_faces);
  // Drop vertices no triangle uses (points, line vertices) so that counts are the surface's.
  std::vector<int32_t> remap(out.vertices.size(), -1);
  std::vector<Vec3> kept;
  for (Triangle& t : out.triangles)
    for (int32_t& v : t) {
      if (remap[v] < 0) {
        remap[v] = static_cast<int32_t>(kept.size());
        kept.push_back(out.vertices[v]);
      }
      v = remap[v];
    }
  out.vertices = std::move(kept);
  return out;
}

namespace {
// Surfaces usually come in single precision: print a float-representable coordinate as the
// shortest float text ("0.3336761", not "0.3336760997772217"), so TetGen sees exactly the numbers
// of the original file and meshes it as it would have meshed that file.
void append_coordinate(std::string& out, double v) {
  const auto f = static_cast<float>(v);
  if (static_cast<double>(f) == v) {
    char buf[32];
    auto [p, ec] = std::to_chars(buf, buf + sizeof buf, f);
    out.append(buf, p);
  } else {
    detail::append_double(out, v);
  }
}
}  // namespace

void write_surface(const SurfaceMesh& surface, const std::string& path) {
  const std::string ext = detail::lower_extension(path);
  std::string text;
  if (ext == ".off") {
    text = "OFF\n";
    detail::append_int(text, static_cast<int64_t>(surface.vertices.size()));
    text += ' ';
    detail::append_int(text, static_cast<int64_t>(surface.triangles.size()));
    text += " 0\n";
  } else if (ext != ".obj") {
    throw MeshError(path + ": surfaces are written as .off or .obj");
  }
  for (const Vec3& p : surface.vertices) {
    if (ext == ".obj") text += "v ";
    for (int k = 0; k < 3; ++k) {
      if (k) text += ' ';
      append_coordinate(text, p[k]);
    }
    text += '\n';
  }
  for (const Triangle& t : surface.triangles) {
    text += ext == ".obj" ? "f" : "3";
    for (int k = 0; k < 3; ++k) {
      text += ' ';
      detail::append_int(text, t[k] + (ext == ".obj" ? 1 : 0));
    }
    text += '\n';
  }
  detail::write_file_bytes(path, text);
}

}  // namespace pliant
