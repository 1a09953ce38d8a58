#!/bin/bash
# Run the container commands of shard-job.yaml and merge-job.yaml on this machine, as
# the pods would run them (JOB_COMPLETION_INDEX = 0 … N−1 one after the other, then the
# merge), with /scenario and /work mapped to a local folder. A check of the manifests'
# shell and paths without a cluster; it does not test Kubernetes itself.
#
#   scripts/k8s/dry-run.sh SCENARIO WORKDIR     (needs python3 with PyYAML, bash, sh)
# BENCH_HARNESS=/path/to/bench-harness (default: target/debug/bench-harness, built).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
scenario=$(realpath "$1")
work=$2
mkdir -p "$work/bin" "$work/scenario" "$work/work"
work=$(realpath "$work")
if [[ -z "${BENCH_HARNESS:-}" ]]; then
    (cd "$repo" && cargo build -p bench-harness -j 2 >&2)
    BENCH_HARNESS=$repo/target/debug/bench-harness
fi
ln -sf "$(realpath "$BENCH_HARNESS")" "$work/bin/bench-harness"
cp "$scenario" "$work/scenario/scenario.toml"
# The manifest's command (sh -c ARG), its SHARDS and completions, with the mount
# points mapped to the local folders.
field() {
    python3 - "$1" "$2" "$work" <<'PY'
import sys, yaml
path, what, work = sys.argv[1:]
job = yaml.safe_load(open(path))
c = job["spec"]["template"]["spec"]["containers"][0]
if what == "script":
    s = c["args"][0]
    print(s.replace("/scenario/", work + "/scenario/").replace("/work/", work + "/work/"))
elif what == "shards":
    print(next(e["value"] for e in c["env"] if e["name"] == "SHARDS"))
elif what == "completions":
    print(job["spec"]["completions"])
PY
}
n=$(field "$here/shard-job.yaml" shards)
completions=$(field "$here/shard-job.yaml" completions)
if [[ $n != "$completions" ]]; then
    echo "error: shard-job.yaml: SHARDS=$n but completions=$completions" >&2
    exit 1
fi
shard_script=$(field "$here/shard-job.yaml" script)
merge_script=$(field "$here/merge-job.yaml" script)
for ((i = 0; i < n; i++)); do
    echo "pod index $i"
    PATH=$work/bin:$PATH JOB_COMPLETION_INDEX=$i SHARDS=$n sh -c "$shard_script"
done
echo "merge"
PATH=$work/bin:$PATH SHARDS=$(field "$here/merge-job.yaml" shards) sh -c "$merge_script"
ls "$work/work/merged"
