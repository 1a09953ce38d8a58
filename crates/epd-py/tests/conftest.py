"""Shared fixtures: the `epd` binary the Python results are checked against, and frames
simulated by it.

The binary is $EPD_BIN when set; else the newest of target/release/epd and
target/debug/epd under $CARGO_TARGET_DIR or the workspace's target folder (build it
with `cargo build -p epd-cli`). Without one the tests that need it fail (they are not
skipped).
"""

import json
import math
import os
import subprocess
from pathlib import Path

import pytest

WORKSPACE = Path(__file__).resolve().parents[3]

# Keys whose values differ between two runs of the same estimate.
TIMINGS = ("elapsed_ms", "read_ms")


def find_epd_bin():
    env = os.environ.get("EPD_BIN")
    if env:
        return Path(env)
    target = Path(os.environ.get("CARGO_TARGET_DIR", WORKSPACE / "target"))
    found = [target / p / "epd" for p in ("release", "debug")]
    found = [p for p in found if p.is_file()]
    if not found:
        return None
    return max(found, key=lambda p: p.stat().st_mtime)


@pytest.fixture(scope="session")
def epd_bin():
    b = find_epd_bin()
    if b is None or not b.is_file():
        pytest.fail(
            "the `epd` binary was not found: set EPD_BIN or run `cargo build -p epd-cli` "
            f"(looked for {b or 'target/{release,debug}/epd'})"
        )
    return b


def run_epd(epd_bin, *args, check=True):
    """Run the binary; returns the CompletedProcess (text)."""
    p = subprocess.run(
        [str(epd_bin), *map(str, args)], capture_output=True, text=True, timeout=600
    )
    if check and p.returncode != 0:
        raise AssertionError(f"epd {' '.join(map(str, args))} exited {p.returncode}: {p.stderr}")
    return p


def cli_json(epd_bin, path, *flags):
    """The one JSON object of `epd estimate --format json PATH FLAGS…` (whatever its exit
    code: a failed file is a result object too)."""
    p = run_epd(epd_bin, "estimate", "--format", "json", "-q", *flags, path, check=False)
    lines = [ln for ln in p.stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, (p.returncode, p.stdout, p.stderr)
    return json.loads(lines[0])


def cli_usage_error(epd_bin, *args):
    """The message of a usage error (exit code 2) of `epd`, without the `error: ` prefix."""
    p = run_epd(epd_bin, *args, check=False)
    assert p.returncode == 2, (p.returncode, p.stdout, p.stderr)
    first = p.stderr.splitlines()[0]
    assert first.startswith("error: "), p.stderr
    return first[len("error: "):]


def same_value(a, b):
    """Equal to the last bit: floats by their repr (which round-trips and keeps -0.0).

    The tool prints a whole float without a fraction (`508`, as Rust's `{}` does), which
    json.loads makes an int: such an int equals the float it was printed from."""
    if isinstance(a, float) and type(b) is int:
        a, b = b, a
    if type(a) is int and isinstance(b, float):
        return float(a) == b and int(b) == a and repr(b) == repr(float(a))
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(a, float) and isinstance(b, float) and (
            repr(a) == repr(b) or (math.isnan(a) and math.isnan(b))
        )
    return type(a) is type(b) and a == b


def assert_same_report(py, cli, skip=TIMINGS):
    """The same keys in the same order and the same values, timings aside."""
    assert list(py) == list(cli), (list(py), list(cli))
    bad = {k: (py[k], cli[k]) for k in py if k not in skip and not same_value(py[k], cli[k])}
    assert not bad, bad


@pytest.fixture(scope="session")
def frames(epd_bin, tmp_path_factory):
    """Three plain frames of 20 000 points (binary double PLY) and their truths."""
    d = tmp_path_factory.mktemp("frames")
    run_epd(epd_bin, "simulate", "--out", d, "--frames", 3, "--seed", 7, "--points", 20000)
    return sorted(d.glob("frame_*.ply"))


@pytest.fixture(scope="session")
def helios_frames(epd_bin, tmp_path_factory):
    """Four Helios2 frames of 30 000 points (with intensity) and a depth table made from
    the first three by `epd calibrate`."""
    d = tmp_path_factory.mktemp("helios")
    run_epd(
        epd_bin, "simulate", "--out", d, "--frames", 4, "--seed", 3, "--points", 30000,
        "--sensor", "helios2",
    )
    plys = sorted(d.glob("frame_*.ply"))
    truth = json.loads((d / "frame_0000.json").read_text())
    table = d / "table.json"
    run_epd(
        epd_bin, "calibrate", *plys[:3], "--known-id-mm", truth["d_max_mm"],
        "--known-dmin-mm", truth["d_min_mm"], "--out", table, "--min-count", 10, "-q",
    )
    return plys, table
