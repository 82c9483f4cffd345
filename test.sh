#!/usr/bin/env bash
# Tests: set up the environment (with test extras) and run pytest, which includes `snakemake --lint`,
# a dry run with the SLURM profile and the reduced-config pipeline run end to end.
set -euo pipefail
cd "$(dirname "$0")"
bash setup.sh test,slurm
.venv/bin/python -m pytest "$@"
