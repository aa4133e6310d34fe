// SPDX-License-Identifier: Apache-2.0
#include "pliant/model.hpp"

#include "kernels/strain_kernel.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace pliant {

double BodyModel::added_inertia() const {
  double added = 0, total = 0;
  for (size_t i = 0; i < mass.size(); ++i) {
    total += mass[i];
    if (!fixed[i]) added += inertia[i] - mass[i];
  }
  return total > 0 ? added / total : 0.0;
}

size_t BodyModel::floored_vertices() const {
  size_t n = 0;
  for (size_t i = 0; i < mass.size(); ++i) n += !fixed[i] && inertia[i] > mass[i];
  return n;
}

std::vector<double> supported_mass(const BodyModel& m) {
  const size_t nv = m.vertex_count();
  // Vertex adjacency over the tets' edges (compressed rows; duplicates are harmless).
  std::vector<int32_t> start(nv + 1, 0);
  for (const TetRest& t : m.tets)
    for (int k = 0; k < 4; ++k) start[t.v[k] + 1] += 3;
  for (size_t i = 0; i < nv; ++i) start[i + 1] += start[i];
  std::vector<int32_t> next(start.begin(), start.end() - 1), adjacent(start[nv]);
  for (const TetRest& t : m.tets)
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b)
        if (a != b) adjacent[next[t.v[a]]++] = t.v[b];
  // Breadth-first distance from the fixed vertices.
  std::vector<int32_t> distance(nv, -1), queue;
  queue.reserve(nv);
  for (size_t i = 0; i < nv; ++i)
    if (i < m.fixed.size() && m.fixed[i]) distance[i] = 0, queue.push_back(int32_t(i));
  for (size_t q = 0; q < queue.size(); ++q) {
    const int32_t i = queue[q];
    for (int32_t k = start[i]; k < start[i + 1]; ++k)
      if (distance[adjacent[k]] < 0) distance[adjacent[k]] = distance[i] + 1, queue.push_back(adjacent[k]);
  }
  const int32_t deepest = queue.empty() ? 0 : distance[queue.back()];
  std::vector<double> beyond(deepest + 2, 0.0);  // mass at distance >= d
  std::vector<int32_t> count(deepest + 1, 0);
  for (size_t i = 0; i < nv; ++i)
    if (distance[i] > 0 && m.mass[i] > 0) beyond[distance[i]] += m.mass[i], count[distance[i]]++;
  for (int32_t d = deepest - 1; d >= 0; --d) beyond[d] += beyond[d + 1];
  std::vector<double> carried(nv, 0.0);
  for (size_t i = 0; i < nv; ++i)
    if (distance[i] > 0 && m.mass[i] > 0) carried[i] = beyond[distance[i]] / count[distance[i]];
  return carried;
}

size_t BodyModel::slot_count() const { return packed ? packed->slot_count() : 0; }

std::vector<Vec6> multipliers_per_tet(const BodyModel& m, const std::vector<Vec6>& slots) {
  if (slots.size() != m.slot_count()) {
    std::ostringstream os;
    os << "lambda: " << slots.size() << " multiplier slots, the model has " << m.slot_count();
    throw std::invalid_argument(os.str());
  }
  std::vector<Vec6> per_tet(m.tet_count());
  for (size_t t = 0; t < m.tet_count(); ++t) per_tet[t] = slots[m.tet_slot[t]];
  return per_tet;
}

std::vector<Vec6> multipliers_in_slots(const BodyModel& m, const std::vector<Vec6>& per_tet) {
  if (per_tet.size() != m.tet_count()) {
    std::ostringstream os;
    os << "lambda: " << per_tet.size() << " tets' multipliers, the model has " << m.tet_count() << " tets";
    throw std::invalid_argument(os.str());
  }
  std::vector<Vec6> slots(m.slot_count(), Vec6::Zero());
  for (size_t t = 0; t < m.tet_count(); ++t) slots[m.tet_slot[t]] = per_tet[t];
  return slots;
}

double BodyModel::total_mass() const {
  double m = 0;
  for (double v : mass) m += v;
  return m;
}

std::vector<int32_t> select_vertices(const std::vector<Vec3>& x, const FixedSelection& sel) {
  std::vector<uint8_t> mark(x.size(), 0);
  for (int32_t i : sel.indices) {
    if (i < 0 || size_t(i) >= x.size()) {
      std::ostringstream os;
      os << "fixed.indices: vertex " << i << " is out of range [0, " << x.size() << ")";
      throw std::invalid_argument(os.str());
    }
    mark[i] = 1;
  }
  for (size_t i = 0; i < x.size(); ++i) {
    for (const auto& b : sel.boxes)
      if ((x[i].array() >= b.min.array()).all() && (x[i].array() <= b.max.array()).all()) mark[i] = 1;
    for (const auto& h : sel.half_spaces)
      if ((x[i] - h.point).dot(h.normal) <= 0) mark[i] = 1;
  }
  std::vector<int32_t> out;
  for (size_t i = 0; i < x.size(); ++i)
    if (mark[i]) out.push_back(static_cast<int32_t>(i));
  return out;
}

std::vector<std::vector<int32_t>> colour_tets(const std::vector<TetRest>& tets, size_t nv) {
  // Greedy: each tet takes the lowest colour none of its vertices has used yet. Vertex colour
  // sets are bitmasks (64 colours per word, more words if a mesh ever needs them).
  std::vector<std::vector<uint64_t>> used(nv);
  std::vector<std::vector<int32_t>> colours;
  for (size_t t = 0; t < tets.size(); ++t) {
    const Tet& v = tets[t].v;
    int c = 0;
    for (;; ++c) {
      size_t w = size_t(c) / 64;
      uint64_t bit = uint64_t(1) << (c % 64);
      bool taken = false;
      for (int k = 0; k < 4 && !taken; ++k) taken = w < used[v[k]].size() && (used[v[k]][w] & bit);
      if (!taken) break;
    }
    size_t w = size_t(c) / 64;
    uint64_t bit = uint64_t(1) << (c % 64);
    for (int k = 0; k < 4; ++k) {
      if (used[v[k]].size() <= w) used[v[k]].resize(w + 1, 0);
      used[v[k]][w] |= bit;
    }
    if (colours.size() <= size_t(c)) colours.resize(c + 1);
    colours[c].push_back(static_cast<int32_t>(t));
  }
  return colours;
}

void vertex_tet_adjacency(const std::vector<TetRest>& tets, size_t nv, std::vector<int32_t>& start,
                          std::vector<int32_t>& entry) {
  start.assign(nv + 1, 0);
  for (const TetRest& t : tets)
    for (int k = 0; k < 4; ++k) start[t.v[k] + 1]++;
  for (size_t i = 0; i < nv; ++i) start[i + 1] += start[i];
  entry.assign(start.back(), 0);
  std::vector<int32_t> fill(start.begin(), start.end() - 1);
  for (size_t t = 0; t < tets.size(); ++t)
    for (int k = 0; k < 4; ++k) entry[fill[tets[t].v[k]]++] = int32_t(4 * t + k);
}

std::vector<std::vector<int32_t>> colour_vertices(const std::vector<TetRest>& tets,
                                                  const std::vector<int32_t>& start,
                                                  const std::vector<int32_t>& entry) {
  const size_t nv = start.empty() ? 0 : start.size() - 1;
  std::vector<int32_t> colour(nv, -1);
  std::vector<uint8_t> taken;  // colours used by the current vertex's neighbours
  std::vector<std::vector<int32_t>> colours;
  for (size_t i = 0; i < nv; ++i) {
    taken.assign(colours.size() + 1, 0);
    for (int32_t a = start[i]; a < start[i + 1]; ++a) {
      const Tet& v = tets[entry[a] / 4].v;
      for (int k = 0; k < 4; ++k)
        if (colour[v[k]] >= 0) taken[colour[v[k]]] = 1;
    }
    int c = 0;
    while (taken[c]) ++c;
    colour[i] = c;
    if (colours.size() <= size_t(c)) colours.resize(c + 1);
    colours[c].push_back(int32_t(i));
  }
  return colours;
}

namespace {

uint64_t next_model_id() {
  static std::atomic<uint64_t> counter{0};
  return ++counter;
}

void set_material(BodyModel& m, const Material& material) {
  if (std::string err = validate(material); !err.empty()) throw std::invalid_argument(err);
  m.material = material;
  m.lame = lame_parameters(material.young, material.poisson);
  m.stiffness = stvk_stiffness(m.lame);
  m.compliance = m.stiffness.inverse();
  m.mass.assign(m.rest_positions.size(), 0.0);
  for (const TetRest& t : m.tets)
    for (int k = 0; k < 4; ++k) m.mass[t.v[k]] += material.density * t.volume / 4.0;
}

// Inertia (the floor and the support share over the lumped mass) and its inverse; needs the
// material's masses and the fixed vertices.
void set_inertia(BodyModel& m) {
  double total = 0;
  size_t used = 0;
  for (double v : m.mass)
    if (v > 0) total += v, ++used;
  const double floor = used > 0 ? m.material.inertia_floor * total / double(used) : 0.0;
  m.inertia.resize(m.mass.size());
  for (size_t i = 0; i < m.mass.size(); ++i) m.inertia[i] = m.mass[i] > 0 ? std::max(m.mass[i], floor) : 0.0;
  if (m.material.support_inertia > 0) {
    const std::vector<double> carried = supported_mass(m);
    for (size_t i = 0; i < m.mass.size(); ++i)
      if (m.mass[i] > 0) m.inertia[i] = std::max(m.inertia[i], m.material.support_inertia * carried[i]);
  }
  m.inv_mass.resize(m.inertia.size());
  for (size_t i = 0; i < m.inertia.size(); ++i)
    m.inv_mass[i] = (m.fixed[i] || m.inertia[i] <= 0) ? 0.0 : 1.0 / m.inertia[i];
}

void set_fixed(BodyModel& m, const FixedSelection& sel) {
  m.fixed.assign(m.rest_positions.size(), 0);
  for (int32_t i : select_vertices(m.rest_positions, sel)) m.fixed[i] = 1;
}

}  // namespace

std::shared_ptr<const BodyModel> build_model(const TetMesh& mesh, const Material& material,
                                             const FixedSelection& fixed) {
  if (mesh.vertices.empty() || mesh.tets.empty())
    throw std::invalid_argument("mesh: '" + mesh.name + "' has no vertices or no tetrahedra");
  auto m = std::make_shared<BodyModel>();
  m->id = next_model_id();
  m->name = mesh.name;
  m->rest_positions = mesh.vertices;
  const size_t nv = mesh.vertices.size();
  for (size_t i = 0; i < nv; ++i)
    if (!mesh.vertices[i].allFinite()) {
      std::ostringstream os;
      os << "mesh.vertices[" << i << "]: coordinate is not finite";
      throw std::invalid_argument(os.str());
    }
  m->tets.reserve(mesh.tets.size());
  m->vertex_tet_count.assign(nv, 0);
  for (size_t t = 0; t < mesh.tets.size(); ++t) {
    const Tet& v = mesh.tets[t];
    for (int k = 0; k < 4; ++k)
      if (v[k] < 0 || size_t(v[k]) >= nv) {
        std::ostringstream os;
        os << "mesh.tets[" << t << "]: vertex index " << v[k] << " out of range [0, " << nv << ")";
        throw std::invalid_argument(os.str());
      }
    Mat3 dm;
    for (int c = 0; c < 3; ++c) dm.col(c) = mesh.vertices[v[c]] - mesh.vertices[v[3]];
    // det(D_m) = -6 V for the (0,1,2,3) orientation convention of signed_tet_volume.
    double vol = signed_tet_volume(mesh.vertices[v[0]], mesh.vertices[v[1]], mesh.vertices[v[2]],
                                   mesh.vertices[v[3]]);
    if (!(vol > 0)) {
      std::ostringstream os;
      os << "mesh.tets[" << t << "]: volume " << vol << " m^3 is not positive (inverted or degenerate)";
      throw std::invalid_argument(os.str());
    }
    TetRest r;
    r.v = v;
    r.dm_inv = dm.inverse();
    r.volume = vol;
    r.sqrt_volume = std::sqrt(vol);
    m->tets.push_back(r);
    for (int k = 0; k < 4; ++k) m->vertex_tet_count[v[k]]++;
  }
  double edges = 0;
  for (const TetRest& t : m->tets)
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) edges += (m->rest_positions[t.v[a]] - m->rest_positions[t.v[b]]).norm();
  m->mean_edge = m->tets.empty() ? 0.0 : edges / (6.0 * double(m->tets.size()));
  m->surface = boundary_triangles(mesh.tets);
  set_material(*m, material);
  set_fixed(*m, fixed);
  set_inertia(*m);
  m->colours = colour_tets(m->tets, nv);
  vertex_tet_adjacency(m->tets, nv, m->vertex_tet_start, m->vertex_tet_entry);
  m->vertex_colours = colour_vertices(m->tets, m->vertex_tet_start, m->vertex_tet_entry);
  detail::compile_solve_order(*m);
  return m;
}

std::shared_ptr<const BodyModel> with_material(const BodyModel& model, const Material& material) {
  auto m = std::make_shared<BodyModel>(model);
  m->id = next_model_id();
  set_material(*m, material);
  set_inertia(*m);
  detail::compile_solve_order(*m);  // the packs carry inverse masses
  return m;
}

std::shared_ptr<const BodyModel> with_fixed(const BodyModel& model, const FixedSelection& fixed) {
  auto m = std::make_shared<BodyModel>(model);
  m->id = next_model_id();
  set_fixed(*m, fixed);
  set_inertia(*m);
  detail::compile_solve_order(*m);
  return m;
}

double pressure_wave_speed(const BodyModel& model) {
  return std::sqrt((model.lame.lambda + 2 * model.lame.mu) / model.material.density);
}

double wave_courant_number(const BodyModel& model, double substep) {
  return model.mean_edge > 0 ? pressure_wave_speed(model) * substep / model.mean_edge : 0.0;
}

}  // namespace pliant
