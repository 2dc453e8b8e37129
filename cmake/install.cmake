# Installing dropfit as a CMake package: the stage libraries (static, as
# dropfit::<stage>), their public headers under include/dropfit/<stage>/,
# and lib/cmake/dropfit/dropfitConfig.cmake for find_package(dropfit).
# Included from the top-level CMakeLists.txt after the stages are defined.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

set(DROPFIT_INSTALL_INCLUDEDIR "${CMAKE_INSTALL_INCLUDEDIR}/dropfit")
set(DROPFIT_INSTALL_CMAKEDIR "${CMAKE_INSTALL_LIBDIR}/cmake/dropfit")

# The installed stages, in dependency order: target dropfit_<stage>, headers
# <stage>/*.h. The video reader (OpenCV), the sample generator and the
# command line stay in the build tree.
set(DROPFIT_INSTALLED_STAGES core capture calibration reconstruction forceplate trial fitting diagnosis report)
if(TARGET dropfit_pipeline AND EXISTS "${PROJECT_SOURCE_DIR}/pipeline")
  list(APPEND DROPFIT_INSTALLED_STAGES pipeline)
endif()
# Headers that only a stage's own sources include (implementation details,
# third-party includes): not installed. The consumer test (tests/consumer)
# compiles every installed header alone, so a public header that includes one
# of these fails there.
set(DROPFIT_INTERNAL_HEADERS
  capture/force_internal.h capture/text_io.h
  capture/footage.h  # dropfit_video (OpenCV footage) stays in the build tree
  diagnosis/internal.h pipeline/contact_height.h
  fitting/models_impl.h fitting/model5_impl.h fitting/model5_layout.h fitting/model5_dual.h
  fitting/model5_integrator.h)

set(dropfit_installed_targets)
foreach(stage IN LISTS DROPFIT_INSTALLED_STAGES)
  set(target dropfit_${stage})
  # In the build tree the headers are found from the source root; installed,
  # from include/dropfit.
  set_target_properties(${target} PROPERTIES EXPORT_NAME ${stage}
    INTERFACE_INCLUDE_DIRECTORIES "$<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}>;$<INSTALL_INTERFACE:${DROPFIT_INSTALL_INCLUDEDIR}>")
  add_library(dropfit::${stage} ALIAS ${target})
  list(APPEND dropfit_installed_targets ${target})

  file(GLOB headers RELATIVE "${PROJECT_SOURCE_DIR}" "${PROJECT_SOURCE_DIR}/${stage}/*.h")
  list(REMOVE_ITEM headers ${DROPFIT_INTERNAL_HEADERS})
  list(TRANSFORM headers PREPEND "${PROJECT_SOURCE_DIR}/")
  install(FILES ${headers} DESTINATION "${DROPFIT_INSTALL_INCLUDEDIR}/${stage}" COMPONENT dropfit_dev)
endforeach()

install(TARGETS ${dropfit_installed_targets} EXPORT dropfitTargets
  ARCHIVE DESTINATION "${CMAKE_INSTALL_LIBDIR}" COMPONENT dropfit_dev)
install(EXPORT dropfitTargets NAMESPACE dropfit:: DESTINATION "${DROPFIT_INSTALL_CMAKEDIR}" COMPONENT dropfit_dev)

configure_package_config_file("${CMAKE_CURRENT_LIST_DIR}/dropfitConfig.cmake.in"
  "${PROJECT_BINARY_DIR}/dropfitConfig.cmake" INSTALL_DESTINATION "${DROPFIT_INSTALL_CMAKEDIR}")
write_basic_package_version_file("${PROJECT_BINARY_DIR}/dropfitConfigVersion.cmake" COMPATIBILITY SameMinorVersion)
install(FILES "${PROJECT_BINARY_DIR}/dropfitConfig.cmake" "${PROJECT_BINARY_DIR}/dropfitConfigVersion.cmake"
  DESTINATION "${DROPFIT_INSTALL_CMAKEDIR}" COMPONENT dropfit_dev)

# The command line too, so that an installed prefix runs sessions.
install(TARGETS dropfit dropfit-track RUNTIME DESTINATION "${CMAKE_INSTALL_BINDIR}" COMPONENT dropfit_cli)
