#!/usr/bin/env bash
# Main job: set up the environment and run the full pipeline on the shipped data.
# Extra arguments go to snakemake, e.g.:  bash run.sh results/strength/s3m24/baseline.csv
# Rerunning the same command resumes an interrupted run (killed, power cut): the default profile (profiles/default)
# reruns incomplete jobs, and the lock a killed Snakemake left behind is removed when no other Snakemake works here.
set -euo pipefail
cd "$(dirname "$0")"
bash setup.sh
mkdir -p .snakemake
exec 9>.snakemake/run_sh.lock
if ! flock -n 9; then
  echo "run.sh: another run.sh is running in $(pwd); wait for it to finish" >&2
  exit 1
fi
snakemake_here() {   # a Snakemake process (other than ours) whose working directory is this folder
  local p
  for p in $(pgrep -f "snakemake" || true); do
    if [ "$p" != "$$" ] && [ "$(readlink "/proc/$p/cwd" 2>/dev/null)" = "$(pwd -P)" ]; then
      return 0
    fi
  done
  return 1
}
if [ -n "$(ls -A .snakemake/locks 2>/dev/null)" ]; then
  if snakemake_here; then
    echo "run.sh: a Snakemake run is working in $(pwd); wait for it to finish" >&2
    exit 1
  fi
  echo "run.sh: removing the lock an interrupted run left behind (snakemake --unlock)" >&2
  .venv/bin/snakemake --unlock >/dev/null 9>&-
fi
.venv/bin/snakemake -c2 "$@" 9>&-   # the lock stays with run.sh, not with the jobs
