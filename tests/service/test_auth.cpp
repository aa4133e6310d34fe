// SPDX-License-Identifier: Apache-2.0
// The access token: read from --token-file or PLIANT_TOKEN (kept out of the process list),
// checked on every pliant.v1 call whatever the presented length, and on reflection when
// --reflection token says so (--reflection off refuses reflection altogether).
#include "pliant/client/client.hpp"
#include "pliant/server/options.hpp"
#include "pliant/server/server.hpp"

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include "in_process_server.hpp"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <unistd.h>

namespace fs = std::filesystem;
using namespace pliant;

namespace {

using namespace test::grpc_codes;

server::EnvLookup env_of(std::map<std::string, std::string> vars) {
  return [vars](const std::string& name) -> std::optional<std::string> {
    auto it = vars.find(name);
    if (it == vars.end()) return std::nullopt;
    return it->second;
  };
}

server::Error parse(std::vector<std::string> args, server::ServerOptions* o,
                    std::map<std::string, std::string> env = {}) {
  bool help = false;
  return server::parse_server_options(args, env_of(std::move(env)), o, &help);
}

fs::path token_file(const std::string& content) {
  fs::path p = fs::temp_directory_path() / ("pliant_token_" + std::to_string(::getpid()) + "_" +
                                            std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()));
  std::ofstream(p) << content;
  return p;
}

// One reflection request (list services) over a raw generic call; the call's final status.
grpc::Status list_services(int port, const std::string& token) {
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);
  grpc::CompletionQueue cq;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  auto call = stub.PrepareCall(&ctx, "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo", &cq);
  auto next = [&] {
    void* tag = nullptr;
    bool ok = false;
    return cq.Next(&tag, &ok) && ok;
  };
  int tags[5];
  call->StartCall(&tags[0]);
  next();
  const char request[] = {0x3a, 0x00};  // ServerReflectionRequest{list_services: ""}
  grpc::Slice slice(request, sizeof request);
  grpc::ByteBuffer buffer(&slice, 1);
  call->Write(buffer, &tags[1]);
  next();
  grpc::ByteBuffer response;
  call->Read(&response, &tags[2]);
  const bool got_answer = next();
  call->WritesDone(&tags[3]);
  next();
  grpc::Status status;
  call->Finish(&status, &tags[4]);
  next();
  cq.Shutdown();
  void* tag;
  bool ok;
  while (cq.Next(&tag, &ok)) {
  }
  if (status.ok() && !got_answer) return grpc::Status(grpc::StatusCode::UNKNOWN, "no answer");
  return status;
}

}  // namespace

TEST(Auth, TokenFromAFileOrTheEnvironment) {
  server::ServerOptions o;
  const fs::path f = token_file("s3cret-from-file\n");
  ASSERT_TRUE(parse({"--token-file", f.string()}, &o).ok());
  EXPECT_EQ(o.token, "s3cret-from-file");
  ASSERT_TRUE(parse({"--token", "on-the-command-line", "--token-file", f.string()}, &o).ok());
  EXPECT_EQ(o.token, "s3cret-from-file");  // the file wins
  ASSERT_TRUE(parse({}, &o, {{"PLIANT_TOKEN", "from-env"}}).ok());
  EXPECT_EQ(o.token, "from-env");
  ASSERT_TRUE(parse({}, &o, {{"PLIANT_TOKEN_FILE", f.string()}}).ok());
  EXPECT_EQ(o.token, "s3cret-from-file");

  server::Error e = parse({"--token-file", "/nonexistent/token"}, &o);
  EXPECT_FALSE(e.ok());
  EXPECT_NE(e.message.find("--token-file must be a readable file"), std::string::npos) << e.message;
  const fs::path spaced = token_file("two words\n");
  e = parse({"--token-file", spaced.string()}, &o);
  EXPECT_FALSE(e.ok());
  EXPECT_EQ(e.message.find("two words"), std::string::npos) << "the token is not echoed: " << e.message;
  e = parse({"--token", "has space"}, &o);
  EXPECT_FALSE(e.ok());
  EXPECT_EQ(e.message.find("has space"), std::string::npos) << e.message;
  fs::remove(f);
  fs::remove(spaced);
}

TEST(Auth, ReflectionOptionIsChecked) {
  server::ServerOptions o;
  EXPECT_TRUE(parse({}, &o).ok());
  EXPECT_EQ(o.reflection, "open");
  server::Error e = parse({"--reflection", "token"}, &o);
  EXPECT_FALSE(e.ok());
  EXPECT_NE(e.message.find("--reflection token needs a token"), std::string::npos) << e.message;
  e = parse({"--reflection", "maybe"}, &o);
  EXPECT_NE(e.message.find("--reflection must be open, token or off, got 'maybe'"), std::string::npos) << e.message;
  EXPECT_TRUE(parse({"--reflection", "token", "--token", "t0k"}, &o).ok());
}

TEST(Auth, WrongTokensOfAnyLengthAreRefused) {
  server::ServerOptions o;
  o.token = "correct-horse";
  test::InProcessServer srv(o);
  ASSERT_TRUE(srv.started.ok());
  for (const std::string& token : {std::string(""), std::string("c"), std::string("correct-hors"),
                                   std::string("correct-horsE"), std::string("correct-horse-"),
                                   std::string(4000, 'c')}) {
    auto r = srv.client(token).list_scenes();
    EXPECT_EQ(r.status.code, kUnauthenticated) << token.size() << ": " << r.status.to_string();
  }
  EXPECT_TRUE(srv.client("correct-horse").list_scenes().ok());
}

TEST(Auth, ReflectionCanRequireTheToken) {
  server::ServerOptions o;
  o.token = "t0k";
  o.reflection = "token";
  test::InProcessServer srv(o);
  ASSERT_TRUE(srv.started.ok());
  EXPECT_FALSE(list_services(srv.port(), "").ok());
  EXPECT_FALSE(list_services(srv.port(), "wrong").ok());
  grpc::Status s = list_services(srv.port(), "t0k");
  EXPECT_TRUE(s.ok()) << s.error_message();
}

TEST(Auth, ReflectionOpenByDefaultAndOffOnRequest) {
  server::ServerOptions o;
  o.token = "t0k";
  {
    test::InProcessServer srv(o);
    ASSERT_TRUE(srv.started.ok());
    grpc::Status s = list_services(srv.port(), "");
    EXPECT_TRUE(s.ok()) << s.error_message();  // documented: open without the token
  }
  o.reflection = "off";
  test::InProcessServer srv(o);
  ASSERT_TRUE(srv.started.ok());
  EXPECT_FALSE(list_services(srv.port(), "t0k").ok());
}
