// SPDX-License-Identifier: Apache-2.0
// Every reader and writer: round trips are exact, and the same mesh in every format loads to the
// same counts and volume.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>


using namespace pliant;
using pliant::test::data_file;
using pliant::test::model_dir;
using pliant::test::ScratchDir;

namespace {

MeshLoadOptions quiet() {
  MeshLoadOptions o;
  o.validation.log = false;
  return o;
}

void expect_same_mesh(const TetMesh& a, const TetMesh& b) {
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  ASSERT_EQ(a.tets.size(), b.tets.size());
  for (size_t i = 0; i < a.vertices.size(); ++i) ASSERT_EQ(a.vertices[i], b.vertices[i]) << "vertex " << i;
  for (size_t i = 0; i < a.tets.size(); ++i) ASSERT_EQ(a.tets[i], b.tets[i]) << "tet " << i;
}

struct WriteCase {
  const char* file;
  MeshWriteOptions options;
};

const WriteCase kWriteCases[] = {
    {"m.node", {false, 41, 0}}, {"m1.node", {false, 41, 1}}, {"m.vtk", {false, 41, 0}},  {"mb.vtk", {true, 41, 0}},
    {"m.vtu", {false, 41, 0}},  {"mb.vtu", {true, 41, 0}},   {"m41.msh", {false, 41, 0}}, {"m41b.msh", {true, 41, 0}},
    {"m22.msh", {false, 22, 0}}, {"m22b.msh", {true, 22, 0}},
};

}  // namespace

TEST(MeshFormats, RoundTripIsExactForEveryWriter) {
  ScratchDir dir;
  // The hippo: irregular coordinates (not representable in few digits) and slivers.
  TetMesh original = load_mesh(model_dir() + "/thesis/hippo.node", quiet());
  // Scale by an awkward factor so that coordinates need all 17 digits.
  scale_mesh(original, 0.1 / 3.0);
  for (const WriteCase& c : kWriteCases) {
    SCOPED_TRACE(c.file);
    write_mesh(original, dir.file(c.file), c.options);
    const TetMesh back = load_mesh(dir.file(c.file), quiet());
    expect_same_mesh(original, back);
  }
}

TEST(MeshFormats, TetGenIndexBaseIsDetectedFromTheFirstNode) {
  ScratchDir dir;
  const TetMesh beam = *builtin_mesh("beam1");
  write_tetgen(beam, dir.file("zero"), 0);
  write_tetgen(beam, dir.file("one"), 1);
  expect_same_mesh(load_mesh(dir.file("zero.node"), quiet()), beam);
  expect_same_mesh(load_mesh(dir.file("one.ele"), quiet()), beam);   // .ele, .node or the stem all work
  expect_same_mesh(load_mesh(dir.file("one"), quiet()), beam);
}

TEST(MeshFormats, SameCubeInEveryHandWrittenFormat) {
  // tests/mesh/data: the unit cube split in 5 tets, written by hand in each format with the
  // extras real files carry (attributes, markers, comments, physical names, entities, point and
  // line elements, triangle cells, field data, point data, two node blocks, base64 blocks, the
  // VTK 5.1 OFFSETS/CONNECTIVITY layout, raw appended VTU data).
  for (const char* f : {"cube.node", "cube_v1.msh", "cube_v22.msh", "cube_v41.msh", "cube.vtk", "cube_v51.vtk", "cube.vtu", "cube_b64.vtu",
                        "cube_appended.vtu"}) {
    SCOPED_TRACE(f);
    const MeshLoadResult r = load_mesh_with_report(data_file(f), quiet());
    EXPECT_EQ(r.mesh.vertices.size(), 8u);
    EXPECT_EQ(r.mesh.tets.size(), 5u);
    EXPECT_NEAR(total_volume(r.mesh), 1.0, 1e-12);
    EXPECT_NEAR(r.report.min_dihedral_deg, 54.7356, 1e-3);
    EXPECT_TRUE(r.report.surface.closed_manifold);
    EXPECT_EQ(r.report.surface.triangles, 12);
    EXPECT_TRUE(r.report.warnings.empty());
  }
}

TEST(MeshFormats, SameModelInEveryFormatHasTheSameCountsAndVolume) {
  ScratchDir dir;
  for (const char* name : {"liver2", "armadillo-small", "beam3"}) {
    SCOPED_TRACE(name);
    const MeshLoadResult ref = resolve_mesh_with_report(name, {model_dir()}, quiet());
    for (const WriteCase& c : kWriteCases) {
      SCOPED_TRACE(c.file);
      write_mesh(ref.mesh, dir.file(c.file), c.options);
      const MeshLoadResult r = load_mesh_with_report(dir.file(c.file), quiet());
      EXPECT_EQ(r.report.vertices, ref.report.vertices);
      EXPECT_EQ(r.report.tets, ref.report.tets);
      EXPECT_DOUBLE_EQ(r.report.volume, ref.report.volume);
      EXPECT_EQ(r.report.surface.triangles, ref.report.surface.triangles);
    }
  }
}

TEST(MeshFormats, SofaLiverGmshV1MatchesTheCounts) {
  const MeshLoadResult liver2 = load_mesh_with_report(model_dir() + "/liver/liver2_sofa.msh", quiet());
  EXPECT_EQ(liver2.report.vertices, 507);  // the 860 boundary triangles and 71 lines are skipped
  EXPECT_EQ(liver2.report.tets, 1493);
  const MeshLoadResult liver = load_mesh_with_report(model_dir() + "/liver/liver_sofa.msh", quiet());
  EXPECT_EQ(liver.report.vertices, 181);
  EXPECT_EQ(liver.report.tets, 596);
}
