// SPDX-License-Identifier: Apache-2.0
// The queue of the inversion floor's later passes from the moved vertices: per pack a bit, taken
// in storage order. A correction queues the packs around the corners it moved: those after it in
// this pass, all of them in the next one (one walk of the vertex's packs fills both, so a pass
// starts from the queue the last one filled). Phase by phase like a sweep: a group's corrections
// move only its own vertices, so they queue packs in its own range (taken by the same chunk) or in
// later phases (merged between the phases); the packs are taken in the order one thread would
// take them, whichever chunk takes them.
#pragma once

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace pliant::detail {

class FloorQueue {
 public:
  // Empty queues for `packs` packs.
  void reset(size_t packs) {
    now_.assign((packs + 63) / 64, 0);
    next_.assign(now_.size(), 0);
    next_first_ = next_.size();
    covers_ = 0;
  }

  // Forgets the next pass's queue (a pass that scans every pack moved vertices instead).
  void forget_next() {
    std::fill(next_.begin() + std::ptrdiff_t(next_first_), next_.end(), 0);
    next_first_ = next_.size();
    covers_ = 0;
  }

  // Starts a pass: the queue the last one filled, plus the packs around moved[covers(), end)
  // (vertices moved by other passes since: a scan's, the settling passes'); `start` and `entry`
  // list each vertex's packs as 16 x pack + 4 x lane + corner.
  void start(const std::vector<int32_t>& moved, const int32_t* start, const int32_t* entry, size_t chunks) {
    now_.swap(next_);  // the old one was emptied at the end of its pass
    first_ = next_first_;
    next_first_ = next_.size();
    for (size_t j = covers_; j < moved.size(); ++j)
      for (int32_t a = start[moved[j]]; a < start[moved[j] + 1]; ++a) {
        const uint32_t q = uint32_t(entry[a]) >> 4;
        now_[q >> 6] |= uint64_t(1) << (q & 63);
        first_ = std::min(first_, size_t(q >> 6));
      }
    chunks_.resize(chunks);
    for (Chunk& c : chunks_) {
      if (c.later.size() != now_.size()) {
        c.later.assign(now_.size(), 0);
        c.next.assign(now_.size(), 0);
      }
      c.later_lo = c.next_lo = now_.size();
      c.later_hi = 0;
    }
  }

  // Packs queued in [b, e) (before the phase holding them runs).
  size_t queued(size_t b, size_t e) const {
    size_t n = 0;
    for (size_t w = std::max(b >> 6, first_); b < e && w <= (e - 1) >> 6; ++w) n += size_t(std::popcount(in_range(w, b, e)));
    return n;
  }

  // Takes the packs queued in [b, e) (a group, or a chunk of a split phase) in order on chunk
  // `chunk`: correct(q) corrects pack q and returns the vertices it moved that are new in
  // this pass, as a span into a list it keeps; their packs are queued. Chunks may run
  // different ranges of one phase at once.
  template <class Correct>
  void take(size_t chunk, size_t b, size_t e, const int32_t* start, const int32_t* entry, const Correct& correct) {
    if (b >= e || (e - 1) >> 6 < first_) return;
    Chunk& c = chunks_[chunk];
    const size_t w0 = b >> 6, w1 = (e - 1) >> 6;
    c.own.resize(w1 - w0 + 1);
    for (size_t w = w0; w <= w1; ++w) c.own[w - w0] = in_range(w, b, e);
    uint64_t* const own = c.own.data();
    uint64_t* const later = c.later.data();
    uint64_t* const next = c.next.data();
    size_t later_lo = c.later_lo, later_hi = c.later_hi, next_lo = c.next_lo;  // (locals: the words alias size_t)
    for (size_t w = 0; w <= w1 - w0; ++w) {
      while (own[w]) {  // a correction may queue packs later in this word
        const uint32_t q = uint32_t((w0 + w) * 64 + size_t(std::countr_zero(own[w])));
        own[w] &= own[w] - 1;
        for (const int32_t v : correct(q)) {
          for (int32_t a = start[v]; a < start[v + 1]; ++a) {
            const uint32_t t = uint32_t(entry[a]) >> 4;
            const size_t tw = t >> 6;
            const uint64_t bit = uint64_t(1) << (t & 63);
            next[tw] |= bit;
            next_lo = std::min(next_lo, tw);
            if (t <= q) continue;
            if (t < e) {
              own[tw - w0] |= bit;
            } else {
              later[tw] |= bit;
              later_lo = std::min(later_lo, tw);
              later_hi = std::max(later_hi, tw);
            }
          }
        }
      }
    }
    c.later_lo = later_lo;
    c.later_hi = later_hi;
    c.next_lo = next_lo;
  }

  // Between two phases: the later phases' packs that the chunks queued.
  void end_phase() {
    for (Chunk& c : chunks_) {
      for (size_t w = c.later_lo; w <= c.later_hi && w < now_.size(); ++w) {
        now_[w] |= c.later[w];
        c.later[w] = 0;
      }
      c.later_lo = now_.size();
      c.later_hi = 0;
    }
  }

  // Ends the pass: the next one's queue from the chunks' (around the first `moved` vertices of
  // the list the pass leaves).
  void end_pass(size_t moved) {
    std::fill(now_.begin() + std::ptrdiff_t(first_), now_.end(), 0);
    for (Chunk& c : chunks_) {
      for (size_t w = c.next_lo; w < next_.size(); ++w) {
        next_[w] |= c.next[w];
        c.next[w] = 0;
      }
      next_first_ = std::min(next_first_, c.next_lo);
    }
    covers_ = moved;
  }

  // The vertices of the moved list whose packs the next queue holds.
  size_t covers() const { return covers_; }

 private:
  struct alignas(64) Chunk {  // (a cache line apart: each thread writes its own)
    std::vector<uint64_t> later, next;  // bits, zero outside a pass
    std::vector<uint64_t> own;          // the range being taken, from its first word
    size_t later_lo = 0, later_hi = 0, next_lo = 0;
  };
  // Word w of this pass's queue, the bits of [b, e) only.
  uint64_t in_range(size_t w, size_t b, size_t e) const {
    uint64_t bits = now_[w];
    if (w == b >> 6) bits &= ~uint64_t(0) << (b & 63);
    if (w == (e - 1) >> 6 && (e & 63)) bits &= ~(~uint64_t(0) << (e & 63));
    return bits;
  }

  std::vector<uint64_t> now_, next_;  // this pass's queue, the next one's
  size_t first_ = 0;                  // the lowest word of now_ queued into
  size_t next_first_ = 0;             // the lowest word of next_ queued into
  size_t covers_ = 0;
  std::vector<Chunk> chunks_;
};

}  // namespace pliant::detail
