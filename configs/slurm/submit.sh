#!/bin/bash
# Submits a ctadsa experiment matrix to SLURM: one array task per run cell (experiment.sbatch);
# when the matrix has ensembles, a second array, one task per ensemble cell, once every run task
# has ended; then one job that collects the finished cells into results.csv / table.md / plots
# once every task has ended. Usage (arguments as for `ctadsa experiment`, --out required):
#   configs/slurm/submit.sh --cases cases/A cases/B --matrix configs/experiments/table1.toml \
#       --out runs/table1 [--set key=value ...]
# Environment: CTADSA (the binary, default `ctadsa` on the PATH), SBATCH_ARGS (extra sbatch
# options, e.g. "--partition=cpu --time=02:00:00 --cpus-per-task=4"), CTADSA_MAX_PARALLEL
# (array tasks running at once, default all). Prints the job ids: the runs' array, the ensembles'
# array (only when the matrix has ensembles), then collect.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
bin="${CTADSA:-ctadsa}"
out=""
args=("$@")
for ((i = 0; i < ${#args[@]}; i++)); do
  if [ "${args[$i]}" = "--out" ]; then out="${args[$((i + 1))]:-}"; fi
done
[ -n "$out" ] || { echo "submit.sh: --out is required" >&2; exit 2; }
list=$("$bin" experiment "$@" --list)
# Columns: index, state, kind (run / ensemble), label, folder; the ensembles come last.
n=$(printf '%s\n' "$list" | awk -F'\t' 'NF >= 5' | wc -l)
e=$(printf '%s\n' "$list" | awk -F'\t' '$3 == "ensemble"' | wc -l)
[ "$n" -gt 0 ] || { echo "submit.sh: the matrix has no cells" >&2; exit 2; }
mkdir -p "$out/logs"
throttle=""
[ -n "${CTADSA_MAX_PARALLEL:-}" ] && throttle="%$CTADSA_MAX_PARALLEL"
submit_array() { # range, then sbatch options (a dependency, or none), then `--`: the array job's id
  range="$1"
  shift
  opts=()
  while [ "$1" != "--" ]; do opts+=("$1"); shift; done
  shift
  # shellcheck disable=SC2086 # SBATCH_ARGS is a list of options
  id=$(sbatch --parsable ${SBATCH_ARGS:-} "${opts[@]}" --array="$range$throttle" \
    --output="$out/logs/cell-%a.log" --export=ALL,CTADSA="$bin" "$here/experiment.sbatch" "$@")
  echo "${id%%;*}"
}
runs=$(submit_array "0-$((n - e - 1))" -- "$@")
ids="$runs"
after="$runs"
if [ "$e" -gt 0 ]; then
  ensembles=$(submit_array "$((n - e))-$((n - 1))" "--dependency=afterany:$runs" -- "$@")
  ids="$ids $ensembles"
  after="$runs:$ensembles"
fi
# shellcheck disable=SC2086
collect=$(sbatch --parsable ${SBATCH_ARGS:-} --job-name=ctadsa-collect --dependency="afterany:$after" \
  --output="$out/logs/collect.log" --wrap="$(printf '%q ' "$bin" experiment "$@" --collect)")
echo "$ids ${collect%%;*}"
