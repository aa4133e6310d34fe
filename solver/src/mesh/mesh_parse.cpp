// SPDX-License-Identifier: Apache-2.0
#include "mesh/mesh_parse.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <fstream>
#include <limits>
#include <sstream>

namespace pliant::detail {

std::string read_file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MeshError(path + ": cannot open file");
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  if (size < 0) throw MeshError(path + ": cannot read file (is it a directory?)");
  in.seekg(0, std::ios::beg);
  std::string bytes(static_cast<size_t>(size), '\0');
  if (size > 0 && !in.read(bytes.data(), size)) throw MeshError(path + ": read error");
  return bytes;
}

void write_file_bytes(const std::string& path, std::string_view bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw MeshError(path + ": cannot open file for writing");
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (!out) throw MeshError(path + ": write error");
}

std::string base_name(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

std::string lower_extension(const std::string& path) {
  const std::string name = base_name(path);
  const size_t dot = name.find_last_of('.');
  if (dot == std::string::npos) return "";
  std::string ext = name.substr(dot);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

std::string Cursor::where() const {
  if (binary_) return file_ + ":byte " + std::to_string(pos_);
  return file_ + ":" + std::to_string(line_);
}

void Cursor::fail(const std::string& msg) const { throw MeshError(where() + ": " + msg); }

bool Cursor::skip_space() {
  while (pos_ < data_.size()) {
    const char c = data_[pos_];
    if (c == '\n') {
      ++line_;
      ++pos_;
    } else if (c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v') {
      ++pos_;
    } else if (comment_ != '\0' && c == comment_) {
      while (pos_ < data_.size() && data_[pos_] != '\n') ++pos_;
    } else {
      return true;
    }
  }
  return false;
}

std::string_view Cursor::token(const char* what) {
  if (!skip_space()) fail(std::string("unexpected end of file while reading ") + what);
  const size_t start = pos_;
  while (pos_ < data_.size()) {
    const char c = data_[pos_];
    if (c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v') break;
    if (comment_ != '\0' && c == comment_) break;
    ++pos_;
  }
  return data_.substr(start, pos_ - start);
}

std::string_view Cursor::rest_of_line() {
  const size_t start = pos_;
  while (pos_ < data_.size() && data_[pos_] != '\n') ++pos_;
  std::string_view out = data_.substr(start, pos_ - start);
  if (!out.empty() && out.back() == '\r') out.remove_suffix(1);
  if (pos_ < data_.size()) {
    ++pos_;
    ++line_;
  }
  return out;
}

void Cursor::next_line() { rest_of_line(); }

bool Cursor::token_on_line(size_t line) {
  // Only blanks (not newlines or comments) may separate tokens on the same line.
  while (pos_ < data_.size() && (data_[pos_] == ' ' || data_[pos_] == '\t' || data_[pos_] == '\r')) ++pos_;
  if (pos_ >= data_.size()) return false;
  const char c = data_[pos_];
  if (c == '\n' || (comment_ != '\0' && c == comment_)) return false;
  return line_ == line;
}

static std::string printable(std::string_view tok) {
  std::string out;
  for (char c : tok.substr(0, 40)) {
    const auto u = static_cast<unsigned char>(c);
    if (u >= 32 && u < 127) {
      out += c;
    } else {
      static const char* hex = "0123456789abcdef";
      out += "\\x";
      out += hex[u >> 4];
      out += hex[u & 15];
    }
  }
  if (tok.size() > 40) out += "...";
  return out;
}

int64_t Cursor::integer(const char* what) {
  const std::string_view tok = token(what);
  int64_t v = 0;
  const char* b = tok.data();
  const char* e = tok.data() + tok.size();
  if (b != e && *b == '+') ++b;
  auto [p, ec] = std::from_chars(b, e, v);
  if (ec == std::errc::result_out_of_range) fail(std::string(what) + " out of range: '" + printable(tok) + "'");
  if (ec != std::errc() || p != e) fail(std::string("expected an integer for ") + what + ", got '" + printable(tok) + "'");
  return v;
}

double Cursor::real(const char* what) {
  const std::string_view tok = token(what);
  double v = 0;
  const char* b = tok.data();
  const char* e = tok.data() + tok.size();
  if (b != e && *b == '+') ++b;
  auto [p, ec] = std::from_chars(b, e, v);
  if (ec == std::errc::result_out_of_range) {
    // Denormal underflow or overflow: report as a value problem, not a syntax one.
    fail(std::string(what) + " out of the range of a double: '" + printable(tok) + "'");
  }
  if (ec != std::errc() || p != e) fail(std::string("expected a number for ") + what + ", got '" + printable(tok) + "'");
  return v;
}

void Cursor::skip_bytes(size_t n, const char* what) {
  if (remaining() < n) fail(std::string("unexpected end of file while reading ") + what);
  pos_ += n;
}

void Cursor::eat_newline() {
  if (pos_ < data_.size() && data_[pos_] == '\r') ++pos_;
  if (pos_ < data_.size() && data_[pos_] == '\n') {
    ++pos_;
    ++line_;
  }
}

bool Cursor::seek_past(std::string_view needle) {
  const size_t at = data_.find(needle, pos_);
  if (at == std::string_view::npos) return false;
  line_ += static_cast<size_t>(std::count(data_.begin() + pos_, data_.begin() + at + needle.size(), '\n'));
  pos_ = at + needle.size();
  return true;
}

size_t Cursor::checked_count(int64_t n, size_t min_bytes_each, const char* what) const {
  if (n < 0) fail(std::string("negative ") + what + ": " + std::to_string(n));
  const size_t each = std::max<size_t>(min_bytes_each, 1);
  if (static_cast<uint64_t>(n) > remaining() / each)
    fail(std::string(what) + " " + std::to_string(n) + " cannot fit in the " + std::to_string(remaining()) +
         " bytes left in the file (truncated file or bad count)");
  if (static_cast<uint64_t>(n) > static_cast<uint64_t>(std::numeric_limits<int32_t>::max()))
    fail(std::string(what) + " " + std::to_string(n) + " exceeds the 32-bit index range");
  return static_cast<size_t>(n);
}

void append_double(std::string& out, double v) {
  char buf[64];
  auto [p, ec] = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, p);
}

void append_int(std::string& out, int64_t v) {
  char buf[32];
  auto [p, ec] = std::to_chars(buf, buf + sizeof buf, v);
  out.append(buf, p);
}

static constexpr char kB64[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

std::string base64_encode(std::string_view bytes) {
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (uint32_t(uint8_t(bytes[i])) << 16) | (uint32_t(uint8_t(bytes[i + 1])) << 8) | uint8_t(bytes[i + 2]);
    out += kB64[(v >> 18) & 63];
    out += kB64[(v >> 12) & 63];
    out += kB64[(v >> 6) & 63];
    out += kB64[v & 63];
  }
  if (i < bytes.size()) {
    uint32_t v = uint32_t(uint8_t(bytes[i])) << 16;
    if (i + 1 < bytes.size()) v |= uint32_t(uint8_t(bytes[i + 1])) << 8;
    out += kB64[(v >> 18) & 63];
    out += kB64[(v >> 12) & 63];
    out += (i + 1 < bytes.size()) ? kB64[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string base64_decode(std::string_view text, const Cursor& cursor) {
  int8_t table[256];
  std::fill(std::begin(table), std::end(table), int8_t(-1));
  for (int i = 0; i < 64; ++i) table[static_cast<unsigned char>(kB64[i])] = static_cast<int8_t>(i);
  std::string out;
  out.reserve(text.size() / 4 * 3);
  uint32_t acc = 0;
  int bits = 0;
  for (char c : text) {
    if (c == ' ' || c == '\n' || c == '\r' || c == '\t') continue;
    if (c == '=') {  // padding ends a block; separately encoded blocks may follow
      acc = 0;
      bits = 0;
      continue;
    }
    const int8_t d = table[static_cast<unsigned char>(c)];
    if (d < 0) cursor.fail(std::string("invalid base64 character '") + printable(std::string_view(&c, 1)) + "'");
    acc = (acc << 6) | uint32_t(d);
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out += static_cast<char>((acc >> bits) & 0xff);
    }
  }
  return out;
}

}  // namespace pliant::detail
