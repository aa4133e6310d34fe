// SPDX-License-Identifier: Apache-2.0
// The server's scenes by id: create (model built, method chosen), look up, delete, the limits
// (scenes, streams, grabs, tick time) and the background threads (watchdog, checkpoints). Each
// call takes the API's request message and answers its response; checking and converting the
// messages is spec_proto / stream_proto, files are snapshot_store. The gRPC glue is service.cpp.
#pragma once

#include "pliant/server/scene.hpp"
#include "pliant/server/snapshot_store.hpp"
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
  // Scene limits under mu_: Unavailable when shutting down, AlreadyExists for a taken id
  // (unless `replacing`), ResourceExhausted at --max-scenes.
  Error check_room(const std::string& id, bool replacing) const;
  Error add_scene(std::shared_ptr<Scene> scene, bool replace);
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
  SnapshotStore store_;
};

}  // namespace pliant::server
