# SPDX-License-Identifier: Apache-2.0
# Install rules and the CMake package: find_package(Pliant) gives
#   Pliant::client   the gRPC client library (typed calls over the generated stubs; Pliant::proto)
#   Pliant::solver   the solver library (with Pliant::mesh, Pliant::settings), when it was built
# plus the programs, the model set (share/pliant/meshes) and the viewer's page (share/pliant/web).
include(CMakePackageConfigHelpers)

set(PLIANT_CMAKE_DIR "${CMAKE_INSTALL_LIBDIR}/cmake/Pliant")
set(PLIANT_COMPONENTS)

# Programs.
foreach(program pliant-server pliant pliant-haptic pliant-web pliant-sim pliant-mesh)
  if(TARGET ${program})
    install(TARGETS ${program} RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR} COMPONENT runtime)
  endif()
endforeach()

# Data: the model set (with its own licences, meshes/SOURCES.md) and the viewer's page.
install(DIRECTORY ${PROJECT_SOURCE_DIR}/meshes/ DESTINATION ${PLIANT_INSTALL_DATADIR}/meshes
        COMPONENT runtime)
if(TARGET pliant-web)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/web/ DESTINATION ${PLIANT_INSTALL_DATADIR}/web
          COMPONENT runtime PATTERN "node_modules" EXCLUDE)
endif()
install(FILES ${PROJECT_SOURCE_DIR}/LICENSE ${PROJECT_SOURCE_DIR}/NOTICE
        DESTINATION ${CMAKE_INSTALL_DOCDIR} COMPONENT runtime)

# Libraries and headers.
set(pliant_export_targets pliant_version pliant_mesh pliant_settings)
install(FILES ${PROJECT_BINARY_DIR}/generated/pliant/version.hpp
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/pliant COMPONENT development)
if(TARGET pliant_solver)
  # The solver's public headers (solver/include/pliant/*.hpp): mesh, settings and solver alike.
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/solver/include/pliant/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/pliant
          COMPONENT development FILES_MATCHING PATTERN "*.hpp")
  list(APPEND pliant_export_targets pliant_solver)
  list(APPEND PLIANT_COMPONENTS solver)
else()
  # Client only: the headers of the two solver libraries that were built.
  set(pliant_mesh_headers mesh mesh_io mesh_validate builtin_meshes render_mesh settings)
  list(TRANSFORM pliant_mesh_headers PREPEND ${PROJECT_SOURCE_DIR}/solver/include/pliant/)
  list(TRANSFORM pliant_mesh_headers APPEND .hpp)
  install(FILES ${pliant_mesh_headers} DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/pliant COMPONENT development)
endif()
if(TARGET pliant_client)
  list(APPEND pliant_export_targets pliant_proto pliant_client)
  list(APPEND PLIANT_COMPONENTS client)
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/client/include/pliant/client/
          DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/pliant/client COMPONENT development
          FILES_MATCHING PATTERN "client.hpp")
  # The generated messages and stubs of the API (pliant/v1/pliant.pb.h, pliant.grpc.pb.h) and
  # the .proto itself, for clients in other languages.
  install(DIRECTORY ${PROJECT_BINARY_DIR}/proto/gen/pliant/ DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/pliant
          COMPONENT development FILES_MATCHING PATTERN "*.h")
  install(DIRECTORY ${PROJECT_SOURCE_DIR}/proto/pliant/ DESTINATION ${PLIANT_INSTALL_DATADIR}/proto/pliant
          COMPONENT development FILES_MATCHING PATTERN "*.proto")
endif()

install(TARGETS ${pliant_export_targets} EXPORT PliantTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR} COMPONENT development
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(EXPORT PliantTargets NAMESPACE Pliant:: DESTINATION ${PLIANT_CMAKE_DIR}
        FILE PliantTargets.cmake COMPONENT development)

configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/PliantConfig.cmake.in
  ${PROJECT_BINARY_DIR}/PliantConfig.cmake INSTALL_DESTINATION ${PLIANT_CMAKE_DIR}
  PATH_VARS PLIANT_INSTALL_DATADIR)
# 0.x: a minor version may break the API, so only the same major.minor is compatible.
write_basic_package_version_file(${PROJECT_BINARY_DIR}/PliantConfigVersion.cmake
  VERSION ${PROJECT_VERSION} COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/PliantConfig.cmake ${PROJECT_BINARY_DIR}/PliantConfigVersion.cmake
        DESTINATION ${PLIANT_CMAKE_DIR} COMPONENT development)
