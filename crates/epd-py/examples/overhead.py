"""What the Python call adds to an estimate: `epd.estimate(points)` against the same
estimate called from Rust (examples/overhead.rs), in alternating rounds so that both
see the same machine load.

    cargo build --release -p epd-py --example overhead
    python overhead.py FILE --rust target/release/examples/overhead [--rounds 5] [--calls 20]
                       [--threads N]

FILE is a point cloud (e.g. `epd simulate --points 100000`). Prints the median time per
call of each and the overhead of the Python call in per cent of the Rust pipeline
(the estimate and its report, what epd.estimate runs) and of `epd_core::estimate` alone;
and, per call, the time spent outside the fit itself (less the `elapsed_ms` timed in
Rust), in Python and in the Rust pipeline: their difference is what the Python call adds,
measured within each call and so hardly touched by the machine's other load.
"""

import argparse
import json
import statistics
import subprocess
import os
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--rust", required=True, help="the built overhead example")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=20)
    ap.add_argument("--threads", type=int, help="RAYON_NUM_THREADS for both (default: all cores)")
    args = ap.parse_args()
    if args.threads:
        # Before epd's thread pool starts; the Rust example inherits it.
        os.environ["RAYON_NUM_THREADS"] = str(args.threads)
    import epd

    points, _ = epd.read(args.file)
    epd.estimate(points)  # warm-up
    py, core, pipe, outside, rust_outside = [], [], [], [], []
    for _ in range(args.rounds):
        for _ in range(args.calls):
            t = time.perf_counter()
            r = epd.estimate(points)
            wall = (time.perf_counter() - t) * 1e3
            py.append(wall)
            # Everything but the fit itself (timed in Rust): the binding, the unit check,
            # the RMS residual, the report and the dict. Measured within each call, so
            # the machine's other load hardly enters it.
            outside.append(wall - r["elapsed_ms"])
        out = subprocess.run(
            [args.rust, args.file, str(args.calls)], capture_output=True, text=True, check=True
        ).stdout
        r = json.loads(out)
        core += r["core"]
        pipe += r["pipeline"]
        rust_outside += r["outside_fit"]
    m = {k: statistics.median(v) for k, v in (("python", py), ("pipeline", pipe), ("core", core))}
    print(
        json.dumps(
            {
                "n_points": len(points),
                "threads": os.environ.get("RAYON_NUM_THREADS", "all cores"),
                "calls_each": len(py),
                "median_ms": m,
                "min_ms": {"python": min(py), "pipeline": min(pipe), "core": min(core)},
                "overhead_vs_pipeline_pct": 100 * (m["python"] / m["pipeline"] - 1),
                "outside_fit_ms_median": {
                    "python": statistics.median(outside),
                    "rust": statistics.median(rust_outside),
                },
                # What the Python call adds to the same pipeline, from the parts outside
                # the fit (each measured within its call).
                "python_added_ms": statistics.median(outside) - statistics.median(rust_outside),
                "python_added_pct": 100
                * (statistics.median(outside) - statistics.median(rust_outside))
                / m["pipeline"],
                "overhead_vs_core_pct": 100 * (m["python"] / m["core"] - 1),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
