// SPDX-License-Identifier: Apache-2.0
// The shipped models (meshes/): every registered model loads at its documented size, the thesis
// armadillo and the IPC armadillo with their counts, the armadillo's render surface embedded
// and deformed, and its surface tetrahedralized as meshes/SOURCES.md says. Seconds each: the
// small files' tests are in the other files.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/render_mesh.hpp"
#include "test_helpers.hpp"

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>

using namespace pliant;
using pliant::test::model_dir;
using pliant::test::ScratchDir;

namespace {

MeshLoadOptions quiet() {
  MeshLoadOptions o;
  o.validation.log = false;
  return o;
}

// An affine map: rotation, anisotropic stretch, translation.
Vec3 affine(const Vec3& p) {
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Matrix3d s = Eigen::Vector3d(1.3, 0.8, 1.1).asDiagonal();
  return r * s * p + Vec3(0.05, -0.02, 0.3);
}

double max_abs_weight_sum_error(const SurfaceBinding& b) {
  double worst = 0;
  for (const auto& w : b.weights) worst = std::max(worst, std::abs(w.sum() - 1.0));
  return worst;
}

}  // namespace

TEST(MeshFormats, IpcGmsh41WithCustomSectionLoads) {
  // Armadillo13K.msh has a non-standard $Surface section after $Elements: skipped.
  const MeshLoadResult r = load_mesh_with_report(model_dir() + "/armadillo/armadillo_13k_ipc.msh", quiet());
  EXPECT_EQ(r.report.vertices, 13230);
  EXPECT_EQ(r.report.tets, 54985);
  EXPECT_NEAR(r.report.min_dihedral_deg, 3.2, 0.05);
  EXPECT_TRUE(r.report.surface.closed_manifold);
}

// How long the load takes is a figure (pliant-mesh info prints it), not an assertion.
TEST(MeshFormats, ThesisArmadilloLoadsWithThesisCountsAndSize) {
  const MeshLoadResult r = resolve_mesh_with_report("armadillo", {model_dir()}, quiet());
  EXPECT_EQ(r.report.vertices, 14779);
  EXPECT_EQ(r.report.tets, 54855);
  const Vec3 e = r.report.bbox.extent();
  EXPECT_NEAR(e.x(), 0.135, 0.0005);
  EXPECT_NEAR(e.y(), 0.086, 0.0005);
  EXPECT_NEAR(e.z(), 0.104, 0.0005);
  EXPECT_NEAR(1027.0 * r.report.volume, 0.125, 0.001);  // the thesis mass, 125 g
  EXPECT_TRUE(r.report.surface.closed_manifold);
  EXPECT_EQ(r.report.surface.euler_characteristic, 2);
}

TEST(MeshResolve, EveryRegisteredModelLoadsAtItsDocumentedSize) {
  MeshLoadOptions o;
  o.validation.log = false;
  for (const ModelEntry& m : model_registry()) {
    SCOPED_TRACE(m.name);
    const MeshLoadResult r = resolve_mesh_with_report(m.name, {model_dir()}, o);
    const double longest = r.report.bbox.extent().maxCoeff();
    EXPECT_GT(longest, 0.12);
    EXPECT_LT(longest, 0.21);
    EXPECT_TRUE(r.report.surface.closed_manifold);
  }
  // The documented sizes of the fitted ones.
  EXPECT_NEAR(resolve_mesh_with_report("liver", {model_dir()}, o).report.bbox.extent().maxCoeff(), 0.20, 1e-6);
  EXPECT_NEAR(resolve_mesh_with_report("bunny", {model_dir()}, o).report.bbox.extent().maxCoeff(), 0.15, 1e-6);
  EXPECT_NEAR(resolve_mesh_with_report("armadillo-small", {model_dir()}, o).report.bbox.extent().maxCoeff(), 0.135, 1e-6);
}

TEST(RenderMesh, ArmadilloSurfaceEmbedsExactlyAndFollowsDeformation) {
  // The shipped render mesh: the 10k-vertex armadillo surface, embedded in armadillo-tetgen
  // (the same frame, the same scale).
  const ModelEntry* model = find_model("armadillo-tetgen");
  ASSERT_NE(model, nullptr);
  ASSERT_FALSE(model->render_surface.empty());
  const TetMesh tets = resolve_mesh_with_report("armadillo-tetgen", {model_dir()}, quiet()).mesh;
  SurfaceLoadOptions so;
  so.scale = model->scale;
  const SurfaceMesh surface = load_surface(find_in_model_path(model->render_surface, {model_dir()}), so);
  EXPECT_EQ(surface.vertices.size(), 10002u);
  EXPECT_EQ(surface.triangles.size(), 20000u);

  const SurfaceBinding b = embed_surface(tets, surface);
  ASSERT_EQ(b.tet.size(), surface.vertices.size());
  EXPECT_EQ(b.outside, 0);  // the surface is the tet mesh's boundary (up to float rounding)
  EXPECT_LT(max_abs_weight_sum_error(b), 1e-12);
  // Vertices on the boundary may sit a float-rounding distance outside their tet: slightly
  // negative weights there, never large ones.
  for (const auto& w : b.weights) EXPECT_GE(w.minCoeff(), -1e-4);

  // Rest positions: reproduced exactly (to round-off).
  const double size = bounding_box(tets.vertices).extent().norm();
  const std::vector<Vec3> rest = deform_surface(b, tets, tets.vertices);
  double worst = 0;
  for (size_t v = 0; v < rest.size(); ++v) worst = std::max(worst, (rest[v] - surface.vertices[v]).norm());
  EXPECT_LT(worst, 1e-14 * size * 100);

  // An affine deformation of the tet mesh moves the surface by the same affine map (barycentric
  // interpolation is exact for affine maps), and the normals rotate with it.
  std::vector<Vec3> x(tets.vertices.size());
  for (size_t i = 0; i < x.size(); ++i) x[i] = affine(tets.vertices[i]);
  const std::vector<Vec3> moved = deform_surface(b, tets, x);
  worst = 0;
  for (size_t v = 0; v < moved.size(); ++v) worst = std::max(worst, (moved[v] - affine(surface.vertices[v])).norm());
  EXPECT_LT(worst, 1e-12);
  const std::vector<Vec3> n = vertex_normals(moved, b.triangles);
  ASSERT_EQ(n.size(), moved.size());
  for (const Vec3& v : n) EXPECT_NEAR(v.norm(), 1.0, 1e-9);

  // A non-affine deformation (a bend): each surface vertex moves with its own tet, so it is the
  // same combination of that tet's deformed corners, and stays continuous: surface edges do not
  // stretch more than the tet edges around them allow.
  auto bend = [](const Vec3& p) {
    const double a = 4.0 * p.y();
    return Vec3(p.x() * std::cos(a) - p.z() * std::sin(a), p.y(), p.x() * std::sin(a) + p.z() * std::cos(a));
  };
  for (size_t i = 0; i < x.size(); ++i) x[i] = bend(tets.vertices[i]);
  const std::vector<Vec3> bent = deform_surface(b, tets, x);
  double max_err = 0;
  for (size_t v = 0; v < bent.size(); ++v) {
    const Tet& t = tets.tets[b.tet[v]];
    Vec3 expect = Vec3::Zero();
    for (int k = 0; k < 4; ++k) expect += b.weights[v][k] * x[t[k]];
    max_err = std::max(max_err, (bent[v] - expect).norm());
    // Close to the exact bend of the rest vertex: the error is the bend's curvature over a tet.
    EXPECT_LT((bent[v] - bend(surface.vertices[v])).norm(), 0.005);
  }
  EXPECT_EQ(max_err, 0.0);
}

TEST(Tetrahedralize, ShippedArmadilloSurfaceGivesTheDocumentedCounts) {
  // meshes/SOURCES.md: `tetgen -pYq1.685 armadillo_10k_surface.ply` gives 13,867 V / 54,990 T.
  // The .ply goes to TetGen unchanged, so the result matches exactly.
  if (!program_available("tetgen")) GTEST_SKIP() << "tetgen is not installed";
  ScratchDir dir;
  const std::string ply = model_dir() + "/armadillo/armadillo_10k_surface.ply";
  TetrahedralizeOptions o;
  o.quality_ratio = 1.685;
  o.work_dir = dir.file("work");
  o.source_file = ply;
  const TetrahedralizeResult t = tetrahedralize_surface(load_surface(ply), o);
  const MeshLoadResult r = load_mesh_with_report(t.node_path, quiet());
  EXPECT_EQ(r.report.vertices, 13867);
  EXPECT_EQ(r.report.tets, 54990);
  EXPECT_EQ(r.report.surface.triangles, 20000);  // -Y: the surface is kept as it is
}
