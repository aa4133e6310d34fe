// SPDX-License-Identifier: Apache-2.0
// The XPBD loop of cloth and ropes: per substep predict, project every constraint group colour
// by colour (Gauss-Seidel inside a colour is conflict-free, so colours run in parallel and
// the result does not depend on the thread count), self-collision, colliders, then
// velocities from positions.
#include "pliant/cloth.hpp"

#include "particles/surface_contact.hpp"
#include "particles/tool_meeting.hpp"
#include "step/thread_pool.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

namespace pliant {

namespace {

// An edge stretched past (1 + this) times its rest length: the step that starts with one leaves
// self-collision out, and the step that ends with one says so in the log (ConstraintBody::step).
constexpr double kSelfCollisionStretchLimit = 1.0;

// A colour smaller than this runs on the calling thread: below it the hand-off to the pool
// costs about what the work does (a few microseconds of constraints). The 64 x 64 drape's
// bending colours (about 700 constraints each) gain from the second thread.
constexpr size_t kMinParallelColour = 128;

void check_nonneg(const char* field, double v) {
  if (!std::isfinite(v) || v < 0.0)
    throw std::invalid_argument(std::string("ConstraintBodySettings.") + field + " must be a finite number >= 0 (got " +
                                fmt::format("{:g}", v) + ")");
}

void validate(const ConstraintBodySettings& s) {
  check_nonneg("stretch_compliance", s.stretch_compliance);
  check_nonneg("shear_compliance", s.shear_compliance);
  check_nonneg("bend_compliance", s.bend_compliance);
  check_nonneg("volume_compliance", s.volume_compliance);
  check_nonneg("damping", s.damping);
  if (!std::isfinite(s.pressure) || s.pressure <= 0.0)
    throw std::invalid_argument("ConstraintBodySettings.pressure must be > 0 (got " + fmt::format("{:g}", s.pressure) + ")");
  if (!s.gravity.allFinite()) throw std::invalid_argument("ConstraintBodySettings.gravity must be finite");
  if (s.substeps < 1 || s.substeps > 10000)
    throw std::invalid_argument("ConstraintBodySettings.substeps must be in [1, 10000] (got " +
                                std::to_string(s.substeps) + ")");
  if (s.iterations < 1 || s.iterations > 10000)
    throw std::invalid_argument("ConstraintBodySettings.iterations must be in [1, 10000] (got " +
                                std::to_string(s.iterations) + ")");
  if (!std::isfinite(s.thickness) || s.thickness <= 0.0)
    throw std::invalid_argument("ConstraintBodySettings.thickness must be > 0 m (got " + fmt::format("{:g}", s.thickness) + ")");
  if (s.threads < 1 || s.threads > 256)
    throw std::invalid_argument("ConstraintBodySettings.threads must be in [1, 256] (got " +
                                std::to_string(s.threads) + ")");
}

// Greedy colouring: colour after colour, take every remaining constraint none of whose
// particles the colour holds yet. Returns the new order and the colour starts.
template <class C, class Particles>
std::vector<size_t> colour(std::vector<C>& items, size_t particles, Particles&& of) {
  std::vector<size_t> starts{0};
  std::vector<C> ordered;
  ordered.reserve(items.size());
  std::vector<char> done(items.size(), 0);
  std::vector<uint32_t> mark(particles, UINT32_MAX);
  size_t left = items.size();
  for (uint32_t c = 0; left > 0; ++c) {
    for (size_t k = 0; k < items.size(); ++k) {
      if (done[k]) continue;
      const auto ps = of(items[k]);
      bool free = true;
      for (uint32_t p : ps) free = free && mark[p] != c;
      if (!free) continue;
      for (uint32_t p : ps) mark[p] = c;
      done[k] = 1;
      ordered.push_back(items[k]);
      --left;
    }
    starts.push_back(ordered.size());
  }
  items = std::move(ordered);
  return starts;
}

Collider inflated(const Collider& c, double r) {
  Collider out = c;
  switch (c.shape) {
    case Collider::Shape::Plane: out.point = c.point + r * c.normal; break;
    case Collider::Shape::Sphere: out.radius = c.radius + r; break;
    case Collider::Shape::Box: out.half_extent = c.half_extent + Vec3::Constant(r); break;
  }
  return out;
}

// Closest point of triangle (a, b, c) to p as barycentric coordinates.
Vec3 closest_barycentric(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  std::array<double, 3> w;
  closest_point_on_triangle(p, a, b, c, w);
  return {w[0], w[1], w[2]};
}

// The cell index of a coordinate already divided by the cell size, clamped so that a body
// that flew apart (or a NaN) neither overflows the conversion nor the cell counts below.
inline int64_t cell_of(double v) { return std::isnan(v) ? 0 : int64_t(std::floor(std::clamp(v, -1e5, 1e5))); }

inline uint32_t cell_hash(int64_t i, int64_t j, int64_t k, uint32_t mask) {
  const uint64_t h = static_cast<uint64_t>(i) * 73856093ull ^ static_cast<uint64_t>(j) * 19349663ull ^
                     static_cast<uint64_t>(k) * 83492791ull;
  return static_cast<uint32_t>(h ^ (h >> 29)) & mask;
}

}  // namespace

ConstraintBody::ConstraintBody() = default;
ConstraintBody::~ConstraintBody() = default;

void ConstraintBody::finish(const ConstraintBodySettings& settings) {
  validate(settings);
  settings_ = settings;
  const size_t n = state_.x.size();
  for (size_t i = 0; i < n; ++i)
    if (!state_.x[i].allFinite())
      throw std::invalid_argument("positions: particle " + std::to_string(i) + " is not finite");
  state_.v.assign(n, Vec3::Zero());
  w_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    if (!(m_[i] > 0.0) || !std::isfinite(m_[i]))
      throw std::invalid_argument("masses: particle " + std::to_string(i) + " has mass " + fmt::format("{:g}", m_[i]) +
                                  " kg (every particle must carry mass > 0: is it on no triangle/segment?)");
    w_[i] = 1.0 / m_[i];
  }
  w_free_ = w_;
  dist_colours_ = colour(dist_, n, [](const Distance& d) { return std::array<uint32_t, 2>{d.i, d.j}; });
  segments_.clear();
  shortest_edge_ = INFINITY;
  for (const Distance& d : dist_)
    if (!d.shear) {
      segments_.push_back({d.i, d.j});
      shortest_edge_ = std::min(shortest_edge_, d.rest);
    }
  // What the tools meet between the particles: the triangles, else a rope's links as (a, b, b).
  tool_faces_ = triangles_;
  if (tool_faces_.empty())
    for (const auto& s : segments_) tool_faces_.push_back({s[0], s[1], s[1]});
  bend_colours_ = colour(bend_, n, [](const Bend& b) { return std::array<uint32_t, 4>{b.a, b.b, b.c, b.d}; });
  for (Bend& b : bend_) {
    b.rest_cos = std::cos(b.rest_angle);
    b.rest_sin = std::sin(b.rest_angle);
  }
  rope_bend_colours_ =
      colour(rope_bend_, n, [](const RopeBend& b) { return std::array<uint32_t, 3>{b.a, b.b, b.c}; });
  if (settings_.volume) {
    if (triangles_.empty()) throw std::invalid_argument("ConstraintBodySettings.volume needs a closed triangle surface");
    rest_volume_ = cloth_math::enclosed_volume(state_.x, triangles_);
    if (!(std::abs(rest_volume_) > 0.0))
      throw std::invalid_argument("ConstraintBodySettings.volume: the surface encloses no volume (open or flat)");
  } else if (!triangles_.empty()) {
    rest_volume_ = cloth_math::enclosed_volume(state_.x, triangles_);
  }
  state_.lambda.assign(constraint_count(), 0.0);
  {
    std::vector<std::vector<uint32_t>> adj(n);
    for (const Distance& d : dist_) {
      adj[d.i].push_back(d.j);
      adj[d.j].push_back(d.i);
    }
    adjacency_start_.assign(n + 1, 0);
    adjacency_.clear();
    for (size_t i = 0; i < n; ++i) {
      std::sort(adj[i].begin(), adj[i].end());
      adj[i].erase(std::unique(adj[i].begin(), adj[i].end()), adj[i].end());
      adjacency_.insert(adjacency_.end(), adj[i].begin(), adj[i].end());
      adjacency_start_[i + 1] = adjacency_.size();
    }
  }
  p_ = state_.x;
  x_prev_ = state_.x;
  if (settings_.threads > 1) pool_ = std::make_unique<ThreadPool>(settings_.threads);
  spdlog::debug("{}: {} particles, {} distance, {} bending constraints, {} colours", kind(), n, dist_.size(),
                bending_constraints(), colours());
  if (settings_.self_collision && !triangles_.empty() && self_thickness() < settings_.thickness &&
      !std::exchange(self_thickness_said_, true))
    spdlog::info("{}: self-collision keeps its layers {:.3g} mm apart, half its shortest edge, not the thickness "
                 "{:.3g} mm (the colliders and the other bodies keep the thickness)",
                 kind(), 1e3 * self_thickness(), 1e3 * settings_.thickness);
}

void ConstraintBody::set_settings(const ConstraintBodySettings& settings) {
  validate(settings);
  if (settings.volume != settings_.volume)
    throw std::invalid_argument("ConstraintBodySettings.volume cannot change after the body is built");
  if (settings.bending != settings_.bending)
    throw std::invalid_argument("ConstraintBodySettings.bending cannot change after the body is built");
  if (settings.threads != settings_.threads)
    pool_ = settings.threads > 1 ? std::make_unique<ThreadPool>(settings.threads) : nullptr;
  settings_ = settings;
}

void ConstraintBody::set_gravity(const Vec3& gravity) {
  if (!gravity.allFinite()) throw std::invalid_argument("ConstraintBodySettings.gravity must be finite");
  settings_.gravity = gravity;
}

size_t ConstraintBody::constraint_count() const {
  return dist_.size() + bend_.size() + rope_bend_.size() + (settings_.volume ? 1 : 0);
}

size_t ConstraintBody::colours() const {
  return (dist_colours_.size() - 1) + (bend_colours_.size() - 1) + (rope_bend_colours_.size() - 1) +
         (settings_.volume ? 1 : 0);
}

double ConstraintBody::total_mass() const {
  double m = 0.0;
  for (double v : m_) m += v;
  return m;
}

Vec3 ConstraintBody::linear_momentum() const {
  Vec3 p = Vec3::Zero();
  for (size_t i = 0; i < m_.size(); ++i) p += m_[i] * state_.v[i];
  return p;
}

ConstraintBody::Stretch ConstraintBody::stretch() const {
  double sum = 0.0, worst = 0.0;
  size_t count = 0;
  for (const Distance& d : dist_) {
    if (d.shear) continue;
    const double e = (state_.x[d.i] - state_.x[d.j]).norm() / d.rest - 1.0;
    sum += e * e;
    worst = std::max(worst, std::abs(e));
    ++count;
  }
  return {count ? std::sqrt(sum / double(count)) : 0.0, worst};
}

double ConstraintBody::max_stretch() const { return stretch().max; }

double ConstraintBody::volume() const { return cloth_math::enclosed_volume(state_.x, triangles_); }

void ConstraintBody::set_state(const ParticleState& s) {
  const size_t n = size();
  check_particle_counts(s, n, kind());
  if (s.lambda.size() != constraint_count())
    throw std::invalid_argument("ParticleState.lambda has " + std::to_string(s.lambda.size()) +
                                " multipliers, the body " + std::to_string(constraint_count()) + " constraints");
  for (size_t i = 0; i < n; ++i)
    if (!s.x[i].allFinite() || !s.v[i].allFinite())
      throw std::invalid_argument("ParticleState: particle " + std::to_string(i) + " is not finite");
  if (!std::isfinite(s.time)) throw std::invalid_argument("ParticleState.time is not finite");
  state_ = s;
}

void ConstraintBody::pin(size_t i) {
  if (i >= size()) throw std::invalid_argument("pin: particle " + std::to_string(i) + " out of range");
  w_[i] = 0.0;
  state_.v[i] = Vec3::Zero();
}

void ConstraintBody::unpin(size_t i) {
  if (i >= size()) throw std::invalid_argument("unpin: particle " + std::to_string(i) + " out of range");
  w_[i] = w_free_[i];
}

void ConstraintBody::set_position(size_t i, const Vec3& x) {
  if (i >= size()) throw std::invalid_argument("set_position: particle " + std::to_string(i) + " out of range");
  if (!x.allFinite()) throw std::invalid_argument("set_position: position is not finite");
  state_.x[i] = x;
  state_.v[i] = Vec3::Zero();
}

template <class F>
void ConstraintBody::for_colours(const std::vector<size_t>& starts, F&& f) {
  for (size_t c = 0; c + 1 < starts.size(); ++c) {
    const size_t b = starts[c], e = starts[c + 1];
    // Small colours on this thread, through the same out-of-line call (run_parallel).
    run_parallel(pool_ && e - b >= kMinParallelColour ? pool_.get() : nullptr, e - b, [&](int, size_t lo, size_t hi) {
      for (size_t k = b + lo; k < b + hi; ++k) f(k);
    });
  }
}

void ConstraintBody::solve_distance(size_t k, double h2) {
  const Distance& d = dist_[k];
  const double wi = w_[d.i], wj = w_[d.j];
  const double alpha = (d.shear ? settings_.shear_compliance : settings_.stretch_compliance) / h2;
  const double denom = wi + wj + alpha;
  if (denom <= 0.0) return;
  const Vec3 r = p_[d.i] - p_[d.j];
  const double len = r.norm();
  if (len < 1e-15) return;
  double& lambda = state_.lambda[k];
  const double dl = (-(len - d.rest) - alpha * lambda) / denom;
  lambda += dl;
  const Vec3 g = r * (dl / len);
  p_[d.i] += wi * g;
  p_[d.j] -= wj * g;
}

void ConstraintBody::solve_bend(size_t k, double h2) {
  const Bend& b = bend_[k];
  const Vec3 &a = p_[b.a], &bb = p_[b.b], &c = p_[b.c], &d = p_[b.d];
  // cloth_math::dihedral_angle and dihedral_gradient, sharing the normals
  const Vec3 e = bb - a;
  const double el = e.norm();
  const Vec3 n1 = e.cross(c - a);
  const Vec3 n2 = (a - bb).cross(d - bb);
  const double q1 = n1.squaredNorm(), q2 = n2.squaredNorm();
  if (el < 1e-15 || q1 < 1e-30 || q2 < 1e-30) return;
  const Vec3 eh = e / el;
  const double angle = cloth_math::angle_from_rest(n1.cross(n2).dot(eh), n1.dot(n2), b.rest_cos, b.rest_sin);
  const Vec3 m1 = n1 / q1, m2 = n2 / q2;
  const Vec3 g[4] = {-(((c - bb).dot(eh)) * m1 + ((d - bb).dot(eh)) * m2),
                     ((c - a).dot(eh)) * m1 + ((d - a).dot(eh)) * m2, -el * m1, -el * m2};
  const double ws[4] = {w_[b.a], w_[b.b], w_[b.c], w_[b.d]};
  const double alpha = settings_.bend_compliance / h2;
  double denom = alpha;
  for (int i = 0; i < 4; ++i) denom += ws[i] * g[i].squaredNorm();
  if (denom <= 1e-30) return;
  double& lambda = state_.lambda[dist_.size() + k];
  const double dl = (-angle - alpha * lambda) / denom;
  lambda += dl;
  p_[b.a] += ws[0] * dl * g[0];
  p_[b.b] += ws[1] * dl * g[1];
  p_[b.c] += ws[2] * dl * g[2];
  p_[b.d] += ws[3] * dl * g[3];
}

void ConstraintBody::solve_rope_bend(size_t k, double h2) {
  const RopeBend& b = rope_bend_[k];
  const Vec3 &a = p_[b.a], &bb = p_[b.b], &c = p_[b.c];
  const double value = cloth_math::rope_bend_value(a, bb, c);
  if (value < 1e-15) return;
  const auto g = cloth_math::rope_bend_gradient(a, bb, c);
  const double ws[3] = {w_[b.a], w_[b.b], w_[b.c]};
  const double alpha = settings_.bend_compliance / h2;
  double denom = alpha;
  for (int i = 0; i < 3; ++i) denom += ws[i] * g[i].squaredNorm();
  if (denom <= 1e-30) return;
  double& lambda = state_.lambda[dist_.size() + bend_.size() + k];
  const double dl = (-(value - b.rest) - alpha * lambda) / denom;
  lambda += dl;
  p_[b.a] += ws[0] * dl * g[0];
  p_[b.b] += ws[1] * dl * g[1];
  p_[b.c] += ws[2] * dl * g[2];
}

void ConstraintBody::solve_volume(double h2) {
  static thread_local std::vector<Vec3> grad;
  cloth_math::enclosed_volume_gradient(p_, triangles_, grad);
  const double c = cloth_math::enclosed_volume(p_, triangles_) - settings_.pressure * rest_volume_;
  const double alpha = settings_.volume_compliance / h2;
  double denom = alpha;
  for (size_t i = 0; i < grad.size(); ++i) denom += w_[i] * grad[i].squaredNorm();
  if (denom <= 1e-30) return;
  double& lambda = state_.lambda.back();
  const double dl = (-c - alpha * lambda) / denom;
  lambda += dl;
  for (size_t i = 0; i < grad.size(); ++i) p_[i] += w_[i] * dl * grad[i];
}

void ConstraintBody::solve_grabs(double h2) {
  for (auto& [id, g] : grabs_) {
    const double w = w_[g.particle];
    const double alpha = g.compliance / h2;
    if (w + alpha <= 0.0) continue;
    const Vec3 c = p_[g.particle] - g.target;
    const Vec3 dl = (-c - alpha * g.lambda) / (w + alpha);
    g.lambda += dl;
    p_[g.particle] += w * dl;
  }
}

// Candidate particle-triangle pairs for the coming step. Gravity and the body's mean velocity
// move particles and triangles alike, so boxes are swept by the velocity relative to the
// mean over dt; triangles go into hashed cells by their box grown by the contact distance
// and a margin (one thickness, for what the constraints move beyond the velocities), and
// every particle keeps the triangles (not its own) that its box can reach.
void ConstraintBody::build_self_hash(double dt) {
  const size_t n = size(), nt = triangles_.size();
  const double th = self_thickness();
  const double reach = 1.5 * th + th;
  Vec3 mean = Vec3::Zero();
  double mass = 0.0;
  for (size_t i = 0; i < n; ++i)
    if (w_[i] > 0.0) {
      mean += m_[i] * state_.v[i];
      mass += m_[i];
    }
  if (mass > 0.0) mean /= mass;
  std::vector<Vec3>& to = x_prev_;  // scratch: the swept end of every particle
  for (size_t i = 0; i < n; ++i) {
    const Vec3 rel = w_[i] > 0.0 ? Vec3(dt * (state_.v[i] - mean)) : Vec3(-dt * mean);
    to[i] = state_.x[i] + rel;
  }
  double edge = 0.0;
  for (const auto& t : triangles_) edge += (state_.x[t[0]] - state_.x[t[1]]).norm();
  edge /= double(std::max<size_t>(nt, 1));
  cell_ = std::max(edge, 2.0 * reach);
  uint32_t buckets = 1;
  while (buckets < 4 * nt) buckets <<= 1;
  const uint32_t mask = buckets - 1;
  const double inv = 1.0 / cell_;
  auto cells = [&](Vec3 lo, Vec3 hi, double grow, std::array<int64_t, 6>& r) {
    lo.array() -= grow;
    hi.array() += grow;
    r = {cell_of(lo.x() * inv), cell_of(hi.x() * inv), cell_of(lo.y() * inv),
         cell_of(hi.y() * inv), cell_of(lo.z() * inv), cell_of(hi.z() * inv)};
    return (r[1] - r[0] + 1) * (r[3] - r[2] + 1) * (r[5] - r[4] + 1);
  };
  std::vector<std::pair<uint32_t, uint32_t>> entries;  // (bucket, triangle)
  entries.reserve(nt * 8);
  std::vector<Vec3> tri_lo(nt), tri_hi(nt);
  for (uint32_t t = 0; t < nt; ++t) {
    Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
    for (uint32_t v : triangles_[t]) {
      lo = lo.cwiseMin(state_.x[v]).cwiseMin(to[v]);
      hi = hi.cwiseMax(state_.x[v]).cwiseMax(to[v]);
    }
    tri_lo[t] = lo.array() - reach;
    tri_hi[t] = hi.array() + reach;
    std::array<int64_t, 6> r;
    if (cells(lo, hi, reach, r) > 4096) continue;  // a torn-apart triangle: skip
    for (int64_t i = r[0]; i <= r[1]; ++i)
      for (int64_t j = r[2]; j <= r[3]; ++j)
        for (int64_t k = r[4]; k <= r[5]; ++k) entries.emplace_back(cell_hash(i, j, k, mask), t);
  }
  bucket_start_.assign(buckets + 1, 0);
  for (const auto& e : entries) ++bucket_start_[e.first + 1];
  for (uint32_t b = 0; b < buckets; ++b) bucket_start_[b + 1] += bucket_start_[b];
  bucket_tris_.resize(entries.size());
  std::vector<uint32_t> fill(bucket_start_.begin(), bucket_start_.end() - 1);
  for (const auto& e : entries) bucket_tris_[fill[e.first]++] = e.second;

  // particles joined by a distance constraint: the fabric itself keeps them apart
  auto neighbours = [&](size_t i, uint32_t j) {
    return std::binary_search(adjacency_.begin() + adjacency_start_[i], adjacency_.begin() + adjacency_start_[i + 1], j);
  };
  const int chunks = pool_ ? pool_->size() : 1;
  std::vector<std::vector<std::pair<uint32_t, uint32_t>>> found(chunks);
  auto work = [&](int chunk, size_t lo_i, size_t hi_i) {
    auto& out = found[chunk];
    std::vector<uint32_t> mine;
    std::vector<uint32_t> seen(nt, UINT32_MAX);  // the particle that last saw a triangle
    for (size_t i = lo_i; i < hi_i; ++i) {
      const Vec3 plo = state_.x[i].cwiseMin(to[i]), phi = state_.x[i].cwiseMax(to[i]);
      std::array<int64_t, 6> r;
      if (cells(plo, phi, 0.0, r) > 512) continue;
      mine.clear();
      for (int64_t a = r[0]; a <= r[1]; ++a)
        for (int64_t b = r[2]; b <= r[3]; ++b)
          for (int64_t c = r[4]; c <= r[5]; ++c) {
            const uint32_t bkt = cell_hash(a, b, c, mask);
            for (uint32_t e = bucket_start_[bkt]; e < bucket_start_[bkt + 1]; ++e) {
              const uint32_t t = bucket_tris_[e];
              if (seen[t] == i) continue;
              seen[t] = uint32_t(i);
              if ((plo.array() > tri_hi[t].array()).any() || (phi.array() < tri_lo[t].array()).any()) continue;
              mine.push_back(t);
            }
          }
      std::sort(mine.begin(), mine.end());  // the same order whatever the cells' order
      for (uint32_t t : mine) {
        const auto& tri = triangles_[t];
        if (tri[0] == i || tri[1] == i || tri[2] == i) continue;
        if (w_[i] + w_[tri[0]] + w_[tri[1]] + w_[tri[2]] == 0.0) continue;
        if (neighbours(i, tri[0]) || neighbours(i, tri[1]) || neighbours(i, tri[2])) continue;
        const Vec3 &a = state_.x[tri[0]], &b = state_.x[tri[1]], &c = state_.x[tri[2]];
        const Vec3 bc = closest_barycentric(state_.x[i], a, b, c);
        const double d = (state_.x[i] - (bc[0] * a + bc[1] * b + bc[2] * c)).norm();
        // linear relative motion over the step bounds how much closer the pair can come
        double rel = 0.0;
        for (uint32_t v : tri) rel = std::max(rel, (state_.v[i] - state_.v[v]).norm());
        if (d > reach + dt * rel) continue;
        out.emplace_back(uint32_t(i), t);
      }
    }
  };
  run_parallel(pool_.get(), n, work, 256);
  candidates_.clear();
  for (auto& f : found) candidates_.insert(candidates_.end(), f.begin(), f.end());
}

// Candidate pairs closer than 1.5 x thickness at the predicted positions; the side a particle
// keeps is the side it was on at the start of the substep.
void ConstraintBody::find_self_contacts() {
  const int chunks = pool_ ? pool_->size() : 1;
  self_scratch_.resize(chunks);
  const double reach = 1.5 * self_thickness();
  auto work = [&](int chunk, size_t lo, size_t hi) {
    auto& out = self_scratch_[chunk];
    for (size_t k = lo; k < hi; ++k) {
      const auto [i, t] = candidates_[k];
      const auto& tri = triangles_[t];
      const Vec3& p = p_[i];
      const Vec3 &a = p_[tri[0]], &b = p_[tri[1]], &c = p_[tri[2]];
      const Vec3 bc = closest_barycentric(p, a, b, c);
      const Vec3 q = bc[0] * a + bc[1] * b + bc[2] * c;
      if ((p - q).squaredNorm() >= reach * reach) continue;
      const Vec3 &a0 = x_prev_[tri[0]], &b0 = x_prev_[tri[1]], &c0 = x_prev_[tri[2]];
      const Vec3 n0 = (b0 - a0).cross(c0 - a0);
      const Vec3 q0 = bc[0] * a0 + bc[1] * b0 + bc[2] * c0;
      const double s = (x_prev_[i] - q0).dot(n0);
      out.push_back(SelfContact{i, t, bc[0], bc[1], bc[2], s >= 0.0 ? 1.0 : -1.0});
    }
  };
  for (auto& s : self_scratch_) s.clear();
  run_parallel(pool_.get(), candidates_.size(), work, 256);
  // chunks are contiguous ranges of the candidate list: the same order for any thread count
  self_contacts_.clear();
  for (auto& s : self_scratch_) self_contacts_.insert(self_contacts_.end(), s.begin(), s.end());
}

void ConstraintBody::solve_self_contacts() {
  const double th = self_thickness();
  for (const SelfContact& sc : self_contacts_) {
    const auto& tri = triangles_[sc.tri];
    Vec3& p = p_[sc.particle];
    Vec3 &a = p_[tri[0]], &b = p_[tri[1]], &c = p_[tri[2]];
    Vec3 n = (b - a).cross(c - a);
    const double nl = n.norm();
    if (nl < 1e-20) continue;
    n *= sc.side / nl;
    const Vec3 q = sc.b0 * a + sc.b1 * b + sc.b2 * c;
    // Along the normal to the side the particle came from (pushing along p - q instead fights
    // the stretch constraints where the fabric folds tightly).
    const double C = (p - q).dot(n) - th;
    if (C >= 0.0) continue;
    const double wp = w_[sc.particle], wa = w_[tri[0]], wb = w_[tri[1]], wc = w_[tri[2]];
    const double denom = wp + sc.b0 * sc.b0 * wa + sc.b1 * sc.b1 * wb + sc.b2 * sc.b2 * wc;
    if (denom <= 0.0) continue;
    const double dl = -C / denom;
    p += wp * dl * n;
    a -= wa * sc.b0 * dl * n;
    b -= wb * sc.b1 * dl * n;
    c -= wc * sc.b2 * dl * n;
  }
}

// Particles against the colliders grown by the thickness; friction at position level from
// the tangential motion over the substep (static below mu_s x depth, else reduced by mu_k x
// depth).
size_t ConstraintBody::solve_colliders(std::span<const Collider> colliders) {
  if (colliders.empty()) return 0;
  std::vector<Collider> grown;
  grown.reserve(colliders.size());
  for (const Collider& c : colliders) grown.push_back(inflated(c, settings_.thickness));
  const size_t n = size();
  const int chunks = pool_ ? pool_->size() : 1;
  std::vector<size_t> counts(chunks, 0);
  auto work = [&](int chunk, size_t lo, size_t hi) {
    size_t count = 0;
    for (size_t i = lo; i < hi; ++i) {
      if (w_[i] == 0.0) continue;
      bool touched = false;
      for (const Collider& c : grown) {
        ContactPoint cp;
        if (!find_contact(c, p_[i], cp)) continue;
        touched = true;
        p_[i] += cp.depth * cp.normal;
        const Vec3 dx = p_[i] - x_prev_[i];
        const Vec3 tangential = dx - dx.dot(cp.normal) * cp.normal;
        const double t = tangential.norm();
        if (t < c.static_friction * cp.depth)
          p_[i] -= tangential;
        else if (t > 0.0)
          p_[i] -= tangential * std::min(c.dynamic_friction * cp.depth / t, 1.0);
      }
      count += touched ? 1 : 0;
    }
    counts[chunk] += count;
  };
  run_parallel(pool_.get(), n, work, 256);
  size_t total = 0;
  for (size_t c : counts) total += c;
  return total;
}

int ConstraintBody::substeps() const { return settings_.substeps; }

// The distance self-collision keeps: the thickness, but at most half the shortest edge. The
// fabric keeps a particle's neighbours apart, not self-collision, and the particles two edges
// away are at twice an edge at rest: a contact reach (1.5 x the distance) past that would push
// them apart across the fabric's own plane as soon as it folds a little (a 32 x 32 cloth of 12 cm,
// 3.9 mm edges, with the 5 mm default blew up draped on a 3 cm sphere: docs/cloth.md).
double ConstraintBody::self_thickness() const { return std::min(settings_.thickness, 0.5 * shortest_edge_); }

struct ConstraintBody::SurfaceContacts {
  SurfaceContacts(SurfaceBoundary& boundary, std::span<const Vec3> particles, double reach);
  void begin_substep(size_t n);
  detail::SurfaceMeeting meeting;
  std::vector<detail::FaceHit> hit;  // per particle: the face it last pushed from
  std::vector<Vec3> moved;           // the surface's moves of it in the substep
  std::vector<double> depth;         // their depths summed (friction's bound)
};

ConstraintBody::SurfaceContacts::SurfaceContacts(SurfaceBoundary& boundary, std::span<const Vec3> particles,
                                                 double reach)
    : meeting(boundary, particles, reach, boundary.radius) {}

void ConstraintBody::SurfaceContacts::begin_substep(size_t n) {
  hit.assign(n, detail::FaceHit{});
  moved.assign(n, Vec3::Zero());
  depth.assign(n, 0.0);
}

// Every free particle out of the soft body's surface: back through the face its path over the
// substep entered, else the radius off the closest face (SurfaceMeeting::push).
void ConstraintBody::meet_surface(SurfaceContacts& sc) {
  auto work = [&](int, size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      if (w_[i] == 0.0) continue;
      const Vec3 before = p_[i];
      detail::FaceHit hit;
      const double d = sc.meeting.push(x_prev_[i], p_[i], hit);
      if (!(d > 0)) continue;
      sc.hit[i] = hit;
      sc.depth[i] += d;
      sc.moved[i] += p_[i] - before;
    }
  };
  run_parallel(pool_.get(), size(), work, 256);
}

// After a substep's iterations: Coulomb friction on each touching particle's slip against the
// surface's motion over the substep (held below friction x its pushes, else shortened by that),
// then the momentum the surface's moves gave it, to the corners of the face it last pushed from.
// Returns the particles it touched.
size_t ConstraintBody::leave_surface(SurfaceContacts& sc, double h) {
  const double mu = sc.meeting.friction();
  size_t touched = 0;
  for (size_t i = 0; i < size(); ++i) {
    if (!(sc.depth[i] > 0)) continue;
    ++touched;
    const Vec3 nn = sc.hit[i].n;
    const Vec3 slip = p_[i] - x_prev_[i] - h * sc.meeting.velocity(sc.hit[i]);
    const Vec3 tang = slip - slip.dot(nn) * nn;
    const double tl = tang.norm();
    if (mu > 0 && tl > 0) {
      const Vec3 back = tl <= mu * sc.depth[i] ? tang : Vec3(tang * (mu * sc.depth[i] / tl));
      p_[i] -= back;
      sc.moved[i] -= back;
    }
    sc.meeting.give(sc.hit[i], m_[i] * sc.moved[i] / h);
  }
  return touched;
}

// Every free particle out of the scene's tools where they are in the substep, each push with its
// tool's friction against the tool's motion, as against the colliders; then the faces between
// them (the triangles, or a rope's links) that a tool reaches between their corners.
void ConstraintBody::meet_tools(detail::ToolMeeting& tm) {
  tm.begin_pass();
  // The particles' box, so that the faces are looked at only when a tool reaches it.
  const int chunks = pool_ ? pool_->size() : 1;
  std::vector<std::pair<Vec3, Vec3>> boxes(size_t(chunks), {Vec3::Constant(INFINITY), Vec3::Constant(-INFINITY)});
  auto work = [&](int chunk, size_t lo, size_t hi) {
    auto& [box_lo, box_hi] = boxes[size_t(chunk)];
    for (size_t i = lo; i < hi; ++i) {
      if (w_[i] != 0.0) {
        const detail::ToolMeeting::Push pr = tm.push(i, p_[i]);
        if (pr.tool >= 0) tm.friction(i, pr.tool, pr.normal, pr.depth, p_[i] - x_prev_[i], p_[i]);
      }
      box_lo = box_lo.cwiseMin(p_[i]);
      box_hi = box_hi.cwiseMax(p_[i]);
    }
  };
  run_parallel(pool_.get(), size(), work, 256);
  Vec3 lo = Vec3::Constant(INFINITY), hi = Vec3::Constant(-INFINITY);
  for (const auto& [l, h] : boxes) {
    lo = lo.cwiseMin(l);
    hi = hi.cwiseMax(h);
  }
  if (tm.reaches(lo, hi)) tm.push_faces(tool_faces_, p_, x_prev_, w_);
}

// The soft body's surface (`surface`) and the scene's tools (`tools`) are met by the particles
// inside every iteration, after the colliders, as the fluid meets them; the segments between them
// are left to the scene's contacts after the step.
ParticleStepReport ConstraintBody::advance(double dt, int substeps, std::span<const Collider> colliders,
                                           bool ends_step, SurfaceBoundary* surface, ToolBoundary* tools) {
  if (!std::isfinite(dt) || dt <= 0.0) throw std::invalid_argument("step: dt must be > 0 s (got " + fmt::format("{:g}", dt) + ")");
  if (substeps < 1) throw std::invalid_argument("step: substeps must be >= 1 (got " + std::to_string(substeps) + ")");
  const auto t0 = std::chrono::steady_clock::now();
  const int ns = substeps;
  const double h = dt / ns, h2 = h * h;
  h_ = h;
  const size_t n = size();
  // Past twice their rest length the edges no longer hold the fabric's shape and self-collision
  // fights the crumpling cloth until it blows up (docs/cloth.md, "Substeps and stretch"), so a
  // step that starts with such an edge leaves self-collision out. Decided from the state alone,
  // so that a restored snapshot steps as the original did.
  const bool wants_self = settings_.self_collision && !triangles_.empty();
  const bool over = wants_self && max_stretch() > kSelfCollisionStretchLimit;
  const bool self = wants_self && !over;
  if (self) build_self_hash(dt);
  const double keep = std::max(0.0, 1.0 - settings_.damping * h);
  ParticleStepReport report;
  report.substeps = ns;
  report.iterations = settings_.iterations;
  report.self_collision_suspended = over;
  // The soft body's surface near where the particles can get over the call (their speed and
  // gravity over dt); a particle that gets farther does not meet it.
  std::optional<SurfaceContacts> on_surface;
  if (surface) {
    double fastest = 0.0;
    for (const Vec3& v : state_.v) fastest = std::max(fastest, v.norm());
    const double reach = dt * (fastest + settings_.gravity.norm() * dt) + surface->radius;
    on_surface.emplace(*surface, state_.x, std::isfinite(reach) ? reach : surface->radius);
  }
  // The tools, unless none can reach the particles over the call (the boundary's sums stay zero).
  std::optional<detail::ToolMeeting> on_tools;
  if (tools && !tools->tools.empty()) {
    on_tools.emplace(*tools, settings_.thickness, dt, ns);
    double fastest = 0.0;
    for (const Vec3& v : state_.v) fastest = std::max(fastest, v.norm());
    if (!on_tools->within_reach(state_.x, fastest, settings_.gravity.norm()))
      on_tools.reset();
    else  // of the faces, those a tool can reach
      on_tools->select_faces(tool_faces_, state_.x, fastest, settings_.gravity.norm());
  }
  for (int s = 0; s < ns; ++s) {
    for (size_t i = 0; i < n; ++i) {
      x_prev_[i] = state_.x[i];
      if (w_[i] > 0.0) {
        state_.v[i] = (state_.v[i] + h * settings_.gravity) * keep;
        p_[i] = state_.x[i] + h * state_.v[i];
      } else {
        p_[i] = state_.x[i];
      }
    }
    std::fill(state_.lambda.begin(), state_.lambda.end(), 0.0);
    for (auto& [id, g] : grabs_) g.lambda.setZero();
    if (self) find_self_contacts();
    if (on_surface) on_surface->begin_substep(n);
    if (on_tools) on_tools->begin_substep(s, n);
    size_t contacts = 0;
    for (int it = 0; it < settings_.iterations; ++it) {
      for_colours(dist_colours_, [&](size_t k) { solve_distance(k, h2); });
      if (settings_.bending) {
        for_colours(bend_colours_, [&](size_t k) { solve_bend(k, h2); });
        for_colours(rope_bend_colours_, [&](size_t k) { solve_rope_bend(k, h2); });
      }
      if (settings_.volume) solve_volume(h2);
      solve_grabs(h2);
      if (self) solve_self_contacts();
      contacts = solve_colliders(colliders);
      if (on_surface) meet_surface(*on_surface);
      if (on_tools) meet_tools(*on_tools);
      if (self && !self_contacts_.empty() && (!colliders.empty() || on_surface || on_tools)) {
        // a layer pressed onto a collider by another: once more, so that neither the
        // layers nor the collider end the substep violated by the other's last correction
        solve_self_contacts();
        contacts = solve_colliders(colliders);
        if (on_surface) meet_surface(*on_surface);
        if (on_tools) meet_tools(*on_tools);
      }
    }
    if (on_surface) report.soft_body_contacts = leave_surface(*on_surface, h);
    if (on_tools) report.tool_contacts = on_tools->give([&](size_t i) { return m_[i]; });
    for (size_t i = 0; i < n; ++i) {
      state_.v[i] = (p_[i] - x_prev_[i]) / h;
      state_.x[i] = p_[i];
    }
    for (auto& [id, g] : grabs_) g.force = g.lambda / h2;
    report.contacts = contacts;
  }
  last_self_contacts_ = self ? self_contacts_.size() : 0;
  state_.time += dt;
  if (ends_step) ++state_.steps;
  const Stretch end = stretch();
  report.constraint_error = end.rms;
  report.max_constraint_error = end.max;
  const double worst = end.max;
  // An edge at twice its rest length means the budget does not resolve the stretch compliance;
  // past that, self-collision fights a crumpling fabric and the body blows up (docs/cloth.md,
  // "Substeps and stretch"). Said once, and again only after the body has recovered.
  if (worst > kSelfCollisionStretchLimit && !stretch_warned_) {
    stretch_warned_ = true;
    spdlog::warn("{}: an edge is stretched to {:.1f} times its rest length with {} substeps x {} iterations in "
                 "{:g} s; the budget is too small for stretch compliance {:g} m/N: use more substeps or iterations{}",
                 log_name(), 1.0 + worst, ns, settings_.iterations, dt, settings_.stretch_compliance,
                 wants_self ? " (self-collision is left out while an edge is past twice its rest length)" : "");
  } else if (worst < 0.25) {
    stretch_warned_ = false;
  }
  report.wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return report;
}

}  // namespace pliant
