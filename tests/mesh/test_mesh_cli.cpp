// SPDX-License-Identifier: Apache-2.0
// The pliant-mesh tool: `info --json` prints one JSON object with the promised keys; bad arguments
// exit non-zero with one line naming the argument; convert/embed write files that load back.
#include "pliant/mesh_io.hpp"
#include "pliant/render_mesh.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>
#include <sys/wait.h>

using namespace pliant;
using pliant::test::data_file;
using pliant::test::model_dir;
using pliant::test::ScratchDir;

namespace {

struct ToolRun {
  int status = -1;
  std::string out, err;
};

ToolRun run_tool(const std::string& args, const ScratchDir& dir) {
  const std::string err_file = dir.file("stderr.txt");
  const std::string cmd = std::string("PLIANT_MODEL_PATH=") + model_dir() + " " + PLIANT_MESH_TOOL + " " + args + " 2>" + err_file;
  ToolRun r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  const int st = ::pclose(p);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  std::ifstream in(err_file);
  r.err.assign(std::istreambuf_iterator<char>(in), {});
  return r;
}

// The output as one JSON object, parsed strictly (nlohmann-json; throws on anything else).
nlohmann::json one_json_object(const std::string& s) {
  nlohmann::json j = nlohmann::json::parse(s);
  if (!j.is_object()) throw std::runtime_error("not a JSON object: " + s);
  return j;
}

}  // namespace

TEST(MeshCli, InfoJsonIsOneObjectWithTheKeys) {
  ScratchDir dir;
  const ToolRun r = run_tool("info --json --density 1227 hippo", dir);
  ASSERT_EQ(r.status, 0) << r.err;
  nlohmann::json j;
  ASSERT_NO_THROW(j = one_json_object(r.out)) << r.out;
  for (const char* key : {"vertices", "tets", "volume", "bbox", "min_dihedral_deg", "surface_triangles", "mass", "dihedral_histogram"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_EQ(j["vertices"].get<int>(), 2885);
  EXPECT_EQ(j["tets"].get<int>(), 10361);
  EXPECT_NEAR(j["mass"].get<double>(), 0.350, 0.001);  // the thesis hippo's 350 g
  EXPECT_NE(r.err.find("tiny tets"), std::string::npos);   // warnings on stderr, not in the JSON stream
}

TEST(MeshCli, BadArgumentsExitNonZeroWithOneLineNamingThem) {
  ScratchDir dir;
  struct Case {
    const char* args;
    const char* names;
  } cases[] = {
      {"info --scale abc beam1", "--scale"},
      {"info --scale -2 beam1", "--scale"},
      {"info --frobnicate beam1", "--frobnicate"},
      {"frobnicate beam1", "frobnicate"},
      {"info", "info needs"},
      {"info beam1 extra", "extra"},
      {"convert beam1 out.vtk --gmsh-version 3", "--gmsh-version"},
      {"info --density", "--density"},
      {"info --unit furlong beam1", "--unit"},
      {"info no-such-mesh", "no-such-mesh"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.args);
    const ToolRun r = run_tool(c.args, dir);
    EXPECT_NE(r.status, 0);
    EXPECT_NE(r.err.find(c.names), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
  }
}

TEST(MeshCli, ValidateConvertAndEmbed) {
  ScratchDir dir;
  ToolRun r = run_tool("validate " + data_file("cube_v22.msh"), dir);
  EXPECT_EQ(r.status, 0) << r.err;
  r = run_tool("validate --strict hippo", dir);
  EXPECT_EQ(r.status, 2);  // quality warnings
  r = run_tool("convert liver " + dir.file("liver.vtu") + " --binary", dir);
  ASSERT_EQ(r.status, 0) << r.err;
  MeshLoadOptions o;
  o.validation.log = false;
  EXPECT_EQ(load_mesh(dir.file("liver.vtu"), o).tets.size(), 596u);
  r = run_tool("embed " + data_file("cube.node") + " " + data_file("octahedron.obj") + " " + dir.file("b.txt"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(read_binding(dir.file("b.txt")).tet.size(), 6u);
  dir.write("garbage.msh", std::string("$MeshFormat\n\x01\x02\xff garbage"));
  r = run_tool("info " + dir.file("garbage.msh"), dir);
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("garbage.msh:2: unsupported Gmsh format version"), std::string::npos) << r.err;
}
