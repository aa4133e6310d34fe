// SPDX-License-Identifier: Apache-2.0
// Server reflection answers, so generic gRPC tools (grpcurl, grpc_cli) can discover the API.
// The reflection protocol is spoken with a raw generic call to keep its stubs out of the build.
#include "pliant/server/server.hpp"

#include "in_process_server.hpp"

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

namespace {

bool next(grpc::CompletionQueue& cq, void* expected) {
  void* tag = nullptr;
  bool ok = false;
  return cq.Next(&tag, &ok) && tag == expected && ok;
}

}  // namespace

TEST(Reflection, ListsThePliantServices) {
  spdlog::set_level(spdlog::level::warn);
  pliant::test::InProcessServer server;
  ASSERT_TRUE(server.started.ok());
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(server.port()),
                                     grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);
  grpc::CompletionQueue cq;
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  auto call = stub.PrepareCall(&ctx, "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo", &cq);
  int tags[5];
  call->StartCall(&tags[0]);
  ASSERT_TRUE(next(cq, &tags[0]));
  // ServerReflectionRequest{list_services: ""}: field 7, length-delimited, empty.
  const char request[] = {0x3a, 0x00};
  grpc::Slice slice(request, sizeof request);
  grpc::ByteBuffer buffer(&slice, 1);
  call->Write(buffer, &tags[1]);
  ASSERT_TRUE(next(cq, &tags[1]));
  grpc::ByteBuffer response;
  call->Read(&response, &tags[2]);
  ASSERT_TRUE(next(cq, &tags[2]));
  std::vector<grpc::Slice> slices;
  ASSERT_TRUE(response.Dump(&slices).ok());
  std::string bytes;
  for (auto& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
  for (const char* service : {"pliant.v1.SceneService", "pliant.v1.FrameService",
                              "pliant.v1.SnapshotService", "grpc.health.v1.Health"})
    EXPECT_NE(bytes.find(service), std::string::npos) << service;
  call->WritesDone(&tags[3]);
  next(cq, &tags[3]);
  grpc::Status status;
  call->Finish(&status, &tags[4]);
  next(cq, &tags[4]);
  EXPECT_TRUE(status.ok()) << status.error_message();
  cq.Shutdown();
  void* tag;
  bool ok;
  while (cq.Next(&tag, &ok)) {
  }
  server.server->shutdown();
}
