// SPDX-License-Identifier: Apache-2.0
// Snapshots: a scene's full state as a pliant.v1.Snapshot (checked on the way in like a create
// request) and the data directory's files, written atomically so that a crash leaves the old
// file or the new one: scenes/<id>.snapshot (checkpoints, restored at start) and
// snapshots/<name>.snapshot (SaveSnapshot with a name). Apart from the scene map so that file
// handling has one owner.
#pragma once

#include "pliant/server/error.hpp"
#include "pliant/server/scene.hpp"
#include "pliant/v1/pliant.pb.h"

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace pliant::server {

Error snapshot_to_proto(const SceneSnapshot& snapshot, v1::Snapshot* out);
// model_path: where a cloth body's model_path file is looked up again.
Error snapshot_from_proto(const v1::Snapshot& snapshot, int max_threads, int64_t max_vertices,
                          const std::vector<std::string>& model_path, SceneSnapshot* out);
// Without a model path (a cloth body read from a file cannot be rebuilt).
inline Error snapshot_from_proto(const v1::Snapshot& snapshot, int max_threads, int64_t max_vertices,
                                 SceneSnapshot* out) {
  return snapshot_from_proto(snapshot, max_threads, max_vertices, {}, out);
}

class SnapshotStore {
 public:
  // An empty data_dir: nothing is stored (enabled() is false).
  explicit SnapshotStore(std::string data_dir);

  bool enabled() const { return !dir_.empty(); }
  std::string scene_file(const std::string& id) const;
  std::string named_file(const std::string& name) const;

  // Named snapshots. load_named: NotFound when there is no such name.
  Error save_named(const std::string& name, const v1::Snapshot& snapshot, std::string* path);
  Error load_named(const std::string& name, v1::Snapshot* out) const;
  std::vector<std::string> names() const;  // sorted

  // Reads one snapshot file (NotFound, or InvalidArgument when it is not a Snapshot).
  static Error read(const std::string& path, v1::Snapshot* out);
  // The checkpoint files in scenes/, sorted.
  std::vector<std::string> scene_files() const;
  // Removes the temporary files a crash left mid-write (never loaded).
  void remove_temporaries() const;

  // Checkpoints. Whether `scene`'s file holds its state at `generation` already.
  bool up_to_date(const std::shared_ptr<Scene>& scene, uint64_t generation);
  // Records that the scene's file holds its state at `generation` (restored from it).
  void mark_written(const std::shared_ptr<Scene>& scene, uint64_t generation);
  // Writes a checkpoint unless `still_hosted()`, asked while no other file operation runs, says
  // the scene was deleted or replaced meanwhile (then Ok, nothing written, *written false).
  Error write_checkpoint(const std::shared_ptr<Scene>& scene, uint64_t generation, const std::string& bytes,
                         const std::function<bool()>& still_hosted, bool* written);
  // A deleted scene's checkpoint: removed durably.
  void remove_scene(const std::string& id);
  // Writes every stopped scene's state (at shutdown). Returns how many files were written;
  // *failed counts those that could not be.
  int write_stopped(const std::map<std::string, std::shared_ptr<Scene>>& scenes, int* failed);

 private:
  std::string dir_;
  // Serialises writing and removing files in scenes/; with what each scene's file holds (the
  // scene and its generation when written).
  std::mutex mu_;
  std::map<std::string, std::pair<std::weak_ptr<Scene>, uint64_t>> written_;
};

}  // namespace pliant::server
