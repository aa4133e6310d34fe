// SPDX-License-Identifier: Apache-2.0
// Writes the fuzzers' seed corpus (fuzz/corpus/<harness>/): small valid inputs of every kind,
// so that mutations start deep inside the parsers. Run by scripts/fuzz.sh --seeds; the output
// is committed.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/server/registry.hpp"

#include <spdlog/spdlog.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace pliant;

namespace {

std::string read_bytes(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

void write_bytes(const fs::path& p, const std::string& bytes) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f << bytes;
}

// A 2 x 1 x 1 cube beam: 10 tets, small enough for quick mutation.
TetMesh tiny() { return make_beam(3, 2, 2, 0.01); }

void mesh_seeds(const fs::path& out, const fs::path& tmp) {
  fs::create_directories(out);
  const TetMesh m = tiny();
  write_tetgen(m, (tmp / "t").string(), 0);
  write_bytes(out / "tetgen0", std::string(1, '\0') + read_bytes(tmp / "t.node") + '\0' + read_bytes(tmp / "t.ele"));
  write_tetgen(m, (tmp / "u").string(), 1);
  write_bytes(out / "tetgen1", std::string(1, '\0') + read_bytes(tmp / "u.node") + '\0' + read_bytes(tmp / "u.ele"));
  struct Variant {
    const char* name;
    char format;
    const char* ext;
    bool binary;
    int gmsh;
  };
  for (const Variant& v : {Variant{"gmsh22", 1, ".msh", false, 22}, Variant{"gmsh41", 1, ".msh", false, 41},
                           Variant{"gmsh41bin", 1, ".msh", true, 41}, Variant{"gmsh22bin", 1, ".msh", true, 22},
                           Variant{"vtk", 2, ".vtk", false, 0}, Variant{"vtkbin", 2, ".vtk", true, 0},
                           Variant{"vtu", 3, ".vtu", false, 0}, Variant{"vtubin", 3, ".vtu", true, 0}}) {
    const fs::path f = tmp / (std::string("m") + v.ext);
    MeshWriteOptions o;
    o.binary = v.binary;
    if (v.gmsh) o.gmsh_version = v.gmsh;
    write_mesh(m, f.string(), o);
    write_bytes(out / v.name, std::string(1, v.format) + read_bytes(f));
  }
}

v1::CreateSceneRequest tiny_request(const std::string& id) {
  v1::CreateSceneRequest r;
  r.set_scene_id(id);
  auto* s = r.mutable_spec();
  const TetMesh m = tiny();
  auto* d = s->mutable_mesh()->mutable_data();
  d->set_name("tiny");
  for (const Vec3& p : m.vertices)
    for (int k = 0; k < 3; ++k) d->add_positions(p[k]);
  for (const auto& t : m.tets)
    for (int k = 0; k < 4; ++k) d->add_tets(t[k]);
  s->mutable_fixed()->add_indices(0);
  s->mutable_fixed()->add_indices(1);
  s->mutable_solver()->set_substeps(2);
  s->mutable_solver()->set_iterations(2);
  s->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  spdlog::set_level(spdlog::level::warn);
  const fs::path root = argc > 1 ? fs::path(argv[1]) : fs::path("fuzz/corpus");
  const fs::path tmp = fs::temp_directory_path() / ("pliant_seeds_" + std::to_string(::getpid()));
  fs::create_directories(tmp);
  mesh_seeds(root / "mesh_loaders", tmp);

  server::SceneRegistry reg({});
  v1::Scene scene;
  if (!reg.create(tiny_request("seed"), &scene).ok()) return 1;
  v1::StepRequest step;
  step.set_scene_id("seed");
  step.set_ticks(2);
  v1::StepResponse stepped;
  if (!reg.step(step, std::chrono::steady_clock::now() + std::chrono::seconds(30), &stepped).ok()) return 1;
  v1::GrabRequest grab;
  grab.set_scene_id("seed");
  grab.set_vertex(5);
  v1::GrabResponse grabbed;
  if (!reg.grab(grab, &grabbed).ok()) return 1;
  v1::SaveSnapshotRequest save;
  save.set_scene_id("seed");
  v1::SaveSnapshotResponse saved;
  if (!reg.save_snapshot(save, &saved).ok()) return 1;
  fs::create_directories(root / "snapshot");
  write_bytes(root / "snapshot" / "tiny", saved.snapshot().SerializeAsString());

  const fs::path req = root / "requests";
  fs::create_directories(req);
  auto put = [&](const char* name, char kind, const std::string& body) {
    write_bytes(req / name, std::string(1, kind) + body);
  };
  put("create_data", 0, tiny_request("c").SerializeAsString());
  v1::CreateSceneRequest builtin;
  builtin.mutable_spec()->mutable_mesh()->set_builtin("beam1");
  builtin.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  builtin.mutable_spec()->mutable_material()->set_young_modulus(1e5);
  builtin.mutable_spec()->mutable_solver()->set_method(v1::METHOD_ANDERSON);
  put("create_builtin", 0, builtin.SerializeAsString());
  v1::CreateSceneRequest file;
  file.mutable_spec()->mutable_mesh()->set_model_path("beams/beam1.vtk");
  file.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  put("create_model_path", 0, file.SerializeAsString());
  v1::StreamFramesRequest stream;
  stream.set_scene_id("seed");
  stream.add_fields(v1::FRAME_FIELD_POSITIONS);
  stream.set_max_rate_hz(30);
  stream.set_every_nth_tick(2);
  put("stream", 1, stream.SerializeAsString());
  v1::ToolPose pose;
  pose.set_scene_id("seed");
  pose.set_shape(v1::TOOL_SHAPE_CAPSULE);
  pose.mutable_position()->set_x(0.01);
  pose.mutable_orientation()->set_w(1);
  pose.set_radius(0.003);
  pose.set_half_length(0.01);
  put("tool_pose", 2, pose.SerializeAsString());
  v1::RestoreSnapshotRequest restore;
  *restore.mutable_snapshot() = saved.snapshot();
  restore.set_scene_id("restored");
  put("restore", 3, restore.SerializeAsString());
  put("model_path", 4, "beams/beam1.vtk");
  put("model_path_escape", 4, "beams/../../etc/passwd");
  fs::remove_all(tmp);
  return 0;
}
