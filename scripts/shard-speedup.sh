#!/bin/bash
# Wall time of one run of SCENARIO against the same run as N shards started at once on
# this machine (each --threads 1, as N one-CPU array tasks) followed by their merge;
# checks that the merge equals the run apart from timings.
#
#   scripts/shard-speedup.sh [SCENARIO [N [WORKDIR]]]
#
# Defaults: scenarios/sigma_sweep.toml, N = 4, WORKDIR = /tmp/epd-shard-speedup (its
# whole/, shards/ and merged/ are replaced). BENCH_HARNESS=/path skips the release build.
# On one machine the shards share its cores: the speed-up is capped by the core count,
# not by N.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/.." && pwd)
scenario=$(realpath "${1:-$repo/scenarios/sigma_sweep.toml}")
n=${2:-4}
work=${3:-/tmp/epd-shard-speedup}
# shellcheck source=bench-common.sh
source "$here/bench-common.sh"
mkdir -p "$work/shards"

# CPU seconds (user + system) of this script's children so far: bash's `times`, which
# must run in this shell (not in a $(…) subshell), then read back.
cpu_now() { times >"$work/.times"; }
cpu_read() { tail -1 "$work/.times" | awk '{ split($1, u, /[ms]/); split($2, s, /[ms]/); printf "%.2f", u[1] * 60 + u[2] + s[1] * 60 + s[2] }'; }
load0=$(cut -d' ' -f1 /proc/loadavg)
cpu_now
c0=$(cpu_read)
t0=$(now)
"$bin" "$scenario" --quiet --out "$work/whole"
t1=$(now)
cpu_now
c1=$(cpu_read)
for ((k = 1; k <= n; k++)); do
    "$bin" "$scenario" --shard "$k/$n" --threads 1 --quiet --out "$work/shards/shard-$k-of-$n" &
done
wait
t2=$(now)
shard_dirs "$work" "$n"
"$bin" merge "${dirs[@]}" --quiet --out "$work/merged"
t3=$(now)
cpu_now
c3=$(cpu_read)
rm -f "$work/.times"
load1=$(cut -d' ' -f1 /proc/loadavg)

if same_apart_from_timings "$work/merged" "$work/whole"; then
    same="equal to the run apart from timings"
else
    same="DIFFERENT from the run"
fi
one=$(secs "$t0" "$t1")
shards=$(secs "$t1" "$t2")
merge=$(secs "$t2" "$t3")
total=$(secs "$t1" "$t3")
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); load average $load0 before, $load1 after"
echo "one run (all cores):               ${one} s wall, $(awk -v a="$c0" -v b="$c1" 'BEGIN { printf "%.2f", b - a }') s CPU"
echo "$n shards at once (--threads 1):    ${shards} s wall"
echo "merge:                             ${merge} s wall"
echo "shards + merge:                    ${total} s wall, $(awk -v a="$c1" -v b="$c3" 'BEGIN { printf "%.2f", b - a }') s CPU"
echo "speed-up (one run / shards+merge): $(awk -v a="$one" -v b="$total" 'BEGIN { printf "%.2f", a / b }')"
echo "merged trials.csv and summary.csv: $same"
[[ $same == equal* ]]
