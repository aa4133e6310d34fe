// SPDX-License-Identifier: Apache-2.0
// The grabs one browser socket holds, so that closing the socket (or leaving a scene) releases
// them: a grab left behind would pull the body forever.
#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <set>
#include <string>
#include <utility>

namespace pliant::web {

class GrabSet {
 public:
  using Key = std::pair<std::string, uint64_t>;  // scene id, grab id

  void add(const std::string& scene, uint64_t grab_id) {
    std::lock_guard lock(mu_);
    grabs_.emplace(scene, grab_id);
  }
  bool contains(const std::string& scene, uint64_t grab_id) const {
    std::lock_guard lock(mu_);
    return grabs_.count({scene, grab_id}) > 0;
  }
  // Forgets a grab; false when this socket did not hold it.
  bool remove(const std::string& scene, uint64_t grab_id) {
    std::lock_guard lock(mu_);
    return grabs_.erase({scene, grab_id}) > 0;
  }
  size_t size() const {
    std::lock_guard lock(mu_);
    return grabs_.size();
  }
  // Calls release for every grab (of `scene`, or of all scenes when empty) and forgets them;
  // returns how many it released. release is called without the lock held.
  size_t release_all(const std::function<void(const std::string&, uint64_t)>& release,
                     const std::string& scene = "") {
    std::set<Key> taken;
    {
      std::lock_guard lock(mu_);
      for (auto it = grabs_.begin(); it != grabs_.end();) {
        if (scene.empty() || it->first == scene) {
          taken.insert(*it);
          it = grabs_.erase(it);
        } else {
          ++it;
        }
      }
    }
    for (const auto& [s, id] : taken) release(s, id);
    return taken.size();
  }

 private:
  mutable std::mutex mu_;
  std::set<Key> grabs_;
};

}  // namespace pliant::web
