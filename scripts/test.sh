#!/usr/bin/env bash
# Install everything the tests need (apt + pip), then lint, check the formatting, type-check
# and run the whole suite against real Moonraker + Klippy printers and Debian's Chromium.
# Extra arguments go to pytest (e.g. -k session -x).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/bootstrap.sh --test
.venv/bin/ruff check src tests bench
.venv/bin/ruff format --check src tests bench
.venv/bin/mypy --strict src
node_modules/.bin/eslint src/kybercore/web
node_modules/.bin/tsc -p tsconfig.json
exec .venv/bin/python -m pytest "$@"
