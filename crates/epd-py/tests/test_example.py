"""The multiprocessing example gives, per file, the tool's JSON object."""

import json
import subprocess
import sys
from pathlib import Path

from conftest import assert_same_report, cli_json

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "batch_estimate.py"


def test_batch_example_over_many_files(epd_bin, frames, tmp_path):
    missing = tmp_path / "missing.ply"
    files = [*frames, missing, *frames]
    p = subprocess.run(
        [sys.executable, EXAMPLE, "--processes", "2", *map(str, files)],
        capture_output=True, text=True, timeout=600,
    )
    assert p.returncode == 1, p.stderr  # one file failed
    lines = [json.loads(ln) for ln in p.stdout.splitlines()]
    assert [r["file"] for r in lines] == list(map(str, files))
    for f, r in zip(files, lines):
        if f == missing:
            assert r["status"] == "error" and r["error"] == cli_json(epd_bin, f)["error"]
        else:
            assert_same_report(r, cli_json(epd_bin, f))
    assert f"{len(files) - 1} of {len(files)} files converged" in p.stderr
