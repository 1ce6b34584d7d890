# Helpers that give every core stage the same shape: one target, one alias, dependencies named in one place.

add_library(posewarp_warnings INTERFACE)
target_compile_options(posewarp_warnings INTERFACE -Wall -Wextra -Wpedantic -Wno-missing-field-initializers
                                                   $<$<CXX_COMPILER_ID:GNU>:-Wshadow=local>)
if(POSEWARP_WERROR)
  target_compile_options(posewarp_warnings INTERFACE -Werror)
endif()

# ITK's headers are wrapped in their own target so that they are only ever seen as SYSTEM headers and only by
# the translation units that ask for them (io/src). Its own copy of Eigen must never meet the system Eigen.
add_library(posewarp_itk INTERFACE)
target_include_directories(posewarp_itk SYSTEM INTERFACE ${ITK_INCLUDE_DIRS} /usr/include/gdcm-3.0)
target_link_libraries(posewarp_itk INTERFACE ${ITK_LIBRARIES} gdcmMSFF gdcmDSED gdcmCommon)

# posewarp_add_stage(<name> SOURCES ... [PUBLIC deps...] [PRIVATE deps...])
# Creates the static library posewarp_<name>, aliased posewarp::<name>, with include/ as its public headers.
function(posewarp_add_stage name)
  cmake_parse_arguments(ARG "" "" "SOURCES;PUBLIC;PRIVATE" ${ARGN})
  set(target posewarp_${name})
  add_library(${target} STATIC ${ARG_SOURCES})
  add_library(posewarp::${name} ALIAS ${target})
  target_include_directories(${target} PUBLIC ${CMAKE_CURRENT_SOURCE_DIR}/include)
  target_link_libraries(${target} PUBLIC ${ARG_PUBLIC} PRIVATE ${ARG_PRIVATE} posewarp_warnings)
  set_target_properties(${target} PROPERTIES POSITION_INDEPENDENT_CODE ON)
endfunction()

# posewarp_add_test(<name> SOURCES ... LIBS ... [LABELS ...])
function(posewarp_add_test name)
  cmake_parse_arguments(ARG "" "" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} GTest::gtest GTest::gtest_main posewarp_warnings)
  target_include_directories(${name} PRIVATE ${PROJECT_SOURCE_DIR}/tests/unit)
  target_compile_definitions(${name} PRIVATE
    POSEWARP_SAMPLE_DIR="${PROJECT_SOURCE_DIR}/data/totalsegmentator_example"
    POSEWARP_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
  # One label word (gtest_discover_tests flattens a list in PROPERTIES): "unit;server" becomes "unit-server", which
  # `ctest -L server` matches.
  string(JOIN "-" label ${ARG_LABELS})
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 PROPERTIES LABELS "${label}")
endfunction()
