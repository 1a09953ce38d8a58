#!/bin/bash
# Time `bench-harness merge` of N shards: by default the 1000 shards of
# scenarios/sigma_sweep.toml (500 trials: half the shards hold one trial, half none).
#
#   scripts/merge-bench.sh [SCENARIO [N [WORKDIR]]]
#
# Makes the N shard folders in WORKDIR/shards (two processes at a time, --threads 1;
# kept and reused when REUSE=1 and they are there), then times three merges into
# WORKDIR/merged and prints each wall time. With COMPARE=1 it also runs the scenario
# unsharded and checks the merge against it (timings aside). WORKDIR defaults to
# /tmp/epd-merge-bench. BENCH_HARNESS=/path skips the release build.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/.." && pwd)
scenario=$(realpath "${1:-$repo/scenarios/sigma_sweep.toml}")
n=${2:-1000}
work=${3:-/tmp/epd-merge-bench}
# shellcheck source=bench-common.sh
source "$here/bench-common.sh"
mkdir -p "$work/shards"
if [[ ${REUSE:-0} != 1 || ! -f "$work/shards/shard-$n-of-$n/shard.json" ]]; then
    t0=$(now)
    seq 1 "$n" | xargs -P 2 -I{} "$bin" "$scenario" --shard "{}/$n" --threads 1 --quiet \
        --out "$work/shards/shard-{}-of-$n"
    echo "made $n shards in $(secs "$t0" "$(now)") s (2 at a time)"
fi
shard_dirs "$work" "$n"
for i in 1 2 3; do
    t0=$(now)
    "$bin" merge "${dirs[@]}" --quiet --out "$work/merged"
    echo "merge $i of $n shards: $(secs "$t0" "$(now)") s"
done
if [[ ${COMPARE:-0} == 1 ]]; then
    "$bin" "$scenario" --quiet --out "$work/whole"
    if same_apart_from_timings "$work/merged" "$work/whole"; then
        echo "merged trials.csv and summary.csv equal the unsharded run's apart from timings"
    else
        echo "error: the merge differs from the unsharded run" >&2
        exit 1
    fi
fi
