#!/bin/bash
# Submits a ctadsa experiment matrix to SLURM: one array task per cell (experiment.sbatch), then
# one job that collects the finished cells into results.csv / table.md / plots once every task
# has ended. Usage (arguments as for `ctadsa experiment`, --out required):
#   configs/slurm/submit.sh --cases cases/A cases/B --matrix configs/experiments/table1.toml \
#       --out runs/table1 [--set key=value ...]
# Environment: CTADSA (the binary, default `ctadsa` on the PATH), SBATCH_ARGS (extra sbatch
# options, e.g. "--partition=cpu --time=02:00:00 --cpus-per-task=4"), CTADSA_MAX_PARALLEL
# (array tasks running at once, default all). Prints the two job ids: array, then collect.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
bin="${CTADSA:-ctadsa}"
out=""
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
  if [ "${args[$i]}" = "--out" ]; then out="${args[$((i + 1))]:-}"; fi
done
[ -n "$out" ] || { echo "submit.sh: --out is required" >&2; exit 2; }
n=$("$bin" experiment "$@" --list | wc -l)
[ "$n" -gt 0 ] || { echo "submit.sh: the matrix has no cells" >&2; exit 2; }
mkdir -p "$out/logs"
range="0-$((n - 1))"
[ -n "${CTADSA_MAX_PARALLEL:-}" ] && range="$range%$CTADSA_MAX_PARALLEL"
# shellcheck disable=SC2086 # SBATCH_ARGS is a list of options
array=$(sbatch --parsable ${SBATCH_ARGS:-} --array="$range" --output="$out/logs/cell-%a.log" \
  --export=ALL,CTADSA="$bin" "$here/experiment.sbatch" "$@")
array="${array%%;*}"
# shellcheck disable=SC2086
collect=$(sbatch --parsable ${SBATCH_ARGS:-} --job-name=ctadsa-collect --dependency="afterany:$array" \
  --output="$out/logs/collect.log" --wrap="$(printf '%q ' "$bin" experiment "$@" --collect)")
echo "$array ${collect%%;*}"
