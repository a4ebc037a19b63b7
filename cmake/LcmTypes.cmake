# Generates C++ headers from lcmtypes/*.lcm into the build tree (LCM 1.3.1 ships
# no CMake config) and exposes them as the INTERFACE target radslam_lcmtypes.
find_program(LCM_GEN lcm-gen REQUIRED)
find_library(LCM_LIBRARY lcm REQUIRED)

function(radslam_add_lcmtypes)
  file(GLOB lcm_files "${PROJECT_SOURCE_DIR}/lcmtypes/*.lcm")
  set(out_dir "${PROJECT_BINARY_DIR}/lcmtypes")
  set(headers)
  foreach(f ${lcm_files})
    get_filename_component(name "${f}" NAME_WE)
    list(APPEND headers "${out_dir}/radslam/${name}.hpp")
  endforeach()
  add_custom_command(
    OUTPUT ${headers}
    COMMAND ${CMAKE_COMMAND} -E make_directory "${out_dir}"
    COMMAND ${LCM_GEN} -x --cpp-hpath "${out_dir}" ${lcm_files}
    COMMAND ${CMAKE_COMMAND} -DDIR=${out_dir}/radslam -P
            "${PROJECT_SOURCE_DIR}/cmake/PatchLcmDecoders.cmake"
    DEPENDS ${lcm_files} "${PROJECT_SOURCE_DIR}/cmake/PatchLcmDecoders.cmake"
    COMMENT "lcm-gen: generating C++ message headers")
  add_custom_target(radslam_lcmtypes_gen DEPENDS ${headers})
  add_library(radslam_lcmtypes INTERFACE)
  add_dependencies(radslam_lcmtypes radslam_lcmtypes_gen)
  target_include_directories(radslam_lcmtypes SYSTEM INTERFACE "${out_dir}")
  target_link_libraries(radslam_lcmtypes INTERFACE ${LCM_LIBRARY})
endfunction()
