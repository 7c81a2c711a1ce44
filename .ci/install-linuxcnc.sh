#!/usr/bin/env bash
# Installs LinuxCNC (Debian package linuxcnc-uspace) for tests/core/test_linuxcnc_integration.py.
# Idempotent: returns at once when the package is already installed.
set -euo pipefail
if dpkg-query -W -f='${Status}' linuxcnc-uspace 2>/dev/null | grep -q "install ok installed"; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  SUDO="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update
$SUDO apt-get install -y --no-install-recommends linuxcnc-uspace
