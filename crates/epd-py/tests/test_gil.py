"""The GIL is released during a fit: another Python thread keeps running meanwhile."""

import sys
import threading
import time

import numpy as np
import pytest

import epd


@pytest.fixture(scope="module")
def big():
    points, _ = epd.simulate(points=300_000, seed=11)
    return points


def progress_during(fit):
    """Run `fit` in a thread while this thread takes a time stamp every half millisecond
    (sleeping in between, so that it needs the GIL often but the CPU little: the fit's
    threads keep the cores); returns the stamps taken while the fit ran, the longest gap
    between two of them (s) and the fit's result."""
    spans, results = [], []

    def worker():
        t0 = time.perf_counter()
        results.append(fit())
        spans.append((t0, time.perf_counter()))

    stamps = []
    old = sys.getswitchinterval()
    # A short switch interval: the threads take turns quickly whenever both run Python.
    sys.setswitchinterval(1e-4)
    try:
        t = threading.Thread(target=worker)
        t.start()
        while t.is_alive():
            stamps.append(time.perf_counter())
            time.sleep(0.0005)
        t.join()
    finally:
        sys.setswitchinterval(old)
    ((t0, t1),) = spans
    inside = [t0] + [s for s in stamps if t0 <= s <= t1] + [t1]
    stall = max(b - a for a, b in zip(inside, inside[1:]))
    return len(inside) - 2, stall, results[0]


@pytest.mark.parametrize("source", ["array", "file"])
def test_another_thread_runs_during_the_fit(big, tmp_path, source):
    if source == "file":
        f = tmp_path / "big.csv"
        np.savetxt(f, big, delimiter=",", fmt="%.17g")
        fit = lambda: epd.estimate(f)  # noqa: E731 (read and fit without the GIL)
    else:
        fit = lambda: epd.estimate(big, method="ru-epd")  # noqa: E731
    fit()  # warm up (the thread pool, the page cache)
    turns, stall, result = progress_during(fit)
    fit_s = result["elapsed_ms"] * 1e-3  # the fit alone, timed in Rust
    assert fit_s > 0.003, result
    # With the GIL held this thread would stand still for the whole fit: one gap at
    # least as long as the fit. Released, it keeps stamping all along.
    assert stall < 0.75 * fit_s, (stall, fit_s, turns)
    assert turns >= 5, (turns, fit_s)
