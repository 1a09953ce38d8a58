# Sourced by merge-bench.sh and shard-speedup.sh (after they set `repo`): the
# bench-harness binary in `bin` ($BENCH_HARNESS, else the workspace's release build, made
# here), wall-clock helpers, the shards' folder names, and the comparison of a merged run
# with the unsharded one.

if [[ -z "${BENCH_HARNESS:-}" ]]; then
    (cd "$repo" && cargo build --release -p bench-harness -j 2 >&2)
    BENCH_HARNESS=$repo/target/release/bench-harness
fi
bin=$BENCH_HARNESS

# Seconds since the epoch, with nanoseconds.
now() { date +%s.%N; }
# Seconds from time $1 to time $2, two decimals.
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.2f", b - a }'; }

# The folders of shards 1…$2 under $1/shards, in the array `dirs`.
shard_dirs() {
    dirs=()
    for ((k = 1; k <= $2; k++)); do dirs+=("$1/shards/shard-$k-of-$2"); done
}

# Whether runs $1 and $2 hold the same trials.csv and summary.csv apart from timings
# (trials.csv's 8th column, time_ms; summary.csv's time_ms rows past their 7th column).
same_apart_from_timings() {
    trials() { cut -d, -f1-7,9- "$1/trials.csv"; }
    summary() { awk -F, -v OFS=, '$4 == "time_ms" { print $1, $2, $3, $4, $5, $6, $7; next } { print }' "$1/summary.csv"; }
    cmp -s <(trials "$1") <(trials "$2") && cmp -s <(summary "$1") <(summary "$2")
}
