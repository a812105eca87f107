#!/usr/bin/env bash
# Sets up scanmill on a bare Debian/Ubuntu machine, at one of two levels, so that running the planner
# does not pull in what only the tests use (servers, a browser):
#
#   scripts/setup.sh run    what `make run` and `make serve` need: the system library Open3D needs, a
#                           virtual environment with the package (no test tools), three.js for the
#                           browser viewer, and the planning kernels compiled into their cache.
#   scripts/setup.sh test   all of `run`, plus what the test suite needs: Redis and PostgreSQL (the tests
#                           of the distributed backend start them on 127.0.0.1), LinuxCNC's rs274 (the
#                           independent reader of the programs), Chromium and its WebDriver (the viewer's
#                           browser tests) and the [test] extras.
#
# No level means `test`: what this script did before it had levels. Safe to run again: it installs only
# what is missing (apt is not even updated when nothing is), and every step below is idempotent.
#
# Options and environment:
#   --dry-run, SCANMILL_SETUP_DRY_RUN=1   print what would be installed (the apt packages, the venv, the
#                                         pip requirement, three.js) and stop before changing anything.
#   VENV=.venv, PYTHON=python3            the virtual environment, and the interpreter that creates it.
#   SCANMILL_SKIP_SERVERS=1               at the test level, leave out redis-server, postgresql and
#                                         linuxcnc-uspace (their tests then skip or fail, saying why). Kept
#                                         for compatibility: it used to be the way to set up for `make run`
#                                         alone, which the run level now does by itself (it never installs
#                                         them).
#   SCANMILL_THREE_TARBALL=PATH           install three.js from a downloaded three-<version>.tgz instead
#                                         of the npm registry (offline machines; same integrity check).
#
# Writes the stamp files the Makefile checks: $VENV/.installed-run, and at the test level also
# $VENV/.installed-test-noservers and, unless SCANMILL_SKIP_SERVERS=1, $VENV/.installed-test (a set-up
# without the servers must not pass for a complete one).
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}
SKIP_SERVERS=${SCANMILL_SKIP_SERVERS:-0}
DRY_RUN=${SCANMILL_SETUP_DRY_RUN:-0}

LEVEL=""
for arg in "$@"; do
  case "$arg" in
    run|test) LEVEL=$arg ;;
    --dry-run|-n) DRY_RUN=1 ;;
    -h|--help) sed -n '2,/^set -euo/{/^set -euo/d;s/^# \{0,1\}//;p}' "$0"; exit 0 ;;
    *) echo "setup: unknown argument '$arg' (usage: scripts/setup.sh [run|test] [--dry-run])" >&2; exit 2 ;;
  esac
done
LEVEL=${LEVEL:-test}

# System packages. Each is looked for where the code that uses it looks, not in dpkg's database, so that
# one installed another way (from source, a backport) is not installed twice.
have_lib() { PATH="$PATH:/sbin:/usr/sbin" ldconfig -p 2>/dev/null | grep "$1" >/dev/null; }  # ldconfig: /sbin for non-root; not grep -q: under pipefail its early exit gives ldconfig SIGPIPE and the test fails
APT=()
# libusb-1.0-0: Open3D's wheel links it, so `import open3d` fails without it.
have_lib 'libusb-1.0.so.0' || APT+=(libusb-1.0-0)
# A bare Debian python3 has no ensurepip (split into python3-venv), and `python3 -m venv` fails without it.
if [ ! -x "$VENV/bin/python" ] && ! "$PYTHON" -c 'import ensurepip' >/dev/null 2>&1; then
  case "$(command -v "$PYTHON" || true)" in /usr/bin/*) APT+=(python3-venv) ;; esac
fi
if [ "$LEVEL" = test ]; then
  if [ "$SKIP_SERVERS" != "1" ]; then
    command -v redis-server >/dev/null 2>&1 || [ -x /usr/bin/redis-server ] || APT+=(redis-server)
    ls /usr/lib/postgresql/*/bin/postgres >/dev/null 2>&1 || APT+=(postgresql)
    command -v rs274 >/dev/null 2>&1 || [ -x /usr/bin/rs274 ] || APT+=(linuxcnc-uspace)
  fi
  # The browser tests drive Debian's /usr/bin/chromium through /usr/bin/chromedriver (selenium), by
  # those paths: a Chrome elsewhere on PATH does not count, its driver version would not match.
  [ -x /usr/bin/chromium ] || APT+=(chromium)
  [ -x /usr/bin/chromedriver ] || APT+=(chromium-driver)
fi

PIP_REQ="."; [ "$LEVEL" = test ] && PIP_REQ=".[test]"

if [ "$DRY_RUN" = "1" ]; then
  echo "setup: dry run, level $LEVEL (SCANMILL_SKIP_SERVERS=$SKIP_SERVERS); nothing is installed"
  echo "setup: apt packages to install: ${APT[*]:-(none)}"
  if [ -x "$VENV/bin/python" ]; then echo "setup: venv: $VENV exists"; else echo "setup: venv: would create $VENV with $PYTHON"; fi
  echo "setup: pip: would install -e '$PIP_REQ' into $VENV"
  if "$PYTHON" scripts/vendor_three.py --check; then echo "setup: three.js: already vendored"
  else echo "setup: three.js: would vendor it (scripts/vendor_three.py${SCANMILL_THREE_TARBALL:+ --from-tarball $SCANMILL_THREE_TARBALL})"; fi
  echo "setup: then: scanmill warmup"
  exit 0
fi

if [ ${#APT[@]} -gt 0 ]; then
  echo "setup: installing ${APT[*]} (apt)"
  SUDO=()
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null 2>&1 || {
      echo "setup: ${APT[*]} must be installed as root and sudo is not available; as root run" >&2
      echo "  apt-get update && apt-get install -y --no-install-recommends ${APT[*]}" >&2
      echo "then run this again" >&2; exit 1; }
    SUDO=(sudo)
    # Without a terminal (CI, make </dev/null) sudo cannot ask for a password: fail at once instead of hanging.
    [ -t 0 ] || SUDO=(sudo -n)
  fi
  # env passes DEBIAN_FRONTEND through sudo (which resets the environment): no debconf question may stop
  # an unattended set-up. Lock::Timeout waits for another apt or dpkg (unattended-upgrades, a second
  # set-up) to finish instead of failing on its lock.
  APT_GET=("${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=600)
  "${APT_GET[@]}" update -qq
  "${APT_GET[@]}" install -y -qq --no-install-recommends "${APT[@]}" >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
# three.js for the browser viewer: fetched from the npm registry and integrity-checked (not committed);
# a no-op when the pinned release is already there. Before pip, so that a built (non-editable) package
# carries it.
"$VENV/bin/python" scripts/vendor_three.py ${SCANMILL_THREE_TARBALL:+--from-tarball "$SCANMILL_THREE_TARBALL"} \
  || { echo "setup: three.js could not be vendored (see above)" >&2; exit 1; }
"$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v "^WARNING: Location" || true
echo "setup: installing scanmill and its dependencies into $VENV (-e '$PIP_REQ')"
"$VENV/bin/python" -m pip install -q -e "$PIP_REQ" 2>&1 | grep -v "^WARNING: Location" || true
# pip's exit status is lost in the filter above: check that what each level needs imports.
CHECK="import open3d, ortools, numpy, scanmill"; [ "$LEVEL" = test ] && CHECK="$CHECK, pytest, selenium, xdist"
"$VENV/bin/python" -c "$CHECK" \
  || { echo "setup: the installation is incomplete (see the pip output above)" >&2; exit 1; }
# Compile the numba kernels into their cache (SCANMILL_CACHE_DIR, default ~/.cache/scanmill/numba) with a
# small plan, so that the first plan, `make run` and `make test` do not spend a minute and more compiling.
echo "setup: compiling the planning kernels (scanmill warmup; once per change of the planning code)"
"$VENV/bin/scanmill" warmup || echo "setup: warmup failed; the first plan will compile the kernels" >&2

# The test level includes the run level, so it satisfies both stamps.
touch "$VENV/.installed-run"
if [ "$LEVEL" = test ]; then
  touch "$VENV/.installed-test-noservers"
  [ "$SKIP_SERVERS" = "1" ] || touch "$VENV/.installed-test"
fi
echo "setup: done (level $LEVEL)"
