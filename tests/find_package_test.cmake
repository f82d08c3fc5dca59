# ctest script: install crfcal into a scratch prefix, then configure, build and run tests/consumer against it.
# Arguments: -DBUILD_DIR=<crfcal build tree> -DSOURCE_DIR=<tests/consumer> -DWORK_DIR=<scratch>
#            [-DLINK_FLAGS=<extra linker flags, e.g. the sanitizer runtimes>]
file(REMOVE_RECURSE "${WORK_DIR}")
execute_process(COMMAND ${CMAKE_COMMAND} --install "${BUILD_DIR}" --prefix "${WORK_DIR}/prefix"
  RESULT_VARIABLE rc OUTPUT_QUIET)
if(rc)
  message(FATAL_ERROR "install failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -S "${SOURCE_DIR}" -B "${WORK_DIR}/build" -G Ninja
  -DCMAKE_BUILD_TYPE=Release "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix" "-DCMAKE_EXE_LINKER_FLAGS=${LINK_FLAGS}"
  RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "configuring the consumer failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build "${WORK_DIR}/build" RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "building the consumer failed: ${rc}")
endif()
execute_process(COMMAND "${WORK_DIR}/build/consumer" RESULT_VARIABLE rc OUTPUT_VARIABLE out)
if(rc OR NOT out MATCHES "^ok gamma:2.2")
  message(FATAL_ERROR "consumer failed: ${rc} ${out}")
endif()
message(STATUS "find_package(crfcal) consumer: ${out}")
file(REMOVE_RECURSE "${WORK_DIR}")
