// SPDX-License-Identifier: Apache-2.0
// Checks at the service's edge that several requests share: how client input is echoed back in
// error messages, and how a model_path name becomes a file inside the server's model path.
#pragma once

#include "pliant/server/error.hpp"

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace pliant::server {

// The most characters of a client's input an error message repeats.
constexpr size_t kMaxEcho = 200;
// The longest error message the server sends (gRPC carries it in a header: 8 KiB at most).
constexpr size_t kMaxErrorMessage = 1024;

// `value` as an error message quotes it: control and non-ASCII bytes as \xNN, cut after
// kMaxEcho characters with the full length appended ("abc... (9000 characters)").
std::string echo(std::string_view value);

// Caps a whole error message at kMaxErrorMessage bytes (a safety net behind echo()).
std::string cap_message(std::string message);

// The file a MeshSource.model_path name stands for: `name` is a relative name resolved in the
// model-path directories, in order; the file found (and a TetGen mesh's .node/.ele pair) must
// lie inside that directory once symlinks are resolved. No NUL, no absolute name, no '..', no
// fallback to the working directory. `field` names the request field in errors.
// On success *path is the canonical path to load (a TetGen mesh: its .node file).
Error resolve_model_file(const std::string& field, const std::string& name,
                         const std::vector<std::string>& model_path, std::string* path);

}  // namespace pliant::server
