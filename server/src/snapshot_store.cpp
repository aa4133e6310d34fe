// SPDX-License-Identifier: Apache-2.0
// Snapshot messages and the data directory's files: the one place that reads, writes and
// removes them, and knows which checkpoint holds which state.
#include "pliant/server/snapshot_store.hpp"

#include "pliant/server/edge.hpp"
#include "pliant/server/spec_proto.hpp"

#include <spdlog/fmt/fmt.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <unistd.h>

namespace fs = std::filesystem;

namespace pliant::server {

namespace {

Error invalid(std::string m) { return Error::invalid(std::move(m)); }

// Writes a temporary file next to `path`, fsyncs it, renames it over `path` and fsyncs the
// directory: after a crash the file is the old one or the new one, never a torn one.
Error write_file_atomically(const std::string& path, const std::string& bytes) {
  static std::atomic<uint64_t> counter{0};
  std::error_code ec;
  const fs::path dir = fs::path(path).parent_path();
  fs::create_directories(dir, ec);
  const std::string tmp = fmt::format("{}.tmp.{}.{}", path, ::getpid(), counter++);
  auto fail = [&](const char* what) {
    const int err = errno;
    ::unlink(tmp.c_str());
    return Error::make(Code::Internal, fmt::format("cannot {} '{}': {}", what, tmp, std::strerror(err)));
  };
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return fail("create");
  for (size_t done = 0; done < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      Error e = fail("write");
      ::close(fd);
      return e;
    }
    done += static_cast<size_t>(n);
  }
  if (::fsync(fd) != 0) {
    Error e = fail("fsync");
    ::close(fd);
    return e;
  }
  if (::close(fd) != 0) return fail("close");
  if (::rename(tmp.c_str(), path.c_str()) != 0) return fail("rename");
  if (const int dfd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dfd >= 0) {
    const int rc = ::fsync(dfd);
    ::close(dfd);
    if (rc != 0) return Error::make(Code::Internal, fmt::format("cannot fsync '{}': {}", dir.string(), std::strerror(errno)));
  }
  return {};
}

// Removes a file and makes the removal durable (fsync of its directory).
void remove_file_durably(const std::string& path) {
  if (::unlink(path.c_str()) != 0) return;
  const fs::path dir = fs::path(path).parent_path();
  if (const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC); dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

}  // namespace

Error snapshot_to_proto(const SceneSnapshot& s, v1::Snapshot* out) {
  const BodyModel& m = *s.model;
  out->set_format_version(1);
  out->set_scene_id(s.id);
  spec_to_proto(s.config, m, out->mutable_spec());
  auto* mesh = out->mutable_mesh();
  mesh->set_name(m.name);
  mesh->mutable_positions()->Reserve(static_cast<int>(3 * m.vertex_count()));
  for (const auto& p : m.rest_positions)
    for (int k = 0; k < 3; ++k) mesh->add_positions(p[k]);
  for (const auto& t : m.tets)
    for (int k = 0; k < 4; ++k) mesh->add_tets(t.v[k]);
  for (size_t i = 0; i < m.fixed.size(); ++i)
    if (m.fixed[i]) out->add_fixed_vertices(static_cast<int32_t>(i));
  for (const auto& p : s.state.x)
    for (int k = 0; k < 3; ++k) out->add_x(p[k]);
  for (const auto& p : s.state.v)
    for (int k = 0; k < 3; ++k) out->add_v(p[k]);
  for (const auto& l : multipliers_per_tet(m, s.state.lambda))  // the state keeps them in solve order
    for (int k = 0; k < 6; ++k) out->add_lambda(l[k]);
  out->set_sim_time(s.state.time);
  out->set_tick(s.tick);
  out->set_paused(s.paused);
  for (const auto& [gid, a] : s.grabs) {
    auto* g = out->add_grabs();
    g->set_grab_id(gid);
    for (int k = 0; k < 4; ++k) {
      if (a.vertices[k] < 0) continue;
      g->add_vertices(a.vertices[k]);
      g->add_weights(a.weights[k]);
    }
    to_proto(a.target, g->mutable_target());
    g->set_compliance(a.compliance);
  }
  out->set_next_grab_id(s.next_grab_id);
  for (size_t b = 0; b < s.body_states.size(); ++b) {
    const ParticleState& st = s.body_states[b];
    auto* pb = out->add_bodies();
    pb->set_name(b < s.config.bodies.size() ? s.config.bodies[b].name : std::string());
    pb->mutable_x()->Reserve(static_cast<int>(3 * st.x.size()));
    for (const auto& x : st.x)
      for (int k = 0; k < 3; ++k) pb->add_x(x[k]);
    pb->mutable_v()->Reserve(static_cast<int>(3 * st.v.size()));
    for (const auto& v : st.v)
      for (int k = 0; k < 3; ++k) pb->add_v(v[k]);
    pb->mutable_lambda()->Add(st.lambda.begin(), st.lambda.end());
    pb->set_time(st.time);
    pb->set_steps(st.steps);
    pb->mutable_solver_order()->Add(st.order.begin(), st.order.end());
    pb->set_substeps(st.substeps);
    for (const EmitterProgress& e : st.emitters) {
      auto* pe = pb->add_emitters();
      pe->set_travelled(e.travelled);
      pe->set_emitted(e.emitted);
    }
    for (const auto& [gid, g] : s.body_grabs) {
      if (g.body != b) continue;
      auto* pg = pb->add_grabs();
      pg->set_grab_id(gid);
      pg->set_particle(static_cast<uint32_t>(g.particle));
      to_proto(g.target, pg->mutable_target());
      pg->set_compliance(g.compliance);
    }
  }
  out->set_saved_unix_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(
                             std::chrono::system_clock::now().time_since_epoch())
                             .count());
  return {};
}

// Ticks and grab ids in a snapshot stay below 2^53: exact as doubles, far from wrapping.
constexpr uint64_t kMaxTick = uint64_t{1} << 53;

Error snapshot_from_proto(const v1::Snapshot& p, int max_threads, int64_t max_vertices,
                          const std::vector<std::string>& model_path, SceneSnapshot* out) {
  if (p.format_version() != 1)
    return invalid(fmt::format("snapshot.format_version {} is not supported (this server reads 1)",
                               p.format_version()));
  TetMesh mesh;
  if (Error e = mesh_from_data(p.mesh(), "snapshot.mesh", max_vertices, &mesh); !e.ok()) return e;
  const size_t nv = mesh.vertices.size(), nt = mesh.tets.size();
  if (static_cast<size_t>(p.x_size()) != 3 * nv || static_cast<size_t>(p.v_size()) != 3 * nv)
    return invalid(fmt::format("snapshot.x/v have {}/{} values, expected {} (3 per vertex)",
                               p.x_size(), p.v_size(), 3 * nv));
  if (static_cast<size_t>(p.lambda_size()) != 6 * nt)
    return invalid(fmt::format("snapshot.lambda has {} values, expected {} (6 per tet)",
                               p.lambda_size(), 6 * nt));
  SceneConfig cfg;
  const auto& spec = p.spec();
  switch (spec.mesh().source_case()) {
    case v1::MeshSource::kModelPath: cfg.mesh_kind = "model_path"; cfg.mesh_name = spec.mesh().model_path(); break;
    case v1::MeshSource::kData: cfg.mesh_kind = "data"; cfg.mesh_name = spec.mesh().data().name(); break;
    default: cfg.mesh_kind = "builtin"; cfg.mesh_name = spec.mesh().builtin(); break;
  }
  cfg.mesh_scale = spec.mesh().has_scale() && spec.mesh().scale() > 0 ? spec.mesh().scale() : 1.0;
  Material material;
  if (Error e = config_from_spec(spec, "snapshot.spec", max_threads, &cfg, &material); !e.ok()) return e;
  if (Error e = bodies_from_spec(spec.bodies(), "snapshot.spec.bodies", model_path, &cfg.bodies); !e.ok()) return e;
  // The bodies' states: one per spec body, named alike (none: the bodies as built).
  std::vector<ParticleState> body_states;
  std::map<uint64_t, ParticleGrab> body_grabs;
  if (p.bodies_size() != 0 && p.bodies_size() != static_cast<int>(cfg.bodies.size()))
    return invalid(fmt::format("snapshot.bodies has {} states, snapshot.spec.bodies {} bodies", p.bodies_size(),
                               cfg.bodies.size()));
  for (int b = 0; b < p.bodies_size(); ++b) {
    const auto& pb = p.bodies(b);
    const std::string f = fmt::format("snapshot.bodies[{}]", b);
    if (pb.name() != cfg.bodies[b].name)
      return invalid(fmt::format("{}.name {} does not match snapshot.spec.bodies[{}].name '{}'", f, echo(pb.name()), b,
                                 cfg.bodies[b].name));
    if (pb.x_size() % 3 != 0 || pb.x_size() != pb.v_size())
      return invalid(fmt::format("{}.x/v have {}/{} values, expected as many, 3 per particle", f, pb.x_size(),
                                 pb.v_size()));
    ParticleState st;
    const size_t n = static_cast<size_t>(pb.x_size()) / 3;
    st.x.resize(n);
    st.v.resize(n);
    for (size_t i = 0; i < n; ++i) {
      st.x[i] = Vec3(pb.x(3 * i), pb.x(3 * i + 1), pb.x(3 * i + 2));
      st.v[i] = Vec3(pb.v(3 * i), pb.v(3 * i + 1), pb.v(3 * i + 2));
      if (!st.x[i].allFinite() || !st.v[i].allFinite())
        return invalid(fmt::format("{}: particle {} has a non-finite position or velocity", f, i));
    }
    st.lambda.assign(pb.lambda().begin(), pb.lambda().end());
    for (size_t i = 0; i < st.lambda.size(); ++i)
      if (!std::isfinite(st.lambda[i])) return invalid(fmt::format("{}.lambda[{}] is not finite", f, i));
    if (!std::isfinite(pb.time()) || pb.time() < 0)
      return invalid(fmt::format("{}.time must be a finite value >= 0 s, got {}", f, pb.time()));
    st.time = pb.time();
    st.steps = pb.steps();
    if (pb.solver_order_size() != 0) {
      if (static_cast<size_t>(pb.solver_order_size()) != n)
        return invalid(fmt::format("{}.solver_order has {} entries, expected {} (one per particle) or none", f,
                                   pb.solver_order_size(), n));
      std::vector<char> seen(n, 0);
      for (size_t k = 0; k < n; ++k) {
        const uint32_t u = pb.solver_order(static_cast<int>(k));
        if (u >= n || seen[u])
          return invalid(fmt::format("{}.solver_order[{}] = {} {} (a permutation of 0..{})", f, k, u,
                                     u >= n ? "is out of range" : "appears twice", n - 1));
        seen[u] = 1;
      }
      st.order.assign(pb.solver_order().begin(), pb.solver_order().end());
    }
    st.substeps = pb.substeps();
    // The emitters' progress: checked against the rebuilt body when the scene sets it.
    if (pb.emitters_size() != 0 && pb.emitters_size() != static_cast<int>(cfg.bodies[b].emitters.size()))
      return invalid(fmt::format("{}.emitters has {} entries, snapshot.spec.bodies[{}] {} emitters", f,
                                 pb.emitters_size(), b, cfg.bodies[b].emitters.size()));
    for (const auto& pe : pb.emitters()) st.emitters.push_back({pe.travelled(), pe.emitted()});
    for (int g = 0; g < pb.grabs_size(); ++g) {
      const auto& pg = pb.grabs(g);
      const std::string gf = fmt::format("{}.grabs[{}]", f, g);
      if (pg.grab_id() == 0 || pg.grab_id() > kMaxTick)
        return invalid(fmt::format("{}.grab_id must be in [1, {}], got {}", gf, kMaxTick, pg.grab_id()));
      if (body_grabs.count(pg.grab_id()))
        return invalid(fmt::format("{}.grab_id = {} appears twice", gf, pg.grab_id()));
      if (pg.particle() >= n)
        return invalid(fmt::format("{}.particle {} is out of range ({} particles)", gf, pg.particle(), n));
      ParticleGrab grab{static_cast<size_t>(b), pg.particle(), from_proto(pg.target()), pg.compliance()};
      if (!grab.target.allFinite() || !std::isfinite(grab.compliance) || grab.compliance < 0)
        return invalid(fmt::format("{}: target must be finite and compliance finite and >= 0", gf));
      body_grabs[pg.grab_id()] = grab;
    }
    body_states.push_back(std::move(st));
  }
  FixedSelection fixed;
  fixed.indices.assign(p.fixed_vertices().begin(), p.fixed_vertices().end());
  std::shared_ptr<const BodyModel> model;
  if (Error e = build_body(mesh, material, fixed, &model); !e.ok()) {
    e.message = "snapshot: " + e.message;
    return e;
  }
  BodyState st;
  st.x.resize(nv);
  st.v.resize(nv);
  st.lambda.resize(nt);
  for (size_t i = 0; i < nv; ++i) {
    st.x[i] = Vec3(p.x(3 * i), p.x(3 * i + 1), p.x(3 * i + 2));
    st.v[i] = Vec3(p.v(3 * i), p.v(3 * i + 1), p.v(3 * i + 2));
  }
  for (size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 6; ++k) st.lambda[t][k] = p.lambda(6 * t + k);
  st.time = p.sim_time();
  st.steps = p.tick();
  if (!is_finite(st)) return invalid("snapshot.x/v contain non-finite values");
  for (size_t t = 0; t < nt; ++t)
    if (!st.lambda[t].allFinite()) return invalid(fmt::format("snapshot.lambda: tet {} has a non-finite value", t));
  st.lambda = multipliers_in_slots(*model, st.lambda);  // per tet -> the model's solve order
  if (!std::isfinite(p.sim_time()) || p.sim_time() < 0)
    return invalid(fmt::format("snapshot.sim_time must be a finite value >= 0 s, got {}", p.sim_time()));
  if (p.tick() > kMaxTick)
    return invalid(fmt::format("snapshot.tick must be at most {}, got {}", kMaxTick, p.tick()));
  if (Error e = check_work(*model, cfg.settings, "snapshot.spec.solver"); !e.ok()) return e;
  // Grabs (absent from snapshots written before they were saved: none).
  std::map<uint64_t, Attachment> grabs;
  for (int i = 0; i < p.grabs_size(); ++i) {
    const auto& g = p.grabs(i);
    const std::string field = fmt::format("snapshot.grabs[{}]", i);
    if (g.grab_id() == 0) return invalid(field + ".grab_id = 0 is not a grab id (ids start at 1)");
    if (g.grab_id() > kMaxTick)
      return invalid(fmt::format("{}.grab_id = {} is larger than {}", field, g.grab_id(), kMaxTick));
    if (grabs.count(g.grab_id()))
      return invalid(fmt::format("{}.grab_id = {} appears twice", field, g.grab_id()));
    if (g.vertices_size() < 1 || g.vertices_size() > 4 || g.weights_size() != g.vertices_size())
      return invalid(fmt::format("{} has {} vertices and {} weights, expected 1 to 4 of each, as many weights as vertices",
                                 field, g.vertices_size(), g.weights_size()));
    Attachment a;
    for (int k = 0; k < g.vertices_size(); ++k) {
      a.vertices[k] = g.vertices(k);
      a.weights[k] = g.weights(k);
    }
    a.target = from_proto(g.target());
    a.compliance = g.compliance();
    if (std::string msg = validate_interaction({a}, {}, *model); !msg.empty()) {
      // validate_interaction names the field "attachments[0]": name the snapshot's instead.
      const std::string prefix = "attachments[0]";
      if (msg.rfind(prefix, 0) == 0) msg = field + msg.substr(prefix.size());
      return invalid(msg);
    }
    grabs.emplace(g.grab_id(), a);
  }
  if (p.next_grab_id() > kMaxTick)
    return invalid(fmt::format("snapshot.next_grab_id = {} is larger than {}", p.next_grab_id(), kMaxTick));
  uint64_t next_grab_id = std::max<uint64_t>(p.next_grab_id(), 1);
  for (const auto& [gid, a] : grabs) next_grab_id = std::max(next_grab_id, gid + 1);
  for (const auto& [gid, g] : body_grabs)
    if (grabs.count(gid))
      return invalid(fmt::format("snapshot.bodies: grab_id {} is also a grab of the tet body", gid));
  out->grabs = std::move(grabs);
  out->next_grab_id = next_grab_id;
  out->body_states = std::move(body_states);
  out->body_grabs = std::move(body_grabs);
  out->id = p.scene_id();
  out->config = std::move(cfg);
  out->model = std::move(model);
  out->state = std::move(st);
  out->tick = p.tick();
  out->paused = p.paused();
  return {};
}

Error SnapshotStore::read(const std::string& path, v1::Snapshot* out) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Error::make(Code::NotFound, fmt::format("snapshot file '{}' not found", path));
  std::stringstream ss;
  ss << f.rdbuf();
  if (!out->ParseFromString(ss.str()))
    return invalid(fmt::format("snapshot file '{}' is not a pliant.v1.Snapshot", path));
  return {};
}

SnapshotStore::SnapshotStore(std::string data_dir) : dir_(std::move(data_dir)) {}

std::string SnapshotStore::scene_file(const std::string& id) const {
  return (fs::path(dir_) / "scenes" / (id + ".snapshot")).string();
}

std::string SnapshotStore::named_file(const std::string& name) const {
  return (fs::path(dir_) / "snapshots" / (name + ".snapshot")).string();
}

namespace {

// The files with extension .snapshot in dir/sub, sorted; none when it cannot be read.
std::vector<fs::path> snapshot_files(const std::string& dir, const char* sub) {
  std::vector<fs::path> files;
  std::error_code ec;
  for (auto it = fs::directory_iterator(fs::path(dir) / sub, ec); !ec && it != fs::directory_iterator();
       it.increment(ec))
    if (it->path().extension() == ".snapshot") files.push_back(it->path());
  std::sort(files.begin(), files.end());
  return files;
}

}  // namespace

Error SnapshotStore::save_named(const std::string& name, const v1::Snapshot& snapshot, std::string* path) {
  *path = named_file(name);
  return write_file_atomically(*path, snapshot.SerializeAsString());
}

Error SnapshotStore::load_named(const std::string& name, v1::Snapshot* out) const {
  const std::string path = named_file(name);
  if (!fs::exists(path))
    return Error::make(Code::NotFound, fmt::format("snapshot name '{}' not found in the data directory", name));
  return read(path, out);
}

std::vector<std::string> SnapshotStore::names() const {
  std::vector<std::string> names;
  if (!enabled()) return names;
  for (const auto& f : snapshot_files(dir_, "snapshots")) names.push_back(f.stem().string());
  return names;
}

std::vector<std::string> SnapshotStore::scene_files() const {
  std::vector<std::string> files;
  if (!enabled()) return files;
  for (const auto& f : snapshot_files(dir_, "scenes")) files.push_back(f.string());
  return files;
}

void SnapshotStore::remove_temporaries() const {
  if (!enabled()) return;
  std::error_code ec;
  for (const char* sub : {"scenes", "snapshots"})
    for (auto it = fs::directory_iterator(fs::path(dir_) / sub, ec); !ec && it != fs::directory_iterator();
         it.increment(ec))
      if (it->path().filename().string().find(".snapshot.tmp.") != std::string::npos) {
        std::error_code removed;
        fs::remove(it->path(), removed);
      }
}

bool SnapshotStore::up_to_date(const std::shared_ptr<Scene>& scene, uint64_t generation) {
  std::lock_guard lk(mu_);
  auto it = written_.find(scene->id());
  return it != written_.end() && it->second.first.lock() == scene && it->second.second == generation;
}

void SnapshotStore::mark_written(const std::shared_ptr<Scene>& scene, uint64_t generation) {
  std::lock_guard lk(mu_);
  written_[scene->id()] = {scene, generation};
}

Error SnapshotStore::write_checkpoint(const std::shared_ptr<Scene>& scene, uint64_t generation,
                                      const std::string& bytes, const std::function<bool()>& still_hosted,
                                      bool* written) {
  *written = false;
  std::lock_guard lk(mu_);
  if (!still_hosted()) return {};  // deleted or replaced meanwhile: its file is not ours to write
  if (Error e = write_file_atomically(scene_file(scene->id()), bytes); !e.ok()) return e;
  written_[scene->id()] = {scene, generation};
  *written = true;
  return {};
}

void SnapshotStore::remove_scene(const std::string& id) {
  if (!enabled()) return;
  std::lock_guard lk(mu_);
  remove_file_durably(scene_file(id));
  written_.erase(id);
}

int SnapshotStore::write_stopped(const std::map<std::string, std::shared_ptr<Scene>>& scenes, int* failed) {
  if (!enabled()) return 0;
  std::lock_guard lk(mu_);
  int written = 0;
  for (auto& [id, s] : scenes) {
    v1::Snapshot proto;
    snapshot_to_proto(s->snapshot_stopped(), &proto);
    if (Error e = write_file_atomically(scene_file(id), proto.SerializeAsString()); !e.ok()) {
      spdlog::error("scene '{}': shutdown snapshot failed: {}", id, e.message);
      ++*failed;
      continue;
    }
    ++written;
  }
  spdlog::info("wrote {} scene snapshot(s) to {}", written, (fs::path(dir_) / "scenes").string());
  return written;
}

}  // namespace pliant::server
