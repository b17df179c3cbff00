#!/usr/bin/env bash
# Debian packages the renderers need: Mesa's EGL for pyrender's offscreen
# rendering, and the X/GL libraries bpy's wheel links against. Installs only
# what is missing; needs root (or sudo) only then.
set -euo pipefail
need=()
have_lib() { ldconfig -p | grep -q "$1"; }
have_lib 'libEGL.so.1 '      || need+=(libegl1)
have_lib 'libEGL_mesa.so.0 ' || need+=(libegl-mesa0)
have_lib 'libgbm.so.1 '      || need+=(libgbm1)
have_lib 'libGL.so.1 '       || need+=(libgl1)
have_lib 'libXi.so.6 '       || need+=(libxi6)
have_lib 'libXrender.so.1 '  || need+=(libxrender1)
have_lib 'libXxf86vm.so.1 '  || need+=(libxxf86vm1)
have_lib 'libXfixes.so.3 '   || need+=(libxfixes3)
have_lib 'libxkbcommon.so.0 ' || need+=(libxkbcommon0)
have_lib 'libSM.so.6 '       || need+=(libsm6)
ls /usr/lib/x86_64-linux-gnu/dri/swrast_dri.so >/dev/null 2>&1 || need+=(libgl1-mesa-dri)
if [ ${#need[@]} -eq 0 ]; then
  exit 0
fi
echo "installing Debian packages: ${need[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "error: need root to install ${need[*]} (apt-get install ${need[*]})" >&2; exit 1; }
  SUDO=sudo
fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
