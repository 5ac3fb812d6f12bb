"""WashoutParams: presets, exact round trips, clear errors, and that the default fits ceart."""

from __future__ import annotations

import copy
import json
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motionbase.errors import ConfigError
from motionbase.platform.robot import load_geometry
from motionbase.washout import ClassicalWashout, WashoutParams

G = 9.80665
DT = 1.0 / 120.0


@pytest.mark.parametrize("name", ["default", "gentle", "telemetry"])
def test_presets_load_and_round_trip_exactly(name, tmp_path):
    p = WashoutParams.preset(name)
    assert WashoutParams.from_dict(p.to_dict()) == p
    # the pipeline stores to_dict() as JSON metadata in the MCAP log
    assert WashoutParams.from_dict(json.loads(json.dumps(p.to_dict())), source="log") == p
    path = tmp_path / "w.toml"
    p.to_toml(path)
    assert WashoutParams.from_toml(path) == p
    assert WashoutParams.load(str(path)) == p
    assert WashoutParams.load(name) == p


def test_si_views_convert_degrees():
    p = WashoutParams.preset("default")
    assert p.tilt_rate_limit == pytest.approx([math.radians(v) for v in p.tilt_rate_limit_deg_s])
    assert p.tilt_angle_limit == pytest.approx([math.radians(v) for v in p.tilt_angle_limit_deg])
    assert np.allclose(p.angular_velocity_limit, np.radians(p.angular_velocity_limit_deg_s))
    assert p.gravity == p.g == 9.80665


def test_default_follows_the_simona_structure():
    p = WashoutParams.preset("default")
    # DESIGN.md: tilt low-pass 2 rad/s, zeta 1, tilt rate 3 deg/s; zeta 1 everywhere
    assert p.tilt_wn == 2.0 and p.tilt_zeta == 1.0 and p.tilt_rate_limit_deg_s == (3.0, 3.0)
    assert p.translational_zeta == (1.0, 1.0, 1.0)
    assert p.method == "tustin"
    gentle = WashoutParams.preset("gentle")
    assert all(
        g <= d for g, d in zip(gentle.specific_force_gain, p.specific_force_gain, strict=True)
    )
    assert all(
        g < d for g, d in zip(gentle.tilt_angle_limit_deg, p.tilt_angle_limit_deg, strict=True)
    )


@pytest.mark.parametrize("name", ["default", "gentle", "telemetry"])
def test_worst_single_axis_inputs_stay_inside_the_ceart_reach(name):
    """Inputs at the saturation limits, one axis at a time, with margin to the reach."""
    p = WashoutParams.preset(name)
    n = int(40.0 / DT)
    margin = 0.9
    # DESIGN.md, "Geometry defaults": surge 0.36 m forward and 0.30 m back, sway +-0.31 m,
    # heave 0.12 m down (+z) and 0.20 m up, roll +-19.0 deg, pitch 30.3 deg nose up and
    # 17.6 deg nose down, yaw +-48.9 deg
    reach_up = np.array(
        [0.36, 0.31, 0.12, math.radians(19.0), math.radians(30.3), math.radians(48.9)]
    )
    reach_lo = -np.array(
        [0.30, 0.31, 0.20, math.radians(19.0), math.radians(17.6), math.radians(48.9)]
    )
    for axis in range(6):
        for sign in (1.0, -1.0):
            f = np.tile([0.0, 0.0, -G], (n, 1))
            w = np.zeros((n, 3))
            if axis < 3:
                f[:, axis] += sign * 1e3  # saturates at specific_force_limit
            else:
                w[:, axis - 3] = sign * 1e3  # saturates at angular_velocity_limit
            poses = ClassicalWashout(p, DT).run(f, w)
            assert np.all(poses <= margin * reach_up + 1e-12), (name, axis, sign)
            assert np.all(poses >= margin * reach_lo - 1e-12), (name, axis, sign)


# --- errors ------------------------------------------------------------------------------------


def _base() -> dict:
    return WashoutParams.preset("default").to_dict()


@pytest.mark.parametrize(
    "edit,match",
    [
        (lambda d: d["translational"].pop("wb"), "missing field 'wb'"),
        (lambda d: d.pop("tilt"), "missing field 'tilt'"),
        (lambda d: d["tilt"].update(speed=1.0), "unknown field 'speed'"),
        (lambda d: d.update(gain=1.0), "unknown field 'gain'"),
        (lambda d: d["translational"].update(wn=[1.0, -1.0, 1.0]), "translational.wn.*> 0"),
        (lambda d: d["rotational"].update(zeta=[1.0, 0.0, 1.0]), "rotational.zeta.*> 0"),
        (lambda d: d["translational"].update(zeta=[1.0, 1.0, -0.5]), "translational.zeta"),
        (lambda d: d["tilt"].update(rate_limit_deg_s=0.0), "rate_limit_deg_s.*> 0"),
        (lambda d: d["tilt"].update(rate_limit_deg_s=-3.0), "rate_limit_deg_s"),
        (lambda d: d["tilt"].update(wn=-2.0), "tilt.wn"),
        (lambda d: d["tilt"].update(angle_limit_deg=90.0), "< 90 deg"),
        (lambda d: d["tilt"].update(accel_limit_deg_s2=0.0), "accel_limit_deg_s2.*> 0"),
        (lambda d: d["tilt"].update(accel_limit_deg_s2=-8.0), "accel_limit_deg_s2"),
        (
            lambda d: d["scaling"].update(specific_force_gain=[0.5, -0.1, 0.3]),
            "specific_force_gain",
        ),
        (lambda d: d["scaling"].update(specific_force_limit=[1.0, 1.0]), "expected 3 numbers"),
        (
            lambda d: d["scaling"].update(angular_velocity_limit_deg_s=[30, "x", 30]),
            "angular_velocity",
        ),
        (lambda d: d["translational"].update(wn=[1.0, float("nan"), 1.0]), "finite"),
        (lambda d: d.update(g=0.0), "'g'"),
        (lambda d: d.update(method="euler"), "method"),
        (lambda d: d["tilt"].update(zeta="one"), "expected a number"),
        (lambda d: d.update(translational=3), r"\[translational\] must be a table"),
        # strict types (issue 13, item 12): never converted
        (lambda d: d["scaling"].update(specific_force_gain="0.5"), "specific_force_gain.*'0.5'"),
        (
            lambda d: d["scaling"].update(specific_force_gain=["0.5", "0.5", "0.5"]),
            "specific_force_gain.*'0.5'",
        ),
        (lambda d: d["translational"].update(wn=True), "translational.wn.*True"),
        (lambda d: d["rotational"].update(zeta=[1.0, True, 1.0]), "rotational.zeta.*True"),
        (lambda d: d["tilt"].update(angle_limit_deg=False), "tilt.angle_limit_deg.*False"),
        (lambda d: d.update(g="9.8"), "'g'.*expected a number"),
    ],
)
def test_bad_values_give_a_clear_config_error(edit, match):
    d = copy.deepcopy(_base())
    edit(d)
    with pytest.raises(ConfigError, match=match):
        WashoutParams.from_dict(d, source="my.toml")


def test_error_messages_name_the_source_and_files_errors_are_config_errors(tmp_path):
    d = _base()
    d["tilt"]["rate_limit_deg_s"] = -1.0
    with pytest.raises(ConfigError, match=r"^my\.toml: field 'tilt\.rate_limit_deg_s'"):
        WashoutParams.from_dict(d, source="my.toml")
    with pytest.raises(ConfigError, match="unknown washout preset 'nope'"):
        WashoutParams.preset("nope")
    with pytest.raises(ConfigError, match="file not found"):
        WashoutParams.from_toml(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[tilt\nwn = 2")
    with pytest.raises(ConfigError, match="not valid TOML"):
        WashoutParams.from_toml(bad)


def test_tilt_accel_limit_is_optional_in_files_written_before_it():
    """Older files (and MCAP metadata) have no tilt.accel_limit_deg_s2: the default applies."""
    from motionbase.washout.params import DEFAULT_TILT_ACCEL_LIMIT_DEG_S2

    d = copy.deepcopy(_base())
    del d["tilt"]["accel_limit_deg_s2"]
    p = WashoutParams.from_dict(d, source="old.toml")
    assert p.tilt_accel_limit_deg_s2 == (DEFAULT_TILT_ACCEL_LIMIT_DEG_S2,) * 2
    assert p.tilt_accel_limit == pytest.approx([math.radians(DEFAULT_TILT_ACCEL_LIMIT_DEG_S2)] * 2)
    assert WashoutParams.from_dict(p.to_dict()) == p  # written back with the key


def test_tilt_limits_take_one_number_or_a_roll_pitch_pair():
    """Each tilt limit is one number for both tilt axes or ``[roll, pitch]``; written back
    as one number when both are equal, as the pair otherwise; a pair that is not two valid
    numbers is refused naming the field."""
    d = copy.deepcopy(_base())
    d["tilt"].update(
        rate_limit_deg_s=[2.0, 3.5], angle_limit_deg=[0.0, 9.0], accel_limit_deg_s2=6.0
    )
    p = WashoutParams.from_dict(d, source="my.toml")
    assert p.tilt_rate_limit_deg_s == (2.0, 3.5)
    assert p.tilt_angle_limit_deg == (0.0, 9.0)  # no roll tilt: sway is not tilt-coordinated
    assert p.tilt_accel_limit_deg_s2 == (6.0, 6.0)
    assert p.tilt_rate_limit == pytest.approx(np.radians([2.0, 3.5]))
    out = p.to_dict()["tilt"]
    assert out["rate_limit_deg_s"] == [2.0, 3.5] and out["accel_limit_deg_s2"] == 6.0
    assert WashoutParams.from_dict(p.to_dict()) == p
    for key, value, match in (
        ("rate_limit_deg_s", [3.0, 3.0, 3.0], r"tilt.rate_limit_deg_s.*2 numbers.*\[roll, pitch\]"),
        ("rate_limit_deg_s", [3.0, 0.0], "tilt.rate_limit_deg_s.*> 0"),
        ("accel_limit_deg_s2", [-1.0, 8.0], "tilt.accel_limit_deg_s2"),
        ("angle_limit_deg", [8.0, 90.0], "tilt.angle_limit_deg.*< 90 deg"),
        ("angle_limit_deg", [8.0, "9"], "tilt.angle_limit_deg"),
    ):
        bad = copy.deepcopy(_base())
        bad["tilt"][key] = value
        with pytest.raises(ConfigError, match=rf"^my\.toml: .*{match}"):
            WashoutParams.from_dict(bad, source="my.toml")
    # a profile may override one axis's limits
    d = copy.deepcopy(_base())
    d["profile"] = {"ground": {"tilt": {"rate_limit_deg_s": [1.0, 3.0]}}}
    p = WashoutParams.from_dict(d, source="my.toml")
    assert p.for_profile("ground").tilt_rate_limit_deg_s == (1.0, 3.0)
    assert WashoutParams.from_dict(p.to_dict()) == p


def test_input_table_is_optional_and_checked():
    """Files (and MCAP metadata) written before the input low-pass existed have no [input]:
    no low-pass. A negative frequency is an error, one above Nyquist too (at the filter)."""
    d = copy.deepcopy(_base())
    d.pop("input", None)
    p = WashoutParams.from_dict(d, source="old.toml")
    assert p.input_lowpass_wn == 0.0
    assert WashoutParams.from_dict(p.to_dict()) == p
    d["input"] = {"lowpass_wn": -1.0}
    with pytest.raises(ConfigError, match=r"^my\.toml: field 'input\.lowpass_wn'"):
        WashoutParams.from_dict(d, source="my.toml")
    d["input"] = {"lowpass_hz": 1.0}
    with pytest.raises(ConfigError, match="unknown field 'lowpass_hz'"):
        WashoutParams.from_dict(d, source="my.toml")
    d["input"] = {"lowpass_wn": 500.0}
    fast = WashoutParams.from_dict(d, source="my.toml")
    with pytest.raises(ConfigError, match=r"Nyquist.*\(washout field input\.lowpass_wn\)$"):
        ClassicalWashout(fast, DT)
    # each filter frequency is named by its field when it is too high for the rate
    for section, axis, label in [
        ("translational", 1, "translational.wn, y"),
        ("rotational", 2, "rotational.wn, yaw"),
        ("tilt", None, "tilt.wn"),
    ]:
        e = WashoutParams.preset("default").to_dict()
        if axis is None:
            e[section]["wn"] = 1e300
        else:
            e[section]["wn"][axis] = 1e300
        with pytest.raises(ConfigError, match=rf"Nyquist.*\(washout field {re.escape(label)}\)$"):
            ClassicalWashout(WashoutParams.from_dict(e), DT)


def test_direct_construction_is_validated_too():
    p = WashoutParams.preset("default")
    import dataclasses

    with pytest.raises(ConfigError, match="zeta"):
        dataclasses.replace(p, tilt_zeta=0.0)
    q = dataclasses.replace(p, translational_wn=np.array([2, 2, 2]))
    assert q.translational_wn == (2.0, 2.0, 2.0)
    assert isinstance(q.translational_wn[0], float)


_pos = st.floats(1e-3, 50.0, allow_nan=False, allow_infinity=False)
_gain = st.floats(0.0, 2.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=100, deadline=None)
@given(
    st.lists(_gain, min_size=6, max_size=6),
    st.lists(_pos, min_size=22, max_size=22),
    st.floats(0.0, 89.9),
    st.sampled_from(["tustin", "zoh"]),
    st.text(max_size=20),
)
def test_any_valid_parameter_set_round_trips_exactly(gains, pos, angle, method, text):
    p = WashoutParams(
        specific_force_gain=tuple(gains[:3]),
        specific_force_limit=tuple(pos[0:3]),
        angular_velocity_gain=tuple(gains[3:]),
        angular_velocity_limit_deg_s=tuple(pos[3:6]),
        translational_wn=tuple(pos[6:9]),
        translational_zeta=tuple(pos[9:12]),
        translational_wb=tuple(pos[12:15]),
        tilt_wn=pos[15],
        tilt_zeta=pos[16],
        tilt_rate_limit_deg_s=(pos[17], pos[21]),
        tilt_angle_limit_deg=angle,
        rotational_wn=tuple(pos[18:21]),
        rotational_zeta=tuple(pos[9:12]),
        tilt_accel_limit_deg_s2=pos[20],
        g=9.81,
        method=method,
        description=text,
    )
    assert WashoutParams.from_dict(p.to_dict()) == p
    assert WashoutParams.from_dict(json.loads(json.dumps(p.to_dict()))) == p


def test_a_geometry_file_given_as_washout_is_named_for_what_it_is():
    from motionbase.config import preset_path, read_toml

    for kind, name in (("rus6", "ceart"), ("rrr3", "udesc")):
        with pytest.raises(ConfigError, match=r"^g.toml: this is a .* geometry file"):
            WashoutParams.from_dict(read_toml(preset_path(kind, name)), source="g.toml")


def test_a_stray_file_named_like_a_preset_is_not_loaded_in_its_place(tmp_path, monkeypatch):
    """``--params default`` beside a file called ``default`` (a log, a note) must not read
    that file as the preset; ``./default`` names the file, and a bare name that is only a
    file is still read as one."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "default").write_text("not a washout file\n")
    with pytest.raises(
        ConfigError, match=r"'default' is both a shipped preset and a file .*\./default"
    ):
        WashoutParams.load("default")
    (tmp_path / "ceart").write_text("x = 1\n")
    with pytest.raises(ConfigError, match=r"'ceart' is both"):  # any kind's preset counts
        load_geometry("ceart")
    with pytest.raises(ConfigError, match="^default: "):  # the file, when asked for
        WashoutParams.load("./default")
    WashoutParams.preset("gentle").to_toml(tmp_path / "mine")
    assert WashoutParams.load("mine") == WashoutParams.preset("gentle")
