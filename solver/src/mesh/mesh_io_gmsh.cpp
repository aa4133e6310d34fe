// SPDX-License-Identifier: Apache-2.0
// Gmsh .msh reader: v1 ($NOD/$ELM), v2.2 and v4.1, ASCII and binary (little-endian, 8-byte
// size_t). Tetrahedra (type 4, and the corners of higher-order tets) are kept; other element
// types are skipped with one log line per type; unknown sections are skipped. Physical groups
// (the physical tag of v1/v2 elements, the physical tags of v4 $Entities, names from
// $PhysicalNames) become TetMesh::groups: the nodes of each group's elements of any type.
#include "mesh/mesh_parse.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <unordered_map>

namespace pliant::detail {
namespace {

// Nodes per element type (Gmsh reference manual, "MSH file format"); -1 if unknown.
int gmsh_nodes_per_element(int64_t type) {
  switch (type) {
    case 1: return 2;   case 2: return 3;   case 3: return 4;   case 4: return 4;
    case 5: return 8;   case 6: return 6;   case 7: return 5;   case 8: return 3;
    case 9: return 6;   case 10: return 9;  case 11: return 10; case 12: return 27;
    case 13: return 18; case 14: return 14; case 15: return 1;  case 16: return 8;
    case 17: return 20; case 18: return 15; case 19: return 13; case 20: return 9;
    case 21: return 10; case 22: return 12; case 23: return 15; case 24: return 15;
    case 25: return 21; case 26: return 4;  case 27: return 5;  case 28: return 6;
    case 29: return 20; case 30: return 35; case 31: return 56; case 92: return 64;
    case 93: return 125;
    default: return -1;
  }
}

bool is_tet_type(int64_t type) { return type == 4 || type == 11 || type == 29 || type == 30 || type == 31; }

// Dimension of an element type: 0 point, 1 line, 2 surface, 3 volume.
int type_dimension(int64_t type) {
  switch (type) {
    case 15: return 0;
    case 1: case 8: case 26: case 27: case 28: return 1;
    case 2: case 3: case 9: case 10: case 16: case 20: case 21: case 22: case 23: case 24: case 25: return 2;
    default: return 3;
  }
}

const char* type_name(int64_t type) {
  switch (type) {
    case 1: return "line"; case 2: return "triangle"; case 3: return "quadrangle"; case 5: return "hexahedron";
    case 6: return "prism"; case 7: return "pyramid"; case 15: return "point";
    default: return "element";
  }
}

// Node tags -> vertex indices: dense when tags are compact, hashed otherwise.
class NodeMap {
 public:
  void add(int64_t tag, int32_t index, const Cursor& c) {
    if (tag < 0) c.fail("negative node tag " + std::to_string(tag));
    if (!hashed_ && tag <= dense_limit_) {
      if (static_cast<size_t>(tag) >= dense_.size()) dense_.resize(static_cast<size_t>(tag) + 1, -1);
      if (dense_[tag] >= 0) c.fail("node tag " + std::to_string(tag) + " defined twice");
      dense_[tag] = index;
      return;
    }
    if (!hashed_) {
      hashed_ = true;
      for (size_t t = 0; t < dense_.size(); ++t)
        if (dense_[t] >= 0) hash_[static_cast<int64_t>(t)] = dense_[t];
      dense_.clear();
    }
    if (!hash_.emplace(tag, index).second) c.fail("node tag " + std::to_string(tag) + " defined twice");
  }
  int32_t find(int64_t tag) const {
    if (!hashed_) return (tag >= 0 && static_cast<size_t>(tag) < dense_.size()) ? dense_[tag] : -1;
    auto it = hash_.find(tag);
    return it == hash_.end() ? -1 : it->second;
  }
  void set_dense_limit(int64_t limit) { dense_limit_ = limit; }

 private:
  int64_t dense_limit_ = 1 << 20;
  bool hashed_ = false;
  std::vector<int32_t> dense_;
  std::unordered_map<int64_t, int32_t> hash_;
};

class GmshReader {
 public:
  GmshReader(std::string_view bytes, const std::string& path) : c_(bytes, base_name(path)) {
    raw_.mesh.name = base_name(path);
    raw_.file = base_name(path);
    raw_.origin_kind = "element";
  }

  RawTetMesh read() {
    const std::string_view first = c_.token("the first section");
    if (first == "$NOD" || first == "$NOE") {
      read_v1();
    } else if (first == "$MeshFormat") {
      read_format();
      while (c_.skip_space()) {
        const size_t line = c_.line();
        const std::string_view sec = c_.token("a section name");
        if (sec.empty() || sec[0] != '$') c_.fail("expected a section name like $Nodes, got '" + std::string(sec.substr(0, 40)) + "'");
        if (sec == "$Nodes") {
          if (have_nodes_) c_.fail("second $Nodes section");
          have_nodes_ = true;
          version_ >= 4 ? read_nodes_v4() : read_nodes_v2();
          expect_end("$EndNodes");
        } else if (sec == "$PhysicalNames") {
          read_physical_names();
          expect_end("$EndPhysicalNames");
        } else if (sec == "$Entities" && version_ >= 4) {
          if (have_elements_) c_.fail("$Entities after $Elements");
          read_entities_v4();
          expect_end("$EndEntities");
        } else if (sec == "$Elements") {
          if (!have_nodes_) c_.fail("$Elements before $Nodes");
          if (have_elements_) c_.fail("second $Elements section");
          have_elements_ = true;
          version_ >= 4 ? read_elements_v4() : read_elements_v2();
          expect_end("$EndElements");
        } else {
          const std::string end = "$End" + std::string(sec.substr(1));
          if (!c_.seek_past(end)) {
            c_.set_pos(c_.pos());
            throw MeshError(c_.file() + ":" + std::to_string(line) + ": section " + std::string(sec) +
                            " has no " + end + " (truncated file?)");
          }
        }
      }
    } else {
      c_.fail("not a Gmsh file: expected $MeshFormat or $NOD, got '" + std::string(first.substr(0, 40)) + "'");
    }
    if (!have_nodes_) c_.fail("no $Nodes section");
    if (!have_elements_) c_.fail("no $Elements section");
    for (const auto& [type, count] : skipped_)
      spdlog::info("{}: skipped {} {} elements (Gmsh type {})", raw_.file, count, type_name(type), type);
    if (raw_.mesh.tets.empty()) c_.fail("no tetrahedra in the file");
    make_groups();
    return std::move(raw_);
  }

 private:
  void expect_end(const char* end) {
    c_.set_binary_mode(false);
    const std::string_view tok = c_.token(end);
    if (tok != end) c_.fail(std::string("expected ") + end + ", got '" + std::string(tok.substr(0, 40)) + "' (bad count?)");
  }

  void read_format() {
    const std::string_view ver = c_.token("the format version");
    if (ver == "2" || ver == "2.0" || ver == "2.1" || ver == "2.2") version_ = 2;
    else if (ver == "4.1") version_ = 4;
    else if (ver == "4" || ver == "4.0") c_.fail("Gmsh format 4.0 is not supported; save as 4.1 or 2.2");
    else c_.fail("unsupported Gmsh format version '" + std::string(ver.substr(0, 20)) + "' (2.2 and 4.1 are read)");
    const int64_t file_type = c_.integer("the file type");
    data_size_ = c_.integer("the data size");
    if (file_type != 0 && file_type != 1) c_.fail("file type must be 0 (ASCII) or 1 (binary), got " + std::to_string(file_type));
    binary_ = file_type == 1;
    if (binary_ && data_size_ != 8) c_.fail("binary files with data size " + std::to_string(data_size_) + " are not supported (8 is)");
    if (binary_) {
      c_.rest_of_line();
      c_.set_binary_mode(true);
      const int32_t one = c_.raw<int32_t>("the endianness marker");
      if (one != 1) c_.fail(one == 0x01000000 ? "big-endian binary files are not supported" : "bad endianness marker " + std::to_string(one));
      c_.set_binary_mode(false);
    }
    expect_end("$EndMeshFormat");
  }

  int32_t add_node(int64_t tag, const Vec3& p) {
    const auto index = static_cast<int32_t>(raw_.mesh.vertices.size());
    for (int k = 0; k < 3; ++k)
      if (!std::isfinite(p[k])) c_.fail("node " + std::to_string(tag) + ": non-finite coordinate " + std::to_string(p[k]));
    nodes_.add(tag, index, c_);
    raw_.mesh.vertices.push_back(p);
    return index;
  }

  int32_t node_index(int64_t tag, int64_t element) const {
    const int32_t i = nodes_.find(tag);
    if (i < 0) c_.fail("element " + std::to_string(element) + ": node " + std::to_string(tag) + " is not defined in the nodes section");
    return i;
  }

  void add_tet(int64_t tag, const int64_t* node_tags) {
    Tet t;
    for (int k = 0; k < 4; ++k) t[k] = node_index(node_tags[k], tag);
    raw_.mesh.tets.push_back(t);
    raw_.tet_origin.push_back(tag);
  }

  // The nodes of an element of `dim` in the physical groups `physicals` (tag 0: none).
  void add_to_groups(int dim, const std::vector<int64_t>& physicals, const int64_t* node_tags, size_t n) {
    for (int64_t phys : physicals) {
      if (phys == 0) continue;
      auto& nodes = group_nodes_[{dim, phys}];
      nodes.insert(nodes.end(), node_tags, node_tags + n);
    }
  }
  void add_to_group(int dim, int64_t phys, const int64_t* node_tags, size_t n) {
    if (phys == 0) return;
    auto& nodes = group_nodes_[{dim, phys}];
    nodes.insert(nodes.end(), node_tags, node_tags + n);
  }

  void make_groups() {
    for (auto& [key, tags] : group_nodes_) {
      VertexGroup g;
      g.dimension = key.first;
      g.tag = key.second;
      if (auto it = names_.find(key); it != names_.end()) g.name = it->second;
      g.vertices.reserve(tags.size());
      for (int64_t t : tags) {
        const int32_t i = nodes_.find(t);
        if (i < 0) c_.fail("physical group " + std::to_string(g.tag) + ": node " + std::to_string(t) + " is not defined in the nodes section");
        g.vertices.push_back(i);
      }
      std::sort(g.vertices.begin(), g.vertices.end());
      g.vertices.erase(std::unique(g.vertices.begin(), g.vertices.end()), g.vertices.end());
      raw_.mesh.groups.push_back(std::move(g));
    }
    // Named groups without elements are listed too (empty), so that a lookup names them.
    for (const auto& [key, name] : names_)
      if (!group_nodes_.count(key)) raw_.mesh.groups.push_back(VertexGroup{key.first, key.second, name, {}});
  }

  // $PhysicalNames (text in every version): count, then "dimension tag "name"" lines.
  void read_physical_names() {
    const size_t n = c_.checked_count(c_.integer("the number of physical names"), 6, "number of physical names");
    for (size_t i = 0; i < n; ++i) {
      const int64_t dim = c_.integer("a physical group dimension");
      const int64_t tag = c_.integer("a physical tag");
      if (dim < 0 || dim > 3) c_.fail("physical name: bad dimension " + std::to_string(dim));
      std::string name(c_.rest_of_line());
      while (!name.empty() && (name.back() == '\r' || name.back() == ' ' || name.back() == '\t')) name.pop_back();
      const size_t a = name.find_first_not_of(" \t");
      name = a == std::string::npos ? "" : name.substr(a);
      if (name.size() >= 2 && name.front() == '"' && name.back() == '"') name = name.substr(1, name.size() - 2);
      names_[{static_cast<int>(dim), tag}] = name;
    }
  }

  // v4 $Entities: the physical tags of every point, curve, surface and volume.
  void read_entities_v4() {
    if (binary_) {
      c_.rest_of_line();
      c_.set_binary_mode(true);
    }
    size_t counts[4];
    for (size_t& n : counts) n = c_.checked_count(static_cast<int64_t>(read_size("an entity count")), 8, "number of entities");
    for (int dim = 0; dim < 4; ++dim) {
      for (size_t e = 0; e < counts[dim]; ++e) {
        const int64_t tag = read_int("an entity tag");
        const int coords = dim == 0 ? 3 : 6;
        for (int k = 0; k < coords; ++k) binary_ ? c_.raw<double>("an entity bound") : c_.real("an entity bound");
        const size_t np = c_.checked_count(static_cast<int64_t>(read_size("a physical tag count")), 4, "number of physical tags");
        std::vector<int64_t> phys(np);
        for (size_t k = 0; k < np; ++k) phys[k] = read_int("a physical tag");
        if (!phys.empty()) entity_physicals_[{dim, tag}] = std::move(phys);
        if (dim > 0) {
          const size_t nb = c_.checked_count(static_cast<int64_t>(read_size("a bounding entity count")), 4, "number of bounding entities");
          for (size_t k = 0; k < nb; ++k) read_int("a bounding entity tag");
        }
      }
    }
  }

  void read_v1() {
    const size_t n = c_.checked_count(c_.integer("the number of nodes"), 8, "number of nodes");
    raw_.mesh.vertices.reserve(n);
    nodes_.set_dense_limit(static_cast<int64_t>(4 * n + 1024));
    for (size_t i = 0; i < n; ++i) {
      const int64_t tag = c_.integer("a node number");
      Vec3 p;
      for (int k = 0; k < 3; ++k) p[k] = c_.real("a coordinate");
      add_node(tag, p);
    }
    expect_end("$ENDNOD");
    have_nodes_ = true;
    const std::string_view elm = c_.token("$ELM");
    if (elm != "$ELM") c_.fail("expected $ELM, got '" + std::string(elm.substr(0, 40)) + "'");
    const size_t m = c_.checked_count(c_.integer("the number of elements"), 12, "number of elements");
    for (size_t i = 0; i < m; ++i) {
      const int64_t tag = c_.integer("an element number");
      const int64_t type = c_.integer("an element type");
      const int64_t phys = c_.integer("a physical region");
      c_.integer("an elementary region");
      const int64_t nn = c_.integer("the number of nodes");
      if (nn < 1 || nn > 1000) c_.fail("element " + std::to_string(tag) + ": bad node count " + std::to_string(nn));
      const int expected = gmsh_nodes_per_element(type);
      if (expected >= 0 && expected != nn)
        c_.fail("element " + std::to_string(tag) + ": type " + std::to_string(type) + " needs " + std::to_string(expected) +
                " nodes, the line says " + std::to_string(nn));
      std::vector<int64_t>& nt = element_nodes_;
      nt.resize(static_cast<size_t>(nn));
      for (int64_t k = 0; k < nn; ++k) nt[k] = c_.integer("a node number");
      add_to_group(type_dimension(type), phys, nt.data(), nt.size());
      if (is_tet_type(type) && nn >= 4) add_tet(tag, nt.data());
      else skipped_[type]++;
    }
    expect_end("$ENDELM");
    have_elements_ = true;
  }

  void read_nodes_v2() {
    const size_t n = c_.checked_count(c_.integer("the number of nodes"), binary_ ? 28 : 8, "number of nodes");
    raw_.mesh.vertices.reserve(n);
    nodes_.set_dense_limit(static_cast<int64_t>(4 * n + 1024));
    if (binary_) {
      c_.rest_of_line();
      c_.set_binary_mode(true);
      for (size_t i = 0; i < n; ++i) {
        const int32_t tag = c_.raw<int32_t>("a node tag");
        Vec3 p;
        for (int k = 0; k < 3; ++k) p[k] = c_.raw<double>("a coordinate");
        add_node(tag, p);
      }
      return;
    }
    for (size_t i = 0; i < n; ++i) {
      const int64_t tag = c_.integer("a node number");
      Vec3 p;
      for (int k = 0; k < 3; ++k) p[k] = c_.real("a coordinate");
      add_node(tag, p);
    }
  }

  void read_elements_v2() {
    const size_t m = c_.checked_count(c_.integer("the number of elements"), binary_ ? 8 : 8, "number of elements");
    if (binary_) {
      c_.rest_of_line();
      c_.set_binary_mode(true);
      size_t done = 0;
      std::vector<int64_t> nt;
      while (done < m) {
        const int32_t type = c_.raw<int32_t>("an element type");
        const int32_t follow = c_.raw<int32_t>("an element count");
        const int32_t ntags = c_.raw<int32_t>("a tag count");
        const int npe = gmsh_nodes_per_element(type);
        if (npe < 0) c_.fail("unknown element type " + std::to_string(type) + " (cannot skip it in a binary file)");
        if (follow <= 0 || static_cast<size_t>(follow) > m - done) c_.fail("bad element block count " + std::to_string(follow));
        if (ntags < 0 || ntags > 100) c_.fail("bad tag count " + std::to_string(ntags));
        const size_t each = 4u * (1u + static_cast<size_t>(ntags) + static_cast<size_t>(npe));
        c_.checked_count(follow, each, "element block size");
        nt.resize(static_cast<size_t>(npe));
        for (int32_t e = 0; e < follow; ++e) {
          const int32_t tag = c_.raw<int32_t>("an element tag");
          int64_t phys = 0;
          for (int32_t k = 0; k < ntags; ++k) {
            const int32_t t = c_.raw<int32_t>("an element tag");
            if (k == 0) phys = t;  // the first tag is the physical group
          }
          for (int k = 0; k < npe; ++k) nt[k] = c_.raw<int32_t>("a node tag");
          add_to_group(type_dimension(type), phys, nt.data(), nt.size());
          if (is_tet_type(type)) add_tet(tag, nt.data());
          else skipped_[type]++;
        }
        done += static_cast<size_t>(follow);
      }
      return;
    }
    for (size_t i = 0; i < m; ++i) {
      const int64_t tag = c_.integer("an element number");
      const size_t line = c_.line();
      const int64_t type = c_.integer("an element type");
      const int64_t ntags = c_.integer("the number of tags");
      if (ntags < 0 || ntags > 100) c_.fail("element " + std::to_string(tag) + ": bad tag count " + std::to_string(ntags));
      int64_t phys = 0;
      for (int64_t k = 0; k < ntags; ++k) {
        const int64_t t = c_.integer("an element tag");
        if (k == 0) phys = t;  // the first tag is the physical group
      }
      const bool tet = is_tet_type(type);
      if (!tet && phys == 0) {
        skipped_[type]++;
        c_.rest_of_line();
        continue;
      }
      std::vector<int64_t>& nt = element_nodes_;
      nt.clear();
      while (c_.token_on_line(line)) nt.push_back(c_.integer("a node number"));  // with higher-order nodes
      if (tet && nt.size() < 4) c_.fail("element " + std::to_string(tag) + ": a tetrahedron needs 4 nodes, the line has " + std::to_string(nt.size()));
      add_to_group(type_dimension(type), phys, nt.data(), nt.size());
      if (tet) add_tet(tag, nt.data());
      else skipped_[type]++;
    }
  }

  size_t read_size(const char* what) {
    if (binary_) {
      const uint64_t v = c_.raw<uint64_t>(what);
      if (v > (uint64_t(1) << 62)) c_.fail(std::string("bad ") + what + " " + std::to_string(v));
      return static_cast<size_t>(v);
    }
    const int64_t v = c_.integer(what);
    if (v < 0) c_.fail(std::string("negative ") + what + " " + std::to_string(v));
    return static_cast<size_t>(v);
  }
  int64_t read_int(const char* what) { return binary_ ? c_.raw<int32_t>(what) : c_.integer(what); }

  void read_nodes_v4() {
    if (binary_) {
      c_.rest_of_line();
      c_.set_binary_mode(true);
    }
    const size_t blocks = c_.checked_count(static_cast<int64_t>(read_size("the number of node blocks")), 8, "number of node blocks");
    const size_t n = c_.checked_count(static_cast<int64_t>(read_size("the number of nodes")), binary_ ? 32 : 8, "number of nodes");
    read_size("the minimum node tag");
    const size_t max_tag = read_size("the maximum node tag");
    nodes_.set_dense_limit(static_cast<int64_t>(std::min<size_t>(max_tag, 4 * n + 1024)));
    raw_.mesh.vertices.reserve(n);
    std::vector<int64_t> tags;
    for (size_t b = 0; b < blocks; ++b) {
      const int64_t dim = read_int("an entity dimension");
      read_int("an entity tag");
      const int64_t parametric = read_int("the parametric flag");
      const size_t count = c_.checked_count(static_cast<int64_t>(read_size("the number of nodes in a block")),
                                            binary_ ? 32 : 8, "number of nodes in a block");
      if (dim < 0 || dim > 3) c_.fail("bad entity dimension " + std::to_string(dim));
      if (parametric != 0 && parametric != 1) c_.fail("bad parametric flag " + std::to_string(parametric));
      if (raw_.mesh.vertices.size() + count > n) c_.fail("node blocks hold more nodes than the header's " + std::to_string(n));
      const int extra = parametric ? static_cast<int>(dim) : 0;
      tags.resize(count);
      for (size_t i = 0; i < count; ++i) tags[i] = static_cast<int64_t>(read_size("a node tag"));
      for (size_t i = 0; i < count; ++i) {
        Vec3 p;
        for (int k = 0; k < 3; ++k) p[k] = binary_ ? c_.raw<double>("a coordinate") : c_.real("a coordinate");
        for (int k = 0; k < extra; ++k) binary_ ? c_.raw<double>("a parametric coordinate") : c_.real("a parametric coordinate");
        add_node(tags[i], p);
      }
    }
    if (raw_.mesh.vertices.size() != n)
      c_.fail("node blocks hold " + std::to_string(raw_.mesh.vertices.size()) + " nodes, the header says " + std::to_string(n));
  }

  void read_elements_v4() {
    if (binary_) {
      c_.rest_of_line();
      c_.set_binary_mode(true);
    }
    const size_t blocks = c_.checked_count(static_cast<int64_t>(read_size("the number of element blocks")), 8, "number of element blocks");
    const size_t m = c_.checked_count(static_cast<int64_t>(read_size("the number of elements")), 4, "number of elements");
    read_size("the minimum element tag");
    read_size("the maximum element tag");
    size_t total = 0;
    std::vector<int64_t> nt;
    for (size_t b = 0; b < blocks; ++b) {
      const int64_t entity_dim = read_int("an entity dimension");
      const int64_t entity_tag = read_int("an entity tag");
      const int64_t type = read_int("an element type");
      static const std::vector<int64_t> kNone;
      const auto phys_it = entity_physicals_.find({static_cast<int>(entity_dim), entity_tag});
      const std::vector<int64_t>& phys = phys_it == entity_physicals_.end() ? kNone : phys_it->second;
      const size_t count = read_size("the number of elements in a block");
      const int npe = gmsh_nodes_per_element(type);
      if (npe < 0 && binary_) c_.fail("unknown element type " + std::to_string(type) + " (cannot skip it in a binary file)");
      c_.checked_count(static_cast<int64_t>(count), binary_ ? 8u * (1u + static_cast<size_t>(npe)) : 4, "number of elements in a block");
      if (total + count > m) c_.fail("element blocks hold more elements than the header's " + std::to_string(m));
      total += count;
      const bool tet = is_tet_type(type);
      nt.resize(npe > 0 ? static_cast<size_t>(npe) : 4);
      for (size_t e = 0; e < count; ++e) {
        if (binary_) {
          const auto tag = static_cast<int64_t>(read_size("an element tag"));
          for (int k = 0; k < npe; ++k) nt[k] = static_cast<int64_t>(read_size("a node tag"));
          add_to_groups(static_cast<int>(entity_dim), phys, nt.data(), static_cast<size_t>(npe));
          if (tet) add_tet(tag, nt.data());
          continue;
        }
        const int64_t tag = c_.integer("an element tag");
        const size_t line = c_.line();
        if (!tet && phys.empty()) {
          c_.rest_of_line();
          continue;
        }
        std::vector<int64_t>& all = element_nodes_;
        all.clear();
        while (c_.token_on_line(line)) all.push_back(c_.integer("a node tag"));  // with higher-order nodes
        if (tet && all.size() < 4) c_.fail("element " + std::to_string(tag) + ": a tetrahedron needs 4 nodes, the line has " + std::to_string(all.size()));
        add_to_groups(static_cast<int>(entity_dim), phys, all.data(), all.size());
        if (tet) add_tet(tag, all.data());
      }
      if (!tet) skipped_[type] += static_cast<int64_t>(count);
    }
    if (total != m) c_.fail("element blocks hold " + std::to_string(total) + " elements, the header says " + std::to_string(m));
  }

  Cursor c_;
  RawTetMesh raw_;
  NodeMap nodes_;
  int version_ = 2;
  int64_t data_size_ = 8;
  bool binary_ = false;
  bool have_nodes_ = false, have_elements_ = false;
  std::map<int64_t, int64_t> skipped_;
  std::map<std::pair<int, int64_t>, std::vector<int64_t>> group_nodes_;       // (dimension, physical tag) -> node tags
  std::map<std::pair<int, int64_t>, std::string> names_;                       // $PhysicalNames
  std::map<std::pair<int, int64_t>, std::vector<int64_t>> entity_physicals_;  // v4: (dimension, entity tag) -> physical tags
  std::vector<int64_t> element_nodes_;
};

}  // namespace

RawTetMesh read_gmsh(const std::string& path) {
  const std::string bytes = read_file_bytes(path);
  GmshReader reader(bytes, path);
  return reader.read();
}

}  // namespace pliant::detail
