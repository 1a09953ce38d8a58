#!/usr/bin/env bash
# Issue 24's two-size calibration through the command line, as a user runs it: rigs of
# 20" and 30" round pipes and test frames of 20", 24" and 30" pipes with 2 % ovality,
# all simulated by `epd simulate --sensor helios2` (tof-sim's camera model), then
# `epd calibrate --rigs` and `epd estimate --calibration … --straight-only`. Prints per
# test size the mean-diameter error of each frame (mm, against the simulator's truth
# beside each frame), their mean and how many the reported 1-σ covers.
#
#   scripts/calibration-cli.sh [EPD] [RIG_FRAMES] [TEST_FRAMES]
#
# EPD defaults to target/release/epd (build it with `cargo build --release -p epd-cli`);
# RIG_FRAMES (6) and TEST_FRAMES (5) per size. Frames go to a temporary folder that is
# removed at the end (about 10 MB a frame).
set -euo pipefail
epd=${1:-target/release/epd}
rig_n=${2:-6}
test_n=${3:-5}
[ -x "$epd" ] || { echo "no epd binary at $epd: cargo build --release -p epd-cli" >&2; exit 2; }
epd=$(cd "$(dirname "$epd")" && pwd)/$(basename "$epd")
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
cd "$dir"
"$epd" simulate --sensor helios2 --out rig20 --frames "$rig_n" --seed 101 --od-in 20 --ovality 0 >/dev/null 2>&1
"$epd" simulate --sensor helios2 --out rig30 --frames "$rig_n" --seed 102 --od-in 30 --ovality 0 >/dev/null 2>&1
for s in 20 24 30; do
  "$epd" simulate --sensor helios2 --out "test$s" --frames "$test_n" --seed "2$s" --od-in "$s" --ovality 0.02 >/dev/null 2>&1
done
python3 - "$rig_n" <<'EOF'
import glob, json, sys
def known(folder):
    t = json.load(open(sorted(glob.glob(folder + "/*.json"))[0]))
    return t["d_max_mm"]
with open("rigs.toml", "w") as f:
    for folder in ("rig20", "rig30"):
        files = ", ".join('"%s"' % p for p in sorted(glob.glob(folder + "/*.ply")))
        f.write("[[rig]]\nknown_id_mm = %r\nfiles = [%s]\n" % (known(folder), files))
EOF
"$epd" calibrate --rigs rigs.toml --out lut.json --quiet ${PASSES:+--passes $PASSES}
for s in 20 24 30; do
  "$epd" estimate "test$s"/*.ply --calibration lut.json --straight-only --format json 2>/dev/null \
    > "est$s.jsonl" || true
  python3 - "$s" <<'EOF'
import json, sys
s = sys.argv[1]
errs, covered = [], 0
for line in open("est%s.jsonl" % s):
    r = json.loads(line)
    if r.get("d_max_mm") is None:
        print('%s": %s refused: %s' % (s, r.get("file"), r.get("status")))
        continue
    t = json.load(open(r["file"][:-4] + ".json"))
    e = (r["d_max_mm"] + r["d_min_mm"] - t["d_max_mm"] - t["d_min_mm"]) / 2
    sd = r["sigma_d_mean_mm"]
    errs.append(e)
    covered += abs(e) <= 1.96 * sd
mean = sum(errs) / len(errs) if errs else float("nan")
print('%s": mean-diameter error %s mm; mean %+.2f mm; covered %d of %d'
      % (s, " ".join("%+.2f" % e for e in errs), mean, covered, len(errs)))
EOF
done
