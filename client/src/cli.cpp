// SPDX-License-Identifier: Apache-2.0
// pliant: the command-line client. Human output by default, --json for scripts.
// Exit codes: 0 ok; 1 the server refused the request (or health is not SERVING);
// 2 usage error; 3 server unreachable or too slow (UNAVAILABLE, DEADLINE_EXCEEDED);
// 4 NOT_FOUND; 5 UNAUTHENTICATED / PERMISSION_DENIED.
#include "pliant/client/client.hpp"
#include "pliant/client/placement.hpp"
#include "pliant/mesh_io.hpp"
#include "pliant/proto/enums.hpp"
#include "pliant/settings.hpp"
#include "pliant/version.hpp"
#include "pliant/vtu_recording.hpp"

#include "cli.hpp"

#include <CLI/CLI.hpp>
#include <google/protobuf/util/json_util.h>
#include <nlohmann/json.hpp>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <climits>
#include <cstdint>
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>
#include <thread>

namespace {

using namespace pliant;
using client::Client;
using client::Status;

constexpr int kExitOk = 0, kExitRefused = 1, kExitUsage = 2, kExitUnreachable = 3, kExitNotFound = 4,
              kExitAuth = 5;

const char* kUsage = R"(usage: pliant [global flags] COMMAND [args]

Commands:
  scenes create [ID] [--spec FILE] [scene flags]
                                     create a scene (ID optional; the server picks one); --spec
                                     reads a SceneSpec in protobuf's JSON mapping (examples/scenes/),
                                     scene flags given beside it override its fields
  scenes list                        list the server's scenes
  scenes get ID                      show one scene
  scenes update ID [scene flags]     change solver settings, material, gravity, dt or mode live
  scenes delete ID                   delete a scene
  scenes reset ID                    back to the rest state at tick 0
  pause ID | resume ID               stop / restart a realtime or as-fast-as-possible scene
  step ID [N]                        advance N ticks (default 1; lockstep or paused scenes)
  force ID --vertices I,J,.. --force FX,FY,FZ [--ticks N]   push vertices for N ticks
  grab ID (--vertex I | --tet T --barycentric B0,B1,B2,B3) [--target X,Y,Z] [--compliance C]
  grab ID --body NAME --vertex I [...]   grab particle I of a particle body
                                     attach a point to a target (default: where it is now)
  move-grab ID GRAB --target X,Y,Z   move a grab's target
  release ID GRAB                    let go
  watch ID [--duration S] [--every N] [--max-rate HZ]
                                     live line: tick, sim time, ticks/s, iterations, residual,
                                     late ticks; ends with a summary (one JSON line with --json)
  snapshot save ID [--name NAME] [--out FILE]
                                     save the scene's full state on the server (--name) and/or
                                     to a local file (--out)
  snapshot restore (--name NAME | --file FILE) [--as ID] [--replace]
  snapshot list                      snapshots in the server's data directory
  record ID --out DIR [--duration S] [--frames N] [--every N] [--max-rate HZ]
                                     stream the scene's frames into DIR as binary .vtu files and
                                     DIR/frames.pvd (simulation time per frame) for ParaView: point
                                     data displacement, velocity (finite differences of consecutive
                                     frames; zero in the first), fixed; cell data det_F; field data
                                     residual; each particle body as its own series
                                     (DIR/body-NAME.pvd). Stops after S seconds, N frames, Ctrl-C
                                     or the end of the stream
  health [--service NAME]            exit 0 when the server is SERVING

Global flags:
  --address HOST:PORT   server (default $PLIANT_ADDRESS or localhost:50051)
  --servers A,B,C       a sharded deployment's servers, in order (docs/deploy.md): commands on a
                        scene go to the server that owns its ID; scenes list asks every server
  --token TOKEN         access token (default $PLIANT_TOKEN)
  --tls                 use TLS with the system roots;  --tls-ca FILE: with these roots
  --timeout S           deadline of each call in seconds (default 30)
  --json                machine-readable output
  --help                this text;   --version   the program's version
Global flags go before or after the command. COMMAND --help lists a command's flags.

Scene flags (create and update):
  --mesh NAME           builtin mesh (beam1 | beam2 | beam3; default beam1) or a file on the
                        server's model path
  --upload FILE         read a mesh locally and send it with the request
  --scale F             scale the mesh coordinates
  --young PA --poisson NU --density KG_M3     material
  --inertia-floor F     inertia of a free vertex at least F x the mean vertex mass (weight
                        unchanged; default 0.1, 0 = plain lumped masses)
  --support-inertia K   inertia of a free vertex at least K x the mass it carries to the
                        fixed vertices (weight unchanged; default 0 = off; 1 holds a stiff
                        body up under a small budget, slower motion near the fixed vertices)
  --model stvk|corotated  strain of the tet constraint (default stvk, the thesis's;
                        corotated resists strong compression, 2-2.2x the cost per iteration)
  --fix I,J,..          fixed vertex indices;   --fix-box X0,Y0,Z0,X1,Y1,Z1   fixed box
  --fix-x-below X       fix every vertex with x <= X (a cantilever's clamped end)
  --fix-file FILE       fix the vertex indices listed in FILE (whitespace or comma separated,
                        '#' starts a comment; read by pliant, sent as indices)
  --fix-group NAME|N    fix the vertices of a physical group of the mesh file (Gmsh .msh: its
                        name or physical tag; resolved by the server), repeatable
  --collider SPEC       a static obstacle, repeatable (create only). SPEC is a shape and
                        key=value parts joined by ':' (vectors as X,Y,Z):
                          plane:point=X,Y,Z:normal=X,Y,Z     solid below the plane
                          box:center=X,Y,Z:half=HX,HY,HZ      axis-aligned box
                          sphere:center=X,Y,Z:radius=R
                        each optionally with :friction=MU (static and dynamic) or
                        :friction=MU_S,MU_D (default 0.5,0.4)
  --rope NAME:from=X,Y,Z:to=X,Y,Z[:segments=N][:density=KG_M][:pin=I,J]
  --cloth NAME:origin=X,Y,Z:size=SX,SY[:resolution=NX,NY][:pin=I,J]
  --fluid NAME:min=X,Y,Z:max=X,Y,Z[:spacing=D][:container=CX,CY,CZ,HX,HY,HZ]
        [:tap=X,Y,Z[:tap-radius=R][:tap-speed=V][:tap-direction=X,Y,Z][:tap-max=N]]
                        (a tap pours particles in as the scene runs; with it min/max may go)
                        particle bodies beside the tet body, repeatable (create only); the
                        other fields take the server's defaults (docs/service.md)
  --gravity GX,GY,GZ    m/s^2 (default 0,-9.81,0)
  --dt S | --rate HZ    tick length (default 1/60 s)
  --mode realtime|lockstep|as-fast-as-possible
  --method xpbd|sor|lambda-sor|chebyshev|anderson|anderson-sor|extrapolation|vbd|newton|auto
                        (auto: the server measures the methods on the body and keeps the most
                        accurate within --time-budget-ms, default half the tick)
  --sweep gauss-seidel|jacobi|sequential   --substeps N   --iterations N   --window M   --omega W
  --newton-linear-solver auto|direct|cg|cg-jacobi|cg-factor|cg-twolevel
                        how newton solves each iteration (cg-twolevel, what cg uses on a large
                        body: vertex blocks plus a coarse solve; cg-factor: an earlier
                        factorisation whatever the size; docs/solver.md)
  --tolerance T         --time-budget-ms MS    --threads N     --paused (create paused)
  --wave-courant C      let the server pick the substeps: the fewest with a pressure wave
                        crossing at most C elements per substep (0.3 resolves the material)

Exit codes: 0 ok, 1 refused by the server, 2 usage, 3 server unreachable, 4 not found,
5 authentication.
)";

struct Usage : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// One command's arguments as CLI11 parsed them: positionals in order (for `scenes X` and
// `snapshot X` the subcommand word first), --flag values by name without "--".
struct Args {
  std::vector<std::string> positional;
  std::map<std::string, std::string> flags;
  std::map<std::string, std::vector<std::string>> repeated;  // flags that may be given several times

  std::vector<std::string> get_all(const std::string& f) const {
    auto it = repeated.find(f);
    return it == repeated.end() ? std::vector<std::string>{} : it->second;
  }
  // Positionals beyond `n` are a usage error (a typo must not be silently ignored).
  void max_positional(size_t n, const std::string& command) const {
    if (positional.size() > n)
      throw Usage(command + ": unexpected argument '" + positional[n] + "'");
  }
  bool has(const std::string& f) const { return flags.count(f) > 0; }
  std::optional<std::string> get(const std::string& f) const {
    auto it = flags.find(f);
    if (it == flags.end()) return std::nullopt;
    return it->second;
  }
};

double to_double(const std::string& flag, const std::string& v) {
  try {
    size_t pos = 0;
    double d = std::stod(v, &pos);
    if (pos == v.size() && std::isfinite(d)) return d;
  } catch (...) {
  }
  throw Usage("--" + flag + " needs a number, got '" + v + "'");
}

long long to_int(const std::string& flag, const std::string& v, long long lo = INT32_MIN, long long hi = INT32_MAX) {
  long long d = 0;
  bool ok = false;
  try {
    size_t pos = 0;
    d = std::stoll(v, &pos);
    ok = pos == v.size();
  } catch (...) {
  }
  if (!ok) throw Usage("--" + flag + " needs an integer, got '" + v + "'");
  if (d < lo || d > hi)
    throw Usage("--" + flag + " must be in [" + std::to_string(lo) + ", " + std::to_string(hi) + "], got " + v);
  return d;
}

std::vector<double> to_doubles(const std::string& flag, const std::string& v, size_t n) {
  std::vector<double> out;
  std::stringstream ss(v);
  for (std::string item; std::getline(ss, item, ',');) out.push_back(to_double(flag, item));
  if (n && out.size() != n)
    throw Usage("--" + flag + " needs " + std::to_string(n) + " comma-separated numbers, got '" + v + "'");
  return out;
}

std::vector<int32_t> to_ints(const std::string& flag, const std::string& v) {
  std::vector<int32_t> out;
  std::stringstream ss(v);
  for (std::string item; std::getline(ss, item, ',');)
    out.push_back(static_cast<int32_t>(to_int(flag, item, 0, INT32_MAX)));
  if (out.empty()) throw Usage("--" + flag + " needs comma-separated integers");
  return out;
}

void set_vec(v1::Vec3* out, const std::vector<double>& v) {
  out->set_x(v[0]);
  out->set_y(v[1]);
  out->set_z(v[2]);
}

std::string json_of(const google::protobuf::Message& m) {
  google::protobuf::util::JsonPrintOptions o;
  o.preserve_proto_field_names = true;
  o.always_print_primitive_fields = true;
  std::string s;
  (void)google::protobuf::util::MessageToJsonString(m, &s, o);
  return s;
}

int exit_code_for(const Status& s) {
  switch (s.code) {
    case 0: return kExitOk;
    case 14: case 4: return kExitUnreachable;  // UNAVAILABLE, DEADLINE_EXCEEDED
    case 5: return kExitNotFound;
    case 16: case 7: return kExitAuth;
    default: return kExitRefused;
  }
}

int fail(const Status& s, const client::ConnectOptions& o) {
  std::fprintf(stderr, "pliant: %s\n", s.to_string().c_str());
  if (s.code == 14)
    std::fprintf(stderr, "pliant: is pliant-server running at %s? (set --address or PLIANT_ADDRESS)\n",
                 o.address.c_str());
  if (s.code == 16) std::fprintf(stderr, "pliant: pass the server's token with --token or PLIANT_TOKEN\n");
  return exit_code_for(s);
}

std::string_view state_name(v1::SceneState s) {
  switch (s) {
    case v1::SCENE_STATE_RUNNING: return "running";
    case v1::SCENE_STATE_PAUSED: return "paused";
    case v1::SCENE_STATE_LOCKSTEP: return "lockstep";
    default: return "?";
  }
}

std::string mesh_name(const v1::MeshSource& m) {
  if (m.has_data()) return m.data().name() + " (uploaded)";
  if (!m.model_path().empty()) return m.model_path();
  return m.builtin();
}

void print_scene_line(const v1::Scene& s) {
  std::printf("%-16s %-9s tick %-9llu t %9.3f s  %6u vertices %7u tets  %-12s %7.1f ticks/s  late %llu%s\n",
              s.scene_id().c_str(), std::string(state_name(s.state())).c_str(),
              static_cast<unsigned long long>(s.tick()), s.sim_time(), s.vertex_count(), s.tet_count(),
              mesh_name(s.spec().mesh()).c_str(), s.ticks_per_second(),
              static_cast<unsigned long long>(s.late_ticks()),
              s.pause_reason().empty() ? "" : ("  (" + s.pause_reason() + ")").c_str());
}

void print_scene(const v1::Scene& s, bool json) {
  if (json) {
    std::printf("%s\n", json_of(s).c_str());
    return;
  }
  const auto& sp = s.spec();
  const auto& so = sp.solver();
  std::printf("scene      %s (%s)\n", s.scene_id().c_str(), std::string(state_name(s.state())).c_str());
  std::printf("mesh       %s: %u vertices, %u tets, %u surface triangles\n", mesh_name(sp.mesh()).c_str(),
              s.vertex_count(), s.tet_count(), s.surface_triangle_count());
  std::printf("material   E %g Pa, nu %g, rho %g kg/m^3, %s\n", sp.material().young_modulus(),
              sp.material().poisson_ratio(), sp.material().density(),
              sp.material().model() == v1::ELASTIC_MODEL_COROTATED ? "corotated" : "stvk");
  std::printf("tick       dt %g s (%g Hz), %s\n", sp.tick().dt(), 1.0 / sp.tick().dt(),
              v1::TickMode_Name(sp.tick().mode()).c_str());
  std::printf("solver     %s, %s, %d substeps x %d iterations, window %d, omega %g, tolerance %g, budget %g ms\n",
              v1::Method_Name(so.method()).c_str(), v1::Sweep_Name(so.sweep()).c_str(), so.substeps(),
              so.iterations(), so.window(), so.omega(), so.tolerance(), so.time_budget_ms());
  if (so.method() == v1::METHOD_NEWTON)
    std::printf("linear     %s\n", v1::NewtonLinearSolver_Name(so.newton_linear_solver()).c_str());
  if (!s.method_choice().empty()) std::printf("auto       chose %s\n", s.method_choice().c_str());
  std::printf("gravity    (%g, %g, %g) m/s^2\n", sp.gravity().x(), sp.gravity().y(), sp.gravity().z());
  for (int i = 0; i < sp.colliders_size(); ++i) {
    const v1::Collider& c = sp.colliders(i);
    const char* label = i == 0 ? "colliders " : "          ";
    auto v = [](const v1::Vec3& p) {
      char b[96];
      std::snprintf(b, sizeof b, "(%g, %g, %g)", p.x(), p.y(), p.z());
      return std::string(b);
    };
    std::string shape;
    if (c.has_plane()) shape = "plane through " + v(c.plane().point()) + ", normal " + v(c.plane().normal());
    else if (c.has_sphere()) {
      char r[48];
      std::snprintf(r, sizeof r, "%g", c.sphere().radius());
      shape = "sphere at " + v(c.sphere().center()) + ", radius " + r;
    }
    else if (c.has_box()) shape = "box at " + v(c.box().center()) + ", half extent " + v(c.box().half_extent());
    std::printf("%s %s, friction %g / %g\n", label, shape.c_str(), c.static_friction(), c.dynamic_friction());
  }
  std::printf("inertia    floor %g of the mean vertex mass, support %g of the mass carried to the fixed vertices: "
              "%u vertices raised, +%.4g%% inertia\n",
              sp.material().inertia_floor(), sp.material().support_inertia(), s.floored_vertices(),
              100 * s.added_inertia());
  // What the number means with this many iterations (a rough guide measured on the beams,
  // docs/solver.md): under_resolution = wave_courant_number / sqrt(iterations).
  const double co = s.wave_courant_number();
  const double u = under_resolution(co, so.iterations());
  const bool projection = so.method() != v1::METHOD_NEWTON && so.method() != v1::METHOD_VBD;
  const char* meaning = !projection ? "(a guide for constraint projection only)"
                        : sp.material().poisson_ratio() > kUnderResolutionMaxPoisson
                            ? "not interpreted for nu above 0.45 (calibrated at 0.4)"
                        : u > 1   ? "clearly softer than the material"
                        : u > 0.3 ? "softer than the material by a few % to ~30%"
                                  : "close to the material (2-5% on the beams)";
  std::printf("resolution a pressure wave crosses %.2g elements per substep (wave_courant_number); over\n"
              "           sqrt(iterations): %.2g, %s\n", co, u, meaning);
  std::printf("progress   tick %llu, t %.4f s, %.1f ticks/s, late %llu, skipped %llu, rollbacks %llu\n",
              static_cast<unsigned long long>(s.tick()), s.sim_time(), s.ticks_per_second(),
              static_cast<unsigned long long>(s.late_ticks()), static_cast<unsigned long long>(s.skipped_ticks()),
              static_cast<unsigned long long>(s.rollbacks()));
  if (!s.pause_reason().empty()) std::printf("paused     %s\n", s.pause_reason().c_str());
  for (int i = 0; i < s.bodies_size(); ++i) {
    const v1::BodySummary& b = s.bodies(i);
    std::printf("%s %s: %s, %u particles", i == 0 ? "bodies    " : "          ", b.name().c_str(), b.kind().c_str(),
                b.particle_count());
    if (b.max_particle_count() > b.particle_count()) std::printf(" (up to %u)", b.max_particle_count());
    if (b.triangle_count()) std::printf(", %u triangles", b.triangle_count());
    if (b.pinned_count()) std::printf(", %u pinned", b.pinned_count());
    std::printf("\n");
  }
}

// "rope (rope, 21 particles), water (fluid, 512 particles)"
std::string bodies_line(const v1::Scene& s) {
  std::string out;
  for (const v1::BodySummary& b : s.bodies())
    out += (out.empty() ? "" : ", ") + b.name() + " (" + b.kind() + ", " + std::to_string(b.particle_count()) +
           " particles)";
  return out;
}

// "HEAD:key=value:key=value" (the compact specs of --collider, --rope, --cloth, --fluid): the
// head, then each key once; take() hands a key's numbers over (n of them, 0: any number) and
// finish() refuses keys nobody took. Errors start with `flag`.
struct CompactSpec {
  CompactSpec(const std::string& text, std::string flag) : flag_(std::move(flag)) {
    std::vector<std::string> parts;
    std::stringstream ss(text);
    for (std::string part; std::getline(ss, part, ':');) parts.push_back(part);
    if (!parts.empty()) head = parts[0];
    for (size_t i = 1; i < parts.size(); ++i) {
      const size_t eq = parts[i].find('=');
      if (eq == std::string::npos || eq == 0) throw Usage(flag_ + ": '" + parts[i] + "' is not key=value");
      const std::string key = parts[i].substr(0, eq);
      if (kv_.count(key)) throw Usage(flag_ + ": " + key + " given twice");
      kv_[key] = parts[i].substr(eq + 1);
    }
  }
  std::optional<std::vector<double>> take(const std::string& key, size_t n) {
    auto it = kv_.find(key);
    if (it == kv_.end()) return std::nullopt;
    std::vector<double> v;
    try {
      v = to_doubles(key, it->second, n);
    } catch (const Usage& u) {
      throw Usage(flag_ + ": " + std::string(u.what()).substr(2));  // "key needs ..."
    }
    kv_.erase(it);
    return v;
  }
  // `what`: named in the message ("unknown key 'k' for a box").
  void finish(const std::string& what = "") const {
    if (!kv_.empty())
      throw Usage(flag_ + ": unknown key '" + kv_.begin()->first + "'" + (what.empty() ? "" : " for a " + what));
  }
  std::string head;

 private:
  std::string flag_;
  std::map<std::string, std::string> kv_;
};

// --rope / --cloth / --fluid SPEC: "NAME:key=value:key=value" (see the flags' help), a compact
// form of the SceneSpec's bodies; every other field takes the server's default.
v1::BodySpec parse_body(const std::string& kind, const std::string& text) {
  const std::string flag = "--" + kind + " '" + text + "'";
  CompactSpec spec(text, flag);
  if (spec.head.empty() || spec.head.find('=') != std::string::npos)
    throw Usage(flag + ": start with the body's name (NAME:key=value:...)");
  auto take = [&](const std::string& key, size_t n) { return spec.take(key, n); };
  auto need = [&](const std::string& key, size_t n) {
    auto v = take(key, n);
    if (!v) throw Usage(flag + ": a " + kind + " needs " + key + "=");
    return *v;
  };
  auto pins = [&](v1::ParticlePins* p) {
    if (auto v = take("pin", 0))
      for (double i : *v) {
        if (i < 0 || i != std::floor(i)) throw Usage(flag + ": pin needs particle indices I,J,..");
        p->add_indices(static_cast<uint32_t>(i));
      }
  };
  v1::BodySpec b;
  b.set_name(spec.head);
  if (kind == "rope") {
    auto* r = b.mutable_rope();
    set_vec(r->add_points(), need("from", 3));
    set_vec(r->add_points(), need("to", 3));
    const double n = take("segments", 1).value_or(std::vector<double>{20})[0];
    if (n < 1 || n != std::floor(n)) throw Usage(flag + ": segments needs a whole number >= 1");
    r->set_segments(static_cast<uint32_t>(n));
    if (auto v = take("density", 1)) r->set_linear_density((*v)[0]);
    pins(r->mutable_pins());
  } else if (kind == "cloth") {
    auto* g = b.mutable_cloth()->mutable_grid();
    set_vec(g->mutable_origin(), need("origin", 3));
    const auto size = need("size", 2);
    g->set_size_x(size[0]);
    g->set_size_y(size[1]);
    const auto res = take("resolution", 2).value_or(std::vector<double>{16, 16});
    if (res[0] < 0 || res[1] < 0) throw Usage(flag + ": resolution needs NX,NY");
    g->set_resolution_x(static_cast<uint32_t>(res[0]));
    g->set_resolution_y(static_cast<uint32_t>(res[1]));
    pins(b.mutable_cloth()->mutable_pins());
  } else {
    auto* f = b.mutable_fluid();
    // A block, a tap (an emitter) or both.
    auto tap = take("tap", 3);
    auto lo = take("min", 3), hi = take("max", 3);
    if (lo || hi || !tap) {
      if (!lo || !hi) throw Usage(flag + ": a fluid needs min= and max= (a block) or tap= (an emitter)");
      auto* blk = f->add_blocks();
      set_vec(blk->mutable_min(), *lo);
      set_vec(blk->mutable_max(), *hi);
    }
    if (tap) {
      auto* e = f->add_emitters();
      set_vec(e->mutable_center(), *tap);
      e->set_radius(take("tap-radius", 1).value_or(std::vector<double>{0.03})[0]);
      e->set_speed(take("tap-speed", 1).value_or(std::vector<double>{1.0})[0]);
      if (auto d = take("tap-direction", 3)) set_vec(e->mutable_direction(), *d);
      if (auto m = take("tap-max", 1)) {
        if ((*m)[0] < 1 || (*m)[0] != std::floor((*m)[0])) throw Usage(flag + ": tap-max needs a whole number >= 1");
        e->set_max_particles(static_cast<uint32_t>((*m)[0]));
      }
    }
    if (auto v = take("spacing", 1)) f->set_spacing((*v)[0]);
    if (auto v = take("container", 6)) {
      auto* box = f->mutable_container()->mutable_box();
      set_vec(box->mutable_center(), {(*v)[0], (*v)[1], (*v)[2]});
      set_vec(box->mutable_half_extent(), {(*v)[3], (*v)[4], (*v)[5]});
    }
  }
  spec.finish();
  return b;
}

// --collider SPEC: "shape:key=value:key=value", vectors as X,Y,Z (see the usage text).
v1::Collider parse_collider(const std::string& text) {
  CompactSpec spec(text, "--collider '" + text + "'");
  if (spec.head.empty() && text.empty()) throw Usage("--collider needs a shape (plane, box, sphere), got ''");
  const std::string shape = spec.head;
  auto take = [&](const std::string& key, size_t n) { return spec.take(key, n); };
  auto need = [&](const std::string& key, size_t n) {
    auto v = take(key, n);
    if (!v) throw Usage("--collider '" + text + "': " + shape + " needs " + key + "=");
    return *v;
  };
  v1::Collider c;
  if (shape == "plane") {
    set_vec(c.mutable_plane()->mutable_point(), need("point", 3));
    set_vec(c.mutable_plane()->mutable_normal(), need("normal", 3));
  } else if (shape == "box") {
    set_vec(c.mutable_box()->mutable_center(), need("center", 3));
    set_vec(c.mutable_box()->mutable_half_extent(), need("half", 3));
  } else if (shape == "sphere") {
    set_vec(c.mutable_sphere()->mutable_center(), need("center", 3));
    c.mutable_sphere()->set_radius(need("radius", 1)[0]);
  } else {
    throw Usage("--collider '" + text + "': shape '" + shape + "' is not one of plane, box, sphere");
  }
  if (auto mu = take("friction", 0)) {
    if (mu->size() == 1) {
      c.set_static_friction((*mu)[0]);
      c.set_dynamic_friction((*mu)[0]);
    } else if (mu->size() == 2) {
      c.set_static_friction((*mu)[0]);
      c.set_dynamic_friction((*mu)[1]);
    } else {
      throw Usage("--collider '" + text + "': friction needs MU or MU_STATIC,MU_DYNAMIC");
    }
  }
  spec.finish(shape);
  return c;
}

// --fix-file FILE: vertex indices separated by whitespace or commas; '#' to the end of a line
// is a comment.
std::vector<int32_t> read_node_set(const std::string& path) {
  std::ifstream f(path);
  if (!f) throw Usage("--fix-file '" + path + "' cannot be read");
  std::vector<int32_t> out;
  std::string line;
  for (int lineno = 1; std::getline(f, line); ++lineno) {
    if (auto hash = line.find('#'); hash != std::string::npos) line.resize(hash);
    std::replace(line.begin(), line.end(), ',', ' ');
    std::stringstream ls(line);
    for (std::string item; ls >> item;) {
      long long v = -1;
      try {
        size_t pos = 0;
        v = std::stoll(item, &pos);
        if (pos != item.size()) v = -1;
      } catch (...) {
        v = -1;
      }
      if (v < 0 || v > INT32_MAX)
        throw Usage("--fix-file '" + path + "' line " + std::to_string(lineno) + ": '" + item +
                    "' is not a vertex index (an integer >= 0)");
      out.push_back(static_cast<int32_t>(v));
    }
  }
  if (out.empty()) throw Usage("--fix-file '" + path + "' lists no vertex index");
  return out;
}

// --spec FILE: a SceneSpec in protobuf's JSON mapping (field names as in the .proto or in
// lowerCamelCase). Unknown fields are errors, named with their path.
void read_spec_file(const std::string& path, v1::SceneSpec* spec) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw Usage("--spec '" + path + "' cannot be read");
  std::stringstream text;
  text << f.rdbuf();
  google::protobuf::util::JsonParseOptions o;
  o.ignore_unknown_fields = false;
  auto st = google::protobuf::util::JsonStringToMessage(text.str(), spec, o);
  if (!st.ok()) {
    std::string msg(st.message());
    std::replace(msg.begin(), msg.end(), '\n', ' ');
    throw Usage("--spec '" + path + "': not a pliant.v1.SceneSpec: " + msg);
  }
}

// Scene flags shared by create and update. Returns whether any was given.
bool read_settings(Args& a, v1::SolverSettings* so, v1::TickSettings* tick, v1::Material* mat,
                   v1::Vec3* gravity, bool* gravity_set) {
  bool any = false;
  auto num = [&](const char* f, auto setter) {
    if (auto v = a.get(f)) {
      setter(to_double(f, *v));
      any = true;
    }
  };
  auto integer = [&](const char* f, auto setter) {
    if (auto v = a.get(f)) {
      setter(to_int(f, *v));
      any = true;
    }
  };
  if (auto v = a.get("method")) {
    auto m = parse_method(*v);
    if (!m) throw Usage("--method '" + *v + "' is not one of " + std::string(method_names()));
    so->set_method(proto::method_to(*m));
    any = true;
  }
  if (auto v = a.get("newton-linear-solver")) {
    auto l = parse_newton_linear_solver(*v);
    if (!l) throw Usage("--newton-linear-solver '" + *v + "' is not one of auto|direct|cg|cg-jacobi|cg-factor|cg-twolevel");
    so->set_newton_linear_solver(proto::newton_linear_solver_to(*l));
    any = true;
  }
  if (auto v = a.get("sweep")) {
    auto s = parse_sweep(*v);
    if (!s) throw Usage("--sweep '" + *v + "' is not one of " + std::string(sweep_names()));
    so->set_sweep(proto::sweep_to(*s));
    any = true;
  }
  integer("substeps", [&](long long x) { so->set_substeps(static_cast<int32_t>(x)); });
  integer("iterations", [&](long long x) { so->set_iterations(static_cast<int32_t>(x)); });
  integer("window", [&](long long x) { so->set_window(static_cast<int32_t>(x)); });
  integer("threads", [&](long long x) { so->set_threads(static_cast<int32_t>(x)); });
  num("omega", [&](double x) { so->set_omega(x); });
  num("tolerance", [&](double x) { so->set_tolerance(x); });
  num("time-budget-ms", [&](double x) { so->set_time_budget_ms(x); });
  num("wave-courant", [&](double x) { so->set_target_wave_courant_number(x); });
  num("dt", [&](double x) { tick->set_dt(x); });
  num("rate", [&](double x) {
    if (x <= 0) throw Usage("--rate must be > 0 Hz");
    tick->set_dt(1.0 / x);
  });
  if (auto v = a.get("mode")) {
    if (*v == "realtime") tick->set_mode(v1::TICK_MODE_REALTIME);
    else if (*v == "lockstep") tick->set_mode(v1::TICK_MODE_LOCKSTEP);
    else if (*v == "as-fast-as-possible" || *v == "afap") tick->set_mode(v1::TICK_MODE_AS_FAST_AS_POSSIBLE);
    else throw Usage("--mode '" + *v + "' is not one of realtime, lockstep, as-fast-as-possible");
    any = true;
  }
  num("young", [&](double x) { mat->set_young_modulus(x); });
  num("poisson", [&](double x) { mat->set_poisson_ratio(x); });
  num("density", [&](double x) { mat->set_density(x); });
  num("inertia-floor", [&](double x) { mat->set_inertia_floor(x); });
  num("support-inertia", [&](double x) { mat->set_support_inertia(x); });
  if (auto v = a.get("model")) {
    if (*v == "stvk") mat->set_model(v1::ELASTIC_MODEL_STVK);
    else if (*v == "corotated") mat->set_model(v1::ELASTIC_MODEL_COROTATED);
    else throw Usage("--model '" + *v + "' is not one of stvk, corotated");
    any = true;
  }
  if (auto v = a.get("gravity")) {
    set_vec(gravity, to_doubles("gravity", *v, 3));
    *gravity_set = true;
    any = true;
  }
  return any;
}

int cmd_scenes(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("scenes needs a subcommand: create | list | get | update | delete | reset");
  const std::string sub = a.positional[0];
  auto need_id = [&]() -> std::string {
    if (a.positional.size() < 2) throw Usage("scenes " + sub + " needs a scene ID");
    a.max_positional(2, "scenes " + sub);
    return a.positional[1];
  };
  if (sub == "create") {
    a.max_positional(2, "scenes create");
    v1::CreateSceneRequest req;
    if (a.positional.size() >= 2) req.set_scene_id(a.positional[1]);
    auto* spec = req.mutable_spec();
    if (auto file = a.get("spec")) read_spec_file(*file, spec);
    const bool spec_has_gravity = spec->has_gravity();
    bool gravity_set = false;
    read_settings(a, spec->mutable_solver(), spec->mutable_tick(), spec->mutable_material(),
                  spec->mutable_gravity(), &gravity_set);
    if (!gravity_set && !spec_has_gravity) spec->clear_gravity();
    auto mesh = a.get("mesh");
    auto upload = a.get("upload");
    if (mesh && upload) throw Usage("give --mesh or --upload, not both");
    const bool keep_spec_mesh = !mesh && !upload && spec->mesh().source_case() != v1::MeshSource::SOURCE_NOT_SET;
    if (upload) {
      TetMesh m;
      try {
        m = resolve_mesh(*upload, default_model_path());
      } catch (const std::exception& e) {
        std::fprintf(stderr, "pliant: --upload %s: %s\n", upload->c_str(), e.what());
        return kExitUsage;
      }
      auto* d = spec->mutable_mesh()->mutable_data();
      d->set_name(m.name);
      for (const auto& p : m.vertices)
        for (int k = 0; k < 3; ++k) d->add_positions(p[k]);
      for (const auto& t : m.tets)
        for (int k = 0; k < 4; ++k) d->add_tets(t[k]);
    } else if (!keep_spec_mesh) {
      std::string name = mesh.value_or("beam1");
      if (name == "beam1" || name == "beam2" || name == "beam3") spec->mutable_mesh()->set_builtin(name);
      else spec->mutable_mesh()->set_model_path(name);
    }
    if (auto v = a.get("scale")) spec->mutable_mesh()->set_scale(to_double("scale", *v));
    if (auto v = a.get("fix")) for (int32_t i : to_ints("fix", *v)) spec->mutable_fixed()->add_indices(i);
    if (auto v = a.get("fix-box")) {
      auto b = to_doubles("fix-box", *v, 6);
      auto* box = spec->mutable_fixed()->add_boxes();
      set_vec(box->mutable_min(), {b[0], b[1], b[2]});
      set_vec(box->mutable_max(), {b[3], b[4], b[5]});
    }
    if (auto v = a.get("fix-x-below")) {
      client::clamp_below_x(*spec, to_double("fix-x-below", *v));
    }
    if (auto v = a.get("fix-file")) for (int32_t i : read_node_set(*v)) spec->mutable_fixed()->add_indices(i);
    for (const std::string& g : a.get_all("fix-group")) {
      if (g.empty()) throw Usage("--fix-group needs a physical group name or number, got ''");
      spec->mutable_fixed()->add_groups(g);
    }
    for (const std::string& c : a.get_all("collider")) *spec->add_colliders() = parse_collider(c);
    for (const char* kind : {"rope", "cloth", "fluid"})
      for (const std::string& b : a.get_all(kind)) *spec->add_bodies() = parse_body(kind, b);
    if (a.has("paused")) spec->set_start_paused(true);
    auto r = c.create_scene(req);
    if (!r.ok()) return fail(r.status, c.options());
    if (json) print_scene(*r, true);
    else std::printf("created scene %s\n", r->scene_id().c_str());
    return kExitOk;
  }
  if (sub == "list") {
    a.max_positional(1, "scenes list");
    auto r = c.list_scenes();
    if (!r.ok()) return fail(r.status, c.options());
    if (json) {
      v1::ListScenesResponse l;
      for (auto& s : r.value) *l.add_scenes() = s;
      std::printf("%s\n", json_of(l).c_str());
    } else if (r->empty()) {
      std::printf("no scenes\n");
    } else {
      for (auto& s : r.value) print_scene_line(s);
    }
    return kExitOk;
  }
  if (sub == "update") {
    v1::UpdateSceneRequest req;
    req.set_scene_id(need_id());
    bool gravity_set = false;
    bool any = read_settings(a, req.mutable_solver(), req.mutable_tick(), req.mutable_material(),
                             req.mutable_gravity(), &gravity_set);
    if (!gravity_set) req.clear_gravity();
    if (!any) throw Usage("scenes update needs at least one setting (e.g. --method anderson-sor)");
    auto r = c.update_scene(req);
    if (!r.ok()) return fail(r.status, c.options());
    print_scene(*r, json);
    return kExitOk;
  }
  if (sub == "get" || sub == "reset") {
    std::string id = need_id();
    auto r = sub == "get" ? c.get_scene(id) : c.reset_scene(id);
    if (!r.ok()) return fail(r.status, c.options());
    if (sub == "reset" && !json) std::printf("reset scene %s\n", id.c_str());
    else print_scene(*r, json);
    return kExitOk;
  }
  if (sub == "delete") {
    std::string id = need_id();
    Status s = c.delete_scene(id);
    if (!s.ok()) return fail(s, c.options());
    if (json) std::printf("%s\n", nlohmann::json{{"deleted", id}}.dump().c_str());
    else std::printf("deleted scene %s\n", id.c_str());
    return kExitOk;
  }
  throw Usage("unknown subcommand 'scenes " + sub + "' (create | list | get | update | delete | reset)");
}

int cmd_pause_resume(Client& c, Args& a, bool json, bool pause) {
  if (a.positional.empty()) throw Usage(std::string(pause ? "pause" : "resume") + " needs a scene ID");
  a.max_positional(1, pause ? "pause" : "resume");
  auto r = pause ? c.pause_scene(a.positional[0]) : c.resume_scene(a.positional[0]);
  if (!r.ok()) return fail(r.status, c.options());
  if (json) print_scene(*r, true);
  else std::printf("%s scene %s at tick %llu\n", pause ? "paused" : "resumed", r->scene_id().c_str(),
                   static_cast<unsigned long long>(r->tick()));
  return kExitOk;
}

int cmd_step(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("step needs a scene ID");
  long long n = 1;
  a.max_positional(2, "step");
  if (a.positional.size() >= 2) n = to_int("ticks", a.positional[1], 1, UINT32_MAX);
  if (auto v = a.get("ticks")) n = to_int("ticks", *v, 1, UINT32_MAX);
  if (n < 1) throw Usage("step: the number of ticks must be >= 1");
  auto r = c.step(a.positional[0], static_cast<uint32_t>(n));
  if (!r.ok()) return fail(r.status, c.options());
  if (json) std::printf("%s\n", json_of(*r).c_str());
  else std::printf("scene %s at tick %llu, t %.6f s%s\n", a.positional[0].c_str(),
                   static_cast<unsigned long long>(r->tick()), r->sim_time(),
                   r->rollbacks() ? (" (" + std::to_string(r->rollbacks()) + " rollbacks)").c_str() : "");
  return kExitOk;
}

int cmd_force(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("force needs a scene ID");
  a.max_positional(1, "force");
  v1::ApplyForceRequest req;
  req.set_scene_id(a.positional[0]);
  auto v = a.get("vertices");
  auto f = a.get("force");
  if (!v || !f) throw Usage("force needs --vertices I,J,.. and --force FX,FY,FZ");
  for (int32_t i : to_ints("vertices", *v)) req.add_vertices(i);
  set_vec(req.mutable_force(), to_doubles("force", *f, 3));
  if (auto t = a.get("ticks")) req.set_ticks(static_cast<uint32_t>(to_int("ticks", *t, 1, UINT32_MAX)));
  auto r = c.apply_force(req);
  if (!r.ok()) return fail(r.status, c.options());
  if (json) std::printf("%s\n", json_of(*r).c_str());
  else std::printf("force applied from tick %llu\n", static_cast<unsigned long long>(r->first_tick()));
  return kExitOk;
}

int cmd_grab(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("grab needs a scene ID");
  a.max_positional(1, "grab");
  v1::GrabRequest req;
  req.set_scene_id(a.positional[0]);
  auto v = a.get("vertex");
  auto t = a.get("tet");
  if (!v == !t) throw Usage("grab needs --vertex I, or --tet T with --barycentric B0,B1,B2,B3");
  if (v) req.set_vertex(to_int("vertex", *v));
  if (auto b = a.get("body")) {
    if (t) throw Usage("grab --body takes --vertex I (a particle index), not --tet");
    req.set_body(*b);
  }
  if (t) {
    req.mutable_tet_point()->set_tet(to_int("tet", *t));
    auto b = a.get("barycentric");
    if (!b) throw Usage("grab --tet needs --barycentric B0,B1,B2,B3");
    for (double x : to_doubles("barycentric", *b, 4)) req.mutable_tet_point()->add_barycentric(x);
  }
  if (auto g = a.get("target")) set_vec(req.mutable_target(), to_doubles("target", *g, 3));
  if (auto k = a.get("compliance")) req.set_compliance(to_double("compliance", *k));
  auto r = c.grab(req);
  if (!r.ok()) return fail(r.status, c.options());
  if (json) std::printf("%s\n", json_of(*r).c_str());
  else std::printf("grab %llu from tick %llu\n", static_cast<unsigned long long>(r->grab_id()),
                   static_cast<unsigned long long>(r->first_tick()));
  return kExitOk;
}

int cmd_move_grab(Client& c, Args& a, bool json) {
  if (a.positional.size() < 2) throw Usage("move-grab needs a scene ID and a grab id");
  a.max_positional(2, "move-grab");
  v1::MoveGrabRequest req;
  req.set_scene_id(a.positional[0]);
  req.set_grab_id(static_cast<uint64_t>(to_int("grab id", a.positional[1], 0, LLONG_MAX)));
  auto g = a.get("target");
  if (!g) throw Usage("move-grab needs --target X,Y,Z");
  set_vec(req.mutable_target(), to_doubles("target", *g, 3));
  auto r = c.move_grab(req);
  if (!r.ok()) return fail(r.status, c.options());
  if (json) std::printf("%s\n", json_of(*r).c_str());
  else std::printf("target moved from tick %llu (last force on the body %.6g %.6g %.6g N)\n",
                   static_cast<unsigned long long>(r->first_tick()), r->force().x(), r->force().y(), r->force().z());
  return kExitOk;
}

int cmd_release(Client& c, Args& a, bool json) {
  if (a.positional.size() < 2) throw Usage("release needs a scene ID and a grab id");
  a.max_positional(2, "release");
  auto st = c.release(a.positional[0], static_cast<uint64_t>(to_int("grab id", a.positional[1], 0, LLONG_MAX)));
  if (!st.ok()) return fail(st, c.options());
  if (json) std::printf("{}\n");
  else std::printf("released\n");
  return kExitOk;
}

std::atomic<bool> g_interrupted{false};
extern "C" void on_sigint(int) { g_interrupted = true; }

// Ends a frame stream from the side: a thread cancels it on Ctrl-C / SIGTERM or once `duration`
// seconds (when > 0) have passed since construction. Destruction (or finish()) stops the thread.
class StreamStopper {
 public:
  StreamStopper(client::FrameStream& stream, double duration)
      : start_(std::chrono::steady_clock::now()), thread_([this, &stream, duration] {
          while (!done_) {
            if (g_interrupted || (duration > 0 && std::chrono::steady_clock::now() - start_ >=
                                                      std::chrono::duration<double>(duration))) {
              stream.cancel();
              return;
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
          }
        }) {
    std::signal(SIGINT, on_sigint);
    std::signal(SIGTERM, on_sigint);
  }
  ~StreamStopper() { finish(); }
  StreamStopper(const StreamStopper&) = delete;
  StreamStopper& operator=(const StreamStopper&) = delete;

  void finish() {
    done_ = true;
    if (thread_.joinable()) thread_.join();
  }
  std::chrono::steady_clock::time_point start() const { return start_; }

 private:
  std::chrono::steady_clock::time_point start_;
  std::atomic<bool> done_{false};
  std::thread thread_;
};

int cmd_watch(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("watch needs a scene ID");
  double duration = 0;
  if (auto v = a.get("duration")) duration = to_double("duration", *v);
  v1::StreamFramesRequest req;
  req.set_scene_id(a.positional[0]);
  req.add_fields(v1::FRAME_FIELD_SOLVER_STATS);  // no positions: a status line needs none
  if (auto v = a.get("every")) req.set_every_nth_tick(static_cast<uint32_t>(to_int("every", *v, 0, UINT32_MAX)));
  if (auto v = a.get("max-rate")) req.set_max_rate_hz(to_double("max-rate", *v));
  a.max_positional(1, "watch");

  const bool tty = isatty(STDOUT_FILENO) && !json;
  // The scene's particle bodies, once (frames without positions do not carry them).
  v1::Scene scene_info;
  if (auto got = c.get_scene(a.positional[0]); got.ok()) scene_info = *got;
  if (!json && scene_info.bodies_size() > 0) std::printf("bodies %s\n", bodies_line(scene_info).c_str());
  auto stream = c.stream_frames(req);
  StreamStopper stopper(*stream, duration);
  const auto start = stopper.start();

  v1::Frame f, first, last;
  uint64_t frames = 0, skipped = 0;
  std::vector<double> residuals;
  double iterations_sum = 0;
  auto last_print = start;
  while (stream->next(&f)) {
    if (frames == 0) first = f;
    last = f;
    ++frames;
    skipped += f.skipped_frames();
    residuals.push_back(f.solver().residual_final());
    iterations_sum += f.solver().iterations();
    auto now = std::chrono::steady_clock::now();
    if (!json && (now - last_print >= std::chrono::milliseconds(tty ? 100 : 1000) || frames == 1)) {
      last_print = now;
      char line[256];
      std::snprintf(line, sizeof line,
                    "tick %-9llu t %9.3f s  %7.1f ticks/s  step %6.2f ms  it %4d  residual %9.3e  late %llu  skipped %llu%s",
                    static_cast<unsigned long long>(f.tick()), f.sim_time(), f.ticks_per_second(),
                    f.solver().step_wall_ms(), f.solver().iterations(), f.solver().residual_final(),
                    static_cast<unsigned long long>(f.late_ticks()), static_cast<unsigned long long>(skipped),
                    f.rollbacks() ? ("  rollbacks " + std::to_string(f.rollbacks())).c_str() : "");
      if (tty) std::printf("\r%-110s", line);
      else std::printf("%s\n", line);
      std::fflush(stdout);
    }
  }
  stopper.finish();
  Status s = stream->finish();
  const bool cancelled_by_us = s.code == 1 && (g_interrupted || duration > 0);
  if (tty) std::printf("\n");
  if (!s.ok() && !cancelled_by_us && frames == 0) return fail(s, c.options());  // nothing to sum up
  const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const uint64_t ticks = frames ? last.tick() - first.tick() : 0;
  const uint64_t late = frames ? last.late_ticks() - first.late_ticks() : 0;
  double mean_r = 0, p99_r = 0;
  if (!residuals.empty()) {
    for (double r : residuals) mean_r += r;
    mean_r /= residuals.size();
    std::vector<double> sorted = residuals;
    std::sort(sorted.begin(), sorted.end());
    p99_r = sorted[std::min(sorted.size() - 1, static_cast<size_t>(std::ceil(0.99 * sorted.size())) - 1)];
  }
  const double mean_it = frames ? iterations_sum / frames : 0;
  const double tps = elapsed > 0 ? ticks / elapsed : 0;
  if (json) {
    // nlohmann writes NaN/inf as null: the line stays valid JSON whatever the residuals were.
    nlohmann::json j = {{"scene_id", a.positional[0]},
                        {"seconds", std::round(elapsed * 1000) / 1000},
                        {"ticks", ticks},
                        {"ticks_per_s", std::round(tps * 1000) / 1000},
                        {"late_ticks", late},
                        {"frames", frames},
                        {"skipped_frames", skipped},
                        {"mean_residual", mean_r},
                        {"p99_residual", p99_r},
                        {"mean_iterations", std::round(mean_it * 1000) / 1000}};
    nlohmann::json bodies = nlohmann::json::array();
    for (const v1::BodySummary& b : scene_info.bodies())
      bodies.push_back({{"name", b.name()}, {"kind", b.kind()}, {"particles", b.particle_count()}});
    j["bodies"] = bodies;
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("%llu ticks in %.1f s (%.1f ticks/s), %llu late, %llu frames, %llu skipped, residual mean %.3e p99 %.3e, "
                "%.1f iterations/tick\n",
                static_cast<unsigned long long>(ticks), elapsed, tps, static_cast<unsigned long long>(late),
                static_cast<unsigned long long>(frames), static_cast<unsigned long long>(skipped), mean_r, p99_r,
                mean_it);
  }
  std::fflush(stdout);
  if (s.ok() || cancelled_by_us) return kExitOk;
  return fail(s, c.options());
}

// One particle body's series in a recording: body-<name>_<tick>.vtu and body-<name>.pvd.
struct BodyRecording {
  std::string name;
  size_t particles = 0;      // at creation
  size_t max_particles = 0;  // a fluid with emitters grows up to it
  bool grows = false;
  std::optional<VtuRecorder> recorder;
  RecordingFrame previous;
  bool have_previous = false;
};

// The body's name as a file name part: the server allows A-Z a-z 0-9 _ . -; anything else (from
// another server) becomes '_'.
std::string file_safe(const std::string& name) {
  std::string s = name;
  for (char& ch : s)
    if (!(std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == '-' || ch == '.')) ch = '_';
  return s;
}

// The recording topology of a particle body: its rest positions, pins as fixed, and its cells
// (a cloth's triangles, a rope's segments between consecutive particles, a fluid's particles).
RecordingTopology body_topology(const v1::BodyTopology& b) {
  RecordingTopology rt;
  const size_t n = b.particle_count();
  if (static_cast<size_t>(b.rest_positions_size()) != 3 * n || b.triangles_size() % 3 != 0)
    throw std::runtime_error("the server's topology of body '" + b.name() + "' is inconsistent");
  rt.rest_positions.resize(n);
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) rt.rest_positions[i][k] = b.rest_positions(static_cast<int>(3 * i + k));
  rt.fixed.assign(n, 0);
  for (uint32_t p : b.pinned())
    if (p < n) rt.fixed[p] = 1;
  if (b.kind() == "cloth")
    for (int t = 0; t + 2 < b.triangles_size(); t += 3)
      rt.triangles.push_back({static_cast<int32_t>(b.triangles(t)), static_cast<int32_t>(b.triangles(t + 1)),
                              static_cast<int32_t>(b.triangles(t + 2))});
  else if (b.kind() == "rope")
    for (size_t i = 0; i + 1 < n; ++i) rt.segments.push_back({static_cast<int32_t>(i), static_cast<int32_t>(i + 1)});
  else
    rt.point_cells = true;
  return rt;
}

// Positions of a frame's packed float xyz, and their finite-difference velocity against the last
// frame written (zero in the first and after a rollback).
void fill_frame(const google::protobuf::RepeatedField<float>& xyz, size_t n, double time, double residual,
                bool rolled_back, const RecordingFrame& previous, bool have_previous, RecordingFrame& frame) {
  frame.time = time;
  frame.residual = residual;
  frame.positions.resize(n);
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) frame.positions[i][k] = xyz[static_cast<int>(3 * i + k)];
  frame.velocity.assign(n, Vec3::Zero());
  const double dt = frame.time - previous.time;
  // Particles an emitter added since the previous frame have no earlier position: speed 0.
  if (have_previous && !rolled_back && dt > 0)
    for (size_t i = 0; i < std::min(n, previous.positions.size()); ++i)
      frame.velocity[i] = (frame.positions[i] - previous.positions[i]) / dt;
}

// record: frames with positions into binary .vtu files and a .pvd collection (and one series per
// particle body). Frames carry no velocity: it is the finite difference of consecutive frames
// received (over the simulated time between them; zero in the first frame and after a rollback).
int cmd_record(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("record needs a scene ID");
  a.max_positional(1, "record");
  const std::string id = a.positional[0];
  auto out = a.get("out");
  if (!out || out->empty()) throw Usage("record needs --out DIR");
  double duration = 0;
  if (auto v = a.get("duration")) {
    duration = to_double("duration", *v);
    if (duration <= 0) throw Usage("--duration must be > 0 s, got " + *v);
  }
  long long max_frames = 0;
  if (auto v = a.get("frames")) max_frames = to_int("frames", *v, 1, INT32_MAX);
  v1::StreamFramesRequest req;
  req.set_scene_id(id);
  req.add_fields(v1::FRAME_FIELD_POSITIONS);
  req.add_fields(v1::FRAME_FIELD_SOLVER_STATS);
  if (auto v = a.get("every")) req.set_every_nth_tick(static_cast<uint32_t>(to_int("every", *v, 0, UINT32_MAX)));
  if (auto v = a.get("max-rate")) {
    const double hz = to_double("max-rate", *v);
    if (hz < 0) throw Usage("--max-rate must be >= 0 Hz, got " + *v);
    req.set_max_rate_hz(hz);
  }

  auto topo = c.topology(id);
  if (!topo.ok()) return fail(topo.status, c.options());
  RecordingTopology rt;
  const size_t n = topo->vertex_count();
  if (static_cast<size_t>(topo->rest_positions_size()) != 3 * n || topo->tets_size() % 4 != 0) {
    std::fprintf(stderr, "pliant: the server's topology of '%s' is inconsistent (%d rest coordinates for %zu vertices)\n",
                 id.c_str(), topo->rest_positions_size(), n);
    return kExitRefused;
  }
  rt.rest_positions.resize(n);
  for (size_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k) rt.rest_positions[i][k] = topo->rest_positions(static_cast<int>(3 * i + k));
  for (int t = 0; t + 3 < topo->tets_size(); t += 4)
    rt.tets.push_back({topo->tets(t), topo->tets(t + 1), topo->tets(t + 2), topo->tets(t + 3)});
  rt.fixed.assign(n, 0);
  for (int32_t v : topo->fixed_vertices())
    if (v >= 0 && static_cast<size_t>(v) < n) rt.fixed[v] = 1;
  std::optional<VtuRecorder> recorder;
  std::vector<BodyRecording> bodies(static_cast<size_t>(topo->bodies_size()));
  try {
    recorder.emplace(*out, std::move(rt));
    for (int b = 0; b < topo->bodies_size(); ++b) {
      const v1::BodyTopology& bt = topo->bodies(b);
      BodyRecording& br = bodies[static_cast<size_t>(b)];
      br.name = bt.name();
      br.particles = bt.particle_count();
      br.max_particles = std::max<size_t>(bt.max_particle_count(), bt.particle_count());
      br.grows = bt.kind() == "fluid" && br.max_particles > br.particles;
      const std::string stem = "body-" + file_safe(bt.name());
      br.recorder.emplace(*out, body_topology(bt), stem, stem);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pliant: --out: %s\n", e.what());
    return kExitRefused;
  }

  auto stream = c.stream_frames(req);
  StreamStopper stopper(*stream, duration);
  v1::Frame f;
  RecordingFrame frame, previous;
  bool have_previous = false;
  uint64_t frames = 0, first_tick = 0, last_tick = 0, skipped = 0;
  double first_time = 0, last_time = 0;
  std::string write_error;
  bool stopped_by_count = false;
  while (stream->next(&f)) {
    if (f.surface_only() || static_cast<size_t>(f.positions_size()) != 3 * n) continue;  // not ours to record
    fill_frame(f.positions(), n, f.sim_time(), f.solver().residual_final(), f.rolled_back(), previous, have_previous,
               frame);
    try {
      recorder->write(frame, static_cast<long>(f.tick()));
      // Each body by name (a frame lists the bodies in spec order, as the topology does).
      for (const v1::FrameBody& bf : f.bodies())
        for (BodyRecording& br : bodies) {
          // A fluid with emitters grows (a point-cell series takes any count); others keep theirs.
          const size_t count = static_cast<size_t>(bf.positions_size()) / 3;
          if (br.name != bf.name() || bf.positions_size() % 3 != 0 ||
              (count != br.particles && !(br.grows && count <= br.max_particles)))
            continue;
          RecordingFrame body_frame;
          fill_frame(bf.positions(), count, f.sim_time(), 0.0, f.rolled_back(), br.previous, br.have_previous,
                     body_frame);
          br.recorder->write(body_frame, static_cast<long>(f.tick()));
          br.previous = std::move(body_frame);
          br.have_previous = true;
        }
    } catch (const std::exception& e) {
      write_error = e.what();
      stream->cancel();
      break;
    }
    if (frames == 0) first_tick = f.tick(), first_time = f.sim_time();
    last_tick = f.tick(), last_time = f.sim_time();
    skipped += f.skipped_frames();
    ++frames;
    std::swap(previous, frame);
    have_previous = true;
    if (max_frames && frames >= static_cast<uint64_t>(max_frames)) {
      stopped_by_count = true;
      stream->cancel();
      break;
    }
  }
  stopper.finish();
  Status s = stream->finish();
  if (!write_error.empty()) {
    std::fprintf(stderr, "pliant: record: %s\n", write_error.c_str());
    return kExitRefused;
  }
  const bool cancelled_by_us = s.code == 1 && (g_interrupted || duration > 0 || stopped_by_count);
  if (!s.ok() && !cancelled_by_us && frames == 0) return fail(s, c.options());
  if (json) {
    nlohmann::json j = {{"scene_id", id},          {"frames", frames},         {"first_tick", first_tick},
                        {"last_tick", last_tick},  {"first_time", first_time}, {"last_time", last_time},
                        {"skipped_frames", skipped}, {"pvd", recorder->pvd_path()}};
    nlohmann::json jb = nlohmann::json::array();
    for (const BodyRecording& br : bodies)
      jb.push_back({{"name", br.name}, {"frames", br.recorder->frames()}, {"pvd", br.recorder->pvd_path()}});
    j["bodies"] = jb;
    std::printf("%s\n", j.dump().c_str());
  } else {
    std::printf("recorded %llu frames (ticks %llu-%llu, t %.4f-%.4f s, %llu skipped) to %s\n",
                static_cast<unsigned long long>(frames), static_cast<unsigned long long>(first_tick),
                static_cast<unsigned long long>(last_tick), first_time, last_time,
                static_cast<unsigned long long>(skipped), recorder->pvd_path().c_str());
    for (const BodyRecording& br : bodies)
      std::printf("  body %s: %zu frames to %s\n", br.name.c_str(), br.recorder->frames(), br.recorder->pvd_path().c_str());
  }
  std::fflush(stdout);
  if (s.ok() || cancelled_by_us) return kExitOk;
  return fail(s, c.options());
}

int cmd_snapshot(Client& c, Args& a, bool json) {
  if (a.positional.empty()) throw Usage("snapshot needs a subcommand: save | restore | list");
  const std::string sub = a.positional[0];
  if (sub == "save") {
    if (a.positional.size() < 2) throw Usage("snapshot save needs a scene ID");
    a.max_positional(2, "snapshot save");
    v1::SaveSnapshotRequest req;
    req.set_scene_id(a.positional[1]);
    auto name = a.get("name");
    auto out = a.get("out");
    if (!name && !out) throw Usage("snapshot save needs --name NAME (on the server) and/or --out FILE (here)");
    if (name) req.set_name(*name);
    req.set_omit_snapshot(!out);
    auto r = c.save_snapshot(req);
    if (!r.ok()) return fail(r.status, c.options());
    if (out) {
      std::ofstream f(*out, std::ios::binary | std::ios::trunc);
      if (!f || !r->snapshot().SerializeToOstream(&f)) {
        std::fprintf(stderr, "pliant: cannot write --out '%s'\n", out->c_str());
        return kExitRefused;
      }
    }
    if (json) {
      nlohmann::json j = {{"scene_id", a.positional[1]},
                          {"tick", r->snapshot().tick()},
                          {"server_path", r->path()},
                          {"file", out.value_or("")}};
      std::printf("%s\n", j.dump().c_str());
    } else {
      if (!r->path().empty()) std::printf("saved on the server: %s\n", r->path().c_str());
      if (out) std::printf("saved to %s (tick %llu)\n", out->c_str(), static_cast<unsigned long long>(r->snapshot().tick()));
    }
    return kExitOk;
  }
  if (sub == "restore") {
    a.max_positional(1, "snapshot restore");
    v1::RestoreSnapshotRequest req;
    auto name = a.get("name");
    auto file = a.get("file");
    if (!!name == !!file) throw Usage("snapshot restore needs exactly one of --name NAME or --file FILE");
    if (name) req.set_name(*name);
    if (file) {
      std::ifstream f(*file, std::ios::binary);
      if (!f || !req.mutable_snapshot()->ParseFromIstream(&f)) {
        std::fprintf(stderr, "pliant: --file '%s' is not a readable Pliant snapshot\n", file->c_str());
        return kExitUsage;
      }
    }
    if (auto id = a.get("as")) req.set_scene_id(*id);
    req.set_replace(a.has("replace"));
    auto r = c.restore_snapshot(req);
    if (!r.ok()) return fail(r.status, c.options());
    if (json) print_scene(*r, true);
    else std::printf("restored scene %s at tick %llu\n", r->scene_id().c_str(), static_cast<unsigned long long>(r->tick()));
    return kExitOk;
  }
  if (sub == "list") {
    a.max_positional(1, "snapshot list");
    auto r = c.list_snapshots();
    if (!r.ok()) return fail(r.status, c.options());
    if (json) {
      v1::ListSnapshotsResponse l;
      for (auto& n : r.value) l.add_names(n);
      std::printf("%s\n", json_of(l).c_str());
    } else {
      for (auto& n : r.value) std::printf("%s\n", n.c_str());
    }
    return kExitOk;
  }
  throw Usage("unknown subcommand 'snapshot " + sub + "' (save | restore | list)");
}

int cmd_health(Client& c, Args& a, bool json) {
  a.max_positional(0, "health");
  std::string service = a.get("service").value_or("");
  auto r = c.health(service);
  if (!r.ok()) {
    if (json)
      std::printf("%s\n", nlohmann::json{{"status", "UNREACHABLE"}, {"error", r.status.code_name()}}.dump().c_str());
    return fail(r.status, c.options());
  }
  if (json) std::printf("%s\n", nlohmann::json{{"status", std::string(client::to_string(*r))}}.dump().c_str());
  else std::printf("%s\n", std::string(client::to_string(*r)).c_str());
  return *r == client::Health::Serving ? kExitOk : kExitRefused;
}

// The command line: global flags (before or after the command), a command word (two for scenes
// and snapshot), then the command's positionals and flags. CLI11 parses it in two passes: the
// global flags up to the command word, then the command's own parser, which also takes the
// global flags, so that option values are never mistaken for command words.
enum class Kind { Value, Flag, Repeated };
struct Opt {
  std::string name, value, help;
  Kind kind = Kind::Value;
};
using Runner = int (*)(Client&, Args&, bool);
struct Command {
  std::vector<std::string> words;
  std::string summary;
  std::vector<std::pair<std::string, std::string>> positionals;  // name, help
  std::vector<Opt> options;
  Runner run;
  bool scene_positional = true;  // positional 1 (after the words) is a scene ID: --servers routes by it
};

std::vector<Opt> settings_flags() {
  return {
      {"young", "PA", "Young's modulus"},
      {"poisson", "NU", "Poisson's ratio"},
      {"density", "KG_M3", "density"},
      {"inertia-floor", "F", "inertia of a free vertex at least F x the mean vertex mass (default 0.1, 0 = off)"},
      {"support-inertia", "K", "inertia of a free vertex at least K x the mass it carries to the fixed vertices "
                               "(default 0 = off)"},
      {"model", "stvk|corotated", "strain of the tet constraint (default stvk)"},
      {"gravity", "GX,GY,GZ", "m/s^2 (default 0,-9.81,0)"},
      {"dt", "S", "tick length (default 1/60 s)"},
      {"rate", "HZ", "ticks per second (instead of --dt)"},
      {"mode", "MODE", "realtime | lockstep | as-fast-as-possible"},
      {"method", "METHOD", "xpbd|sor|lambda-sor|chebyshev|anderson|anderson-sor|extrapolation|vbd|newton|auto"},
      {"sweep", "SWEEP", "gauss-seidel | jacobi | sequential"},
      {"newton-linear-solver", "L", "newton's linear solver: auto | direct | cg | cg-jacobi | cg-factor | cg-twolevel"},
      {"substeps", "N", "substeps per tick"},
      {"iterations", "N", "solver iterations per substep"},
      {"window", "M", "Anderson window"},
      {"omega", "W", "over-relaxation factor"},
      {"tolerance", "T", "residual tolerance"},
      {"time-budget-ms", "MS", "time the solver may spend per tick"},
      {"threads", "N", "solver threads"},
      {"wave-courant", "C", "let the server pick the substeps: the fewest with a pressure wave crossing at most C "
                            "elements per substep"},
  };
}

std::vector<Opt> create_flags() {
  std::vector<Opt> o = {
      {"spec", "FILE", "a SceneSpec in protobuf's JSON mapping (examples/scenes/); flags override its fields"},
      {"mesh", "NAME", "builtin mesh (beam1 | beam2 | beam3; default beam1) or a file on the server's model path"},
      {"upload", "FILE", "read a mesh locally and send it with the request"},
      {"scale", "F", "scale the mesh coordinates"},
      {"fix", "I,J,..", "fixed vertex indices"},
      {"fix-box", "X0,Y0,Z0,X1,Y1,Z1", "fix the vertices in this box"},
      {"fix-x-below", "X", "fix every vertex with x <= X"},
      {"fix-file", "FILE", "fix the vertex indices listed in FILE (whitespace or comma separated, '#' comments); "
                           "read here, sent as indices"},
      {"fix-group", "NAME|N", "fix the vertices of the mesh file's physical group NAME or tag N (Gmsh .msh on the "
                              "server's model path), repeatable",
       Kind::Repeated},
      {"collider", "SPEC", "a static obstacle, repeatable: plane:point=X,Y,Z:normal=X,Y,Z | "
                           "box:center=X,Y,Z:half=HX,HY,HZ | sphere:center=X,Y,Z:radius=R, each with an optional "
                           ":friction=MU or :friction=MU_S,MU_D",
       Kind::Repeated},
      {"rope", "SPEC", "a rope, repeatable: NAME:from=X,Y,Z:to=X,Y,Z with optional :segments=N (20), "
                       ":density=KG_PER_M, :pin=I,J,.. (particle indices)",
       Kind::Repeated},
      {"cloth", "SPEC", "a cloth grid, repeatable: NAME:origin=X,Y,Z:size=SX,SY (along x and z) with optional "
                        ":resolution=NX,NY (16,16), :pin=I,J,..",
       Kind::Repeated},
      {"fluid", "SPEC", "a fluid block, repeatable: NAME:min=X,Y,Z:max=X,Y,Z with optional :spacing=D (0.02), "
                        ":container=CX,CY,CZ,HX,HY,HZ (a box the fluid stays in), :tap=X,Y,Z (an emitter pouring "
                        "down; with it min/max may go) with :tap-radius=R (0.03), :tap-speed=V (1 m/s), "
                        ":tap-direction=X,Y,Z, :tap-max=N (10000)",
       Kind::Repeated},
      {"paused", "", "create the scene paused", Kind::Flag},
  };
  for (Opt& s : settings_flags()) o.push_back(std::move(s));
  return o;
}

const std::vector<Command>& commands() {
  static const std::vector<Command> c = {
      {{"scenes", "create"}, "create a scene (ID optional: the server picks one)", {{"ID", "scene id"}},
       create_flags(), cmd_scenes},
      {{"scenes", "list"}, "list the server's scenes", {}, {}, cmd_scenes, false},
      {{"scenes", "get"}, "show one scene", {{"ID", "scene id"}}, {}, cmd_scenes},
      {{"scenes", "update"}, "change solver settings, material, gravity, dt or mode live", {{"ID", "scene id"}},
       settings_flags(), cmd_scenes},
      {{"scenes", "delete"}, "delete a scene", {{"ID", "scene id"}}, {}, cmd_scenes},
      {{"scenes", "reset"}, "back to the rest state at tick 0", {{"ID", "scene id"}}, {}, cmd_scenes},
      {{"pause"}, "stop a realtime or as-fast-as-possible scene", {{"ID", "scene id"}}, {},
       [](Client& c, Args& a, bool j) { return cmd_pause_resume(c, a, j, true); }},
      {{"resume"}, "restart a paused scene", {{"ID", "scene id"}}, {},
       [](Client& c, Args& a, bool j) { return cmd_pause_resume(c, a, j, false); }},
      {{"step"}, "advance N ticks (lockstep or paused scenes)", {{"ID", "scene id"}, {"N", "ticks (default 1)"}},
       {{"ticks", "N", "ticks (instead of the positional N)"}}, cmd_step},
      {{"force"}, "push vertices for N ticks", {{"ID", "scene id"}},
       {{"vertices", "I,J,..", "vertex indices"}, {"force", "FX,FY,FZ", "force in N"},
        {"ticks", "N", "ticks the force lasts"}},
       cmd_force},
      {{"grab"}, "attach a point to a target (default: where it is now)", {{"ID", "scene id"}},
       {{"vertex", "I", "grab a vertex"}, {"tet", "T", "grab a point in a tet (with --barycentric)"},
        {"barycentric", "B0,B1,B2,B3", "the point's barycentric coordinates in --tet"},
        {"target", "X,Y,Z", "where to pull it"}, {"compliance", "C", "the grab's compliance"},
        {"body", "NAME", "grab particle --vertex of this particle body (rope, cloth, fluid)"}},
       cmd_grab},
      {{"move-grab"}, "move a grab's target", {{"ID", "scene id"}, {"GRAB", "grab id"}},
       {{"target", "X,Y,Z", "the new target"}}, cmd_move_grab},
      {{"release"}, "let go", {{"ID", "scene id"}, {"GRAB", "grab id"}}, {}, cmd_release},
      {{"watch"}, "live line: tick, sim time, ticks/s, iterations, residual, late ticks; ends with a summary",
       {{"ID", "scene id"}},
       {{"duration", "S", "stop after S seconds (default: Ctrl-C)"}, {"every", "N", "every Nth tick"},
        {"max-rate", "HZ", "at most HZ frames per second"}},
       cmd_watch},
      {{"record"}, "stream the scene's frames into DIR as binary .vtu files and DIR/frames.pvd for ParaView",
       {{"ID", "scene id"}},
       {{"out", "DIR", "output directory"}, {"duration", "S", "stop after S seconds"},
        {"frames", "N", "stop after N frames"}, {"every", "N", "every Nth tick"},
        {"max-rate", "HZ", "at most HZ frames per second"}},
       cmd_record},
      {{"snapshot", "save"}, "save the scene's full state on the server (--name) and/or to a local file (--out)",
       {{"ID", "scene id"}},
       {{"name", "NAME", "snapshot name on the server"}, {"out", "FILE", "local file"}}, cmd_snapshot},
      {{"snapshot", "restore"}, "restore a snapshot as a scene", {},
       {{"name", "NAME", "a snapshot on the server"}, {"file", "FILE", "a local snapshot file"},
        {"as", "ID", "the restored scene's id"}, {"replace", "", "replace a scene of that id", Kind::Flag}},
       cmd_snapshot, false},
      {{"snapshot", "list"}, "snapshots in the server's data directory", {}, {}, cmd_snapshot, false},
      {{"health"}, "exit 0 when the server is SERVING", {}, {{"service", "NAME", "a service name"}}, cmd_health,
       false},
  };
  return c;
}

// The global flags, as the first pass and every command's parser take them.
struct Globals {
  client::ConnectOptions* connect;
  bool* json;
  std::optional<std::string>* servers;
  bool* address_given;  // on the command line (not from PLIANT_ADDRESS)
};

void add_global_flags(CLI::App& app, const Globals& g) {
  const std::string group = "Global flags (before or after the command)";
  auto* address = app.add_option_function<std::string>(
      "--address",
      [g](const std::string& v) {
        g.connect->address = v;
        *g.address_given = true;
      },
      "server HOST:PORT (default $PLIANT_ADDRESS or localhost:50051)");
  auto* token = app.add_option_function<std::string>(
      "--token", [g](const std::string& v) { g.connect->token = v; }, "access token (default $PLIANT_TOKEN)");
  auto* servers = app.add_option_function<std::string>(
      "--servers", [g](const std::string& v) { *g.servers = v; },
      "A,B,C: a sharded deployment's servers in order; scenes go to their owner by id (docs/deploy.md)");
  auto* tls = app.add_flag_callback("--tls", [g] { g.connect->tls = true; }, "use TLS with the system roots");
  auto* tls_ca = app.add_option_function<std::string>(
      "--tls-ca",
      [g](const std::string& v) {
        std::ifstream ca(v);
        std::stringstream pem;
        pem << ca.rdbuf();
        if (!ca || pem.str().find("-----BEGIN") == std::string::npos)
          throw CLI::ValidationError("--tls-ca '" + v + "' cannot be read as PEM certificates");
        g.connect->tls_ca_file = v;
      },
      "use TLS with these PEM roots");
  auto* timeout = app.add_option_function<std::string>(
      "--timeout",
      [g](const std::string& v) {
        double t = 0;
        try {
          t = to_double("timeout", v);
        } catch (const Usage& u) {
          throw CLI::ValidationError(u.what());
        }
        if (!(t > 0)) throw CLI::ValidationError("--timeout must be > 0 s, got " + v);
        g.connect->timeout = std::chrono::milliseconds(static_cast<long long>(t * 1000));
      },
      "deadline of each call in seconds (default 30)");
  auto* json = app.add_flag_callback("--json", [g] { *g.json = true; }, "machine-readable output");
  for (CLI::Option* o : {address, token, servers, tls_ca, timeout})
    o->type_name("VALUE")->multi_option_policy(CLI::MultiOptionPolicy::TakeLast)->group(group);
  address->type_name("HOST:PORT");
  servers->type_name("A,B,C");
  tls_ca->type_name("FILE");
  timeout->type_name("S");
  token->type_name("TOKEN");
  tls->group(group);
  json->group(group);
}

// Throws Usage for a CLI11 parse error; returns the exit code for --help / --version.
std::optional<int> parse_command(CLI::App& app, std::vector<std::string> args) {
  std::reverse(args.begin(), args.end());  // CLI11 takes a vector last argument first
  try {
    app.parse(args);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    throw Usage(pliant::cli::one_line(e.what()));
  }
  return std::nullopt;
}

std::string join(const std::vector<std::string>& words, const std::string& sep) {
  std::string s;
  for (const std::string& w : words) s += (s.empty() ? "" : sep) + w;
  return s;
}

// The subcommands of a two-word command ("create | list | ...").
std::string subcommands_of(const std::string& word) {
  std::vector<std::string> subs;
  for (const Command& c : commands())
    if (c.words.size() == 2 && c.words[0] == word) subs.push_back(c.words[1]);
  return join(subs, " | ");
}

// `pliant --servers A,B,C`: the servers are parsed once; `scenes list` asks each, commands on a
// scene ask its owner (placement.hpp), others need one --address.
int run_sharded(const Command& cmd, Args& args, const client::ConnectOptions& base, const std::string& text,
                bool json) {
  std::vector<std::string> servers;
  std::string error;
  if (!client::parse_servers(text, &servers, &error)) throw Usage("--servers: " + error);
  const size_t id_at = cmd.words.size() - 1;  // positional index of the scene ID
  if (cmd.words == std::vector<std::string>{"scenes", "list"}) {
    v1::ListScenesResponse all;
    for (const std::string& s : servers) {
      client::ConnectOptions o = base;
      o.address = s;
      Client c(o);
      auto r = c.list_scenes();
      if (!r.ok()) return fail(r.status, c.options());
      for (auto& scene : r.value) *all.add_scenes() = scene;
    }
    if (json) std::printf("%s\n", json_of(all).c_str());
    else if (all.scenes().empty()) std::printf("no scenes\n");
    else
      for (const auto& s : all.scenes()) print_scene_line(s);
    return kExitOk;
  }
  if (!cmd.scene_positional)
    throw Usage("--servers: '" + join(cmd.words, " ") + "' works on one server: give --address instead");
  if (args.positional.size() <= id_at)
    throw Usage("--servers: '" + join(cmd.words, " ") + "' needs a scene ID (scenes are placed by id)");
  client::ConnectOptions o = base;
  o.address = client::owner(args.positional[id_at], servers);
  Client c(o);
  return cmd.run(c, args, json);
}

const char* kCommandFooter =
    "Exit codes: 0 ok, 1 refused by the server, 2 usage, 3 server unreachable, 4 not found, 5 authentication.\n"
    "All commands: pliant --help.";

}  // namespace

int main(int argc, char** argv) {
  client::ConnectOptions opt;
  if (const char* v = std::getenv("PLIANT_ADDRESS"); v && *v) opt.address = v;
  if (const char* v = std::getenv("PLIANT_TOKEN"); v && *v) opt.token = v;
  bool json = false, address_given = false;
  std::optional<std::string> servers;
  const Globals globals{&opt, &json, &servers, &address_given};
  try {
    // First pass: the global flags up to the command word; the rest stays for the command.
    CLI::App root{"pliant: the command-line client of a Pliant server", "pliant"};
    root.prefix_command();
    root.set_help_flag();
    bool help = false;
    root.add_flag("-h,--help", help);
    root.set_version_flag("--version", std::string(pliant::kVersion));
    add_global_flags(root, globals);
    try {
      root.parse(argc, argv);
    } catch (const CLI::CallForVersion& e) {
      return root.exit(e);
    } catch (const CLI::ParseError& e) {
      throw Usage(pliant::cli::one_line(e.what()));
    }
    if (help) {
      std::fputs(kUsage, stdout);
      return kExitOk;
    }
    std::vector<std::string> rest = root.remaining();
    if (rest.empty()) throw Usage("no command given");
    if (rest[0].size() > 1 && rest[0][0] == '-') throw Usage("unknown flag " + rest[0] + " (before the command)");

    // The command: one word, or two for scenes and snapshot.
    const Command* cmd = nullptr;
    bool two_words = false;
    for (const Command& c : commands())
      if (c.words[0] == rest[0]) two_words = c.words.size() == 2;
    if (two_words) {
      const std::string subs = subcommands_of(rest[0]);
      if (rest.size() < 2 || rest[1] == "--help" || rest[1] == "-h") {
        if (rest.size() >= 2) {
          std::printf("usage: pliant %s SUBCOMMAND [args]\n  subcommands: %s\n  pliant %s SUBCOMMAND --help for "
                      "each\n",
                      rest[0].c_str(), subs.c_str(), rest[0].c_str());
          return kExitOk;
        }
        throw Usage(rest[0] + " needs a subcommand: " + subs);
      }
      for (const Command& c : commands())
        if (c.words.size() == 2 && c.words[0] == rest[0] && c.words[1] == rest[1]) cmd = &c;
      if (!cmd) throw Usage("unknown subcommand '" + rest[0] + " " + rest[1] + "' (" + subs + ")");
    } else {
      for (const Command& c : commands())
        if (c.words[0] == rest[0]) cmd = &c;
      if (!cmd) throw Usage("unknown command '" + rest[0] + "'");
    }

    // Second pass: the command's positionals and flags (and the global flags again).
    Args args;
    for (size_t i = 1; i < cmd->words.size(); ++i) args.positional.push_back(cmd->words[i]);
    const std::string name = "pliant " + join(cmd->words, " ");
    CLI::App app{cmd->summary, name};
    app.footer(kCommandFooter);
    app.set_version_flag("--version", std::string(pliant::kVersion));
    for (const auto& [pos, help] : cmd->positionals)
      app.add_option_function<std::string>(pos, [&args](const std::string& v) { args.positional.push_back(v); },
                                           help);
    for (const Opt& o : cmd->options) {
      const std::string flag = "--" + o.name;
      const std::string key = o.name;
      if (o.kind == Kind::Flag) {
        app.add_flag_callback(flag, [&args, key] { args.flags[key] = "true"; }, o.help);
      } else if (o.kind == Kind::Repeated) {
        app.add_option_function<std::vector<std::string>>(
               flag, [&args, key](const std::vector<std::string>& v) { args.repeated[key] = v; }, o.help)
            ->type_name(o.value)
            ->expected(1)
            ->multi_option_policy(CLI::MultiOptionPolicy::TakeAll);
      } else {
        app.add_option_function<std::string>(flag, [&args, key](const std::string& v) { args.flags[key] = v; },
                                             o.help)
            ->type_name(o.value);
      }
    }
    add_global_flags(app, globals);
    app.allow_extras();  // reported below, first one first
    try {
      if (auto rc = parse_command(app, std::vector<std::string>(rest.begin() + static_cast<long>(cmd->words.size()),
                                                                rest.end())))
        return *rc;
      if (const auto extra = app.remaining(); !extra.empty()) {
        if (extra[0].size() > 1 && extra[0][0] == '-') throw Usage("unknown flag " + extra[0] + " for this command");
        throw Usage("unexpected argument '" + extra[0] + "'");
      }
    } catch (const Usage& u) {
      std::fprintf(stderr, "pliant: %s (see %s --help)\n", u.what(), name.c_str());
      return kExitUsage;
    }
    if (servers) {
      if (address_given) throw Usage("give --servers or --address, not both");
      return run_sharded(*cmd, args, opt, *servers, json);
    }
    Client c(opt);
    return cmd->run(c, args, json);
  } catch (const Usage& u) {
    std::fprintf(stderr, "pliant: %s (see pliant --help)\n", u.what());
    return kExitUsage;
  }
}
