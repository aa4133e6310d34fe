# SPDX-License-Identifier: Apache-2.0
# pliant_add_gtest: one GoogleTest executable, its tests registered with ctest under one label
# and one per-test timeout. Sources are listed explicitly (a new test file is added to the
# executable whose speed and area it shares; tests/README.md says which).
#
#   pliant_add_gtest(NAME <executable>
#                    LABELS <label>             one of: unit physics slow service browser deploy
#                    TIMEOUT <seconds>          per test, sized to what the executable does
#                    SOURCES <file>...
#                    [LIBRARIES <target>...]    linked PRIVATE (GTest and pliant_test_support always)
#                    [DEFINITIONS <def>...]     compile definitions, PRIVATE
#                    [DEPENDS <target>...])     built before the tests run (tools they start)
set(PLIANT_TEST_LABELS unit physics slow service browser deploy)

# Sanitizer builds run the same tests several times slower: their build directories set
# PLIANT_TEST_TIMEOUT_SCALE (scripts/sanitize.sh) and every per-test timeout is multiplied by it.
set(PLIANT_TEST_TIMEOUT_SCALE 1 CACHE STRING "Factor applied to every test's timeout (sanitizer builds)")
if(NOT PLIANT_TEST_TIMEOUT_SCALE MATCHES "^[1-9][0-9]*$")
  message(FATAL_ERROR "PLIANT_TEST_TIMEOUT_SCALE must be a whole number >= 1, got '${PLIANT_TEST_TIMEOUT_SCALE}'")
endif()

# A build may compile only some labels' executables (the sanitizer builds in CI run three labels
# and need not compile the physics and slow suites): PLIANT_TEST_BUILD_LABELS lists them
# (default: every label). An executable of another label is not defined at all, so
# `ctest -L <those labels>` in such a build finds every test of them.
set(PLIANT_TEST_BUILD_LABELS "${PLIANT_TEST_LABELS}" CACHE STRING
    "Labels whose test executables are built (a ;-list of: unit physics slow service browser deploy)")
foreach(_label ${PLIANT_TEST_BUILD_LABELS})
  if(NOT _label IN_LIST PLIANT_TEST_LABELS)
    string(REPLACE ";" ", " _known "${PLIANT_TEST_LABELS}")
    message(FATAL_ERROR "PLIANT_TEST_BUILD_LABELS: unknown label '${_label}' (one of: ${_known})")
  endif()
endforeach()

# pliant_test_label_built(<var> <label>): TRUE in <var> when this build compiles <label>'s tests.
function(pliant_test_label_built var label)
  if(label IN_LIST PLIANT_TEST_BUILD_LABELS)
    set(${var} TRUE PARENT_SCOPE)
  else()
    set(${var} FALSE PARENT_SCOPE)
  endif()
endfunction()

# pliant_test_timeout(<var> <seconds>): <seconds> times PLIANT_TEST_TIMEOUT_SCALE, into <var>.
function(pliant_test_timeout var seconds)
  math(EXPR scaled "${seconds} * ${PLIANT_TEST_TIMEOUT_SCALE}")
  set(${var} ${scaled} PARENT_SCOPE)
endfunction()

# Fails the configure step for a label outside the documented set (a typo would hide a test
# from `ctest -L`).
function(pliant_check_test_labels where)
  string(REPLACE ";" ", " known "${PLIANT_TEST_LABELS}")
  if(NOT ARGN)
    message(FATAL_ERROR "${where}: LABELS is required (one of: ${known})")
  endif()
  foreach(label ${ARGN})
    if(NOT label IN_LIST PLIANT_TEST_LABELS)
      message(FATAL_ERROR "${where}: unknown test label '${label}' (one of: ${known})")
    endif()
  endforeach()
endfunction()

function(pliant_add_gtest)
  cmake_parse_arguments(PARSE_ARGV 0 arg "" "NAME;TIMEOUT" "LABELS;SOURCES;LIBRARIES;DEFINITIONS;DEPENDS")
  if(arg_UNPARSED_ARGUMENTS)
    message(FATAL_ERROR "pliant_add_gtest: unexpected arguments '${arg_UNPARSED_ARGUMENTS}'")
  endif()
  if(NOT arg_NAME OR NOT arg_SOURCES)
    message(FATAL_ERROR "pliant_add_gtest: NAME and SOURCES are required")
  endif()
  if(NOT arg_TIMEOUT MATCHES "^[1-9][0-9]*$")
    message(FATAL_ERROR "pliant_add_gtest(${arg_NAME}): TIMEOUT must be a whole number of seconds, got '${arg_TIMEOUT}'")
  endif()
  pliant_check_test_labels("pliant_add_gtest(${arg_NAME})" ${arg_LABELS})
  # One label per executable: gtest_discover_tests hands PROPERTIES on as a flat list, so a
  # second label would be read as a property name.
  list(LENGTH arg_LABELS label_count)
  if(NOT label_count EQUAL 1)
    message(FATAL_ERROR "pliant_add_gtest(${arg_NAME}): one label per executable, got '${arg_LABELS}'")
  endif()

  pliant_test_label_built(built ${arg_LABELS})
  if(NOT built)
    return()
  endif()
  add_executable(${arg_NAME} ${arg_SOURCES})
  target_link_libraries(${arg_NAME} PRIVATE ${arg_LIBRARIES} pliant_test_support GTest::gtest GTest::gtest_main)
  if(arg_DEFINITIONS)
    target_compile_definitions(${arg_NAME} PRIVATE ${arg_DEFINITIONS})
  endif()
  if(arg_DEPENDS)
    add_dependencies(${arg_NAME} ${arg_DEPENDS})
  endif()
  pliant_test_timeout(timeout ${arg_TIMEOUT})
  pliant_test_timeout(discovery 60)
  # COST: ctest -j starts the costlier tests first. A fresh build has no measured costs
  # (Testing/Temporary/CTestCostData.txt), and without them the minutes-long physics and slow
  # tests, declared late, would run last beside an idle core; the executable's timeout is sized
  # to what it does, so it ranks them.
  gtest_discover_tests(${arg_NAME} DISCOVERY_TIMEOUT ${discovery}
                       PROPERTIES LABELS ${arg_LABELS} TIMEOUT ${timeout} COST ${arg_TIMEOUT})
endfunction()
