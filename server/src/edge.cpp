// SPDX-License-Identifier: Apache-2.0
// Echoing client input in errors, and model_path names confined to the model path.
#include "pliant/server/edge.hpp"

#include <spdlog/fmt/fmt.h>

#include <cctype>
#include <filesystem>

namespace fs = std::filesystem;

namespace pliant::server {

std::string echo(std::string_view value) {
  std::string out = "'";
  size_t shown = 0;
  for (unsigned char c : value) {
    if (shown == kMaxEcho) break;
    if (c >= 0x20 && c < 0x7f && c != '\'' && c != '\\') out += static_cast<char>(c);
    else out += fmt::format("\\x{:02x}", c);
    ++shown;
  }
  out += "'";
  if (value.size() > kMaxEcho) out += fmt::format("... ({} characters)", value.size());
  return out;
}

std::string cap_message(std::string message) {
  if (message.size() <= kMaxErrorMessage) return message;
  const size_t full = message.size();
  message.resize(kMaxErrorMessage - 48);
  message += fmt::format("... (message cut, {} bytes in all)", full);
  return message;
}

namespace {

constexpr size_t kMaxModelName = 4096;

Error invalid(std::string m) { return Error::make(Code::InvalidArgument, std::move(m)); }

// True when canonical `p` lies strictly inside canonical directory `root`.
bool inside(const fs::path& root, const fs::path& p) {
  const fs::path rel = p.lexically_relative(root);
  return !rel.empty() && *rel.begin() != ".." && rel != ".";
}

std::string lower_extension(const fs::path& p) {
  std::string e = p.extension().string();
  for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

// Every file the mesh loader may open when given `file`: the file, and the TetGen .node/.ele
// pair next to it (by its stem, or with the extension appended when it has none it knows).
std::vector<fs::path> loader_files(const fs::path& file) {
  std::vector<fs::path> out{file};
  const std::string ext = lower_extension(file);
  const bool tetgen = ext == ".node" || ext == ".ele" || ext == ".face" || ext == ".edge" || ext == ".neigh";
  fs::path stem = file;
  if (tetgen) stem.replace_extension();
  for (const char* e : {".node", ".ele"}) out.push_back(fs::path(stem.string() + e));
  if (tetgen)
    for (const char* e : {".node", ".ele"}) out.push_back(fs::path(file.string() + e));
  return out;
}

}  // namespace

Error resolve_model_file(const std::string& field, const std::string& name,
                         const std::vector<std::string>& model_path, std::string* path) {
  if (name.empty()) return invalid(fmt::format("{} is empty; give a file name on the server's model path", field));
  if (size_t nul = name.find('\0'); nul != std::string::npos)
    return invalid(fmt::format("{} {} contains a NUL character at offset {}", field, echo(name), nul));
  if (name.size() > kMaxModelName)
    return invalid(fmt::format("{} {} is longer than {} characters", field, echo(name), kMaxModelName));
  const fs::path p(name);
  bool escapes = p.is_absolute() || p.has_root_name() || p.has_root_directory();
  for (const auto& part : p)
    if (part == "..") escapes = true;
  if (escapes)
    return invalid(fmt::format("{} {} must be a relative name on the server's model path (no '..', not absolute)",
                               field, echo(name)));
  if (model_path.empty())
    return Error::make(Code::FailedPrecondition, fmt::format("{} {}: this server has no --model-path", field, echo(name)));
  for (const std::string& dir : model_path) {
    std::error_code ec;
    const fs::path root = fs::canonical(dir, ec);
    if (ec || !fs::is_directory(root, ec)) continue;
    fs::path candidate = root / p;
    if (!fs::exists(candidate, ec)) candidate += ".node";  // a TetGen mesh named by its stem
    if (!fs::exists(candidate, ec)) continue;
    const fs::path file = fs::canonical(candidate, ec);
    if (ec || !inside(root, file))
      return invalid(fmt::format("{} {} leads outside the model path directory (through a symlink)", field, echo(name)));
    if (!fs::is_regular_file(file, ec))
      return invalid(fmt::format("{} {} is not a regular file", field, echo(name)));
    for (const fs::path& companion : loader_files(file)) {
      if (!fs::exists(companion, ec)) continue;
      const fs::path c = fs::canonical(companion, ec);
      if (ec || !inside(root, c) || !fs::is_regular_file(c, ec))
        return invalid(fmt::format("{} {}: a file the mesh is read from leads outside the model path directory "
                                   "or is not a regular file", field, echo(name)));
    }
    *path = file.string();
    return {};
  }
  return Error::make(Code::NotFound, fmt::format("{} {} not found on the server's model path", field, echo(name)));
}

}  // namespace pliant::server
