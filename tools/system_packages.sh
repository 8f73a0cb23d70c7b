#!/usr/bin/env bash
# Debian/Ubuntu packages for software OpenGL: Mesa's EGL + llvmpipe, OSMesa (fallback
# backend), Xvfb (previewer tests). Uses sudo only when not root (fresh containers run
# as root and often have no sudo).
set -euo pipefail
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq \
    libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 xvfb >/dev/null
