"""The per-motor output mapping: signs, offsets, gear ratios, units, drive ranges, TOML."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motionbase.config import preset_path
from motionbase.errors import ConfigError
from motionbase.platform import OutputMapping, Rus6Geometry, sweep_profile

GEOMETRY = Rus6Geometry.preset("ceart")
LO, HI = np.array(GEOMETRY.angle_min), np.array(GEOMETRY.angle_max)  # -60..60 deg


def make(**table) -> OutputMapping:
    return OutputMapping.from_dict(table, angle_min=LO, angle_max=HI)


def test_counts_apply_gear_and_offset_once():
    # 3600 counts per motor turn = 10 counts per motor degree; a 3:1 gearbox turns the motor
    # 3 deg per crank degree; the encoder reads 90 deg (900 counts) with the crank horizontal.
    m = make(unit="counts", counts_per_rev=3600, gear_ratio=3.0, zero_offset_deg=90.0)
    q0 = np.zeros(6)
    np.testing.assert_array_equal(m.to_drive(q0), np.full(6, 900.0))
    one_deg = np.full(6, math.radians(1.0))
    np.testing.assert_array_equal(m.to_drive(one_deg) - m.to_drive(q0), np.full(6, 30.0))
    np.testing.assert_array_equal(m.to_drive(-one_deg), np.full(6, 870.0))
    # the crank limits +-60 deg are the default drive range: 900 -+ 1800 counts
    np.testing.assert_array_equal(m.drive_min, [-900.0] * 6)
    np.testing.assert_array_equal(m.drive_max, [2700.0] * 6)


def test_mirrored_motor_moves_the_opposite_way():
    m = make(unit="deg", sign=[1, -1, 1, -1, 1, -1], zero_offset_deg=[0, 10, 0, 0, 0, 0])
    q = np.radians([20.0, 20.0, 0, 0, 0, 0])
    v = m.to_drive(q)
    assert v[0] == pytest.approx(20.0)
    assert v[1] == pytest.approx(10.0 - 20.0)  # offset once, then the mirrored crank angle
    up = m.to_drive(q + math.radians(1.0))
    assert up[0] > v[0] and up[1] < v[1]
    np.testing.assert_allclose(m.from_drive(v), q, atol=1e-15)


def test_range_spans_the_crank_range_and_reverses_when_mirrored():
    m = make(unit="range", sign=[1, -1, 1, 1, 1, 1], range_lo=0, range_hi=4095)
    at_min, at_max = m.to_drive(LO), m.to_drive(HI)
    assert at_min[0] == 0 and at_max[0] == 4095
    assert at_min[1] == 4095 and at_max[1] == 0  # mirrored: crank up -> value down
    mid = m.to_drive(np.zeros(6))
    assert abs(mid[0] - 4095 / 2) <= 0.5  # neutral (0 deg) is mid-range: -60..60 symmetric
    assert m.in_range(at_min).all() and m.in_range(at_max).all()
    # a 16-bit range gives 65535 steps over 120 deg
    m16 = make(unit="range", range_lo=0, range_hi=65535)
    np.testing.assert_allclose(m16.resolution(), math.radians(120.0) / 65535, rtol=1e-12)


def test_a_span_narrower_than_the_cranks_never_maps_past_the_range():
    """``range_lo..range_hi`` is what the drive takes: 0..4095 across +-45 deg of motor
    angle, on cranks limited to +-60 deg, gave a default drive range of -682..4777, so a
    crank at 50 deg went out as 4322 (a 12-bit drive wraps it to 226, near its other end).
    The default drive range is now the crank range's image within 0..4095."""
    m = make(unit="range", range_lo=0, range_hi=4095, span_min_deg=-45.0, span_max_deg=45.0)
    assert np.all(np.array(m.drive_min) >= 0) and np.all(np.array(m.drive_max) <= 4095)
    deg = np.linspace(-60.0, 60.0, 241)
    for d in deg:
        v = m.to_drive(np.full(6, math.radians(d)))
        expected = (d + 45.0) / 90.0 * 4095.0  # the span's straight line
        assert np.all(np.abs(v - expected) <= 0.5)
        assert m.in_range(v).all() == (0.0 <= round(expected) <= 4095.0), d
    # the same with a mirrored motor: the crank range's image reversed, still within 0..4095
    r = make(unit="range", sign=-1, range_lo=0, range_hi=4095, span_min_deg=-45, span_max_deg=45)
    assert np.all(np.array(r.drive_min) >= 0) and np.all(np.array(r.drive_max) <= 4095)
    assert not r.in_range(r.to_drive(np.full(6, math.radians(50.0)))).any()


@settings(max_examples=150, deadline=None)
@given(
    st.sampled_from(["deg", "rad", "counts", "range"]),
    st.lists(st.sampled_from([1, -1]), min_size=6, max_size=6),
    st.floats(-180, 180),
    st.floats(0.1, 50),
    st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
)
def test_from_drive_inverts_to_drive_within_one_step(unit, sign, offset_deg, gear, frac):
    extra = {"counts": {"counts_per_rev": 4096}, "range": {"range_lo": 0, "range_hi": 4095}}
    m = make(
        unit=unit, sign=sign, zero_offset_deg=offset_deg, gear_ratio=gear, **extra.get(unit, {})
    )
    q = np.array(frac) * HI
    v = m.to_drive(q)
    assert m.in_range(v).all()  # within the crank limits -> within the drive range
    if m.integer:
        np.testing.assert_array_equal(v, np.rint(v))
    # half a step of rounding, in crank angle
    assert np.all(np.abs(m.from_drive(v) - q) <= 0.5 * m.resolution() * (1 + 1e-9) + 1e-12)


def test_values_beyond_the_crank_limits_or_nan_are_out_of_range():
    for table in (
        {"unit": "deg"},
        {"unit": "range", "range_lo": 0, "range_hi": 4095, "sign": -1},
        {"unit": "counts", "counts_per_rev": 10000, "gear_ratio": 5.0},
    ):
        m = make(**table)
        beyond = HI + math.radians(1.0)
        assert not m.in_range(m.to_drive(beyond)).any()
        assert not m.in_range(m.to_drive(LO - math.radians(1.0))).any()
        q = np.zeros(6)
        q[2] = np.nan
        assert list(m.in_range(m.to_drive(q))) == [True, True, False, True, True, True]
    # an explicit, narrower drive range wins
    m = make(unit="range", range_lo=0, range_hi=1000, drive_min=100, drive_max=900)
    assert not m.in_range(m.to_drive(LO)).any()


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ({"unit": "steps"}, r"'unit'.*deg, rad, counts, range"),
        ({"unit": "deg", "sign": [1, 1, 0.5, 1, 1, 1]}, r"'sign'"),
        ({"unit": "deg", "gear_ratio": 0.0}, r"'gear_ratio'.*> 0"),
        ({"unit": "counts"}, r"counts_per_rev"),
        ({"unit": "range", "range_lo": 10, "range_hi": 10}, r"range_lo.*<.*range_hi"),
        ({"unit": "range", "range_lo": 0.5, "range_hi": 10}, r"integer 'range_lo'"),
        ({"unit": "deg", "range_hi": 10}, r"'range_hi' only applies"),
        ({"unit": "deg", "span_min_deg": 10}, r"'span_min_deg' only applies"),
        ({"unit": "deg", "gear": 2}, r"unknown field 'gear'"),
        ({"sign": 1}, r"missing field 'unit'"),
        ({"unit": "deg", "sign": [1, 1, 1]}, r"'sign'.*6 numbers"),
        ({"unit": "deg", "drive_min": 5, "drive_max": 5}, r"drive_min.*min < max"),
        ({"unit": "deg", "zero_offset": 0.1, "zero_offset_deg": 5}, r"either"),
        # strict types (issue 13, item 12)
        ({"unit": "deg", "sign": ["1", "-1", "1", "-1", "1", "-1"]}, r"'sign'.*'1'"),
        ({"unit": "deg", "gear_ratio": True}, r"'gear_ratio'.*True"),
        ({"unit": "deg", "zero_offset_deg": "5"}, r"'zero_offset_deg'.*'5'"),
        ({"unit": "counts", "counts_per_rev": "4096"}, r"'counts_per_rev'.*expected a number"),
        ({"unit": "range", "range_lo": 0, "range_hi": True}, r"integer 'range_hi'"),
        # an offset that swamps the crank's motion (it blamed drive_min/drive_max, unwritten)
        (
            {"unit": "deg", "zero_offset_deg": 1e300},
            r"x.toml: \[output\]: motor 1's crank range "
            r"maps to one drive value .*zero_offset and gear_ratio",
        ),  # fmt: skip
    ],
)
def test_validation_names_the_field(table, match):
    with pytest.raises(ConfigError, match=match):
        OutputMapping.from_dict(table, angle_min=LO, angle_max=HI, source="x.toml: [output]")


# --------------------------------------------------------------------------- geometry file


def test_geometry_without_output_is_unchanged():
    assert GEOMETRY.output is None
    assert "output" not in GEOMETRY.to_dict()
    assert Rus6Geometry.from_dict(GEOMETRY.to_dict()) == GEOMETRY


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(["deg", "rad", "counts", "range"]),
    st.lists(st.sampled_from([1, -1]), min_size=6, max_size=6),
    st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6),
    st.floats(0.5, 100.0),
)
def test_geometry_with_output_round_trips_exactly(tmp_path_factory, unit, sign, offset, gear):
    data = GEOMETRY.to_dict()
    table = {"unit": unit, "sign": sign, "zero_offset": offset, "gear_ratio": gear}
    table.update(
        {"counts": {"counts_per_rev": 131072}, "range": {"range_lo": 0, "range_hi": 65535}}.get(
            unit, {}
        )
    )
    data["output"] = table
    g = Rus6Geometry.from_dict(data, source="g.toml")
    assert isinstance(g.output, OutputMapping) and g.output.unit == unit
    assert Rus6Geometry.from_dict(g.to_dict()) == g
    # through JSON (the log's metadata) and TOML
    assert Rus6Geometry.from_dict(json.loads(json.dumps(g.to_dict()))) == g
    path = tmp_path_factory.mktemp("g") / "g.toml"
    g.to_toml(path)
    assert Rus6Geometry.from_toml(path) == g
    g.to_toml(path, units="deg")
    assert Rus6Geometry.from_toml(path).output == g.output


def test_output_table_in_a_hand_written_toml(tmp_path):
    text = preset_path("rus6", "ceart").read_text() + (
        '\n[output]\nunit = "range"\nsign = [1, -1, 1, -1, 1, -1]\nrange_lo = 0\nrange_hi = 4095\n'
    )
    path = tmp_path / "mine.toml"
    path.write_text(text)
    g = Rus6Geometry.from_toml(path)
    assert g.output.sign == (1.0, -1.0) * 3
    assert g.output.range_hi == 4095
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('unit = "range"', 'unit = "range"\nspeed = 3'))
    with pytest.raises(ConfigError, match=r"bad.toml: \[output\]: unknown field 'speed'"):
        Rus6Geometry.from_toml(bad)


# --------------------------------------------------------------------------- wiring sweep


def test_sweep_moves_one_motor_at_a_time_within_speed_and_accel():
    dt, speed, accel, rng = 0.01, math.radians(10.0), 5.0, math.radians(5.0)
    park = np.full(6, GEOMETRY.park_angle)
    neutral = GEOMETRY.neutral_angle
    q, motor = sweep_profile(park, neutral, LO, HI, range_rad=rng, speed=speed, accel=accel, dt=dt)
    np.testing.assert_array_equal(q[0], park)
    np.testing.assert_allclose(q[-1], park, atol=1e-12)
    assert list(dict.fromkeys(motor.tolist())) == [0, 1, 2, 3, 4, 5, 6]
    v = np.diff(q, axis=0) / dt
    assert np.abs(v).max() <= speed * 1.001
    assert np.abs(np.diff(v, axis=0) / dt).max() <= accel * 1.01
    for i in range(1, 7):
        seg = q[motor == i]
        others = np.delete(seg, i - 1, axis=1)
        np.testing.assert_allclose(
            others, np.broadcast_to(np.delete(neutral, i - 1), others.shape), atol=1e-12
        )
        assert seg[:, i - 1].max() == pytest.approx(neutral[i - 1] + rng, abs=1e-12)
        assert seg[:, i - 1].min() == pytest.approx(neutral[i - 1] - rng, abs=1e-12)
    with pytest.raises(ConfigError, match="range-deg"):
        sweep_profile(
            park, neutral, LO, HI, range_rad=math.radians(70), speed=speed, accel=accel, dt=dt
        )


def test_sweep_of_some_motors_moves_only_those_in_the_order_given():
    """``motors`` (a drive that carries three of six): only they leave neutral, in that
    order; the others stay at neutral between the moves from and to park."""
    dt, speed, accel, rng = 0.01, math.radians(10.0), 5.0, math.radians(5.0)
    park = np.full(6, GEOMETRY.park_angle)
    neutral = GEOMETRY.neutral_angle
    q, motor = sweep_profile(
        park, neutral, LO, HI, range_rad=rng, speed=speed, accel=accel, dt=dt, motors=[4, 0]
    )
    assert [m for m, _ in itertools.groupby(motor.tolist())] == [0, 5, 1, 0]
    away = np.abs(q[motor > 0] - neutral) > 1e-12
    assert not away[:, [1, 2, 3, 5]].any() and away[:, [0, 4]].any(axis=0).all()
    np.testing.assert_allclose(q[-1], park, atol=1e-12)


def test_sweep_of_some_motors_checks_the_range_against_their_limits_only():
    """A motor left out of ``motors`` (carried by another drive) with less room about
    neutral than the range: it only goes from park to neutral and back, so the sweep of the
    others is made (it was refused, "leaves the crank limits", as if it were swept), and
    it stays within its own limits; sweeping it is still refused."""
    dt, speed, accel, rng = 0.01, math.radians(10.0), 5.0, math.radians(5.0)
    park = np.full(6, GEOMETRY.park_angle)
    neutral = GEOMETRY.neutral_angle
    hi = HI.copy()
    hi[3] = max(neutral[3], park[3]) + math.radians(1.0)  # motor 4: 1 deg of room
    q, motor = sweep_profile(
        park, neutral, LO, hi, range_rad=rng, speed=speed, accel=accel, dt=dt, motors=[0, 1]
    )
    assert np.all(q <= hi + 1e-12) and np.all(q >= LO - 1e-12)
    ends = [q[motor == k + 1, k] for k in (0, 1)]  # each swept motor, in its sweep
    np.testing.assert_allclose(
        [[e.max(), e.min()] for e in ends], [[n + rng, n - rng] for n in neutral[:2]]
    )
    with pytest.raises(ConfigError, match="leaves the crank limits"):
        sweep_profile(
            park, neutral, LO, hi, range_rad=rng, speed=speed, accel=accel, dt=dt, motors=[3]
        )
