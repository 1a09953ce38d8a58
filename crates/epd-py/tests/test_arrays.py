"""Points at the boundary: float64 C-contiguous (N, 3) arrays are read in place, other
layouts and dtypes are converted once and give the same result, and the caller's array
is never changed."""

import numpy as np
import pytest

import epd
from conftest import TIMINGS, assert_same_report


@pytest.fixture(scope="module")
def cloud():
    points, _ = epd.simulate(points=20000, seed=5)
    return points


def address(a):
    return a.__array_interface__["data"][0]


def test_float64_c_contiguous_is_not_copied(cloud):
    a = cloud.copy()
    buf, copied = epd._points_buffer(a)
    assert (buf, copied) == (address(a), False)
    # A read-only array is borrowed as well.
    a.setflags(write=False)
    assert epd._points_buffer(a) == (address(a), False)


def test_a_row_slice_of_a_contiguous_array_is_not_copied(cloud):
    a = cloud[100:5000]
    assert a.flags.c_contiguous
    assert epd._points_buffer(a) == (address(a), False)


@pytest.mark.parametrize(
    "make",
    [
        lambda c: np.asfortranarray(c),
        lambda c: c[::2],
        lambda c: c[::-1],
        lambda c: c.astype(">f8"),
        lambda c: c.tolist(),
    ],
    ids=["fortran", "strided", "reversed", "big-endian", "list"],
)
def test_other_layouts_are_copied_and_give_the_same_result(cloud, make):
    a = make(cloud)
    _, copied = epd._points_buffer(a)
    assert copied
    expected = epd.estimate(np.ascontiguousarray(np.asarray(a, dtype=np.float64)))
    assert_same_report(epd.estimate(a), expected)


def test_float32_and_integers_are_converted(cloud):
    f32 = cloud.astype(np.float32)
    assert epd._points_buffer(f32)[1]
    assert_same_report(epd.estimate(f32), epd.estimate(f32.astype(np.float64)))
    mm = np.round(cloud * 1e3).astype(np.int32)
    assert_same_report(
        epd.estimate(mm, units="mm"), epd.estimate(mm.astype(np.float64), units="mm")
    )


def test_the_callers_array_is_left_unchanged(cloud):
    a = cloud.copy()
    flags = a.flags.writeable, a.flags.c_contiguous, a.flags.owndata
    before = a.copy()
    epd.estimate(a)
    epd.estimate(a * 1e3, units="mm", frame="optical")
    b = a * 1e3
    b_before = b.copy()
    epd.estimate(b, units="mm")
    assert np.array_equal(a, before) and np.array_equal(b, b_before)
    assert (a.flags.writeable, a.flags.c_contiguous, a.flags.owndata) == flags


def test_no_copy_when_calibration_is_absent_means_the_same_bits(cloud):
    """The borrowed path and a converted copy of the same values agree to the bit."""
    a = cloud.copy()
    f = np.asfortranarray(a)
    r1, r2 = epd.estimate(a), epd.estimate(f)
    assert_same_report(r1, r2)
    assert all(k in r1 for k in TIMINGS)
