// SPDX-License-Identifier: Apache-2.0
// What the frame streams and the interaction calls exchange with a scene, in the API's
// messages: which parts of a frame a subscriber wants, frames and tool feedback built from a
// published Frame, tool poses and grab points checked on the way in (errors name the field
// and the value). The gRPC handlers (service.cpp) and the registry share it.
#pragma once

#include "pliant/server/error.hpp"
#include "pliant/server/scene.hpp"
#include "pliant/v1/pliant.pb.h"

#include <cstdint>
#include <vector>

namespace pliant::server {

// StreamFramesRequest.max_rate_hz: 0 (no limit) or within these.
constexpr double kMinRateHz = 0.01, kMaxRateHz = 100'000;

// Which parts of a frame a subscriber asked for.
struct FrameSelection {
  bool positions = true;
  bool residuals = true;
  bool solver_stats = true;
  bool surface_only = false;
};

// Checks a StreamFramesRequest and fills the selection.
Error parse_stream_request(const v1::StreamFramesRequest& request, FrameSelection* out);

// The frame message a subscriber gets: the parts it selected (positions of the surface
// vertices only with surface_only), `skipped` frames it missed.
void frame_to_proto(const Frame& frame, const FrameSelection& selection, const std::vector<int32_t>& surface_vertices,
                    uint64_t skipped, v1::Frame* out);
// The solver's report of a tick as the API states it; `all`: every figure, else only
// iterations and the residuals (what a frame carries when solver stats were not selected).
void solver_stats_to_proto(const StepReport& report, bool all, v1::SolverStats* out);

// A haptic pose as a tool; `previous` supplies the shape for fields the pose leaves unset
// (null on the first pose: server defaults).
Error parse_tool_pose(const v1::ToolPose& pose, const RigidTool* previous, RigidTool* out);
// Tool `tool_id`'s feedback from a frame; false when the frame has no reaction for it yet
// (its first pose is not in a tick).
bool tool_feedback_to_proto(const Frame& frame, uint64_t tool_id, uint64_t skipped, v1::ToolFeedback* out);

// The attachment a Grab asks for on this scene: a vertex or a point in a tet, held where it is
// now (the latest frame, or the positions the scene started from) unless a target is given.
Error grab_from_proto(const v1::GrabRequest& request, const Scene& scene, Attachment* out);

// The scene's fixed geometry: rest positions, tets, surface, fixed vertices.
void topology_to_proto(const Scene& scene, v1::Topology* out);

}  // namespace pliant::server
