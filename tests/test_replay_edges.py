"""``motionbase replay`` against recordings that lie, change or hold odd values.

Found by an adversarial review of the replay path (crafted MCAP files, real CLI runs):
each test here failed on the code before its fix.
"""

from __future__ import annotations

import math

import pytest

from motionbase import app

# --------------------------------------------------------------------------- --check's compare


KEYS = ("a", "b", "c", "d", "e", "f")


@pytest.mark.parametrize("where", range(len(KEYS)))
@pytest.mark.parametrize("recorded_nan", [True, False])
def test_check_sees_a_nan_against_a_number_wherever_it_sits(where, recorded_nan):
    """A value that is NaN on one side and a number on the other is a difference, wherever
    it sits in a message (a list position or a field). It was lost when ``max`` met it after
    a 0: ``max(0.0, nan)`` is 0.0, so the check said "identical"."""
    finite = [0.5 * k for k in range(len(KEYS))]
    with_nan = list(finite)
    with_nan[where] = math.nan
    rec, rep = (with_nan, finite) if recorded_nan else (finite, with_nan)
    as_list = app.compare_recordings({"/x": [{"v": rec}]}, {"/x": [{"v": rep}]})
    as_fields = app.compare_recordings(
        {"/x": [dict(zip(KEYS, rec, strict=True))]}, {"/x": [dict(zip(KEYS, rep, strict=True))]}
    )
    for report in (as_list, as_fields):
        assert not report.identical
        assert "check: DIFFERS" in report.lines()[0]


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_check_finds_the_same_non_finite_value_identical(value):
    """A replay that reproduces a non-finite value (a rejected NaN input, logged as it came)
    reproduces it bit for bit: no difference, whatever the order of the fields."""
    msg = {k: (value if k == "c" else 1.0) for k in KEYS}
    report = app.compare_recordings(
        {"/x": [msg, {"v": [value, 2.0]}]}, {"/x": [msg, {"v": [value, 2.0]}]}
    )
    assert report.identical, report.lines()


def test_check_of_an_integer_beyond_any_float_is_a_difference_not_a_crash():
    """JSON holds integers of any size (a crafted file); comparing one with a number raised
    OverflowError, a traceback from ``replay --check``."""
    report = app.compare_recordings({"/x": [{"n": 10**400}]}, {"/x": [{"n": 0}]})
    assert not report.identical
    assert app.compare_recordings({"/x": [{"n": 10**400}]}, {"/x": [{"n": 10**400}]}).identical
