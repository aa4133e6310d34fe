// SPDX-License-Identifier: Apache-2.0
// MeshSource.model_path confined to --model-path: symlinks out of it, '..', NUL and names that
// exist only relative to the working directory are refused; a file that is not a mesh is
// refused without quoting it; long input is echoed capped. Registry-level, plus one check of
// the gRPC status for input longer than gRPC's metadata limit.
#include "pliant/builtin_meshes.hpp"
#include "pliant/client/client.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/server/edge.hpp"
#include "pliant/server/registry.hpp"
#include "pliant/server/server.hpp"

#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace pliant;
using server::Code;

namespace {

fs::path fresh_dir(const std::string& name) {
  fs::path p = fs::temp_directory_path() /
               ("pliant_modelpath_" + name + "_" + std::to_string(::getpid()) + "_" +
                std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()));
  fs::create_directories(p);
  return p;
}

void write_text(const fs::path& p, const std::string& text) {
  std::ofstream f(p, std::ios::binary);
  f << text;
}

v1::CreateSceneRequest model_request(const std::string& name) {
  v1::CreateSceneRequest r;
  r.mutable_spec()->mutable_mesh()->set_model_path(name);
  r.mutable_spec()->mutable_tick()->set_mode(v1::TICK_MODE_LOCKSTEP);
  r.mutable_spec()->mutable_solver()->set_substeps(1);
  return r;
}

// A model directory holding a valid mesh, next to an "outside" directory with another valid
// mesh and a secret; symlinks from inside lead out.
struct ModelDirs {
  fs::path root = fresh_dir("root");
  fs::path models = root / "models";
  fs::path outside = root / "outside";
  ModelDirs() {
    fs::create_directories(models / "sub");
    fs::create_directories(outside);
    const TetMesh beam = *builtin_mesh("beam1");
    write_mesh(beam, (models / "ok.vtk").string());
    write_mesh(beam, (models / "sub" / "nested.msh").string());
    write_mesh(beam, (models / "pair.node").string());  // TetGen: pair.node + pair.ele
    write_mesh(beam, (outside / "out.vtk").string());
    write_mesh(beam, (outside / "outpair.node").string());
    write_text(outside / "secret", "TOPSECRET-4711 not a mesh\n");
    fs::create_symlink(outside / "out.vtk", models / "escape.vtk");
    fs::create_directory_symlink(outside, models / "linkdir");
    fs::create_symlink(models / "ok.vtk", models / "inner_link.vtk");  // stays inside: fine
    // A TetGen pair whose .node is inside but whose .ele leads out.
    fs::copy_file(outside / "outpair.node", models / "half.node");
    fs::create_symlink(outside / "outpair.ele", models / "half.ele");
    write_text(models / "garbage.vtk", "# vtk DataFile Version 3.0\nTOPSECRET-4711\nASCII\nDATASET POLYDATA\n");
  }
  ~ModelDirs() {
    std::error_code ec;
    fs::remove_all(root, ec);
  }
  server::SceneRegistry registry() const {
    server::RegistryOptions o;
    o.model_path = {models.string()};
    return server::SceneRegistry(o);
  }
};

}  // namespace

TEST(ModelPath, FilesInsideTheModelPathLoad) {
  ModelDirs d;
  auto reg = d.registry();
  for (const char* name : {"ok.vtk", "sub/nested.msh", "pair.node", "pair", "inner_link.vtk", "beam2"}) {
    v1::Scene out;
    server::Error e = reg.create(model_request(name), &out);
    EXPECT_TRUE(e.ok()) << name << ": " << e.message;
    if (e.ok()) {
      EXPECT_GT(out.vertex_count(), 0u) << name;
    }
  }
}

TEST(ModelPath, SymlinksOutOfTheModelPathAreRefused) {
  ModelDirs d;
  auto reg = d.registry();
  for (const char* name : {"escape.vtk", "linkdir/out.vtk", "linkdir/outpair", "half.node", "half"}) {
    v1::Scene out;
    server::Error e = reg.create(model_request(name), &out);
    EXPECT_EQ(e.code, Code::InvalidArgument) << name << ": " << e.message;
    EXPECT_NE(e.message.find("spec.mesh.model_path"), std::string::npos) << e.message;
    EXPECT_NE(e.message.find("outside the model path"), std::string::npos) << e.message;
  }
}

TEST(ModelPath, EscapingNamesAndNulAreRefused) {
  ModelDirs d;
  auto reg = d.registry();
  for (const std::string& name : {std::string("../outside/out.vtk"), std::string("sub/../../outside/out.vtk"),
                                 (d.outside / "out.vtk").string()}) {
    v1::Scene out;
    server::Error e = reg.create(model_request(name), &out);
    EXPECT_EQ(e.code, Code::InvalidArgument) << name << ": " << e.message;
    EXPECT_NE(e.message.find("must be a relative name"), std::string::npos) << e.message;
  }
  v1::Scene out;
  server::Error e = reg.create(model_request(std::string("ok.vtk\0../../etc/passwd", 23)), &out);
  EXPECT_EQ(e.code, Code::InvalidArgument) << e.message;
  EXPECT_NE(e.message.find("NUL character at offset 6"), std::string::npos) << e.message;
  EXPECT_NE(e.message.find("ok.vtk\\x00"), std::string::npos) << e.message;  // shown escaped
}

// A name that exists only relative to the server's working directory is not found, exactly
// like one that exists nowhere.
TEST(ModelPath, NoFallbackToTheWorkingDirectory) {
  ModelDirs d;
  auto reg = d.registry();
  const fs::path cwd = fs::current_path();
  fs::current_path(d.outside);
  v1::Scene out;
  server::Error exists = reg.create(model_request("out.vtk"), &out);
  server::Error missing = reg.create(model_request("nonexistent.vtk"), &out);
  fs::current_path(cwd);
  EXPECT_EQ(exists.code, Code::NotFound) << exists.message;
  EXPECT_EQ(missing.code, Code::NotFound) << missing.message;
  EXPECT_EQ(exists.message, "spec.mesh.model_path 'out.vtk' not found on the server's model path");
}

TEST(ModelPath, ErrorsDoNotQuoteTheFile) {
  ModelDirs d;
  auto reg = d.registry();
  v1::Scene out;
  server::Error e = reg.create(model_request("garbage.vtk"), &out);
  EXPECT_EQ(e.code, Code::InvalidArgument) << e.message;
  EXPECT_NE(e.message.find("'garbage.vtk' is not a valid tet mesh"), std::string::npos) << e.message;
  EXPECT_EQ(e.message.find("TOPSECRET"), std::string::npos) << e.message;
  // A directory and a file that is no mesh at all.
  for (const char* name : {"sub", "linkdir/secret"}) {
    server::Error r = reg.create(model_request(name), &out);
    EXPECT_EQ(r.code, Code::InvalidArgument) << name << ": " << r.message;
    EXPECT_EQ(r.message.find("TOPSECRET"), std::string::npos) << r.message;
  }
}

TEST(ModelPath, LongInputIsEchoedCapped) {
  EXPECT_EQ(server::echo("abc"), "'abc'");
  EXPECT_EQ(server::echo(std::string("a\nb'", 4)), "'a\\x0ab\\x27'");
  const std::string long_name(9000, 'x');
  const std::string shown = server::echo(long_name);
  std::string expected(1, '\'');  // built by appends: GCC 12 warns (-Wrestrict) on "'" + string
  expected.append(server::kMaxEcho, 'x');
  expected += "'... (9000 characters)";
  EXPECT_EQ(shown, expected);

  ModelDirs d;
  auto reg = d.registry();
  v1::Scene out;
  server::Error e = reg.create(model_request(long_name + ".vtk"), &out);
  EXPECT_EQ(e.code, Code::InvalidArgument);  // longer than a model name may be
  EXPECT_LT(e.message.size(), 400u) << e.message;
  EXPECT_NE(e.message.find("(9004 characters)"), std::string::npos) << e.message;
  v1::CreateSceneRequest bad_id = model_request("ok.vtk");
  bad_id.set_scene_id(long_name);
  e = reg.create(bad_id, &out);
  EXPECT_EQ(e.code, Code::InvalidArgument);
  EXPECT_LT(e.message.size(), 400u);
  e = reg.get(long_name, &out);
  EXPECT_EQ(e.code, Code::NotFound);
  EXPECT_LT(e.message.size(), 400u);
}

// Over gRPC, input far longer than the 8 KiB metadata limit still gets INVALID_ARGUMENT (the
// status message carries only its capped echo).
TEST(ModelPath, HugeInputGetsInvalidArgumentOverGrpc) {
  test::InProcessServer srv;
  ASSERT_TRUE(srv.started.ok());
  client::Client cl = srv.client();
  for (const std::string& huge : {std::string(9000, 'y'), std::string(20000, '\x01')}) {
    v1::CreateSceneRequest r = model_request("ok.vtk");
    r.set_scene_id(huge);
    auto created = cl.create_scene(r);
    EXPECT_EQ(created.status.code, 3) << created.status.to_string().substr(0, 300);
    auto model = cl.create_scene(model_request(huge));
    EXPECT_EQ(model.status.code, 3) << model.status.to_string().substr(0, 300);
    auto got = cl.get_scene(huge);
    EXPECT_EQ(got.status.code, 5) << got.status.to_string().substr(0, 300);
  }
  srv.server->shutdown();
}
