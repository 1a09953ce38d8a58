"""Estimate many point-cloud files in parallel, one process per core, and print one JSON
line per file: the keys and values of `epd estimate --format json` (a file that cannot be
used gives a line with `"status": "error"` and the message in `error`).

    python batch_estimate.py [--processes N] [--method ml-epd] [--units m] FILE... > out.jsonl

Each worker process fits one file at a time with one thread (RAYON_NUM_THREADS=1, set
before the workers start): over many files that keeps every core busy without the
workers' thread pools fighting over them. The pool uses the "spawn" start method: clean
workers on every platform, each reading RAYON_NUM_THREADS when it starts (a forked worker
would also work: epd rebuilds its thread pool in a forked child).
"""

import argparse
import json
import multiprocessing as mp
import os
import sys


def estimate_one(job):
    """One file's result as a dict (never raises: errors become result lines)."""
    import epd

    path, kwargs = job
    try:
        return epd.estimate(path, **kwargs)
    except (OSError, ValueError) as e:
        message = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        return {"file": path, "status": "error", "error": message}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--processes", type=int, default=os.cpu_count())
    ap.add_argument("--method", default="ml-epd")
    ap.add_argument("--units", default="m")
    ap.add_argument("--frame", default="sensor")
    args = ap.parse_args(argv)
    kwargs = {"method": args.method, "units": args.units, "frame": args.frame}
    # Inherited by the spawned workers; read by the thread pool when it starts.
    os.environ["RAYON_NUM_THREADS"] = "1"
    failed = 0
    ctx = mp.get_context("spawn")
    with ctx.Pool(args.processes) as pool:
        jobs = [(f, kwargs) for f in args.files]
        for result in pool.imap(estimate_one, jobs, chunksize=1):
            failed += result["status"] != "converged"
            print(json.dumps(result), flush=True)
    print(f"{len(args.files) - failed} of {len(args.files)} files converged", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
