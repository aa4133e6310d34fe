// SPDX-License-Identifier: Apache-2.0
// The vertex block descent kernel on lanes: one vertex's tets kLanes<T> at a time (4 with v4d,
// one AVX2 instruction per operation), for the Gauss-Newton blocks of vbd_kernel.cpp (the
// readable per-tet forms the tests compare against).
//
// Each tet is stored as seen from the vertex: its corners reordered so that the vertex is the
// origin, F = [x_o0 - x_i, x_o1 - x_i, x_o2 - x_i] B with B the reordered D_m^-1 (the same F:
// it is the gradient of one affine map), and dF/dx_i = dx b with b = -(sum of B's rows). A
// vertex's packs are gathered once per visit (VertexTets::gather); moving the vertex by d then
// changes every F by d b, so its Newton steps and line-search trials need no further gathers.
// Padding lanes of a vertex's last pack repeat one of its real tets with volume 0: they add
// nothing and their det F is a real tet's.
#pragma once

#include "kernels/strain_kernel.hpp"
#include "pliant/model.hpp"

#include <array>
#include <cstdint>
#include <vector>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wignored-attributes"

namespace pliant::detail {

template <class T>
struct alignas(sizeof(T)) VertexTetLanes {
  T B[9];     // row major: B[3 * r + i] = B(r, i)
  T b[3];     // dF/dx_i = dx b
  T volume;   // V0; 0 in padding lanes
  int32_t other[3][kLanes<T>];  // the tet's other corners, per lane
};

// Every vertex's tets in packs, compiled from a model.
template <class T>
struct VertexPacks {
  std::vector<VertexTetLanes<T>> packs;
  std::vector<int32_t> begin;  // vertex i's packs: [begin[i], begin[i + 1])
};

template <class T>
VertexPacks<T> compile_vertex_packs(const BodyModel& model);

// One vertex's tets gathered at the positions x (the vertex itself at x[i]): the deformation
// gradients F0 per pack, from which every later evaluation with the vertex moved by d follows.
template <class T>
class VertexTets {
 public:
  void gather(const VertexPacks<T>& packs, int32_t i, const std::vector<Vec3>& x);

  // Sum over the tets of dE/dx_i (g) and, when H is not null, of the Gauss-Newton block
  // d2E/dx_i^2 (vbd_kernel.cpp's VbdHessian::GaussNewton), the vertex moved by d.
  void derivatives(const Vec3& d, const Lame& lame, ElasticModel model, Vec3& g, Mat3* H) const;

  // Sum over the tets of their elastic energy with the vertex moved by d; false (energy
  // unchanged) when the move makes a tet's det F <= 0.
  bool energy(const Vec3& d, const Lame& lame, ElasticModel model, double& e) const;

 private:
  const VertexTetLanes<T>* packs_ = nullptr;
  int count_ = 0;
  std::vector<std::array<T, 9>> f_;  // F0 per pack, f[3 * i + c]: component c of column i
};

}  // namespace pliant::detail

#pragma GCC diagnostic pop
