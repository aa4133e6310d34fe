// SPDX-License-Identifier: Apache-2.0
#include "pliant/stepper.hpp"

#include "accelerators/accelerators.hpp"
#include "kernels/projection.hpp"
#include "kernels/strain_kernel.hpp"
#include "step/family.hpp"
#include "step/floor_queue.hpp"
#include "step/obstacles.hpp"
#include "step/sequential_sweep.hpp"
#include "step/stages.hpp"
#include "step/thread_pool.hpp"

#include <Eigen/Dense>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <optional>
#include <span>
#include <stdexcept>

namespace pliant {

using detail::Clock;
using detail::ms_since;

namespace {

// End-of-substep passes of the inversion floor: the first visits every tet, the later ones only
// the tets with a corner that a floor correction has moved since (docs/solver.md, "The floor
// pass"), until a pass corrects nothing or kVolumePasses have run. When kSettleAfter passes have
// not ended it, each later pass is followed by up to kSettlePasses passes over the packs the
// floor has acted on in this substep: they settle a cluster of neighbouring slivers that the
// passes alone bring back only slowly. (Settling from the second pass on kept the hippo at 10
// and 100 kPa from coming to rest: docs/solver.md, "The floor pass".)
constexpr int kVolumePasses = 40;
constexpr int kSettleAfter = 16;
// At most kSettlePasses a call, and in all no more pack visits a substep than one pass over
// the body.
constexpr int kSettlePasses = 100;
// Settling splits its packs into clusters that share no moving corner, for the threads, from
// this many packs.
constexpr size_t kSettleSplitPacks = 8;
// A tet acts when det F is under the floor by more than this fraction of it: a settled cluster,
// each tet on the floor to rounding, then stops acting.
constexpr double kFloorSlack = 1e-6;
// A later pass that scans every pack (the pass before it moved an eighth of the pack count in
// vertices or more) is in a tangled body, whose passes do not converge: each correction, aimed at
// the floor, is undone in part by its neighbours', and a crushed region comes back by a few
// percent a pass. There the corrections are projected SOR: aimed at kTangledAim x the floor and
// over-relaxed by kTangledRelaxation. Elsewhere a tet under the floor goes to the floor itself: a
// sliver resting just under it is then a fixed point (both rules in every pass kept the hippo and
// the armadillo at 10 and 100 kPa from coming to rest). docs/solver.md, "The floor in a tangled
// body".
constexpr double kTangledAim = 1.05;
constexpr double kTangledRelaxation = 1.5;
// A pass from the moved vertices shares a phase between the threads from this many packs queued
// in it (or this many a chunk of a split phase).
constexpr size_t kFloorPassGrain = 32;

// Packs a block of the residual's sum (per block, then in block order: ThreadPool's block_sum).
constexpr size_t kResidualBlock = 64;

// Adds the elapsed time of a scope to a counter.
struct PhaseTimer {
  double& sink;
  Clock::time_point t0 = Clock::now();
  ~PhaseTimer() { sink += ms_since(t0); }
};

// Deals items of the given loads to n chunks, the largest first, each to the chunk with the
// least so far; returns the largest chunk's load.
size_t deal_by_load(const std::vector<size_t>& load, size_t n, std::vector<int>& owner) {
  std::vector<size_t> order(load.size()), sum(n, 0);
  for (size_t k = 0; k < load.size(); ++k) order[k] = k;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return load[a] > load[b]; });
  owner.assign(load.size(), 0);
  for (size_t k : order) {
    const size_t c = size_t(std::min_element(sum.begin(), sum.end()) - sum.begin());
    owner[k] = int(c);
    sum[c] += load[k];
  }
  return *std::max_element(sum.begin(), sum.end());
}

// The groups of a phase dealt to `chunks` threads: in runs of equal counts in storage order,
// unless dealing them by their packs (deal_by_load) leaves the busiest thread fewer packs. The
// armadillo's slabs hold 1,325 to 1,568 packs: in runs one thread had 6,045 of the first phase's
// 11,509 and the other waited for it; dealt so, 5,788 (docs/solver.md, "Groups dealt to the
// threads by their packs"). A lone group, or one thread: everything to the calling thread.
void deal_groups(const detail::SolvePhase& phase, int chunks, std::vector<int>& owner) {
  const std::vector<size_t>& g = phase.group_begin;
  const size_t groups = g.size() - 1, n = size_t(chunks);
  owner.assign(groups, 0);
  if (groups < 2 || n < 2) return;
  std::vector<size_t> size(groups), load(n, 0);
  for (size_t k = 0; k < groups; ++k) size[k] = g[k + 1] - g[k];
  for (size_t c = 0; c < n; ++c)  // as ThreadPool::parallel_for cuts [0, groups)
    for (size_t k = groups * c / n; k < groups * (c + 1) / n; ++k) {
      owner[k] = int(c);
      load[c] += size[k];
    }
  const size_t in_runs = *std::max_element(load.begin(), load.end());
  std::vector<int> dealt;
  if (deal_by_load(size, n, dealt) < in_runs) owner = std::move(dealt);
}

// Calls fn(chunk, first, end) for every pack of the model's solve order (PackedModel::phases),
// phase after phase: a phase's groups run in parallel, each group's packs in order on one
// thread (deal_groups: the same groups on the same thread in every loop, so their data stays
// in its core's caches); a split phase (one colour) is cut between the threads, at least
// `grain` packs a chunk. fn may be called several times a chunk. The result is that of every
// pack in storage order on one thread, for any thread count.
template <class Fn>
void for_each_pack(const detail::PackedModel& pm, ThreadPool& tp, const Fn& fn, size_t grain = 32) {
  std::vector<int> owner;
  for (const detail::SolvePhase& phase : pm.phases) {
    const std::vector<size_t>& g = phase.group_begin;
    if (phase.split) {
      tp.parallel_for(g.back() - g.front(), [&](int chunk, size_t b, size_t e) { fn(chunk, g.front() + b, g.front() + e); },
                      grain);
    } else {
      // A chunk runs its groups whatever range it is given (one group: on this thread). One
      // thread too runs through parallel_for: the same compiled fn for any thread count.
      deal_groups(phase, tp.size(), owner);
      tp.parallel_for(std::min(g.size() - 1, size_t(tp.size())), [&](int chunk, size_t, size_t) {
        for (size_t k = 0; k + 1 < g.size(); ++k)
          if (owner[k] == chunk) fn(chunk, g[k], g[k + 1]);
      }, 2);
    }
  }
}

}  // namespace

struct Stepper::Impl {
  std::unique_ptr<ThreadPool> pool;
  int pool_threads = 0;
  IterationHook hook;
  std::unique_ptr<detail::SolverFamily> vbd, newton;  // made on first use
  detail::ObstacleContacts obstacles;                  // a step's triangle obstacles

  // The last sweep's multiplier increments, in the model's solve order (the accelerators'
  // input); padding slots stay zero.
  std::vector<Vec6> dlambda;
  uint64_t dlambda_model = 0;  // the model dlambda was zeroed for

  // Scratch.
  std::vector<Vec3> x_before, x_saved, v_prev;
  std::vector<Vec6> lambda_proposed;  // an accelerator's proposal (SweepResult::lambda_proposed)
  std::vector<Vec3> jacobi_dx;  // 4 per slot
  std::vector<double> partial;  // per-block sums
  std::vector<uint32_t> floor_stamp;      // per vertex: the floor pass (serial) that last moved it
  uint32_t floor_serial = 0;              // floor passes made (with this vertex count)
  std::vector<int32_t> floor_moved;       // vertices the last floor pass moved
  bool floor_scanned = false;             // the last floor pass checked every pack
  // Per chunk of a floor pass, a cache line apart (the threads append to them pack after pack):
  // the vertices it moved first in the pass, the packs that acted, the corrections.
  struct alignas(64) FloorChunk {
    std::vector<int32_t> moved, acted;
    int hits = 0;
  };
  std::vector<FloorChunk> floor_chunks;
  detail::FloorQueue floor_queue;        // the later passes' packs around moved vertices
  std::vector<size_t> floor_group_load;  // per group of a phase: packs queued
  std::vector<int> floor_group_owner;    // per group of a phase: its chunk
  std::vector<int32_t> floor_acted;                    // packs the floor acted on in this substep
  std::vector<char> floor_acted_mark;                  // per pack: in floor_acted
  size_t floor_settle_visits = 0;                      // pack visits left to this substep's settling
  // Settling's clusters: per acted pack (its index in floor_acted) a union-find parent, per
  // vertex the last acted pack seen with it as a moving corner (valid where the stamp is this
  // call's), per cluster its packs in storage order and its thread.
  std::vector<int32_t> settle_parent, settle_vertex_pack;
  std::vector<uint32_t> settle_vertex_stamp;
  uint32_t settle_serial = 0;
  std::vector<size_t> settle_cluster_of;
  std::vector<std::vector<int32_t>> settle_clusters;
  size_t settle_cluster_count = 0;
  int settled_apart = 0;  // clusters settle_clusters_apart ran (the report's floor_settle_clusters)
  std::vector<size_t> settle_load;
  std::vector<int> settle_owner, settle_chunk_passes;

  // The accelerator of the last substep, kept with its buffers while its settings stay.
  std::unique_ptr<detail::Accelerator> accel;
  detail::AcceleratorKey accel_key{};
  detail::Accelerator& accelerator(const SolverSettings& s) {
    const detail::AcceleratorKey key = detail::accelerator_key(s);
    if (!accel || key != accel_key) {
      accel = detail::make_accelerator(s);
      accel_key = key;
    }
    return *accel;
  }

  ThreadPool& threads(int n) {
    if (!pool || pool_threads != n) {
      pool = std::make_unique<ThreadPool>(n);
      pool_threads = n;
    }
    return *pool;
  }

  double residual(const BodyModel& m, const std::vector<Vec3>& x, const std::vector<Vec6>& lambda,
                  const detail::KernelCompliance& alpha_tilde, ThreadPool& tp) {
    const detail::PackedModel& packed = detail::packed(m);
    const std::vector<detail::TetPack>& packs = packs_in_order(packed);
    // Summed per block of packs: the same bits with any thread count and either numbering.
    return std::sqrt(block_sum(tp, packed.packs.size(), kResidualBlock, partial, [&](size_t b, size_t e) {
      double s = 0;
      for (size_t i = b; i < e; ++i) {
        detail::prefetch_ahead(packs, i, e, x, lambda);
        s += detail::residual_squared_lanes(packs[i], x, lambda, alpha_tilde, m.material.model);
      }
      return s;
    }));
  }

  // One Gauss-Seidel sweep in the model's solve order, four tets of a colour at a time; blocks
  // or colours run in parallel (the result does not depend on the thread count). The
  // increments go to dlambda only when `keep_increments` (an accelerator reads them); with
  // `lambda_zero` the multipliers are taken as zero and written whole. The sweep runs on the
  // positions in its own vertex numbering (PackedModel::sweep_vertex).
  int sweep_gauss_seidel(const BodyModel& m, std::vector<Vec3>& x, std::vector<Vec6>& lambda,
                         const detail::ProjectionParams& params, bool keep_increments, bool lambda_zero,
                         ThreadPool& tp) {
    const detail::PackedModel& packed = detail::packed(m);
    std::vector<int> floor_hits(tp.size(), 0);
    std::vector<Vec6>* increments = keep_increments ? &dlambda : nullptr;
    SweepOrder order(*this, packed, x);
    const std::vector<detail::TetPack>& packs = packs_in_order(packed);
    std::vector<Vec3>& xs = order.positions();
    for_each_pack(packed, tp, [&](int chunk, size_t b, size_t e) {
      int hits = 0;
      for (size_t i = b; i < e; ++i) {
        if (increments)
          detail::prefetch_ahead(packs, i, e, xs, lambda, dlambda);
        else
          detail::prefetch_ahead(packs, i, e, xs, lambda);
        hits += detail::project_pack(packs[i], xs, lambda, increments, m, params.alpha_tilde, params.lambda_scale,
                                     params.inversion_floor, params.line_search, lambda_zero);
      }
      floor_hits[chunk] += hits;
    });
    int total = 0;
    for (int h : floor_hits) total += h;
    return total;
  }

  // The passes over the packs (the sweep, the position update, the floor's passes) run on the
  // positions in the sweep's vertex numbering (PackedModel::sweep_vertex): for the scope of a
  // SweepOrder they are copied into sweep_x, and back when it ends. A mesh's numbering may
  // scatter a block's vertices: threads then write positions that share cache lines, and one
  // thread misses the cache more (docs/solver.md, "The sweep's own vertex numbering").
  std::vector<Vec3> sweep_x;
  bool in_sweep_order = false;  // while a SweepOrder holds the positions in sweep_x
  // The packs with their corners in the numbering the positions are in now.
  const std::vector<detail::TetPack>& packs_in_order(const detail::PackedModel& packed) const {
    return in_sweep_order ? packed.sweep_packs : packed.packs;
  }
  // The same for the floor's records of the packs.
  const std::vector<detail::FloorCheck>& checks_in_order(const detail::PackedModel& packed) const {
    return in_sweep_order ? packed.sweep_floor_checks : packed.floor_checks;
  }
  // The positions in the sweep's vertex numbering for the life of the object, copied back at
  // its end; the packs and floor records so numbered are used meanwhile (packs_in_order). Inside
  // another one's life it takes the positions as they are (already so numbered).
  class SweepOrder {
   public:
    SweepOrder(Impl& impl, const detail::PackedModel& packed, std::vector<Vec3>& x)
        : impl_(impl), packed_(packed), x_(x), on_(!impl.in_sweep_order) {
      if (!on_) return;
      impl_.sweep_x.resize(x_.size());
      for (size_t s = 0; s < x_.size(); ++s) impl_.sweep_x[s] = x_[size_t(packed_.mesh_vertex[s])];
      impl_.in_sweep_order = true;
    }
    ~SweepOrder() {
      if (!on_) return;
      // Read through the numbering, written in order (a gather: cheaper than the scatter).
      for (size_t v = 0; v < x_.size(); ++v) x_[v] = impl_.sweep_x[size_t(packed_.sweep_vertex[v])];
      impl_.in_sweep_order = false;
    }
    SweepOrder(const SweepOrder&) = delete;
    SweepOrder& operator=(const SweepOrder&) = delete;
    std::vector<Vec3>& positions() { return on_ ? impl_.sweep_x : x_; }

   private:
    Impl& impl_;
    const detail::PackedModel& packed_;
    std::vector<Vec3>& x_;
    bool on_;
  };

  // One Jacobi sweep: every tet computes its increment from the same positions, scaled by
  // relaxation / (largest number of tets at one of its corners), so that no vertex moves more
  // than the average of its tets' corrections. Scaling each tet's increment (instead of
  // averaging per vertex) keeps every correction a proper constraint impulse: momentum is
  // conserved and lambda stays consistent with the positions.
  int sweep_jacobi(const BodyModel& m, std::vector<Vec3>& x, std::vector<Vec6>& lambda,
                   const detail::ProjectionParams& params, double relaxation, ThreadPool& tp) {
    const detail::PackedModel& packed = detail::packed(m);
    jacobi_dx.resize(4 * packed.slot_count());
    // Tets in slot order, so that the multipliers and the corrections are walked in order.
    tp.parallel_for(packed.packs.size(), [&](int, size_t b, size_t e) {
      for (size_t i = b; i < e; ++i) {
        const detail::TetPack& pack = packed.packs[i];
        for (int l = 0; l < pack.lanes; ++l) {
          // The tet's rest data from the pack (read in order, unlike m.tets[pack.tet[l]]).
          const detail::TetOne tet = detail::lane_of(pack, l);
          const int32_t slot = tet.slot;
          double lam[6];
          for (int r = 0; r < 6; ++r) lam[r] = lambda[slot][r];
          detail::StrainStep<double> st;
          detail::strain_step(tet, x, lam, params.model, params.alpha_tilde, params.lambda_scale, params.line_search, st);
          Vec3* dx = &jacobi_dx[4 * size_t(slot)];
          if (!(st.ok & 1)) {  // not positive definite (cannot happen with alpha~ > 0): no move
            dlambda[slot].setZero();
            for (int k = 0; k < 4; ++k) dx[k].setZero();
            continue;
          }
          int most = 1;
          for (int k = 0; k < 4; ++k) most = std::max(most, int(m.vertex_tet_count[tet.v[k][0]]));
          const double scale = relaxation / most;
          for (int r = 0; r < 6; ++r) dlambda[slot][r] = st.dlambda[r] * scale;
          lambda[slot] += dlambda[slot];
          for (int k = 0; k < 4; ++k) dx[k] = Vec3(st.dx[k][0], st.dx[k][1], st.dx[k][2]) * scale;
        }
      }
    }, 16);
    tp.parallel_for(m.vertex_count(), [&](int, size_t b, size_t e) {
      for (size_t v = b; v < e; ++v) {
        Vec3 sum = Vec3::Zero();
        for (int32_t a = m.vertex_tet_start[v]; a < m.vertex_tet_start[v + 1]; ++a)
          sum += jacobi_dx[packed.vertex_slot_entry[a]];
        x[v] += sum;
      }
    });
    return params.inversion_floor > 0 ? volume_pass(m, x, params.inversion_floor, tp) : 0;
  }

  // One pass of the inversion floor in the solve order, four tets at a time. The first pass of
  // a substep (all = true) visits every pack (those a pre-check shows above the floor cost a
  // sixth of their data); a later one only the packs with a corner that a
  // floor correction moved in the previous pass or earlier in this one (a tet's det F changes
  // only when a corner moves). When few vertices moved it queues their packs as bits
  // (volume_pass_from_moved); otherwise it checks every pack's corners. Either way phase by
  // phase like a sweep (the result does not depend on the thread count) and the same packs
  // (docs/solver.md, "The floor pass"); the scan's corrections are projected SOR (kTangledAim).
  // Returns the corrections made.
  int volume_pass(const BodyModel& m, std::vector<Vec3>& x, double floor, ThreadPool& tp, bool all = true) {
    const detail::PackedModel& packed = detail::packed(m);
    if (floor_stamp.size() != m.vertex_count() || floor_acted_mark.size() != packed.packs.size() ||
        floor_serial >= UINT32_MAX - 1) {
      floor_stamp.assign(m.vertex_count(), 0);
      floor_queue.reset(packed.packs.size());
      floor_acted_mark.assign(packed.packs.size(), 0);
      floor_acted.clear();
      floor_serial = 0;
    }
    const uint32_t serial = ++floor_serial;  // stamps >= serial - 1: moved in the last pass or this one
    floor_scanned = all || floor_moved.size() * 8 >= packed.packs.size();
    if (!floor_scanned) return volume_pass_from_moved(m, x, floor, serial, tp);
    start_floor_chunks(size_t(tp.size()));
    const double trigger = floor * (1 - kFloorSlack);
    const std::vector<detail::FloorCheck>& checks = checks_in_order(packed);
    for_each_pack(packed, tp, [&](int chunk, size_t b, size_t e) {
      int hits = 0;
      for (size_t i = b; i < e; ++i) {
        const detail::FloorCheck& c = checks[i];
        if (all && i + 2 < e) detail::prefetch_corners(checks[i + 2], x);  // (a later pass skips most)
        if (!all && !pack_moved(c, serial - 1)) continue;
        // In the first pass most packs are far above the floor: told so from a sixth of their
        // data. (A later pass visits only packs with a moved corner, and the correction itself
        // starts from det F and returns when no lane is below: a pre-check would only repeat it.)
        if (all && !detail::floor_may_act(c, x, trigger)) continue;
        const int h = correct_pack(c, x, floor, serial, floor_chunks[size_t(chunk)].moved, !all);
        if (h) floor_chunks[size_t(chunk)].acted.push_back(int32_t(i));
        hits += h;
      }
      floor_chunks[size_t(chunk)].hits += hits;
    });
    floor_moved.clear();
    floor_queue.forget_next();
    return collect_floor_chunks();
  }

  void start_floor_chunks(size_t chunks) {
    floor_chunks.resize(chunks);
    for (FloorChunk& c : floor_chunks) {
      c.moved.clear();
      c.acted.clear();
      c.hits = 0;
    }
  }

  // Appends the chunks' moved vertices to floor_moved and notes the packs that acted, in chunk
  // order; returns the corrections.
  int collect_floor_chunks() {
    int hits = 0;
    for (const FloorChunk& c : floor_chunks) {
      floor_moved.insert(floor_moved.end(), c.moved.begin(), c.moved.end());
      for (int32_t q : c.acted) note_acted(q);
      hits += c.hits;
    }
    return hits;
  }

  // A later pass from the vertices the previous one moved (detail::FloorQueue), phase by phase:
  // a phase's groups dealt to the threads by the packs queued in them, the most first (the
  // floor's work gathers where the body is crushed, not spread as the groups' sizes are), a
  // phase with few on one thread.
  int volume_pass_from_moved(const BodyModel& m, std::vector<Vec3>& x, double floor, uint32_t serial,
                             ThreadPool& tp) {
    const detail::PackedModel& packed = detail::packed(m);
    const int32_t* start = (in_sweep_order ? packed.sweep_slot_start : m.vertex_tet_start).data();
    const int32_t* entry = (in_sweep_order ? packed.sweep_slot_entry : packed.vertex_slot_entry).data();
    const std::vector<detail::FloorCheck>& checks = checks_in_order(packed);
    const size_t chunks = size_t(tp.size());
    floor_queue.start(floor_moved, start, entry, chunks);
    floor_moved.clear();
    start_floor_chunks(chunks);
    auto take = [&](int chunk, size_t b, size_t e) {
      FloorChunk& fc = floor_chunks[size_t(chunk)];
      floor_queue.take(size_t(chunk), b, e, start, entry, [&](uint32_t q) {
        const size_t before = fc.moved.size();
        const int h = correct_pack(checks[q], x, floor, serial, fc.moved);
        if (h) fc.acted.push_back(int32_t(q));
        fc.hits += h;
        return std::span<const int32_t>(fc.moved.data() + before, fc.moved.size() - before);
      });
    };
    std::vector<size_t>& load = floor_group_load;
    std::vector<int>& owner = floor_group_owner;
    for (const detail::SolvePhase& phase : packed.phases) {
      const std::vector<size_t>& g = phase.group_begin;
      if (phase.split) {
        if (floor_queue.queued(g.front(), g.back()) < kFloorPassGrain) take(0, g.front(), g.back());
        else
          tp.parallel_for(g.back() - g.front(), [&](int chunk, size_t b, size_t e) { take(chunk, g.front() + b, g.front() + e); },
                          kFloorPassGrain);
      } else {
        const size_t groups = g.size() - 1;
        load.resize(groups);
        size_t total = 0;
        for (size_t k = 0; k < groups; ++k) total += load[k] = floor_queue.queued(g[k], g[k + 1]);
        owner.assign(groups, 0);
        const size_t n = total < kFloorPassGrain ? 1 : std::min(groups, chunks);
        if (n > 1) deal_by_load(load, n, owner);
        tp.parallel_for(n, [&](int chunk, size_t, size_t) {
          for (size_t k = 0; k < groups; ++k)
            if (owner[k] == chunk && load[k]) take(chunk, g[k], g[k + 1]);
        }, 2);
      }
      floor_queue.end_phase();
    }
    const int hits = collect_floor_chunks();
    floor_queue.end_pass(floor_moved.size());
    return hits;
  }

  // Passes over the packs the floor has acted on in this substep, in storage order, until one
  // acts on none, kSettlePasses have run or stop() says to end. A cluster of slivers that invert
  // each other (typically next to fixed corners) comes back by a small fraction a pass when
  // each pass reaches it only through the vertices the previous one moved; passes over just the
  // cluster settle it in a few. Part of the pass made just before (same serial: the vertices
  // they move are the next pass's to follow). Returns the corrections made.
  template <class Stop>
  int settle_acted(const BodyModel& m, std::vector<Vec3>& x, double floor, const Stop& stop, ThreadPool& tp) {
    const detail::PackedModel& packed = detail::packed(m);
    // A cluster is a small part of the body; a set over a sixteenth of its packs is a tangled
    // body, which the passes would not settle (docs/solver.md, "The floor pass").
    if (floor_acted.size() * 16 > packed.packs.size()) return 0;
    std::sort(floor_acted.begin(), floor_acted.end());
    const std::vector<detail::FloorCheck>& checks = checks_in_order(packed);
    // The passes the visits left allow (the serial loop's limit, whichever way it runs).
    const int limit = int(std::min<size_t>(kSettlePasses, floor_settle_visits / floor_acted.size()));
    if (tp.size() > 1 && floor_acted.size() >= kSettleSplitPacks && split_clusters(m, checks) > 1)
      return settle_clusters_apart(x, floor, limit, stop, tp, checks);
    int hits = 0;
    const int passes = settle_passes(floor_acted, checks, x, floor, limit, stop, floor_moved, hits);
    floor_settle_visits -= floor_acted.size() * size_t(passes);
    return hits;
  }

  // Passes over `packs` (in storage order) until one acts on none, `limit` have run or stop()
  // says to end; adds their corrections to hits and returns the passes made.
  template <class Stop>
  int settle_passes(std::span<const int32_t> packs, const std::vector<detail::FloorCheck>& checks, std::vector<Vec3>& x,
                    double floor, int limit, const Stop& stop, std::vector<int32_t>& moved, int& hits) {
    int pass = 0;
    while (pass < limit && !stop()) {
      ++pass;
      int acted = 0;
      for (int32_t q : packs) acted += correct_pack(checks[size_t(q)], x, floor, floor_serial, moved);
      hits += acted;
      if (!acted) break;
    }
    return pass;
  }

  // Splits floor_acted (sorted) into clusters that share no moving corner: settle_clusters, each
  // in storage order. Returns their count.
  size_t split_clusters(const BodyModel& m, const std::vector<detail::FloorCheck>& checks) {
    const size_t n = floor_acted.size();
    if (settle_vertex_stamp.size() != m.vertex_count() || settle_serial == UINT32_MAX) {
      settle_vertex_stamp.assign(m.vertex_count(), 0);
      settle_vertex_pack.assign(m.vertex_count(), 0);
      settle_serial = 0;
    }
    const uint32_t serial = ++settle_serial;
    settle_parent.resize(n);
    for (size_t a = 0; a < n; ++a) settle_parent[a] = int32_t(a);
    auto root = [&](int32_t a) {
      while (settle_parent[size_t(a)] != a) a = settle_parent[size_t(a)] = settle_parent[size_t(settle_parent[size_t(a)])];
      return a;
    };
    for (size_t a = 0; a < n; ++a) {
      const detail::FloorCheck& c = checks[size_t(floor_acted[a])];
      for (int l = 0; l < c.lanes; ++l)
        for (int k = 0; k < 4; ++k) {
          const int32_t v = c.v[k][l];
          if (!(c.w[k][l] > 0)) continue;  // a fixed corner is read, never moved: it joins nothing
          if (settle_vertex_stamp[size_t(v)] != serial) {
            settle_vertex_stamp[size_t(v)] = serial;
            settle_vertex_pack[size_t(v)] = int32_t(a);
          } else {
            const int32_t ra = root(int32_t(a)), rb = root(settle_vertex_pack[size_t(v)]);
            if (ra != rb) settle_parent[size_t(std::max(ra, rb))] = std::min(ra, rb);
          }
        }
    }
    // A parent is never after its child, so a cluster's root is its first pack: numbered when
    // met, its packs follow in storage order.
    size_t clusters = 0;
    settle_cluster_of.resize(n);
    for (size_t a = 0; a < n; ++a) {
      const size_t r = size_t(root(int32_t(a)));
      if (r == a) {
        if (settle_clusters.size() <= clusters) settle_clusters.emplace_back();
        settle_clusters[clusters].clear();
        settle_cluster_of[a] = clusters++;
      } else {
        settle_cluster_of[a] = settle_cluster_of[r];
      }
      settle_clusters[settle_cluster_of[a]].push_back(floor_acted[a]);
    }
    settle_cluster_count = clusters;  // (the vectors past it keep their buffers)
    return clusters;
  }

  // settle_acted's passes with the clusters on separate threads: each cluster runs them until a
  // pass acts on none of its packs or `limit`; a pass over a cluster that acted on nothing
  // changes nothing, so every cluster ends as the serial loop leaves it, bit for bit, and the
  // visits counted are the serial loop's. (The step's stop is asked once, before.)
  template <class Stop>
  int settle_clusters_apart(std::vector<Vec3>& x, double floor, int limit, const Stop& stop, ThreadPool& tp,
                            const std::vector<detail::FloorCheck>& checks) {
    if (limit == 0 || stop()) return 0;
    const size_t clusters = settle_cluster_count;
    settle_load.resize(clusters);
    for (size_t k = 0; k < clusters; ++k) settle_load[k] = settle_clusters[k].size();
    const size_t chunks = std::min(clusters, size_t(tp.size()));
    deal_by_load(settle_load, chunks, settle_owner);
    start_floor_chunks(size_t(tp.size()));
    settle_chunk_passes.assign(chunks, 0);  // per chunk: the most passes one of its clusters made
    const auto never = [] { return false; };
    tp.parallel_for(chunks, [&](int, size_t b, size_t e) {
      for (size_t chunk = b; chunk < e; ++chunk) {
        FloorChunk& fc = floor_chunks[chunk];
        for (size_t k = 0; k < clusters; ++k)
          if (size_t(settle_owner[k]) == chunk)
            settle_chunk_passes[chunk] = std::max(
                settle_chunk_passes[chunk], settle_passes(settle_clusters[k], checks, x, floor, limit, never, fc.moved, fc.hits));
      }
    }, 2);
    const int passes = *std::max_element(settle_chunk_passes.begin(), settle_chunk_passes.end());
    floor_settle_visits -= floor_acted.size() * size_t(passes);
    settled_apart += int(clusters);
    int hits = 0;
    for (const FloorChunk& fc : floor_chunks) {
      floor_moved.insert(floor_moved.end(), fc.moved.begin(), fc.moved.end());
      hits += fc.hits;
    }
    return hits;
  }

  void note_acted(int32_t q) {
    if (floor_acted_mark[size_t(q)]) return;
    floor_acted_mark[size_t(q)] = 1;
    floor_acted.push_back(q);
  }

  // Empties the set of packs the floor acted on and renews the settling passes' visits (at the
  // start of a substep's floor).
  void forget_acted(const BodyModel& m) {
    for (int32_t q : floor_acted) floor_acted_mark[size_t(q)] = 0;
    floor_acted.clear();
    floor_settle_visits = detail::packed(m).packs.size();
  }

  // The floor on one pack's lanes, from its record (with sor, a tangled body's scan: aimed at
  // kTangledAim x the floor and over-relaxed); stamps the corners it moved (appending those not yet
  // moved in this pass to moved). Returns the corrections.
  int correct_pack(const detail::FloorCheck& c, std::vector<Vec3>& x, double floor, uint32_t serial,
                   std::vector<int32_t>& moved, bool sor = false) {
    const int corrected = detail::volume_floor_pack(c, x, floor * (1 - kFloorSlack), sor ? kTangledAim * floor : floor,
                                                    sor ? kTangledRelaxation : 1.0);
    int hits = 0;
    for (int l = 0; l < c.lanes; ++l) {
      if (!(corrected & (1 << l))) continue;
      ++hits;
      for (int k = 0; k < 4; ++k) {
        const int32_t v = c.v[k][l];
        if (!(c.w[k][l] > 0) || floor_stamp[v] == serial) continue;
        floor_stamp[v] = serial;
        moved.push_back(v);
      }
    }
    return hits;
  }

  bool pack_moved(const detail::FloorCheck& c, uint32_t since) const {
    for (int k = 0; k < 4; ++k)
      for (int l = 0; l < 4; ++l)  // padding lanes repeat a real one
        if (floor_stamp[c.v[k][l]] >= since) return true;
    return false;
  }

  void apply_increment(const BodyModel& m, std::vector<Vec3>& x, const std::vector<Vec6>& dl, ThreadPool& tp) {
    const detail::PackedModel& packed = detail::packed(m);
    SweepOrder order(*this, packed, x);
    const std::vector<detail::TetPack>& packs = packs_in_order(packed);
    std::vector<Vec3>& xs = order.positions();
    for_each_pack(packed, tp, [&](int, size_t b, size_t e) {
      for (size_t i = b; i < e; ++i) {
        detail::prefetch_ahead(packs, i, e, xs, dl);
        detail::apply_increment_lanes(packs[i], xs, dl, m.material.model);
      }
    });
  }

  // Interaction scratch: per tool, the contact multiplier of each vertex in this substep
  // (lambda as a vector, normal and friction together; Delta x = w * Delta lambda) and the
  // vertices touched; per attachment, its 3-vector multiplier.
  // Per-vertex vectors that only the few vertices in contact touch: a value and a normal per
  // vertex, the list of vertices touched, and a reset that clears only those.
  struct SparseVertexVectors {
    std::vector<Vec3> value, normal;
    std::vector<uint8_t> marked;
    std::vector<int32_t> vertices;
    void reset(size_t nv) {
      if (value.size() != nv) {
        value.assign(nv, Vec3::Zero());
        normal.assign(nv, Vec3::Zero());
        marked.assign(nv, 0);
      } else {
        for (int32_t v : vertices) {
          value[v].setZero();
          marked[v] = 0;
        }
      }
      vertices.clear();
    }
    void mark(int32_t v) {
      if (!marked[v]) {
        marked[v] = 1;
        vertices.push_back(v);
      }
    }
  };
  // Per tool: contact multipliers of the current substep (value = lambda).
  std::vector<SparseVertexVectors> tool_scratch;
  // Time of the current substep's end relative to the end of the step (<= 0): tools with a
  // velocity are at position + velocity * offset.
  double tool_time_offset = 0;
  std::vector<Vec3> attachment_lambda;
  // Step accumulators (sums over substeps) for the per-contact report.
  // Per tool: contact forces summed over the substeps of a step (value = force).
  std::vector<SparseVertexVectors> tool_accumulators;

  void begin_interaction(size_t nv, const StepInputs& inputs) {
    tool_scratch.resize(inputs.tools.size());
    for (SparseVertexVectors& ts : tool_scratch) ts.reset(nv);
    attachment_lambda.assign(inputs.attachments.size(), Vec3::Zero());
  }

  // Attachments (compliant XPBD, 3 rows each), then tool contacts (hard, position-level
  // friction as for the static colliders). Returns the number of tool contacts found.
  int interact(const BodyModel& m, std::vector<Vec3>& x, const std::vector<Vec3>& x_start,
               const StepInputs& inputs, double h) {
    for (size_t j = 0; j < inputs.attachments.size(); ++j) {
      const Attachment& a = inputs.attachments[j];
      double wsum = 0;
      for (int k = 0; k < 4; ++k)
        if (a.vertices[k] >= 0) wsum += a.weights[k] * a.weights[k] * m.inv_mass[a.vertices[k]];
      if (wsum <= 0) continue;  // only fixed vertices: nothing can move
      const double at = a.compliance / (h * h);
      const Vec3 c = a.point(x) - a.target;
      const Vec3 dl = (-c - at * attachment_lambda[j]) / (wsum + at);
      for (int k = 0; k < 4; ++k)
        if (a.vertices[k] >= 0) x[a.vertices[k]] += m.inv_mass[a.vertices[k]] * a.weights[k] * dl;
      attachment_lambda[j] += dl;
    }
    int n = 0;
    for (size_t t = 0; t < inputs.tools.size(); ++t) {
      // The tool where it is in this substep, and how far it moved during it.
      const RigidTool tool = inputs.tools[t].at(tool_time_offset);
      SparseVertexVectors& ts = tool_scratch[t];
      // Vertices inside the tool, then boundary triangles (pliant/interaction.hpp).
      n += project_tool_contacts(m, x, x_start, tool, h,
                                 [&ts](int32_t v, const Vec3& dlambda, const Vec3& normal) {
                                   ts.value[v] += dlambda;
                                   ts.normal[v] = normal;
                                   ts.mark(v);
                                 });
    }
    return n;
  }

  // The substep's reactions from the multipliers: f = lambda / h^2.
  void finish_interaction(const std::vector<Vec3>& x, const StepInputs& inputs, double h, StepReport& rep) {
    const double inv_h2 = 1.0 / (h * h);
    rep.tools.assign(inputs.tools.size(), ToolReaction{});
    for (size_t t = 0; t < inputs.tools.size(); ++t) {
      const SparseVertexVectors& ts = tool_scratch[t];
      ToolReaction& r = rep.tools[t];
      const Vec3 centre = inputs.tools[t].at(tool_time_offset).position;
      for (int32_t v : ts.vertices) {
        const Vec3 f_tool = -ts.value[v] * inv_h2;
        r.force += f_tool;
        r.torque += (x[v] - centre).cross(f_tool);
        r.contacts.push_back(ToolContact{v, x[v], ts.normal[v], f_tool});
      }
    }
    rep.attachment_forces.resize(inputs.attachments.size());
    for (size_t j = 0; j < inputs.attachments.size(); ++j) rep.attachment_forces[j] = attachment_lambda[j] * inv_h2;
  }

};

Stepper::Stepper() : impl_(std::make_unique<Impl>()) {}
Stepper::~Stepper() = default;
Stepper::Stepper(Stepper&&) noexcept = default;
Stepper& Stepper::operator=(Stepper&&) noexcept = default;

void Stepper::set_iteration_hook(IterationHook hook) { impl_->hook = std::move(hook); }

StepReport Stepper::solve_substep(const BodyModel& m, const std::vector<Vec3>& x_prev,
                                  std::vector<Vec3>& x, std::vector<Vec6>& lambda, double h,
                                  const SolverSettings& s, const StepInputs& inputs) {
  if (lambda.empty()) lambda.assign(m.slot_count(), Vec6::Zero());
  if (lambda.size() != m.slot_count())
    throw std::invalid_argument("lambda: " + std::to_string(lambda.size()) + " multipliers, expected " +
                                std::to_string(m.slot_count()) + " (the model's solve slots) or none");
  return solve_in_slots(m, x_prev, x, lambda, h, s, inputs, 0.0, false);
}

StepReport Stepper::solve_in_slots(const BodyModel& m, const std::vector<Vec3>& x_prev, std::vector<Vec3>& x_mesh,
                                   std::vector<Vec6>& lambda, double h, const SolverSettings& s,
                                   const StepInputs& inputs, double budget_ms, bool lambda_zero) {
  Impl& I = *impl_;
  // Multipliers to be read as zero: the first Gauss-Seidel sweep takes them so and writes every
  // slot; anything else that would read them first gets them zeroed.
  bool zero_pending = lambda_zero;
  auto zero_lambda = [&] {
    if (zero_pending) std::fill_n(lambda.data()->data(), 6 * lambda.size(), 0.0);
    zero_pending = false;
  };
  if (s.record_residuals || s.sweep != Sweep::GaussSeidel || s.iterations <= 0) zero_lambda();
  const detail::PackedModel& packed = detail::packed(m);
  const auto t_start = Clock::now();
  StepReport rep;
  rep.substeps = 1;
  ThreadPool& tp = I.threads(s.threads);
  detail::Accelerator* accel = &I.accelerator(s);
  accel->begin_substep(m.vertex_count(), packed.slot_count());
  detail::ProjectionParams params;
  params.model = m.material.model;
  params.alpha_tilde = detail::KernelCompliance(Mat6(m.compliance / (h * h)));
  params.lambda_scale = accel->increment_scale();
  params.inversion_floor = s.inversion_floor;
  params.line_search = s.line_search;
  // Every real slot is written by each sweep; padding slots must read zero for the accelerators.
  if (I.dlambda_model != m.id || I.dlambda.size() != packed.slot_count()) {
    I.dlambda.assign(packed.slot_count(), Vec6::Zero());
    I.dlambda_model = m.id;
  }
  const bool interacting = !inputs.tools.empty() || !inputs.attachments.empty();
  if (interacting) I.begin_interaction(m.vertex_count(), inputs);
  // Gauss-Seidel sweeps with nothing between them that reads the mesh's numbering (contacts,
  // grabs, tools, the experiment hook) run the whole substep in the sweep's numbering: the
  // positions copied in and out once, the residuals read on the packs so numbered.
  std::optional<Impl::SweepOrder> held;
  if (s.sweep == Sweep::GaussSeidel && inputs.colliders.empty() && !interacting && !I.obstacles.active() && !I.hook)
    held.emplace(I, packed, x_mesh);
  std::vector<Vec3>& x = held ? held->positions() : x_mesh;

  detail::AcceleratorServices services;
  services.report = &rep;
  services.apply_increment = [&](const std::vector<Vec6>& dl) {
    PhaseTimer t{rep.times.update_ms};
    I.apply_increment(m, x, dl, tp);
  };
  services.parallel_for = [&tp](size_t n, const std::function<void(size_t, size_t)>& fn) {
    tp.parallel_for(n, [&fn](int, size_t b, size_t e) { fn(b, e); }, 2);
  };

  double r0 = 0;
  if (s.record_residuals) {
    PhaseTimer t{rep.times.residual_ms};
    r0 = I.residual(m, x, lambda, params.alpha_tilde, tp);
  }
  rep.residual_initial = rep.residual_final = r0;
  rep.residuals.reserve(s.iterations);
  double hook_ms = 0;  // time spent in the experiment hook, excluded from the report
  const bool proposes = s.method == Method::Anderson || s.method == Method::AndersonSor ||
                        s.method == Method::Extrapolation;
  double r_reference = r0;  // what the divergence test compares against

  for (int it = 0; it < s.iterations; ++it) {
    if (accel->needs_previous()) I.x_before = x;
    {
      PhaseTimer t{rep.times.projection_ms};
      switch (s.sweep) {
        case Sweep::GaussSeidel:
          rep.volume_corrections =
              I.sweep_gauss_seidel(m, x, lambda, params, accel->needs_increments(), zero_pending, tp);
          zero_pending = false;
          break;
        case Sweep::Jacobi:
          rep.volume_corrections = I.sweep_jacobi(m, x, lambda, params, s.jacobi_relaxation, tp);
          break;
        case Sweep::Sequential:
          rep.volume_corrections = detail::sweep_sequential(m, x, lambda, I.dlambda, params);
          break;
      }
    }
    if (!inputs.colliders.empty()) {
      PhaseTimer t{rep.times.other_ms};
      rep.contacts = detail::resolve_colliders(m, x, x_prev, inputs.colliders);
    }
    if (interacting) {
      PhaseTimer t{rep.times.other_ms};
      const int n = I.interact(m, x, x_prev, inputs, h);
      if (inputs.colliders.empty()) rep.contacts = n;
      else rep.contacts += n;
    }
    if (I.obstacles.active()) {
      PhaseTimer t{rep.times.other_ms};
      const int n = I.obstacles.resolve(m, x, x_prev, h);
      if (inputs.colliders.empty() && !interacting) rep.contacts = n;
      else rep.contacts += n;
    }
    double r = 0;
    // Position-space accelerators move x after the sweep: their residual is taken after that.
    if (s.record_residuals && (proposes || !accel->needs_previous())) {
      PhaseTimer t{rep.times.residual_ms};
      r = I.residual(m, x, lambda, params.alpha_tilde, tp);
    }
    if (proposes) {
      I.lambda_proposed.resize(lambda.size());
      detail::SweepResult sr{x, lambda, I.dlambda, I.x_before, it, &I.lambda_proposed};
      I.x_saved = x;
      bool proposed;
      {
        PhaseTimer t{rep.times.anderson_ms};
        // apply_increment inside is timed as update; subtract it back out below.
        const double update_before = rep.times.update_ms;
        proposed = accel->after_sweep(sr, services);
        rep.times.anderson_ms -= (rep.times.update_ms - update_before);
      }
      if (proposed) {
        rep.accelerations_tried++;
        double r_acc;
        {
          PhaseTimer t{rep.times.residual_ms};
          r_acc = I.residual(m, x, I.lambda_proposed, params.alpha_tilde, tp);
        }
        if (std::isfinite(r_acc) && r_acc < r) {
          rep.accelerations_accepted++;
          r = r_acc;
          lambda.swap(I.lambda_proposed);
        } else {
          x.swap(I.x_saved);
        }
      }
    } else {
      detail::SweepResult sr{x, lambda, I.dlambda, I.x_before, it};
      {
        PhaseTimer t{rep.times.update_ms};
        accel->after_sweep(sr, services);
      }
      if (accel->needs_previous() && s.record_residuals) {
        PhaseTimer tr{rep.times.residual_ms};
        r = I.residual(m, x, lambda, params.alpha_tilde, tp);
      }
    }
    rep.iterations++;
    if (s.record_residuals) {
      rep.residuals.push_back(r);
      rep.residual_final = r;
    }
    if (I.hook) detail::call_iteration_hook(I.hook, it, x, r, t_start, hook_ms);
    if (s.record_residuals) {
      // Tools and grabs move vertices after the sweep, so the first iteration's residual can
      // exceed r0 by any factor (r0 is exactly 0 for an undisturbed body without gravity):
      // with them, the blow-up test compares against the larger of r0 and that first residual.
      if (interacting && it == 0) r_reference = std::max(r0, r);
      if (!std::isfinite(r) || r > 1e8 * std::max(r_reference, 1e-300)) {
        rep.diverged = true;
        break;
      }
      if (s.tolerance > 0 && r <= s.tolerance * r0) {
        rep.stopped_by_tolerance = true;
        break;
      }
    }
    if (inputs.cancel && inputs.cancel->load(std::memory_order_relaxed)) {
      rep.cancelled = true;
      break;
    }
    if (budget_ms > 0 && ms_since(t_start) - hook_ms >= budget_ms) {
      rep.stopped_by_budget = it + 1 < s.iterations;
      break;
    }
  }
  zero_lambda();  // (no sweep ran)
  if (s.inversion_floor > 0) {
    // Neighbours projected later in a pass can push an earlier tet back under the floor:
    // repeat (kVolumePasses at most) until a pass finds nothing to do. The later passes belong
    // to the step's time: they stop when the budget is spent or the step is cancelled (on a
    // tangled mesh they do not converge, and 40 of them can cost more than the sweeps).
    PhaseTimer t{rep.times.other_ms}, t_floor{rep.times.floor_ms};
    auto stop = [&] {
      if (inputs.cancel && inputs.cancel->load(std::memory_order_relaxed)) {
        rep.cancelled = true;
        return true;
      }
      if (budget_ms > 0 && ms_since(t_start) - hook_ms >= budget_ms) {
        rep.floor_stopped_by_budget = true;
        return true;
      }
      return false;
    };
    I.forget_acted(m);
    Impl::SweepOrder order(I, packed, x);
    std::vector<Vec3>& xf = order.positions();
    int hits = I.volume_pass(m, xf, s.inversion_floor, tp);
    rep.volume_corrections += hits;
    int pass = 1;
    for (; pass < kVolumePasses && hits > 0 && !stop(); ++pass) {
      const auto t_pass = Clock::now();
      hits = I.volume_pass(m, xf, s.inversion_floor, tp, false);
      if (I.floor_scanned) {
        rep.floor_scan_passes++;
        rep.times.floor_scan_ms += ms_since(t_pass);
      }
      if (hits > 0 && pass >= kSettleAfter) hits += I.settle_acted(m, xf, s.inversion_floor, stop, tp);
      rep.volume_corrections += hits;
    }
    rep.floor_passes += pass;
    rep.floor_settle_clusters += I.settled_apart;
    I.settled_apart = 0;
    spdlog::trace("inversion floor: {} passes, {} corrections in the last", pass, hits);
  }
  held.reset();  // the positions back in the mesh's numbering
  if (interacting) I.finish_interaction(x_mesh, inputs, h, rep);
  rep.wall_ms = ms_since(t_start) - hook_ms;
  return rep;
}

StepReport Stepper::step(const BodyModel& m, BodyState& state, const SolverSettings& s,
                         const StepInputs& inputs) {
  Impl& I = *impl_;
  switch (family_of(s.method)) {
    case SolverFamilyKind::VertexBlockDescent:
      if (!I.vbd) I.vbd = detail::make_vbd_family();
      return I.vbd->step(m, state, s, inputs, I.hook);
    case SolverFamilyKind::Newton:
      if (!I.newton) I.newton = detail::make_newton_family();
      return I.newton->step(m, state, s, inputs, I.hook);
    case SolverFamilyKind::ConstraintProjection: break;
  }
  if (s.method == Method::Auto)
    throw std::invalid_argument("solver.method auto names no solver: the server resolves it per scene");
  const auto t_start = Clock::now();
  int n = effective_substeps(m, s);
  const double h = s.dt / n;
  const size_t nv = m.vertex_count();
  StepReport total;
  const SolverSettings quiet = detail::quiet_substep(s);
  const bool interacting = !inputs.tools.empty() || !inputs.attachments.empty();
  if (interacting) {
    I.tool_accumulators.resize(inputs.tools.size());
    for (auto& acc : I.tool_accumulators) acc.reset(nv);
    total.tools.assign(inputs.tools.size(), ToolReaction{});
    total.attachment_forces.assign(inputs.attachments.size(), Vec3::Zero());
  }
  I.obstacles.begin_step(m, state.x, inputs.obstacles);
  for (int sub = 0; sub < n; ++sub) {
    const auto t_other = Clock::now();
    detail::predict(m, state, s, inputs, h, I.v_prev);
    // Each substep's multipliers start at zero: its solve takes them so (no zeroing pass).
    const bool lambda_sized = state.lambda.size() == m.slot_count();
    if (!lambda_sized) state.lambda.assign(m.slot_count(), Vec6::Zero());
    state.lambda_h = h;
    total.times.other_ms += ms_since(t_other);

    double budget = 0;
    if (s.time_budget_ms > 0) budget = std::max(0.0, (s.time_budget_ms - ms_since(t_start)) / (n - sub));
    // The report carries the residual history of the last substep only; earlier substeps
    // compute residuals only when the method or a tolerance needs them.
    I.tool_time_offset = (sub + 1 - n) * h;
    StepReport r = solve_in_slots(m, I.v_prev, state.x, state.lambda, h, sub + 1 == n ? s : quiet, inputs,
                                  s.time_budget_ms > 0 ? std::max(budget, 1e-6) : 0.0, lambda_sized);

    const auto t_vel = Clock::now();
    detail::finish_substep(m, state, I.v_prev, s, h);
    total.times.other_ms += ms_since(t_vel);

    if (interacting) {
      for (size_t t = 0; t < r.tools.size(); ++t) {
        auto& acc = I.tool_accumulators[t];
        total.tools[t].force += r.tools[t].force;
        total.tools[t].torque += r.tools[t].torque;
        for (const ToolContact& c : r.tools[t].contacts) {
          acc.value[c.vertex] += c.force;
          acc.normal[c.vertex] = c.normal;
          acc.mark(c.vertex);
        }
      }
      for (size_t j = 0; j < r.attachment_forces.size(); ++j) total.attachment_forces[j] += r.attachment_forces[j];
    }
    const bool cancelled = r.cancelled;
    detail::add_substep(total, std::move(r));
    if (cancelled) {
      n = sub + 1;  // the averages below are over the substeps run
      break;
    }
  }
  I.tool_time_offset = 0;  // solve_substep on its own: tools at their pose
  I.obstacles.finish(total);
  if (interacting) {
    // Averages over the substeps: the impulse delivered during the step divided by dt.
    for (size_t t = 0; t < total.tools.size(); ++t) {
      ToolReaction& r = total.tools[t];
      r.force /= n;
      r.torque /= n;
      const auto& acc = I.tool_accumulators[t];
      r.contacts.reserve(acc.vertices.size());
      for (int32_t v : acc.vertices) r.contacts.push_back(ToolContact{v, state.x[v], acc.normal[v], acc.value[v] / n});
    }
    for (Vec3& f : total.attachment_forces) f /= n;
  }
  total.substeps = n;
  state.time += total.cancelled ? n * h : s.dt;
  state.steps++;
  if (!is_finite(state)) total.diverged = true;
  total.wall_ms = ms_since(t_start);
  return total;
}

int effective_substeps(const BodyModel& m, const SolverSettings& s) {
  if (!(s.target_wave_courant_number > 0)) return s.substeps;
  const double per_substep = wave_courant_number(m, s.dt);  // for one substep of the whole tick
  if (!(per_substep > 0) || !std::isfinite(per_substep)) return s.substeps;
  // (1 - 1e-12): a ratio that is a whole number up to rounding does not round up to one more.
  const double n = std::ceil(per_substep / s.target_wave_courant_number * (1 - 1e-12));
  return int(std::clamp(n, 1.0, double(kMaxSubsteps)));
}

void apply_damping(const BodyModel& m, BodyState& state, const SolverSettings& s, double h) {
  const size_t nv = m.vertex_count();
  switch (s.damping) {
    case Damping::None: return;
    case Damping::Simple: {
      const double f = std::exp(-s.damping_coefficient * h);
      for (size_t i = 0; i < nv; ++i) state.v[i] *= f;
      return;
    }
    case Damping::RigidPreserving: {
      // Mueller et al. 2007: damp only the deviation from the body's rigid motion. k is per
      // step; per substep we use k_s with (1 - k_s)^substeps = 1 - k. Momenta use the inertia the
      // solver moves (the damping then conserves the momentum the sweeps conserve).
      const double k = 1.0 - std::pow(1.0 - s.damping_coefficient, h / s.dt);
      double mass = 0;
      Vec3 xc = Vec3::Zero(), vc = Vec3::Zero();
      for (size_t i = 0; i < nv; ++i) {
        if (m.inv_mass[i] == 0) continue;
        mass += m.inertia[i];
        xc += m.inertia[i] * state.x[i];
        vc += m.inertia[i] * state.v[i];
      }
      if (mass <= 0) return;
      xc /= mass;
      vc /= mass;
      Vec3 L = Vec3::Zero();
      Mat3 I = Mat3::Zero();
      for (size_t i = 0; i < nv; ++i) {
        if (m.inv_mass[i] == 0) continue;
        const Vec3 r = state.x[i] - xc;
        L += r.cross(m.inertia[i] * state.v[i]);
        I += m.inertia[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
      }
      const Eigen::FullPivLU<Mat3> lu(I);
      const Vec3 omega = lu.isInvertible() ? Vec3(lu.solve(L)) : Vec3::Zero();
      for (size_t i = 0; i < nv; ++i) {
        if (m.inv_mass[i] == 0) continue;
        const Vec3 dv = vc + omega.cross(state.x[i] - xc) - state.v[i];
        state.v[i] += k * dv;
      }
      return;
    }
  }
}

double residual_norm(const BodyModel& m, const std::vector<Vec3>& x, const std::vector<Vec6>& lambda,
                     double h) {
  const detail::KernelCompliance at(Mat6(m.compliance / (h * h)));
  double sum = 0;
  if (lambda.size() != m.slot_count())
    throw std::invalid_argument("lambda: " + std::to_string(lambda.size()) + " multipliers, expected " +
                                std::to_string(m.slot_count()) + " (the model's solve slots)");
  for (const detail::TetPack& p : detail::packed(m).packs)
    sum += detail::residual_squared_lanes(p, x, lambda, at, m.material.model);
  return std::sqrt(sum);
}

}  // namespace pliant
