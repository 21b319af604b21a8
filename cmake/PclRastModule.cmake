# pcl_rast_add_module(<name> [DEPS <modules...>] [PCL <components...>] [LIBS <libraries...>]
#                     [PRIVATE_LIBS <libraries...>])
#
# Builds library pcl_rast::<name> (file libpcl_rast_<name>) from <name>/src/*.cpp with public headers in
# <name>/include/pcl/<name>/, exports it as pcl_rast::<name> and installs it.
# Sources are globbed (CONFIGURE_DEPENDS) so that adding a unit is one new file.
function(pcl_rast_add_module name)
  cmake_parse_arguments(ARG "" "" "DEPS;PCL;LIBS;PRIVATE_LIBS" ${ARGN})
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
  # In the build tree a module links pcl_common and the PCL components its sources use
  # (PCL <components>), not all of ${PCL_LIBRARIES}: with the whole set on the link line,
  # --as-needed recorded pcl_segmentation and pcl_registration, which Debian's pcl_search
  # refers to, and with them pcl_features, so that every program of the project loaded
  # 100,000 more symbol relocations at its start (doc/architecture.md, "Start-up time").
  # Installed, a module still brings all of ${PCL_LIBRARIES} to users' projects, as
  # before: code that puts our classes where PCL's stood uses the rest of PCL too.
  set(pcl_used pcl_common)
  foreach(component IN LISTS ARG_PCL)
    list(APPEND pcl_used pcl_${component})
  endforeach()
  target_link_libraries(${target} PUBLIC "$<BUILD_INTERFACE:${pcl_used}>"
                        "$<INSTALL_INTERFACE:${PCL_LIBRARIES}>" Eigen3::Eigen ${ARG_LIBS})
  # A library that uses a symbol none of its libraries provides fails to link, instead of
  # working by luck in programs that load that library for other reasons (FLANN's LZ4 in
  # features did, session 37). Not in the sanitizer builds: their runtime's symbols come
  # from the program.
  if(BUILD_SHARED_LIBS AND NOT CMAKE_CXX_FLAGS MATCHES "-fsanitize")
    target_link_options(${target} PRIVATE "LINKER:-z,defs")
  endif()
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
