# Warning and sanitizer flags shared by every crfcal target (crfcal_compile_options(target)).
add_library(crfcal_warnings INTERFACE)
target_compile_options(crfcal_warnings INTERFACE
  $<$<CXX_COMPILER_ID:GNU,Clang>:-Wall -Wextra -Wpedantic>
  $<$<AND:$<CXX_COMPILER_ID:GNU,Clang>,$<BOOL:${CRFCAL_WERROR}>>:-Werror>
  # GCC 12's libstdc++ raises a false -Wrestrict on `"literal" + std::string` at -O2 (GCC bug 105329).
  $<$<AND:$<CXX_COMPILER_ID:GNU>,$<VERSION_LESS:$<CXX_COMPILER_VERSION>,13>>:-Wno-restrict>)
if(CRFCAL_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  add_link_options(-fsanitize=address,undefined)
endif()
function(crfcal_compile_options target)
  target_link_libraries(${target} PRIVATE $<BUILD_INTERFACE:crfcal_warnings>)
endfunction()
