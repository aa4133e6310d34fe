// SPDX-License-Identifier: Apache-2.0
// The outcome of an operation at the service's edge: a gRPC-like code and a message naming the
// field and the value. Its own header so that code which only reports errors (request checks,
// snapshot files, options) needs neither the scene nor gRPC.
#pragma once

#include <string>
#include <utility>

namespace pliant::server {

enum class Code {
  Ok,
  InvalidArgument,
  NotFound,
  AlreadyExists,
  ResourceExhausted,
  FailedPrecondition,
  Unauthenticated,
  Unavailable,
  DeadlineExceeded,
  Cancelled,
  Internal,
};

// Ok when code == Ok.
struct Error {
  Code code = Code::Ok;
  std::string message;
  bool ok() const { return code == Code::Ok; }
  static Error make(Code c, std::string m) { return Error{c, std::move(m)}; }
  // The most common failure: the request's field holds a value the server does not accept.
  static Error invalid(std::string m) { return Error{Code::InvalidArgument, std::move(m)}; }
};

}  // namespace pliant::server
