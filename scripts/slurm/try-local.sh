#!/bin/bash
# Try the Slurm recipe for real on this one machine: install Debian's slurm-wlm and
# munge, run munged, slurmctld and slurmd as a one-node cluster (NodeName=localhost,
# CPUs=2, one partition) whose configuration, keys, sockets, state and logs all live in
# WORKDIR (nothing is written to /etc), submit a sharded run and its dependent merge with
# submit.sh, wait for both, check the merge against an unsharded run of the same binary
# (trials.csv and summary.csv equal apart from timings), print the jobs' ids, states and
# elapsed times, and stop the daemons.
#
#   scripts/slurm/try-local.sh [SCENARIO [N [WORKDIR]]]
#
# Defaults: scenarios/ci_regression.toml, N = 4, WORKDIR = /tmp/epd-slurm-try (emptied
# first). Needs root (apt-get, the daemons). BENCH_HARNESS=/path/to/bench-harness skips
# the release build. KEEP=1 leaves the daemons running.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
scenario=$(realpath "${1:-$repo/scenarios/ci_regression.toml}")
n=${2:-4}
work=${3:-/tmp/epd-slurm-try}
log() { printf '[try-local %s] %s\n' "$(date +%T)" "$*"; }

if [[ $(id -u) != 0 ]]; then
    echo "error: run as root (apt-get install, munged, slurmd)" >&2
    exit 2
fi
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    log "installing slurm-wlm and munge"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
fi
log "$(slurmctld -V), munge $(munged --version 2>&1 | head -1)"

if [[ -z "${BENCH_HARNESS:-}" ]]; then
    log "building bench-harness (release)"
    (cd "$repo" && cargo build --release -p bench-harness -j 2 >&2)
    BENCH_HARNESS=$repo/target/release/bench-harness
fi
export BENCH_HARNESS

# Stop what a previous try left running, then start afresh.
stop() {
    for p in "$work"/slurm/slurmd.pid "$work"/slurm/slurmctld.pid "$work"/munge/munged.pid; do
        if [[ -f $p ]]; then
            kill "$(cat "$p")" 2>/dev/null || true
            rm -f "$p"
        fi
    done
}
if [[ -d $work ]]; then
    stop
    sleep 1
    rm -rf "$work"
fi
mkdir -p "$work"/munge "$work"/slurm/state "$work"/slurm/spool "$work"/run
work=$(realpath "$work")
chmod 700 "$work/munge"
if [[ ${KEEP:-0} != 1 ]]; then
    trap 'log "stopping the daemons"; stop' EXIT
fi

log "starting munged (key and socket in $work/munge)"
dd if=/dev/urandom of="$work/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$work/munge/munge.key"
munged --force --key-file="$work/munge/munge.key" --socket="$work/munge/munge.socket" \
    --pid-file="$work/munge/munged.pid" --log-file="$work/munge/munged.log" \
    --seed-file="$work/munge/munged.seed"
munge --socket="$work/munge/munge.socket" -n | unmunge --socket="$work/munge/munge.socket" >/dev/null
log "munge credential round trip ok"

host=$(hostname -s)
export SLURM_CONF=$work/slurm/slurm.conf
cat >"$SLURM_CONF" <<CONF
# A one-node cluster for try-local.sh: everything under $work.
ClusterName=epdtry
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$work/munge/munge.socket
StateSaveLocation=$work/slurm/state
SlurmdSpoolDir=$work/slurm/spool
SlurmctldPidFile=$work/slurm/slurmctld.pid
SlurmdPidFile=$work/slurm/slurmd.pid
SlurmctldLogFile=$work/slurm/slurmctld.log
SlurmdLogFile=$work/slurm/slurmd.log
SlurmctldPort=6817
SlurmdPort=6818
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MinJobAge=3600
NodeName=localhost NodeAddr=127.0.0.1 CPUs=2 State=UNKNOWN
PartitionName=local Nodes=localhost Default=YES MaxTime=INFINITE State=UP
CONF
log "starting slurmctld and slurmd ($SLURM_CONF)"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF" -N localhost
for _ in $(seq 60); do
    state=$(sinfo -h -N -o '%t' 2>/dev/null | head -1 || true)
    [[ $state == idle ]] && break
    sleep 1
done
log "node localhost: ${state:-no answer}"
if [[ ${state:-} != idle ]]; then
    echo "error: the node did not come up; see $work/slurm/slurmctld.log and slurmd.log" >&2
    exit 1
fi

log "submitting $n shards of $scenario and the merge"
t0=$(date +%s)
read -r array merge < <("$here/submit.sh" "$scenario" "$n" "$work/run")
log "array job $array, merge job $merge (afterok:$array)"
while squeue -h -j "$array,$merge" 2>/dev/null | grep -q .; do
    sleep 2
done
t1=$(date +%s)
log "all jobs left the queue after $((t1 - t0)) s"

echo "job summary (scontrol show job): id, array task, name, state, exit code, start, end, elapsed"
{
    scontrol -o show job "$array"
    scontrol -o show job "$merge"
} | awk '{
        delete f
        for (i = 1; i <= NF; i++) {
            eq = index($i, "=")
            if (eq > 0) f[substr($i, 1, eq - 1)] = substr($i, eq + 1)
        }
        task = ("ArrayTaskId" in f) ? f["ArrayJobId"] "_" f["ArrayTaskId"] : "-"
        printf "%-5s %-6s %-10s %-10s %-5s %s %s %s\n", f["JobId"], task, f["JobName"],
            f["JobState"], f["ExitCode"], f["StartTime"], f["EndTime"], f["RunTime"]
    }' | sort -n | tee "$work/jobs.txt"
merge_state=$(scontrol -o show job "$merge" | grep -o 'JobState=[A-Z_]*' | cut -d= -f2)
if [[ $merge_state != COMPLETED ]]; then
    echo "error: the merge job is $merge_state; logs in $work/run/logs" >&2
    exit 1
fi

log "unsharded run of the same binary for comparison"
t2=$(date +%s.%N)
"$work/run/bench-harness" "$scenario" --quiet --out "$work/whole"
t3=$(date +%s.%N)
log "unsharded run: $(awk -v a="$t2" -v b="$t3" 'BEGIN { printf "%.1f", b - a }') s"
# trials.csv without time_ms (column 8); summary.csv without the time_ms rows' statistics.
trials() { cut -d, -f1-7,9- "$1/trials.csv"; }
summary() { awk -F, -v OFS=, '$4 == "time_ms" { print $1, $2, $3, $4, $5, $6, $7; next } { print }' "$1/summary.csv"; }
if cmp -s <(trials "$work/run/merged") <(trials "$work/whole") &&
    cmp -s <(summary "$work/run/merged") <(summary "$work/whole"); then
    log "OK: the merged trials.csv ($(($(wc -l <"$work/whole/trials.csv") - 1)) rows) and summary.csv equal the unsharded run's apart from timings"
else
    echo "error: the merge differs from the unsharded run:" >&2
    diff <(trials "$work/run/merged") <(trials "$work/whole") | head >&2 || true
    diff <(summary "$work/run/merged") <(summary "$work/whole") | head >&2 || true
    exit 1
fi
