// SPDX-License-Identifier: Apache-2.0
// Validation and repair on meshes built in memory, quality measures, the resolver and the model set.
#include "pliant/builtin_meshes.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/mesh_validate.hpp"
#include "test_helpers.hpp"

#include <gtest/gtest.h>

#include <cmath>

using namespace pliant;
using pliant::test::model_dir;

namespace {

MeshValidationOptions quiet() {
  MeshValidationOptions o;
  o.log = false;
  return o;
}

TetMesh regular_tet() {
  TetMesh m;
  m.vertices = {{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}};
  m.tets = {{0, 1, 2, 3}};
  if (tet_volume(m, 0) < 0) std::swap(m.tets[0][2], m.tets[0][3]);
  return m;
}

}  // namespace

TEST(MeshQuality, RegularTetHasTheRegularDihedralAndAspectOne) {
  const TetMesh m = regular_tet();
  const auto& v = m.vertices;
  EXPECT_NEAR(tet_min_dihedral_deg(v[0], v[1], v[2], v[3]), std::acos(1.0 / 3.0) * 180 / M_PI, 1e-9);
  EXPECT_NEAR(tet_aspect_ratio(v[0], v[1], v[2], v[3]), 1.0, 1e-12);
  // A sliver: four nearly coplanar points; the dihedral angle goes to 0 and the aspect ratio grows.
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(0, 1, 0), d(1, 1, 0.01);
  EXPECT_LT(tet_min_dihedral_deg(a, b, c, d), 2.0);
  EXPECT_GT(tet_aspect_ratio(a, b, c, d), 10.0);
}

TEST(MeshValidate, UnreferencedVerticesAreDroppedAndIndicesRemapped) {
  TetMesh m = regular_tet();
  // Two unused vertices, one before and one among the used ones.
  m.vertices.insert(m.vertices.begin(), Vec3(9, 9, 9));
  m.vertices.insert(m.vertices.begin() + 3, Vec3(7, 7, 7));
  const TetMesh expected = regular_tet();
  for (int32_t& i : m.tets[0]) i = i == 0 ? 1 : i == 1 ? 2 : i + 2;  // old 0,1,2,3 -> 1,2,4,5
  const MeshReport r = validate_mesh(m, quiet());
  EXPECT_EQ(r.dropped_vertices, 2);
  ASSERT_EQ(m.vertices.size(), 4u);
  for (int k = 0; k < 4; ++k) EXPECT_EQ(m.vertices[m.tets[0][k]], expected.vertices[expected.tets[0][k]]);
}

TEST(MeshValidate, DuplicateTetsAreDropped) {
  TetMesh m = *builtin_mesh("beam1");
  const size_t n = m.tets.size();
  Tet dup = m.tets[7];
  std::swap(dup[0], dup[1]);  // the same tet, inverted and re-listed
  m.tets.push_back(dup);
  const MeshReport r = validate_mesh(m, quiet());
  EXPECT_EQ(r.dropped_duplicates, 1);
  EXPECT_EQ(m.tets.size(), n);
  EXPECT_NEAR(r.volume, 0.115 * 0.01 * 0.01, 1e-12);
}

TEST(MeshValidate, NonManifoldBoundaryIsAWarning) {
  // Two tets sharing only an edge: the boundary is closed but not manifold along that edge.
  TetMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {-1, 0, 0}, {0, -1, 0}};
  m.tets = {{0, 1, 2, 3}, {0, 4, 5, 3}};
  for (size_t t = 0; t < m.tets.size(); ++t)
    if (tet_volume(m, t) < 0) std::swap(m.tets[t][2], m.tets[t][3]);
  const MeshReport r = validate_mesh(m, quiet());
  EXPECT_FALSE(r.surface.closed_manifold);
  EXPECT_EQ(r.surface.nonmanifold_edges, 1);
  ASSERT_FALSE(r.warnings.empty());
  EXPECT_NE(r.warnings.back().find("not a closed manifold"), std::string::npos);
}

TEST(MeshValidate, TetsTouchingAtOneVertexArePinched) {
  // Every edge is fine, but the shared vertex's triangles form two fans.
  TetMesh m;
  m.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {-1, 0, 0}, {0, -1, 0}, {0, 0, -1}};
  m.tets = {{0, 1, 2, 3}, {0, 4, 5, 6}};
  for (size_t t = 0; t < m.tets.size(); ++t)
    if (tet_volume(m, t) < 0) std::swap(m.tets[t][2], m.tets[t][3]);
  const MeshReport r = validate_mesh(m, quiet());
  EXPECT_EQ(r.surface.nonmanifold_edges, 0);
  EXPECT_EQ(r.surface.boundary_edges, 0);
  EXPECT_EQ(r.surface.nonmanifold_vertices, 1);
  EXPECT_FALSE(r.surface.closed_manifold);
  // A single tet and the beam are fine.
  TetMesh beam = make_beam(4, 3, 3, 0.1);
  EXPECT_EQ(validate_mesh(beam, quiet()).surface.nonmanifold_vertices, 0);
}

TEST(MeshValidate, NonFiniteAndEmptyMeshesAreRejected) {
  TetMesh m = regular_tet();
  m.vertices[2].y() = std::nan("");
  try {
    validate_mesh(m, quiet());
    FAIL();
  } catch (const MeshError& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 2: non-finite coordinate"), std::string::npos) << e.what();
  }
  TetMesh empty;
  EXPECT_THROW(validate_mesh(empty, quiet()), MeshError);
}

TEST(MeshValidate, ThesisHippoLoadsWithQualityWarningsNotErrors) {
  // Its tiny tets (volume 5.9e-15 against a mean of 2.75e-5, file units) are positive: warn only.
  MeshLoadOptions o;
  o.validation.log = false;
  const MeshLoadResult r = load_mesh_with_report(model_dir() + "/thesis/hippo.node", o);
  EXPECT_EQ(r.report.vertices, 2885);
  EXPECT_EQ(r.report.tets, 10361);
  EXPECT_NEAR(r.report.min_volume, 5.9e-15, 0.1e-15);
  EXPECT_NEAR(r.report.mean_volume, 2.75e-5, 0.01e-5);
  EXPECT_GT(r.report.tiny_tets, 0);
  EXPECT_EQ(r.report.reoriented, 0);
  EXPECT_LT(r.report.min_dihedral_deg, 0.01);
  ASSERT_EQ(r.report.worst.size(), 5u);
  EXPECT_LE(r.report.worst[0].min_dihedral_deg, r.report.worst[1].min_dihedral_deg);
  bool tiny_warning = false;
  for (const std::string& w : r.report.warnings) tiny_warning |= w.find("tiny tets") != std::string::npos;
  EXPECT_TRUE(tiny_warning);
  int64_t histogram_total = 0;
  for (int64_t c : r.report.dihedral_histogram.counts) histogram_total += c;
  EXPECT_EQ(histogram_total, r.report.tets);
}

TEST(MeshValidate, LightVerticesAreCounted) {
  // beam1: its only vertices under 1/10 of the mean lumped mass are the four box corners that
  // belong to a single tet (0.098 of the mean).
  TetMesh beam = *builtin_mesh("beam1");
  const MeshReport b = validate_mesh(beam);
  EXPECT_EQ(b.light_vertices, 4);
  EXPECT_NEAR(b.min_vertex_mass_ratio, 0.0978, 0.0005);
  // The thesis hippo: vertices down to about 1e-6 of the mean, and many under 1/10.
  MeshLoadOptions o;
  o.validation.log = false;
  const MeshLoadResult h = load_mesh_with_report(model_dir() + "/thesis/hippo.node", o);
  EXPECT_LT(h.report.min_vertex_mass_ratio, 1e-5);
  EXPECT_GT(h.report.light_vertices, 1000);
  EXPECT_LT(h.report.light_vertices, 1200);
}

TEST(MeshResolve, BuiltinsModelsAndPaths) {
  EXPECT_EQ(resolve_mesh("beam1", {model_dir()}).tets.size(), 460u);
  const TetMesh hippo = resolve_mesh("hippo", {model_dir()});
  EXPECT_EQ(hippo.name, "hippo");
  const Vec3 e = bounding_box(hippo.vertices).extent();
  EXPECT_NEAR(e.x(), 0.173, 0.0005);  // 17.3 x 9.0 x 5.8 cm
  EXPECT_NEAR(e.y(), 0.090, 0.0005);
  EXPECT_NEAR(e.z(), 0.058, 0.0005);
  // A path works too (no model scale applied).
  const TetMesh raw = resolve_mesh(model_dir() + "/thesis/hippo.node", {model_dir()});
  EXPECT_NEAR(bounding_box(raw.vertices).extent().x(), 1.73, 0.005);
}

TEST(MeshResolve, UnknownNamesListTheKnownOnes) {
  try {
    resolve_mesh("armadilo", {model_dir()});
    FAIL();
  } catch (const MeshError& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("'armadilo'"), std::string::npos) << msg;
    for (const char* n : {"beam1", "armadillo", "armadillo-small", "hippo", "liver", "liver2", "bunny"})
      EXPECT_NE(msg.find(n), std::string::npos) << n;
  }
}

TEST(MeshResolve, ScaleAndFitSize) {
  MeshLoadOptions o;
  o.validation.log = false;
  o.fit_size = 0.5;
  const MeshLoadResult r = resolve_mesh_with_report("beam1", {}, o);
  EXPECT_NEAR(r.report.bbox.extent().maxCoeff(), 0.5, 1e-12);
  o.fit_size = 0;
  o.scale = 2.0;
  const MeshLoadResult s = resolve_mesh_with_report("hippo", {model_dir()}, o);
  EXPECT_NEAR(s.report.bbox.extent().x(), 0.346, 0.001);  // the model's 0.1 times 2
  EXPECT_NEAR(s.applied_scale, 0.2, 1e-12);
}
