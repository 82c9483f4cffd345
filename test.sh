#!/usr/bin/env bash
# Tests: set up the environment (with test extras) and run pytest, which includes `snakemake --lint`,
# a dry run with the SLURM profile and the reduced-config pipeline run end to end.
set -euo pipefail
cd "$(dirname "$0")"
bash setup.sh test,slurm
# Headless Chromium for tests/browser (the report as a browser shows it): Debian's package, driven by Playwright
# (no Playwright browser download)
if [ -z "${CHROMIUM:-}" ] && ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null; then
  { apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium >/dev/null; } ||
    { echo "test.sh: could not install Debian's chromium (needs root and apt); install it, or set CHROMIUM to a Chromium executable" >&2; exit 1; }
fi
# Two worker processes (pytest-xdist; PYTEST_WORKERS overrides, 0 = one process): the suite takes about half the
# time on 2 cores. Tests that share the reduced pipeline's workflow copy stay in one worker (tests/conftest.py).
.venv/bin/python -m pytest -n "${PYTEST_WORKERS:-2}" --dist loadgroup "$@"
