#!/usr/bin/env bash
# Create .venv (if missing) and install the package with the given extras. Used by run.sh and test.sh.
set -euo pipefail
cd "$(dirname "$0")"
extras="${1:-}"
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
if [ -n "$extras" ]; then
  .venv/bin/python -m pip install -q -e ".[$extras]"
else
  .venv/bin/python -m pip install -q -e .
fi
