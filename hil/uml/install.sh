#!/usr/bin/env bash
# The install step for hardware-in-the-loop runs on kernels without CAN: User-Mode Linux (whose
# kernel has SocketCAN and vcan) and kmod (insmod), from Debian/Ubuntu packages. A C compiler is
# needed too on AVX-512/AMX hosts (hil/uml/xstate-shim.c). Does nothing when they are present.
set -euo pipefail
if command -v linux.uml >/dev/null && command -v insmod >/dev/null; then
  exit 0
fi
SUDO=
[ "$(id -u)" = 0 ] || SUDO=sudo
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get install -y user-mode-linux kmod || { $SUDO apt-get update && $SUDO apt-get install -y user-mode-linux kmod; }
