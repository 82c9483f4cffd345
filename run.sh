#!/usr/bin/env bash
# Main job: set up the environment and run the full pipeline on the shipped data.
# Extra arguments go to snakemake, e.g.:  bash run.sh results/strength/s3m24/baseline.csv
set -euo pipefail
cd "$(dirname "$0")"
bash setup.sh
.venv/bin/snakemake -c2 "$@"
