# f4d_require_pkg(<PREFIX> <pkg-config module> <Debian package> <option>)
#
# For a dependency the build must not lose silently (a backend a board file
# names, a test harness): pkg_check_modules(<PREFIX> IMPORTED_TARGET <module>),
# and when that fails, a configure error that names every pkg-config module
# pkg-config could not resolve (the module itself, or one of its Requires, such
# as libusb-1.0 for aravis-0.8) with the Debian package that ships it, and how
# to leave the part out (-D<option>=OFF). tools/setup-debian.sh installs the
# packages from tools/deps/*.txt.
#
# A macro, so that <PREFIX>_FOUND and the imported target land in the caller.

# pkg-config module -> Debian 12 package, for the modules this tree uses and
# their Requires (check: pkg-config --print-requires --print-requires-private).
set(F4D_DEB_OF_aravis-0.8   libaravis-dev)
set(F4D_DEB_OF_libusb-1.0   libusb-1.0-0-dev)
set(F4D_DEB_OF_libgpiod     libgpiod-dev)
set(F4D_DEB_OF_umockdev-1.0 libumockdev-dev)
set(F4D_DEB_OF_glib-2.0     libglib2.0-dev)
set(F4D_DEB_OF_gobject-2.0  libglib2.0-dev)
set(F4D_DEB_OF_gio-2.0      libglib2.0-dev)
set(F4D_DEB_OF_libxml-2.0   libxml2-dev)
set(F4D_DEB_OF_zlib         zlib1g-dev)
set(F4D_DEB_OF_libcjson     libcjson-dev)
set(F4D_DEB_OF_libpng       libpng-dev)
set(F4D_DEB_OF_cmocka       libcmocka-dev)
set(F4D_DEB_OF_libzstd      libzstd-dev)
set(F4D_DEB_OF_srt          libsrt-openssl-dev)

macro(f4d_require_pkg _prefix _module _deb _option)
  pkg_check_modules(${_prefix} QUIET IMPORTED_TARGET ${_module})
  if(NOT ${_prefix}_FOUND)
    execute_process(COMMAND ${PKG_CONFIG_EXECUTABLE} --print-errors --exists ${_module}
                    OUTPUT_QUIET ERROR_VARIABLE _f4d_why)
    # "Package 'libusb-1.0', required by 'aravis-0.8', not found"
    string(REGEX MATCHALL "Package '[^']+', required by '[^']+', not found" _f4d_lines "${_f4d_why}")
    set(_f4d_missing "")
    foreach(_l IN LISTS _f4d_lines)
      string(REGEX REPLACE "Package '([^']+)', required by '([^']+)'.*" "\\1;\\2" _pair "${_l}")
      list(GET _pair 0 _m)
      list(GET _pair 1 _by)
      if(DEFINED F4D_DEB_OF_${_m})
        set(_d "${F4D_DEB_OF_${_m}}")
      elseif(_m STREQUAL _module)
        set(_d "${_deb}")
      else()
        set(_d "the Debian package that ships ${_m}.pc (apt-file search ${_m}.pc)")
      endif()
      if(_by STREQUAL "virtual:world")
        string(APPEND _f4d_missing "\n  pkg-config module '${_m}' not found: install the Debian package ${_d}")
      else()
        string(APPEND _f4d_missing "\n  pkg-config module '${_m}' (required by '${_by}') not found: install the Debian package ${_d}")
      endif()
    endforeach()
    if(_f4d_missing STREQUAL "")
      set(_f4d_missing "\n  pkg-config module '${_module}' not usable: install the Debian package ${_deb}\n  pkg-config says: ${_f4d_why}")
    endif()
    message(FATAL_ERROR "${CMAKE_CURRENT_LIST_DIR}: ${_option} is ON but ${_module} cannot be used:${_f4d_missing}\n"
            "  (bash tools/setup-debian.sh installs every package of tools/deps/*.txt), "
            "or configure with -D${_option}=OFF to build without it.")
  endif()
endmacro()
