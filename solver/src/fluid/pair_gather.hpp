// SPDX-License-Identifier: Apache-2.0
// The loads of the fluid's pair loops: four neighbours' 3-vectors as three vectors of four
// doubles (x, y, z), the offsets (c - p_j) / h of a particle's neighbours rounded to single
// precision, and four single-precision pair terms widened to doubles. With AVX a neighbour is one
// masked load (its x, y, z; the fourth lane is not read) and four of them are transposed by
// shuffles, about half the instructions of three scalar loads, subtractions, multiplications,
// roundings and stores a neighbour. Both forms compute the same expressions in the same order, so
// they give the same bits (FluidGather tests).
#pragma once

#include "pliant/mesh.hpp"

#include <cstddef>
#include <cstdint>
#include <cstring>

#if defined(__AVX__)
#include <immintrin.h>
#endif

namespace pliant::fluid {

using Double4 = double __attribute__((vector_size(32)));
using Float4 = float __attribute__((vector_size(16)));

struct Lanes3 {
  Double4 x, y, z;
};

// The 3-vectors P[J[0]] .. P[J[3]] by component.
inline Lanes3 gather4(const Vec3* P, const uint32_t* J) {
#if defined(__AVX__)
  const __m256i xyz = _mm256_setr_epi64x(-1, -1, -1, 0);
  const __m256d a0 = _mm256_maskload_pd(P[J[0]].data(), xyz);  // x0 y0 z0 0
  const __m256d a1 = _mm256_maskload_pd(P[J[1]].data(), xyz);
  const __m256d a2 = _mm256_maskload_pd(P[J[2]].data(), xyz);
  const __m256d a3 = _mm256_maskload_pd(P[J[3]].data(), xyz);
  const __m256d t0 = _mm256_unpacklo_pd(a0, a1);  // x0 x1 z0 z1
  const __m256d t1 = _mm256_unpackhi_pd(a0, a1);  // y0 y1 0 0
  const __m256d t2 = _mm256_unpacklo_pd(a2, a3);  // x2 x3 z2 z3
  const __m256d t3 = _mm256_unpackhi_pd(a2, a3);  // y2 y3 0 0
  return {Double4(_mm256_permute2f128_pd(t0, t2, 0x20)), Double4(_mm256_permute2f128_pd(t1, t3, 0x20)),
          Double4(_mm256_permute2f128_pd(t0, t2, 0x31))};
#else
  const Vec3 &a = P[J[0]], &b = P[J[1]], &c = P[J[2]], &d = P[J[3]];
  return {Double4{a.x(), b.x(), c.x(), d.x()}, Double4{a.y(), b.y(), c.y(), d.y()},
          Double4{a.z(), b.z(), c.z(), d.z()}};
#endif
}

// Four single-precision values at a, exactly, as doubles: with AVX one instruction (GCC 12 makes
// the generic conversion two conversions of two lanes and an insert, which cost the density and
// correction passes a tenth of their time).
inline Double4 widen4(const float* a) {
#if defined(__AVX__)
  return Double4(_mm256_cvtps_pd(_mm_loadu_ps(a)));
#else
  Float4 f;
  std::memcpy(&f, a, sizeof f);
  return __builtin_convertvector(f, Double4);
#endif
}

// Four doubles rounded to single precision, stored at out.
inline void store_rounded4(float* out, const Double4& v) {
  const Float4 f = __builtin_convertvector(v, Float4);
  std::memcpy(out, &f, sizeof f);
}

// rx[q], ry[q], rz[q] = float((c - P[J[q]]) * inv_h) for q < m: by fours, then one at a time.
inline void pair_offsets(const Vec3& c, const Vec3* P, const uint32_t* J, size_t m, double inv_h, float* rx,
                         float* ry, float* rz) {
  const double cx = c.x(), cy = c.y(), cz = c.z();
  size_t q = 0;
  for (; q + 4 <= m; q += 4) {
    const Lanes3 n = gather4(P, J + q);
    store_rounded4(rx + q, (cx - n.x) * inv_h);
    store_rounded4(ry + q, (cy - n.y) * inv_h);
    store_rounded4(rz + q, (cz - n.z) * inv_h);
  }
  for (; q < m; ++q) {
    const Vec3& pj = P[J[q]];
    rx[q] = static_cast<float>((cx - pj.x()) * inv_h);
    ry[q] = static_cast<float>((cy - pj.y()) * inv_h);
    rz[q] = static_cast<float>((cz - pj.z()) * inv_h);
  }
}

}  // namespace pliant::fluid
