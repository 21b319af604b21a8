# pcl_rast_add_module(<name> [DEPS <modules...>] [LIBS <libraries...>] [PRIVATE_LIBS <libraries...>])
#
# Builds library pcl_rast::<name> (file libpcl_rast_<name>) from <name>/src/*.cpp with public headers in
# <name>/include/pcl/<name>/, exports it as pcl_rast::<name> and installs it.
# Sources are globbed (CONFIGURE_DEPENDS) so that adding a unit is one new file.
function(pcl_rast_add_module name)
  cmake_parse_arguments(ARG "" "" "DEPS;LIBS;PRIVATE_LIBS" ${ARGN})
  file(GLOB srcs CONFIGURE_DEPENDS "${CMAKE_CURRENT_SOURCE_DIR}/src/*.cpp")
  # The target is pcl_rast_<name>_lib (file libpcl_rast_<name>.so): the plain name is
  # taken by the tools (pcl_rast_slam, pcl_rast_features are programs).
  set(target pcl_rast_${name}_lib)
  if(NOT srcs)
    # A module still without sources (only headers so far) builds from an empty unit.
    set(srcs "${CMAKE_CURRENT_BINARY_DIR}/${target}_empty.cpp")
    file(WRITE "${srcs}" "// ${target} has no compiled sources yet.\n")
  endif()
  add_library(${target} ${srcs})
  add_library(pcl_rast::${name} ALIAS ${target})
  set_target_properties(${target} PROPERTIES EXPORT_NAME ${name} OUTPUT_NAME pcl_rast_${name}
                        VERSION ${PROJECT_VERSION} SOVERSION ${PROJECT_VERSION_MAJOR}.${PROJECT_VERSION_MINOR})
  target_include_directories(${target} PUBLIC
    $<BUILD_INTERFACE:${CMAKE_CURRENT_SOURCE_DIR}/include>
    $<INSTALL_INTERFACE:${PCL_RAST_INCLUDE_INSTALL_DIR}>)
  target_include_directories(${target} SYSTEM PUBLIC ${PCL_INCLUDE_DIRS})
  target_compile_definitions(${target} PUBLIC ${PCL_DEFINITIONS})
  foreach(dep IN LISTS ARG_DEPS)
    target_link_libraries(${target} PUBLIC pcl_rast::${dep})
  endforeach()
  # ${PCL_LIBRARIES}, not single pcl_* targets: those lack their inter-module deps.
  target_link_libraries(${target} PUBLIC ${PCL_LIBRARIES} Eigen3::Eigen ${ARG_LIBS})
  # Libraries only the sources use (OpenCV): consumers get neither their headers nor
  # their include paths.
  target_link_libraries(${target} PRIVATE ${ARG_PRIVATE_LIBS})
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wno-unused-parameter)
  # Unity batches of a few sources: PCL's and Eigen's headers are parsed once per batch,
  # not once per file (doc/architecture.md, "Compile time").
  set_target_properties(${target} PROPERTIES UNITY_BUILD ${PCL_RAST_UNITY_BUILD}
                        UNITY_BUILD_BATCH_SIZE 4)
  install(TARGETS ${target} EXPORT pcl_rastTargets
          LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
          ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
          RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR})
  install(DIRECTORY include/ DESTINATION ${PCL_RAST_INCLUDE_INSTALL_DIR})
endfunction()
