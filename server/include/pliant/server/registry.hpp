// SPDX-License-Identifier: Apache-2.0
// The server's scenes by id, and everything between the API messages (pliant.v1) and the
// scenes: validating requests (errors name the field and value), building models, limits,
// snapshots in the data directory. Protobuf messages only; the gRPC glue is service.cpp.
#pragma once

#include "pliant/server/scene.hpp"
#include "pliant/v1/pliant.pb.h"

#include <atomic>
#include <condition_variable>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace pliant::server {

// The most solver sweeps (substeps x iterations per substep) one tick may ask for.
constexpr int64_t kMaxSweepsPerTick = 200'000;
// StreamFramesRequest.max_rate_hz: 0 (no limit) or within these.
constexpr double kMinRateHz = 0.01, kMaxRateHz = 100'000;

struct RegistryOptions {
  int max_scenes = 16;
  int64_t max_vertices = 2'000'000;
  int max_threads = 1;                   // cap on a scene's solver threads
  std::string data_dir;                  // empty: no snapshots on disk
  std::vector<std::string> model_path;   // directories searched for mesh files
  // A tick whose solver runs longer is stopped at its next sweep, undone, and its scene paused
  // (a lockstep Step fails). 0: no limit.
  int64_t max_tick_ms = 10'000;
  // A tick still running after this long marks the server stuck: on_health(false) until it
  // ends. 0: never.
  int64_t stuck_tick_ms = 15'000;
  // Scenes that changed are written to <data-dir>/scenes/ this often, off the tick threads;
  // created scenes at once. 0: only at shutdown.
  int64_t checkpoint_ms = 5'000;
  // Open StreamFrames + HapticStream calls, server-wide and per scene; grabs per scene.
  int max_streams = 256;
  int max_streams_per_scene = 64;
  int max_grabs_per_scene = 64;
  // Called by the watchdog when a tick becomes stuck (false) or no tick is stuck any more (true).
  std::function<void(bool serving)> on_health;
};

// Which parts of a frame a subscriber asked for.
struct FrameSelection {
  bool positions = true;
  bool residuals = true;
  bool solver_stats = true;
  bool surface_only = false;
};

class SceneRegistry {
 public:
  explicit SceneRegistry(RegistryOptions options);
  ~SceneRegistry();

  const RegistryOptions& options() const { return options_; }

  Error create(const v1::CreateSceneRequest& request, v1::Scene* out);
  Error list(v1::ListScenesResponse* out) const;
  Error get(const std::string& id, v1::Scene* out) const;
  Error update(const v1::UpdateSceneRequest& request, v1::Scene* out);
  Error remove(const std::string& id);
  Error reset(const std::string& id, v1::Scene* out);
  Error pause(const std::string& id, v1::Scene* out);
  Error resume(const std::string& id, v1::Scene* out);
  Error step(const v1::StepRequest& request, std::chrono::steady_clock::time_point deadline,
             v1::StepResponse* out, const std::function<bool()>& cancelled = {});
  Error apply_force(const v1::ApplyForceRequest& request, v1::ApplyForceResponse* out);
  Error topology(const std::string& id, v1::Topology* out) const;

  // InteractionService: grabs (validated here, applied by the scene's tick).
  Error grab(const v1::GrabRequest& request, v1::GrabResponse* out);
  Error move_grab(const v1::MoveGrabRequest& request, v1::MoveGrabResponse* out);
  Error release(const v1::ReleaseRequest& request);
  // A haptic pose as a tool; `previous` supplies the shape for fields the pose leaves unset
  // (null on the first pose: server defaults). Errors name the field and the value.
  static Error parse_tool_pose(const v1::ToolPose& pose, const RigidTool* previous, RigidTool* out);

  Error save_snapshot(const v1::SaveSnapshotRequest& request, v1::SaveSnapshotResponse* out);
  Error restore_snapshot(const v1::RestoreSnapshotRequest& request, v1::Scene* out);
  Error list_snapshots(v1::ListSnapshotsResponse* out) const;

  // Counts an open stream on the scene against max_streams and max_streams_per_scene
  // (RESOURCE_EXHAUSTED naming the limit); releasing *slot ends the count.
  Error open_stream(const std::string& scene_id, std::shared_ptr<void>* slot);

  // Every hosted scene (a copy of the list, taken under a short lock).
  std::vector<std::shared_ptr<Scene>> scenes() const;
  // Open streams per scene id, and in *total all of them (for the metrics endpoint).
  std::map<std::string, int> stream_counts(int* total) const;

  // The scene with this id, or NotFound.
  Error find(const std::string& id, std::shared_ptr<Scene>* out) const;
  // Checks a StreamFramesRequest and fills the selection.
  static Error parse_stream_request(const v1::StreamFramesRequest& request, FrameSelection* out);
  static void fill_frame(const Frame& frame, const FrameSelection& selection,
                         const std::vector<int32_t>& surface_vertices, uint64_t skipped,
                         v1::Frame* out);

  // Scenes whose snapshots are in <data-dir>/scenes/ are recreated (on start).
  // Returns how many were restored; unreadable files are logged and skipped.
  int restore_from_data_dir();
  // Starts the watchdog (tick limits) and, with a data directory, the checkpoint writer.
  void start_background();
  // Writes every scene that changed since its last checkpoint (what the checkpoint thread does
  // every checkpoint_ms). Returns how many files were written.
  int checkpoint();
  // Marks the registry as closing: streams end with UNAVAILABLE, new scenes are refused, every
  // scene's tick stops at its next sweep.
  void begin_shutdown();
  bool shutting_down() const { return shutting_down_.load(); }
  // Stops every scene and writes its snapshot to <data-dir>/scenes/ (when set).
  // Returns how many snapshots were written; failed_saves() says how many could not be.
  int shutdown();
  int failed_saves() const { return failed_saves_; }

 private:
  Error describe(const Scene& scene, v1::Scene* out) const;
  Error add_scene(std::shared_ptr<Scene> scene, bool replace);
  std::string scene_file(const std::string& id) const;
  std::string snapshot_file(const std::string& name) const;
  void watchdog_loop();
  void checkpoint_loop();
  void wake_checkpoint();
  void stop_background();

  RegistryOptions options_;
  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<Scene>> scenes_;
  uint64_t next_id_ = 1;
  std::atomic<bool> shutting_down_{false};
  int failed_saves_ = 0;
  int open_streams_ = 0;                        // under mu_
  std::map<std::string, int> scene_streams_;    // under mu_

  // Background threads: watchdog and checkpoint writer (bg_mu_ guards the flags).
  std::mutex bg_mu_;
  std::condition_variable bg_cv_;
  bool bg_stop_ = false;
  bool checkpoint_requested_ = false;
  std::thread watchdog_, checkpointer_;
  // Serialises writing and removing files in <data-dir>/scenes/; with what each scene's file
  // holds (the scene and its generation when written).
  std::mutex files_mu_;
  std::map<std::string, std::pair<std::weak_ptr<Scene>, uint64_t>> written_;
};

// Conversions (exposed for tests and the snapshot tools).
Error snapshot_to_proto(const SceneSnapshot& snapshot, v1::Snapshot* out);
Error snapshot_from_proto(const v1::Snapshot& snapshot, int max_threads, int64_t max_vertices,
                          SceneSnapshot* out);

}  // namespace pliant::server
