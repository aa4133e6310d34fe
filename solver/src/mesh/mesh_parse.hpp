// SPDX-License-Identifier: Apache-2.0
// Private to the mesh loaders: a bounded cursor over a whole file held in memory. Every read
// checks the remaining bytes, so a truncated or garbage file ends in a MeshError naming the file
// and the line (text) or byte offset (binary), never in a crash or an endless loop.
#pragma once

#include "pliant/mesh.hpp"
#include "pliant/mesh_io.hpp"

#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <vector>

namespace pliant::detail {

// Reads a whole file; MeshError if it cannot be opened or read.
std::string read_file_bytes(const std::string& path);

// What a format loader hands to validation: the mesh plus, for each tet, where it came from in
// the file (a line number or an element id), so messages can point at it.
struct RawTetMesh {
  TetMesh mesh;
  std::vector<int64_t> tet_origin;   // per tet: line number or element id in the file
  std::string origin_kind = "element";  // "line" or "element"
  std::string file;
};

class Cursor {
 public:
  Cursor(std::string_view data, std::string file, char comment = '\0')
      : data_(data), file_(std::move(file)), comment_(comment) {}

  const std::string& file() const { return file_; }
  size_t line() const { return line_; }
  size_t pos() const { return pos_; }
  size_t size() const { return data_.size(); }
  size_t remaining() const { return data_.size() - pos_; }
  std::string_view data() const { return data_; }
  bool binary_mode() const { return binary_; }
  void set_binary_mode(bool b) { binary_ = b; }

  // "file:line N: msg" (text) or "file:byte N: msg" (binary sections).
  [[noreturn]] void fail(const std::string& msg) const;
  std::string where() const;

  // Skips blanks, newlines and comments; true if a token follows.
  bool skip_space();
  bool at_end() { return !skip_space(); }
  // Next whitespace-delimited token; fails with "unexpected end of file while reading <what>".
  std::string_view token(const char* what);
  // The rest of the current line (without the newline), and moves to the next line.
  std::string_view rest_of_line();
  // Skips to the start of the next line.
  void next_line();
  // True if the next token (after skipping space) starts at a new line compared to `line`.
  bool token_on_line(size_t line);

  int64_t integer(const char* what);
  double real(const char* what);  // rejects non-numbers; accepts nan/inf (validation rejects them)

  // Binary reads (little- or big-endian as asked), bounded by the buffer.
  template <typename T>
  T raw(const char* what, bool big_endian = false) {
    if (remaining() < sizeof(T)) fail(std::string("unexpected end of file while reading ") + what);
    T v;
    if (big_endian) {
      unsigned char b[sizeof(T)];
      for (size_t i = 0; i < sizeof(T); ++i) b[i] = static_cast<unsigned char>(data_[pos_ + sizeof(T) - 1 - i]);
      std::memcpy(&v, b, sizeof(T));
    } else {
      std::memcpy(&v, data_.data() + pos_, sizeof(T));
    }
    pos_ += sizeof(T);
    return v;
  }
  void skip_bytes(size_t n, const char* what);
  // Binary: consumes one '\n' (optionally preceded by '\r') if present.
  void eat_newline();
  // Finds `needle` from the current position; moves past it. False if absent (no move).
  bool seek_past(std::string_view needle);
  void set_pos(size_t p) { pos_ = p; }
  void restore(size_t p, size_t line) { pos_ = p; line_ = line; }

  // A count read from the file must be non-negative and small enough that `min_bytes_each`
  // bytes per item still fit in what is left of the file.
  size_t checked_count(int64_t n, size_t min_bytes_each, const char* what) const;

 private:
  std::string_view data_;
  std::string file_;
  char comment_;
  size_t pos_ = 0;
  size_t line_ = 1;
  bool binary_ = false;
};

// File name without directories, for messages.
std::string base_name(const std::string& path);
std::string lower_extension(const std::string& path);  // ".node", ".vtk", ... lower case

// Loaders (one per format); all throw MeshError.
RawTetMesh read_tetgen(const std::string& path);
RawTetMesh read_gmsh(const std::string& path);
RawTetMesh read_vtk_legacy(const std::string& path);
RawTetMesh read_vtu(const std::string& path);

// Shortest text that reads back to the same double.
void append_double(std::string& out, double v);
void append_int(std::string& out, int64_t v);
void write_file_bytes(const std::string& path, std::string_view bytes);

// base64 (RFC 4648, standard alphabet)
std::string base64_encode(std::string_view bytes);
// Fails through `cursor` on bad characters.
std::string base64_decode(std::string_view text, const Cursor& cursor);

}  // namespace pliant::detail
