"""What the Python call adds to an estimate: `epd.estimate(points)` against the same
estimate called from Rust (examples/overhead.rs), in alternating rounds so that both
see the same machine load.

    cargo build --release -p epd-py --example overhead
    python overhead.py FILE --rust target/release/examples/overhead [--rounds 5] [--calls 20]

FILE is a point cloud (e.g. `epd simulate --points 100000`). Prints the median time per
call of each and the overhead of the Python call in per cent of the Rust pipeline
(the estimate and its report, what epd.estimate runs) and of `epd_core::estimate` alone.
"""

import argparse
import json
import statistics
import subprocess
import time

import epd


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--rust", required=True, help="the built overhead example")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=20)
    args = ap.parse_args()
    points, _ = epd.read(args.file)
    epd.estimate(points)  # warm-up
    py, core, pipe = [], [], []
    for _ in range(args.rounds):
        for _ in range(args.calls):
            t = time.perf_counter()
            epd.estimate(points)
            py.append((time.perf_counter() - t) * 1e3)
        out = subprocess.run(
            [args.rust, args.file, str(args.calls)], capture_output=True, text=True, check=True
        ).stdout
        r = json.loads(out)
        core += r["core"]
        pipe += r["pipeline"]
    m = {k: statistics.median(v) for k, v in (("python", py), ("pipeline", pipe), ("core", core))}
    print(
        json.dumps(
            {
                "n_points": len(points),
                "calls_each": len(py),
                "median_ms": m,
                "min_ms": {"python": min(py), "pipeline": min(pipe), "core": min(core)},
                "overhead_vs_pipeline_pct": 100 * (m["python"] / m["pipeline"] - 1),
                "overhead_vs_core_pct": 100 * (m["python"] / m["core"] - 1),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
