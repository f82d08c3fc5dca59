# FindLibRaw — LibRaw ships only a pkg-config file on Debian 12.
# Defines the imported target LibRaw::LibRaw (thread-safe libraw_r) and LibRaw_VERSION.
find_package(PkgConfig QUIET)
if(PkgConfig_FOUND)
  pkg_check_modules(PC_LIBRAW QUIET libraw_r)
endif()
find_path(LibRaw_INCLUDE_DIR libraw/libraw.h HINTS ${PC_LIBRAW_INCLUDE_DIRS})
find_library(LibRaw_LIBRARY NAMES raw_r raw HINTS ${PC_LIBRAW_LIBRARY_DIRS})
set(LibRaw_VERSION "${PC_LIBRAW_VERSION}")
include(FindPackageHandleStandardArgs)
find_package_handle_standard_args(LibRaw
  REQUIRED_VARS LibRaw_LIBRARY LibRaw_INCLUDE_DIR
  VERSION_VAR LibRaw_VERSION)
if(LibRaw_FOUND AND NOT TARGET LibRaw::LibRaw)
  add_library(LibRaw::LibRaw UNKNOWN IMPORTED)
  set_target_properties(LibRaw::LibRaw PROPERTIES
    IMPORTED_LOCATION "${LibRaw_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${LibRaw_INCLUDE_DIR}"
    INTERFACE_COMPILE_OPTIONS "${PC_LIBRAW_CFLAGS_OTHER}")
endif()
mark_as_advanced(LibRaw_INCLUDE_DIR LibRaw_LIBRARY)
