#!/usr/bin/env bash
# Sets up scanmill on a bare Debian/Ubuntu machine: the system library Open3D needs, a virtual
# environment in .venv, and the package with its test dependencies. Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}

# System packages: libusb-1.0-0 (Open3D's wheel links it); redis-server and postgresql, which the tests
# of the distributed backend start on 127.0.0.1, and linuxcnc-uspace, whose standalone interpreter rs274
# the tests run on the LinuxCNC programs as an independent reader (SCANMILL_SKIP_SERVERS=1 leaves these
# three out where only the embedded service is wanted).
APT=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || APT+=(libusb-1.0-0)
if [ "${SCANMILL_SKIP_SERVERS:-0}" != "1" ]; then
  command -v redis-server >/dev/null 2>&1 || [ -x /usr/bin/redis-server ] || APT+=(redis-server)
  ls /usr/lib/postgresql/*/bin/postgres >/dev/null 2>&1 || APT+=(postgresql)
  command -v rs274 >/dev/null 2>&1 || [ -x /usr/bin/rs274 ] || APT+=(linuxcnc-uspace)
fi
if [ ${#APT[@]} -gt 0 ]; then
  echo "setup: installing ${APT[*]} (apt)"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${APT[@]}" >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
echo "setup: installing scanmill and its dependencies into $VENV"
"$VENV/bin/python" -m pip install -q -e '.[test]' 2>&1 | grep -v "^WARNING: Location" || true
"$VENV/bin/python" -c "import open3d, ortools, numpy, scanmill" \
  || { echo "setup: the installation is incomplete (see the pip output above)" >&2; exit 1; }
# Compile the numba kernels into their cache (SCANMILL_CACHE_DIR, default ~/.cache/scanmill/numba) with a
# small plan, so that the first plan, `make run` and `make test` do not spend a minute and more compiling.
echo "setup: compiling the planning kernels (scanmill warmup; once per change of the planning code)"
"$VENV/bin/scanmill" warmup || echo "setup: warmup failed; the first plan will compile the kernels" >&2
touch "$VENV/.installed"
