// SPDX-License-Identifier: Apache-2.0
// VTK readers: legacy UNSTRUCTURED_GRID (.vtk; ASCII and big-endian BINARY; the classic
// CELLS layout and the 5.1 OFFSETS/CONNECTIVITY layout) and XML UnstructuredGrid (.vtu; ascii,
// inline base64 binary and raw appended data, uncompressed or zlib-compressed as VTK and meshio
// write by default: compressor="vtkZLibDataCompressor"). Cells of type 10 (VTK_TETRA) and the
// corners of type 24 (VTK_QUADRATIC_TETRA) become tets; other cells are skipped with a log line.
#include "mesh/mesh_parse.hpp"

#include <spdlog/spdlog.h>
#include <zlib.h>

#include <algorithm>
#include <charconv>
#include <cstring>
#include <limits>
#include <optional>
#include <cmath>
#include <map>

namespace pliant::detail {
namespace {

constexpr int kVtkTetra = 10;
constexpr int kVtkQuadraticTetra = 24;

// ---------------------------------------------------------------- legacy

struct LegacyType {
  int bytes = 0;
  bool is_float = false;
  bool is_signed = true;
};

LegacyType legacy_type(std::string_view name, const Cursor& c) {
  std::string n(name);
  for (char& ch : n) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  if (n == "float") return {4, true, true};
  if (n == "double") return {8, true, true};
  if (n == "char") return {1, false, true};
  if (n == "unsigned_char") return {1, false, false};
  if (n == "short") return {2, false, true};
  if (n == "unsigned_short") return {2, false, false};
  if (n == "int" || n == "vtktypeint32") return {4, false, true};
  if (n == "unsigned_int" || n == "vtktypeuint32") return {4, false, false};
  if (n == "long" || n == "vtktypeint64" || n == "vtkidtype") return {8, false, true};
  if (n == "unsigned_long" || n == "vtktypeuint64") return {8, false, false};
  c.fail("unsupported data type '" + n + "'");
}

// One number of the given type, from text or big-endian binary.
double legacy_value(Cursor& c, bool binary, const LegacyType& t, const char* what) {
  if (!binary) return t.is_float ? c.real(what) : static_cast<double>(c.integer(what));
  switch (t.bytes) {
    case 1: return t.is_signed ? double(c.raw<int8_t>(what)) : double(c.raw<uint8_t>(what));
    case 2: return t.is_signed ? double(c.raw<int16_t>(what, true)) : double(c.raw<uint16_t>(what, true));
    case 4:
      if (t.is_float) return c.raw<float>(what, true);
      return t.is_signed ? double(c.raw<int32_t>(what, true)) : double(c.raw<uint32_t>(what, true));
    default:
      if (t.is_float) return c.raw<double>(what, true);
      return t.is_signed ? double(c.raw<int64_t>(what, true)) : double(c.raw<uint64_t>(what, true));
  }
}

int64_t legacy_index(Cursor& c, bool binary, const LegacyType& t, const char* what) {
  if (t.is_float) c.fail(std::string(what) + " must have an integer type");
  if (!binary) return c.integer(what);
  switch (t.bytes) {
    case 1: return t.is_signed ? int64_t(c.raw<int8_t>(what)) : int64_t(c.raw<uint8_t>(what));
    case 2: return t.is_signed ? int64_t(c.raw<int16_t>(what, true)) : int64_t(c.raw<uint16_t>(what, true));
    case 4: return t.is_signed ? int64_t(c.raw<int32_t>(what, true)) : int64_t(c.raw<uint32_t>(what, true));
    default: {
      if (t.is_signed) return c.raw<int64_t>(what, true);
      const uint64_t v = c.raw<uint64_t>(what, true);
      if (v > uint64_t(std::numeric_limits<int64_t>::max())) c.fail(std::string(what) + " out of range: " + std::to_string(v));
      return static_cast<int64_t>(v);
    }
  }
}

void begin_binary_block(Cursor& c, bool binary) {
  if (!binary) return;
  c.rest_of_line();  // the data start right after the keyword line
  c.set_binary_mode(true);
}

}  // namespace

RawTetMesh read_vtk_legacy(const std::string& path) {
  const std::string bytes = read_file_bytes(path);
  Cursor c(bytes, base_name(path));
  RawTetMesh raw;
  raw.mesh.name = base_name(path);
  raw.file = base_name(path);
  raw.origin_kind = "cell";

  const std::string_view magic = c.rest_of_line();
  if (magic.substr(0, 5) != "# vtk") c.fail("not a VTK legacy file: the first line must start with '# vtk'");
  c.rest_of_line();  // title
  const std::string_view mode = c.token("ASCII or BINARY");
  const bool binary = mode == "BINARY" || mode == "binary";
  if (!binary && mode != "ASCII" && mode != "ascii") c.fail("expected ASCII or BINARY, got '" + std::string(mode.substr(0, 40)) + "'");
  const std::string_view ds = c.token("DATASET");
  const std::string_view kind = c.token("the dataset type");
  if (ds != "DATASET") c.fail("expected DATASET, got '" + std::string(ds.substr(0, 40)) + "'");
  if (kind != "UNSTRUCTURED_GRID") c.fail("only UNSTRUCTURED_GRID datasets hold tets, got '" + std::string(kind.substr(0, 40)) + "'");

  std::vector<int64_t> offsets, connectivity;  // cells in offsets/connectivity form
  std::vector<int64_t> types;
  bool have_points = false, have_cells = false, have_types = false;
  while (!(have_points && have_cells && have_types)) {
    c.set_binary_mode(false);
    if (!c.skip_space()) break;
    const std::string_view key = c.token("a keyword");
    if (key == "POINTS") {
      const size_t n = c.checked_count(c.integer("the number of points"), binary ? 3 : 6, "number of points");
      const LegacyType t = legacy_type(c.token("the point type"), c);
      if (!t.is_float && t.bytes < 2) c.fail("points of type char are not supported");
      begin_binary_block(c, binary);
      if (binary) c.checked_count(static_cast<int64_t>(n), 3u * t.bytes, "number of points");
      raw.mesh.vertices.resize(n);
      for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 3; ++k) {
          const double v = legacy_value(c, binary, t, "a coordinate");
          if (!std::isfinite(v)) c.fail("point " + std::to_string(i) + ": non-finite coordinate " + std::to_string(v));
          raw.mesh.vertices[i][k] = v;
        }
      have_points = true;
    } else if (key == "CELLS") {
      const size_t line = c.line();
      const int64_t a = c.integer("the number of cells");
      const int64_t b = c.integer("the cell list size");
      if (c.token_on_line(line)) c.fail("unexpected token after CELLS n size");
      size_t n_cells;
      // Peek: the 5.1 layout continues with OFFSETS.
      const size_t save = c.pos(), save_line = c.line();
      c.skip_space();
      if (c.data().substr(c.pos(), 7) == "OFFSETS") {
        const size_t n_off = c.checked_count(a, binary ? 4 : 2, "number of offsets");
        const size_t n_conn = c.checked_count(b, binary ? 4 : 2, "connectivity size");
        c.token("OFFSETS");
        const LegacyType ot = legacy_type(c.token("the offsets type"), c);
        begin_binary_block(c, binary);
        offsets.resize(n_off);
        for (size_t i = 0; i < n_off; ++i) offsets[i] = legacy_index(c, binary, ot, "an offset");
        c.set_binary_mode(false);
        const std::string_view kc = c.token("CONNECTIVITY");
        if (kc != "CONNECTIVITY") c.fail("expected CONNECTIVITY, got '" + std::string(kc.substr(0, 40)) + "'");
        const LegacyType ct = legacy_type(c.token("the connectivity type"), c);
        begin_binary_block(c, binary);
        connectivity.resize(n_conn);
        for (size_t i = 0; i < n_conn; ++i) connectivity[i] = legacy_index(c, binary, ct, "a point index");
        if (n_off == 0 || offsets[0] != 0) c.fail("OFFSETS must start with 0");
        n_cells = n_off - 1;
      } else {
        c.restore(save, save_line);
        n_cells = c.checked_count(a, binary ? 8 : 4, "number of cells");
        const size_t size = c.checked_count(b, binary ? 4 : 2, "cell list size");
        begin_binary_block(c, binary);
        const LegacyType it{4, false, true};
        offsets.assign(1, 0);
        connectivity.reserve(size > n_cells ? size - n_cells : 0);
        size_t used = 0;
        for (size_t i = 0; i < n_cells; ++i) {
          const int64_t k = legacy_index(c, binary, it, "a cell's point count");
          used += 1;
          if (k < 0 || static_cast<size_t>(k) > size - std::min(size, used))
            c.fail("cell " + std::to_string(i) + ": point count " + std::to_string(k) + " overruns the cell list size " + std::to_string(size));
          for (int64_t j = 0; j < k; ++j) connectivity.push_back(legacy_index(c, binary, it, "a point index"));
          used += static_cast<size_t>(k);
          offsets.push_back(static_cast<int64_t>(connectivity.size()));
        }
        if (used != size) c.fail("cell list holds " + std::to_string(used) + " numbers, the header says " + std::to_string(size));
      }
      (void)n_cells;
      have_cells = true;
    } else if (key == "CELL_TYPES") {
      const size_t n = c.checked_count(c.integer("the number of cell types"), binary ? 4 : 2, "number of cell types");
      begin_binary_block(c, binary);
      types.resize(n);
      const LegacyType it{4, false, true};
      for (size_t i = 0; i < n; ++i) types[i] = legacy_index(c, binary, it, "a cell type");
      have_types = true;
    } else if (key == "FIELD") {
      c.token("the field name");
      const int64_t arrays = c.integer("the number of arrays");
      if (arrays < 0 || arrays > 10000) c.fail("bad number of field arrays " + std::to_string(arrays));
      for (int64_t a = 0; a < arrays; ++a) {
        c.set_binary_mode(false);
        c.token("an array name");
        const int64_t comps = c.integer("the number of components");
        const int64_t tuples = c.integer("the number of tuples");
        const LegacyType t = legacy_type(c.token("the array type"), c);
        if (comps < 0 || tuples < 0 || comps > 1000000 || tuples > static_cast<int64_t>(c.size()))
          c.fail("bad field array size " + std::to_string(comps) + " x " + std::to_string(tuples));
        const size_t total = c.checked_count(comps * tuples, binary ? static_cast<size_t>(t.bytes) : 1, "field array size");
        begin_binary_block(c, binary);
        if (binary) c.skip_bytes(total * static_cast<size_t>(t.bytes), "field data");
        else for (size_t i = 0; i < total; ++i) c.token("field data");
      }
    } else if (key == "POINT_DATA" || key == "CELL_DATA" || key == "METADATA") {
      break;  // attributes follow; nothing the mesh needs
    } else {
      c.fail("unexpected keyword '" + std::string(key.substr(0, 40)) + "'");
    }
  }
  c.set_binary_mode(false);
  if (!have_points) c.fail("no POINTS section");
  if (!have_cells) c.fail("no CELLS section");
  if (!have_types) c.fail("no CELL_TYPES section");
  const size_t n_cells = offsets.size() - 1;
  if (types.size() != n_cells)
    c.fail("CELL_TYPES lists " + std::to_string(types.size()) + " cells, CELLS lists " + std::to_string(n_cells));

  const int64_t n_points = static_cast<int64_t>(raw.mesh.vertices.size());
  std::map<int64_t, int64_t> skipped;
  for (size_t i = 0; i < n_cells; ++i) {
    const int64_t begin = offsets[i], end = offsets[i + 1];
    if (begin < 0 || end < begin || end > static_cast<int64_t>(connectivity.size()))
      c.fail("cell " + std::to_string(i) + ": bad offsets " + std::to_string(begin) + ".." + std::to_string(end));
    if (types[i] != kVtkTetra && types[i] != kVtkQuadraticTetra) {
      skipped[types[i]]++;
      continue;
    }
    const int64_t need = types[i] == kVtkTetra ? 4 : 10;
    if (end - begin != need)
      c.fail("cell " + std::to_string(i) + ": type " + std::to_string(types[i]) + " needs " + std::to_string(need) +
             " points, it has " + std::to_string(end - begin));
    Tet t;
    for (int k = 0; k < 4; ++k) {
      const int64_t v = connectivity[static_cast<size_t>(begin + k)];
      if (v < 0 || v >= n_points)
        c.fail("cell " + std::to_string(i) + ": point index " + std::to_string(v) + " out of range [0, " +
               std::to_string(n_points - 1) + "]");
      t[k] = static_cast<int32_t>(v);
    }
    raw.mesh.tets.push_back(t);
    raw.tet_origin.push_back(static_cast<int64_t>(i));
  }
  for (const auto& [type, count] : skipped)
    spdlog::info("{}: skipped {} cells of VTK type {}", raw.file, count, type);
  if (raw.mesh.tets.empty()) c.fail("no tetrahedra (VTK cell type 10) in the file");
  return raw;
}

// ---------------------------------------------------------------- XML (.vtu)

namespace {

struct XmlTag {
  size_t begin = 0, end = 0;  // the tag's text [begin, end) including '<' and '>'
  std::string name;
  std::map<std::string, std::string> attrs;
  bool self_closing = false;
};

class VtuReader {
 public:
  VtuReader(std::string_view bytes, const std::string& path) : text_(bytes), c_(bytes, base_name(path)) {}

  [[noreturn]] void fail_at(size_t pos, const std::string& msg) const {
    const size_t line = 1 + static_cast<size_t>(std::count(text_.begin(), text_.begin() + std::min(pos, text_.size()), '\n'));
    throw MeshError(c_.file() + ":" + std::to_string(line) + ": " + msg);
  }

  // Next tag named `name` at or after `from` (and before `limit`); nullopt if none.
  std::optional<XmlTag> find_tag(std::string_view name, size_t from, size_t limit) const {
    const std::string open = "<" + std::string(name);
    size_t at = from;
    while (true) {
      at = text_.find(open, at);
      if (at == std::string_view::npos || at >= limit) return std::nullopt;
      const size_t after = at + open.size();
      if (after < text_.size() && (text_[after] == ' ' || text_[after] == '>' || text_[after] == '/' ||
                                   text_[after] == '\n' || text_[after] == '\t' || text_[after] == '\r'))
        break;
      at = after;
    }
    const size_t close = text_.find('>', at);
    if (close == std::string_view::npos) fail_at(at, "unterminated <" + std::string(name) + " tag");
    XmlTag tag;
    tag.begin = at;
    tag.end = close + 1;
    tag.name = std::string(name);
    tag.self_closing = close > at && text_[close - 1] == '/';
    size_t p = at + 1 + name.size();
    while (p < close) {
      while (p < close && (text_[p] == ' ' || text_[p] == '\n' || text_[p] == '\t' || text_[p] == '\r' || text_[p] == '/')) ++p;
      if (p >= close) break;
      const size_t eq = text_.find('=', p);
      if (eq == std::string_view::npos || eq >= close) fail_at(p, "malformed attribute in <" + std::string(name) + ">");
      std::string key(text_.substr(p, eq - p));
      while (!key.empty() && key.back() == ' ') key.pop_back();
      size_t q = eq + 1;
      while (q < close && text_[q] == ' ') ++q;
      if (q >= close || (text_[q] != '"' && text_[q] != '\'')) fail_at(q, "attribute " + key + " has no quoted value");
      const char quote = text_[q];
      const size_t vend = text_.find(quote, q + 1);
      if (vend == std::string_view::npos || vend > close) fail_at(q, "unterminated value of attribute " + key);
      tag.attrs[key] = std::string(text_.substr(q + 1, vend - q - 1));
      p = vend + 1;
    }
    return tag;
  }

  XmlTag need_tag(std::string_view name, size_t from, size_t limit) const {
    auto t = find_tag(name, from, limit);
    if (!t) fail_at(from, "no <" + std::string(name) + "> element");
    return *t;
  }

  size_t closing(std::string_view name, const XmlTag& open) const {
    if (open.self_closing) return open.end;
    const size_t at = text_.find("</" + std::string(name), open.end);
    if (at == std::string_view::npos) fail_at(open.begin, "<" + std::string(name) + "> is not closed (truncated file?)");
    return at;
  }

  // Where a DataArray's inline values end: its closing tag, or the first child element before it
  // (VTK writes <InformationKey> elements after the values of some arrays).
  size_t values_end(const XmlTag& open) const {
    const size_t close = closing("DataArray", open);
    return std::min(close, text_.find('<', open.end));
  }

  static int64_t attr_int(const XmlTag& t, const std::string& key, const VtuReader& r) {
    auto it = t.attrs.find(key);
    if (it == t.attrs.end()) r.fail_at(t.begin, "<" + t.name + "> has no " + key + " attribute");
    int64_t v = 0;
    auto [p, ec] = std::from_chars(it->second.data(), it->second.data() + it->second.size(), v);
    if (ec != std::errc() || p != it->second.data() + it->second.size() || v < 0)
      r.fail_at(t.begin, "bad " + key + "=\"" + it->second.substr(0, 40) + "\"");
    return v;
  }

  // Reads a DataArray's values as doubles (exact for the integers meshes use).
  std::vector<double> read_array(const XmlTag& tag, size_t expected, const char* what) {
    const std::string type = tag.attrs.count("type") ? tag.attrs.at("type") : "";
    const std::string format = tag.attrs.count("format") ? tag.attrs.at("format") : "ascii";
    int bytes = 0;
    bool is_float = false, is_signed = true;
    if (type == "Float32") bytes = 4, is_float = true;
    else if (type == "Float64") bytes = 8, is_float = true;
    else if (type == "Int8") bytes = 1;
    else if (type == "UInt8") bytes = 1, is_signed = false;
    else if (type == "Int16") bytes = 2;
    else if (type == "UInt16") bytes = 2, is_signed = false;
    else if (type == "Int32") bytes = 4;
    else if (type == "UInt32") bytes = 4, is_signed = false;
    else if (type == "Int64") bytes = 8;
    else if (type == "UInt64") bytes = 8, is_signed = false;
    else fail_at(tag.begin, std::string(what) + ": unsupported DataArray type '" + type + "'");
    std::vector<double> out;
    if (format == "ascii") {
      const size_t end = values_end(tag);
      Cursor ac(text_.substr(0, end), c_.file());
      ac.set_pos(tag.end);
      // Line numbers: count once up to the array's start.
      const size_t first_line = 1 + static_cast<size_t>(std::count(text_.begin(), text_.begin() + tag.end, '\n'));
      out.reserve(std::min(expected, (end - tag.end) / 2 + 1));
      while (ac.skip_space()) {
        if (out.size() >= expected) break;
        try {
          out.push_back(is_float ? ac.real(what) : static_cast<double>(ac.integer(what)));
        } catch (const MeshError& e) {
          throw MeshError(c_.file() + ":" + std::to_string(first_line + ac.line() - 1) + ": bad value in " + what);
        }
      }
      if (out.size() < expected)
        fail_at(end, std::string(what) + ": " + std::to_string(out.size()) + " values, expected " + std::to_string(expected));
      return out;
    }
    std::string decoded;
    std::string_view payload;
    if (format == "binary") {
      const size_t end = values_end(tag);
      Cursor bc(text_, c_.file());
      bc.set_pos(tag.end);
      decoded = base64_decode(text_.substr(tag.end, end - tag.end), bc);
      payload = decoded;
    } else if (format == "appended") {
      if (appended_start_ == std::string_view::npos) fail_at(tag.begin, "format=\"appended\" but no raw <AppendedData>");
      const int64_t off = attr_int(tag, "offset", *this);
      if (static_cast<size_t>(off) > text_.size() - appended_start_) fail_at(tag.begin, "appended offset beyond the end of the file");
      payload = text_.substr(appended_start_ + static_cast<size_t>(off));
    } else {
      fail_at(tag.begin, "unsupported DataArray format '" + format + "'");
    }
    const size_t hbytes = header64_ ? 8 : 4;
    if (payload.size() < hbytes) fail_at(tag.begin, std::string(what) + ": binary data shorter than its header");
    auto header_at = [&](size_t i) -> uint64_t {
      return header64_ ? load<uint64_t>(payload.data() + i * hbytes) : load<uint32_t>(payload.data() + i * hbytes);
    };
    uint64_t nbytes = 0;
    const char* d = nullptr;
    std::string inflated;
    if (zlib_) {
      // zlib (vtkZLibDataCompressor): header [blocks, block size, last block's size (0: full),
      // compressed size of each block], then the compressed blocks back to back.
      const uint64_t blocks = header_at(0);
      if (blocks > payload.size() / hbytes || payload.size() < (3 + blocks) * hbytes)
        fail_at(tag.begin, std::string(what) + ": compressed header announces " + std::to_string(blocks) +
                               " blocks, the data is too short for them (truncated?)");
      const uint64_t block_size = header_at(1), last_size = header_at(2);
      constexpr uint64_t kMaxInflated = uint64_t{1} << 34;  // 16 GiB: a corrupt header, not a mesh
      if (block_size > kMaxInflated || last_size > kMaxInflated || last_size > block_size ||
          (blocks > 1 && block_size > 0 && blocks - 1 > kMaxInflated / block_size))
        fail_at(tag.begin, std::string(what) + ": implausible compressed header (blocks " + std::to_string(blocks) +
                               ", block size " + std::to_string(block_size) + ", last " + std::to_string(last_size) + ")");
      uint64_t at = (3 + blocks) * hbytes;
      const uint64_t total = blocks == 0 ? 0 : (blocks - 1) * block_size + (last_size ? last_size : block_size);
      if (total / static_cast<uint64_t>(bytes) < expected)
        fail_at(tag.begin, std::string(what) + ": " + std::to_string(total / bytes) + " values, expected " + std::to_string(expected));
      // zlib expands at most ~1032:1; a header claiming more is corrupt (and must not make us
      // allocate it).
      if (total > 1100 * static_cast<uint64_t>(payload.size()) + 4096)
        fail_at(tag.begin, std::string(what) + ": compressed header claims " + std::to_string(total) +
                               " bytes from " + std::to_string(payload.size()) + " bytes of data (corrupt?)");
      inflated.resize(total);
      uint64_t filled = 0;
      for (uint64_t b = 0; b < blocks; ++b) {
        const uint64_t csize = header_at(3 + b);
        const uint64_t usize = (b + 1 == blocks && last_size) ? last_size : block_size;
        if (csize > payload.size() - at)
          fail_at(tag.begin, std::string(what) + ": compressed block " + std::to_string(b) + " of " +
                                 std::to_string(csize) + " bytes runs past the end of the data (truncated?)");
        uLongf out_len = static_cast<uLongf>(usize);
        const int rc = uncompress(reinterpret_cast<Bytef*>(inflated.data() + filled), &out_len,
                                  reinterpret_cast<const Bytef*>(payload.data() + at), static_cast<uLong>(csize));
        if (rc != Z_OK || out_len != usize)
          fail_at(tag.begin, std::string(what) + ": compressed block " + std::to_string(b) + " does not inflate to " +
                                 std::to_string(usize) + " bytes (zlib error " + std::to_string(rc) + ")");
        filled += usize;
        at += csize;
      }
      nbytes = total;
      d = inflated.data();
    } else {
      // Uncompressed: a header (UInt32 or UInt64 byte count) then the data.
      nbytes = header_at(0);
      if (nbytes > payload.size() - hbytes) fail_at(tag.begin, std::string(what) + ": header says " + std::to_string(nbytes) + " bytes, only " + std::to_string(payload.size() - hbytes) + " present (truncated?)");
      if (nbytes / static_cast<uint64_t>(bytes) < expected)
        fail_at(tag.begin, std::string(what) + ": " + std::to_string(nbytes / bytes) + " values, expected " + std::to_string(expected));
      d = payload.data() + hbytes;
    }
    out.resize(expected);
    for (size_t i = 0; i < expected; ++i, d += bytes) {
      switch (bytes) {
        case 1: out[i] = is_signed ? double(int8_t(*d)) : double(uint8_t(*d)); break;
        case 2: out[i] = is_signed ? double(load<int16_t>(d)) : double(load<uint16_t>(d)); break;
        case 4: out[i] = is_float ? double(load<float>(d)) : is_signed ? double(load<int32_t>(d)) : double(load<uint32_t>(d)); break;
        default: out[i] = is_float ? load<double>(d) : is_signed ? double(load<int64_t>(d)) : double(load<uint64_t>(d)); break;
      }
    }
    return out;
  }

  template <typename T>
  T load(const char* p) const {
    T v;
    if (big_endian_) {
      char b[sizeof(T)];
      for (size_t i = 0; i < sizeof(T); ++i) b[i] = p[sizeof(T) - 1 - i];
      std::memcpy(&v, b, sizeof(T));
    } else {
      std::memcpy(&v, p, sizeof(T));
    }
    return v;
  }

  RawTetMesh read(const std::string& path) {
    RawTetMesh raw;
    raw.mesh.name = base_name(path);
    raw.file = base_name(path);
    raw.origin_kind = "cell";
    auto file = find_tag("VTKFile", 0, text_.size());
    if (!file) c_.fail("not a VTK XML file: no <VTKFile> element");
    if (file->attrs["type"] != "UnstructuredGrid")
      fail_at(file->begin, "only type=\"UnstructuredGrid\" holds tets, got \"" + file->attrs["type"] + "\"");
    if (file->attrs.count("compressor") && !file->attrs["compressor"].empty()) {
      if (file->attrs["compressor"] != "vtkZLibDataCompressor")
        fail_at(file->begin, "compressor " + file->attrs["compressor"] +
                                 " is not supported (vtkZLibDataCompressor is; or save uncompressed)");
      zlib_ = true;
    }
    big_endian_ = file->attrs["byte_order"] == "BigEndian";
    header64_ = file->attrs["header_type"] == "UInt64";
    if (auto app = find_tag("AppendedData", file->end, text_.size())) {
      if (app->attrs["encoding"] != "raw") fail_at(app->begin, "only raw <AppendedData> is supported");
      const size_t underscore = text_.find('_', app->end);
      if (underscore == std::string_view::npos) fail_at(app->begin, "<AppendedData> has no '_' marker");
      appended_start_ = underscore + 1;
    }
    const size_t limit = appended_start_ == std::string_view::npos ? text_.size() : appended_start_;
    const XmlTag piece = need_tag("Piece", file->end, limit);
    const int64_t np = attr_int(piece, "NumberOfPoints", *this);
    const int64_t nc = attr_int(piece, "NumberOfCells", *this);
    const size_t n_points = c_.checked_count(np, 3, "NumberOfPoints");
    const size_t n_cells = c_.checked_count(nc, 2, "NumberOfCells");

    const XmlTag points = need_tag("Points", piece.end, limit);
    const XmlTag parr = need_tag("DataArray", points.end, closing("Points", points));
    if (parr.attrs.count("NumberOfComponents") && parr.attrs.at("NumberOfComponents") != "3")
      fail_at(parr.begin, "points must have NumberOfComponents=\"3\"");
    const std::vector<double> xyz = read_array(parr, 3 * n_points, "points");
    raw.mesh.vertices.resize(n_points);
    for (size_t i = 0; i < n_points; ++i) {
      for (int k = 0; k < 3; ++k) {
        const double v = xyz[3 * i + k];
        if (!std::isfinite(v)) fail_at(parr.begin, "point " + std::to_string(i) + ": non-finite coordinate " + std::to_string(v));
        raw.mesh.vertices[i][k] = v;
      }
    }

    const XmlTag cells = need_tag("Cells", piece.end, limit);
    const size_t cells_end = closing("Cells", cells);
    std::optional<XmlTag> conn_tag, off_tag, type_tag;
    for (size_t at = cells.end;;) {
      auto t = find_tag("DataArray", at, cells_end);
      if (!t) break;
      const std::string name = t->attrs["Name"];
      if (name == "connectivity") conn_tag = t;
      else if (name == "offsets") off_tag = t;
      else if (name == "types") type_tag = t;
      at = t->end;
    }
    if (!conn_tag || !off_tag || !type_tag) fail_at(cells.begin, "<Cells> needs connectivity, offsets and types arrays");
    const std::vector<double> offsets = read_array(*off_tag, n_cells, "offsets");
    const std::vector<double> types = read_array(*type_tag, n_cells, "types");
    const double conn_size = n_cells ? offsets.back() : 0;
    if (conn_size < 0 || conn_size > double(text_.size())) fail_at(off_tag->begin, "bad last offset " + std::to_string(conn_size));
    const std::vector<double> conn = read_array(*conn_tag, static_cast<size_t>(conn_size), "connectivity");

    std::map<int64_t, int64_t> skipped;
    double begin = 0;
    for (size_t i = 0; i < n_cells; ++i) {
      const double end = offsets[i];
      if (end < begin || end > conn_size) fail_at(off_tag->begin, "cell " + std::to_string(i) + ": bad offset " + std::to_string(end));
      // Cell types are small integers; anything else (garbage) is just an unknown type.
      const int64_t type = (types[i] >= 0 && types[i] < 1e6) ? static_cast<int64_t>(types[i]) : -1;
      const auto b = static_cast<size_t>(begin);
      const auto count = static_cast<int64_t>(end - begin);
      begin = end;
      if (type != kVtkTetra && type != kVtkQuadraticTetra) {
        skipped[type]++;
        continue;
      }
      const int64_t need = type == kVtkTetra ? 4 : 10;
      if (count != need)
        fail_at(conn_tag->begin, "cell " + std::to_string(i) + ": type " + std::to_string(type) + " needs " +
                                     std::to_string(need) + " points, it has " + std::to_string(count));
      Tet t;
      for (int k = 0; k < 4; ++k) {
        const double v = conn[b + k];
        if (!(v >= 0 && v < double(n_points)))
          fail_at(conn_tag->begin, "cell " + std::to_string(i) + ": point index " + std::to_string(v) +
                                       " out of range [0, " + std::to_string(int64_t(n_points) - 1) + "]");
        t[k] = static_cast<int32_t>(v);
      }
      raw.mesh.tets.push_back(t);
      raw.tet_origin.push_back(static_cast<int64_t>(i));
    }
    for (const auto& [type, count] : skipped) spdlog::info("{}: skipped {} cells of VTK type {}", raw.file, count, type);
    if (raw.mesh.tets.empty()) c_.fail("no tetrahedra (VTK cell type 10) in the file");
    return raw;
  }

 private:
  std::string_view text_;
  Cursor c_;
  bool big_endian_ = false;
  bool header64_ = false;
  bool zlib_ = false;
  size_t appended_start_ = std::string_view::npos;
};

}  // namespace

RawTetMesh read_vtu(const std::string& path) {
  const std::string bytes = read_file_bytes(path);
  VtuReader reader(bytes, path);
  return reader.read(path);
}

}  // namespace pliant::detail
