// SPDX-License-Identifier: Apache-2.0
// Render-mesh embedding: every surface vertex is bound with weights summing to 1, the rest surface
// is reproduced exactly, a deformed tet mesh moves the surface consistently, the binding file
// round-trips; surfaces load through assimp; tetrahedralize runs TetGen when it is installed.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/render_mesh.hpp"
#include "test_helpers.hpp"

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <cmath>

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

double max_abs_weight_sum_error(const SurfaceBinding& b) {
  double worst = 0;
  for (const auto& w : b.weights) worst = std::max(worst, std::abs(w.sum() - 1.0));
  return worst;
}

}  // namespace

TEST(SurfaceLoad, ObjAndStlGiveTheSameWeldedClosedSurface) {
  const SurfaceMesh obj = load_surface(data_file("octahedron.obj"));
  const SurfaceMesh stl = load_surface(data_file("octahedron.stl"));  // unindexed: welded on load
  for (const SurfaceMesh* s : {&obj, &stl}) {
    EXPECT_EQ(s->vertices.size(), 6u);
    EXPECT_EQ(s->triangles.size(), 8u);
    const SurfaceStats st = surface_stats(s->vertices, s->triangles);
    EXPECT_TRUE(st.closed_manifold);
    EXPECT_EQ(st.euler_characteristic, 2);
  }
  EXPECT_THROW(load_surface(data_file("missing.obj")), MeshError);
  EXPECT_THROW(load_surface(data_file("cube.ele")), MeshError);
}

TEST(RenderMesh, OctahedronInsideAndOutsideTheCube) {
  const TetMesh cube = load_mesh(data_file("cube.node"), quiet());
  SurfaceMesh s = load_surface(data_file("octahedron.obj"));
  s.vertices.push_back(Vec3(1.5, 0.5, 0.5));  // outside the cube: bound to the nearest tet
  const SurfaceBinding b = embed_surface(cube, s);
  ASSERT_EQ(b.tet.size(), s.vertices.size());
  EXPECT_EQ(b.outside, 1);
  EXPECT_NEAR(b.max_outside_distance, 0.5, 1e-12);
  EXPECT_LT(max_abs_weight_sum_error(b), 1e-12);
  for (size_t v = 0; v + 1 < s.vertices.size(); ++v) EXPECT_GE(b.weights[v].minCoeff(), -1e-10) << "vertex " << v;
  // The outside vertex's tet must touch the x = 1 face.
  const Tet& t = cube.tets[b.tet.back()];
  int on_face = 0;
  for (int32_t i : t) on_face += cube.vertices[i].x() == 1.0;
  EXPECT_GE(on_face, 3);
  const std::vector<Vec3> rest = deform_surface(b, cube, cube.vertices);
  for (size_t v = 0; v < s.vertices.size(); ++v) EXPECT_LT((rest[v] - s.vertices[v]).norm(), 1e-14);
}

TEST(RenderMesh, BindingFileRoundTripsAndIsChecked) {
  ScratchDir dir;
  const TetMesh cube = load_mesh(data_file("cube.node"), quiet());
  const SurfaceMesh s = load_surface(data_file("octahedron.obj"));
  const SurfaceBinding b = embed_surface(cube, s);
  write_binding(b, dir.file("b.txt"), "cube", "octahedron");
  const SurfaceBinding back = read_binding(dir.file("b.txt"));
  EXPECT_EQ(back.tet, b.tet);
  EXPECT_EQ(back.triangles, b.triangles);
  EXPECT_EQ(back.tet_vertex_count, 8);
  EXPECT_EQ(back.tet_count, 5);
  for (size_t v = 0; v < b.weights.size(); ++v) EXPECT_EQ(back.weights[v], b.weights[v]);
  // A binding for another mesh is refused at use.
  const TetMesh beam = *builtin_mesh("beam1");
  EXPECT_THROW(deform_surface(back, beam, beam.vertices), MeshError);
  // Malformed binding files.
  dir.write("bad.txt", "pliant-binding 1\ntet_mesh 8 5\nvertices 1\n0 0.5 0.5 0.5 0.5\ntriangles 0\n");
  EXPECT_THROW(read_binding(dir.file("bad.txt")), MeshError);  // weights sum to 2
  dir.write("bad2.txt", "pliant-binding 1\ntet_mesh 8 5\nvertices 1\n9 1 0 0 0\ntriangles 0\n");
  EXPECT_THROW(read_binding(dir.file("bad2.txt")), MeshError);  // tet out of range
  dir.write("bad3.txt", "pliant-binding 1\ntet_mesh 8 5\nvertices 3\n0 1 0 0 0\n");
  EXPECT_THROW(read_binding(dir.file("bad3.txt")), MeshError);  // truncated
}

TEST(Tetrahedralize, OctahedronThroughTetGenKeepsTheSurface) {
  if (!program_available("tetgen")) GTEST_SKIP() << "tetgen is not installed";
  ScratchDir dir;
  const SurfaceMesh s = load_surface(data_file("octahedron.obj"));
  TetrahedralizeOptions o;
  o.quality_ratio = 1.5;
  o.work_dir = dir.file("work");
  const TetrahedralizeResult t = tetrahedralize_surface(s, o);
  const MeshLoadResult r = load_mesh_with_report(t.node_path, quiet());
  // -Y keeps the boundary: the volume is the octahedron's, (4/3) r^3.
  // (TetGen prints coordinates with ~16 digits, hence the tolerance.)
  EXPECT_NEAR(r.report.volume, 4.0 / 3.0 * 0.4 * 0.4 * 0.4, 1e-7);
  EXPECT_TRUE(r.report.surface.closed_manifold);
  EXPECT_EQ(r.report.surface.triangles, 8);
  // An open surface is refused before TetGen runs.
  SurfaceMesh open = s;
  open.triangles.pop_back();
  EXPECT_THROW(tetrahedralize_surface(open, o), MeshError);
  TetrahedralizeOptions missing = o;
  missing.tetgen = "no-such-tetgen-program";
  try {
    tetrahedralize_surface(s, missing);
    FAIL();
  } catch (const MeshError& e) {
    EXPECT_NE(std::string(e.what()).find("not installed"), std::string::npos);
  }
}
