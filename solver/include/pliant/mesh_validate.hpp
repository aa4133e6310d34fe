// SPDX-License-Identifier: Apache-2.0
// Validation and repair of tet meshes, run on every load: what would break a simulation is
// refused with a message naming the file, the element and the value; what can be repaired
// safely (inverted tets, unreferenced vertices, duplicate tets) is repaired with a warning; what
// only hurts accuracy or speed (slivers, an open boundary) is reported as a quality warning.
#pragma once

#include "pliant/mesh.hpp"

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace pliant {

struct MeshValidationOptions {
  // A tet is degenerate (zero volume) when |6V| <= degenerate_rel_volume * Lmax^3, Lmax its
  // longest edge: shape-relative, so it does not depend on units. The thesis hippo's smallest
  // tets (volume ratio ~2e-10 to the mean) are far above this and load with a warning.
  double degenerate_rel_volume = 1e-12;
  bool drop_degenerate = false;   // drop zero-volume tets instead of rejecting the mesh
  bool reorient_inverted = true;  // swap two vertices of negative tets (warning) instead of rejecting
  // Quality warnings: tets with volume below tiny_volume_ratio * mean, or a min dihedral angle
  // below warn_min_dihedral_deg, are counted and the worst few are listed in the log.
  double tiny_volume_ratio = 1e-6;
  double warn_min_dihedral_deg = 1.0;
  int worst_listed = 5;
  bool log = true;  // spdlog warnings/info; the report is filled either way
  // For messages: how tets are numbered in the source ("element" ids or "line" numbers) and the
  // number of each tet in the source (empty: tet index).
  std::string source;                 // file name for messages
  std::string origin_kind = "tet";
  std::vector<int64_t> tet_origin;
};

struct QualityHistogram {
  // Min dihedral angle per tet, in bins [0,1) [1,5) [5,10) [10,20) [20,30) [30,40) [40,50)
  // [50,60) [60,..] degrees (a regular tet has 70.53 deg).
  static constexpr std::array<double, 9> kEdgesDeg{0, 1, 5, 10, 20, 30, 40, 50, 60};
  std::array<int64_t, 9> counts{};
};

struct WorstTet {
  int64_t tet = -1;       // index in the (repaired) mesh
  int64_t origin = -1;    // element id / line in the file
  double min_dihedral_deg = 0;
  double aspect_ratio = 0;
  double volume = 0;
};

struct SurfaceStats {
  int64_t triangles = 0;
  int64_t vertices = 0;
  int64_t edges = 0;
  int64_t boundary_edges = 0;      // edges with one triangle (holes)
  int64_t nonmanifold_edges = 0;   // edges with more than two triangles, or inconsistent winding
  int64_t nonmanifold_vertices = 0; // vertices whose triangles form more than one fan (pinches)
  int64_t overfull_faces = 0;      // faces shared by more than two tets
  int euler_characteristic = 0;     // V - E + F; 2 per closed genus-0 component
  int components = 0;               // connected components (by shared vertices)
  bool closed_manifold = false;
  double area = 0;
};

struct MeshReport {
  std::string source;
  std::string origin_kind = "tet";         // what WorstTet::origin counts: "line", "element", "cell", "tet"
  int64_t vertices = 0, tets = 0;          // after repair
  int64_t reoriented = 0;                  // inverted tets flipped
  int64_t dropped_degenerate = 0;
  int64_t dropped_duplicates = 0;
  int64_t dropped_vertices = 0;            // unreferenced vertices removed
  int64_t tiny_tets = 0;                   // positive but below tiny_volume_ratio * mean
  int64_t poor_tets = 0;                   // min dihedral below warn_min_dihedral_deg
  double volume = 0;
  double min_volume = 0, max_volume = 0, mean_volume = 0;
  double min_dihedral_deg = 0;             // over the mesh
  double max_aspect_ratio = 0;             // 1 for a regular tet
  double mean_aspect_ratio = 0;
  // Lumped vertex masses (any density): the lightest over the mean, and the vertices under
  // kDefaultInertiaFloor of the mean, whose inertia the default floor raises.
  double min_vertex_mass_ratio = 0;
  int64_t light_vertices = 0;
  Aabb bbox;
  QualityHistogram dihedral_histogram;
  std::vector<WorstTet> worst;             // by min dihedral angle, ascending
  SurfaceStats surface;
  std::vector<std::string> warnings;       // the same lines that were logged
};

// Checks and repairs `mesh` in place; throws MeshError on what cannot be repaired (out-of-range
// or repeated indices, NaN/inf coordinates, zero-volume tets unless dropped, inverted tets when
// reorientation is off, an empty mesh).
MeshReport validate_mesh(TetMesh& mesh, const MeshValidationOptions& options = {});

// Per-tet quality: the smallest of the six dihedral angles (degrees) and the normalised aspect
// ratio Lmax / (2*sqrt(6)*r_in) (1 for a regular tet, grows without bound for slivers).
double tet_min_dihedral_deg(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);
double tet_aspect_ratio(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d);

// Boundary triangles (one tet), outward wound; a faster equivalent of boundary_triangles() that
// also counts faces shared by more than two tets.
std::vector<Triangle> boundary_faces(const std::vector<Tet>& tets, int64_t* overfull_faces = nullptr);

// Edge/Euler/manifold statistics of a triangle surface.
SurfaceStats surface_stats(const std::vector<Vec3>& vertices, const std::vector<Triangle>& triangles);

}  // namespace pliant
