#!/bin/bash
# Submit a sharded bench-harness run to Slurm: a job array of N shards, then the merge,
# which waits for all of them (--dependency=afterok).
#
#   scripts/slurm/submit.sh SCENARIO N WORKDIR [extra sbatch options…]
#
# WORKDIR (on a file system every node sees) receives a copy of the binary (so a
# rebuild while the jobs wait cannot mix two builds; the merge would refuse them
# anyway), the shard folders under WORKDIR/shards/, the job logs, and the merged run in
# WORKDIR/merged/ (trials.csv, summary.csv, metadata.json, plots).
# BENCH_HARNESS=/path/to/bench-harness skips the build (default: cargo build --release).
# Prints: <array job id> <merge job id>.
set -euo pipefail
if [[ $# -lt 3 ]]; then
    echo "usage: $0 SCENARIO N WORKDIR [sbatch options…]" >&2
    exit 2
fi
scenario=$(realpath "$1")
n=$2
work=$3
shift 3
if ! [[ "$n" =~ ^[1-9][0-9]*$ ]]; then
    echo "error: N = $n: a whole number ≥ 1" >&2
    exit 2
fi
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
if [[ -z "${BENCH_HARNESS:-}" ]]; then
    (cd "$repo" && cargo build --release -p bench-harness >&2)
    BENCH_HARNESS=$repo/target/release/bench-harness
fi
mkdir -p "$work/shards" "$work/logs"
work=$(realpath "$work")
cp "$BENCH_HARNESS" "$work/bench-harness"
env=ALL,BENCH_HARNESS=$work/bench-harness,SCENARIO=$scenario,SHARDS=$n,SHARDS_DIR=$work/shards,OUT=$work/merged
array=$(sbatch --parsable --array="1-$n" --export="$env" \
    --output="$work/logs/shard-%A_%a.out" "$@" "$here/sweep.sbatch")
array=${array%%;*}
merge=$(sbatch --parsable --dependency="afterok:$array" --kill-on-invalid-dep=yes \
    --export="$env" --output="$work/logs/merge-%j.out" "$@" "$here/merge.sbatch")
merge=${merge%%;*}
echo "$array $merge"
