// SPDX-License-Identifier: Apache-2.0
// Recordings for ParaView: one binary VTK XML UnstructuredGrid (.vtu) per frame and a .pvd
// collection that gives each frame its simulation time. Shared by `pliant-sim run` (offline)
// and `pliant record` (frames streamed from a server).
//
// A frame carries the current positions as the points, and point data `displacement` (x - rest),
// `velocity`, `fixed` (1 for a held vertex), cell data `det_F` (volume ratio of each tet against
// its rest shape; a recording of tets only) and field data `residual` and `TimeValue`. Binary
// data is appended raw, little endian, with UInt64 headers. Besides tets a recording may hold
// triangles (a cloth), line segments (a rope) and one vertex cell per point (a fluid's particles),
// so that the particle bodies of a scene are recorded as their own series.
#pragma once

#include "pliant/mesh.hpp"

#include <array>
#include <cstdint>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

namespace pliant {

// What stays the same over a recording.
struct RecordingTopology {
  std::vector<Vec3> rest_positions;
  std::vector<Tet> tets;
  std::vector<uint8_t> fixed;  // one per vertex (empty: none fixed)
  std::vector<std::array<int32_t, 3>> triangles;  // VTK_TRIANGLE cells
  std::vector<std::array<int32_t, 2>> segments;   // VTK_LINE cells
  // One VTK_VERTEX cell per point. A topology of point cells only takes frames of any point
  // count (a fluid whose emitters add particles): points beyond the rest positions are
  // written with zero displacement and not fixed.
  bool point_cells = false;
};

// One frame's data. `velocity` may be empty (written as zeros).
struct RecordingFrame {
  double time = 0;
  std::vector<Vec3> positions;
  std::vector<Vec3> velocity;
  double residual = 0;
};

// det F = det[x1-x0, x2-x0, x3-x0] / det[X1-X0, X2-X0, X3-X0] per tet (rest X, current x).
std::vector<double> tet_volume_ratios(const std::vector<Vec3>& rest, const std::vector<Tet>& tets,
                                      const std::vector<Vec3>& current);

// Writes one frame as a .vtu file. Throws std::runtime_error naming the path when it cannot,
// std::invalid_argument when the frame's arrays do not match the topology.
void write_vtu_frame(const RecordingTopology& topology, const RecordingFrame& frame, const std::string& path);

// Writes a .pvd collection: (time, file relative to the .pvd) per entry, in the given order.
// Written to a temporary file and renamed, so a reader never sees half a collection.
void write_pvd(const std::vector<std::pair<double, std::string>>& entries, const std::string& path);

// A recording in a directory: <dir>/<stem>_NNNNNN.vtu per frame and <dir>/<stem>s.pvd, which
// grows by one entry per frame and ends with its closing tags after every frame, so that a
// recording cut short is still a valid collection.
class VtuRecorder {
 public:
  // Creates the directory if needed (std::runtime_error if it cannot). The collection is
  // <dir>/<pvd_stem>.pvd, by default <stem>s.pvd.
  VtuRecorder(std::string dir, RecordingTopology topology, std::string stem = "frame", std::string pvd_stem = "");

  // Writes the frame numbered `index` (the file name's number) and updates the .pvd. Returns the
  // .vtu's path.
  std::string write(const RecordingFrame& frame, long index);
  // As above, numbered by the count of frames written so far.
  std::string write(const RecordingFrame& frame) { return write(frame, static_cast<long>(entries_.size())); }

  const RecordingTopology& topology() const { return topology_; }
  size_t frames() const { return entries_.size(); }
  std::string pvd_path() const;

 private:
  std::string dir_, stem_, pvd_stem_;
  RecordingTopology topology_;
  std::vector<std::pair<double, std::string>> entries_;
  std::fstream pvd_;
  long long pvd_tail_ = 0;  // where the closing tags start
};

}  // namespace pliant
