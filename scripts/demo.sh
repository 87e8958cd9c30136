#!/usr/bin/env bash
# Install KyberCore and start the demo: 3 virtual printers (real Klippy + Moonraker on a
# simulated MCU) and the dashboard on http://127.0.0.1:8000/. Extra arguments go to
# `kybercore demo` (e.g. --printers 5 --port 8080).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh
exec .venv/bin/kybercore demo "$@"
