"""6-UPS Stewart platform: inverse, forward, clamp, park, workspace, geometry TOML.

Expectations come from outside the code under test: the layout as the preset's comments and
the geometry docstring describe it (joint angles written out here in degrees), leg lengths
|B_i - (p + R q_i)| with this file's own rotation matrices, closed forms of pure heave, and
the mirror symmetry of the layout.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from motionbase.errors import ConfigError
from motionbase.platform import Stewart6, Stewart6Geometry, single_axis_envelope
from motionbase.platform.rus6_workspace import AXES

GEOMETRY = Stewart6Geometry.preset("seat")
HEX = Stewart6(GEOMETRY)
SETTINGS = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.filter_too_much]
)

# The preset, read from its comments: base joints on a 0.50 m circle in pairs centred at 0,
# 120, 240 deg, 12 deg either side; platform joints on a 0.35 m circle in pairs centred at 60,
# 180, 300 deg, 12 deg either side; leg i joins the base joint and the platform joint beside it.
BASE_DEG = [-12.0, 12.0, 108.0, 132.0, 228.0, 252.0]
PLATFORM_DEG = [-48.0, 48.0, 72.0, 168.0, 192.0, 288.0]
R_BASE, R_PLATFORM, L_NEUTRAL, L_MIN, L_MAX = 0.50, 0.35, 0.75, 0.60, 0.90


def _ring(radius: float, degrees: list[float], z: float) -> np.ndarray:
    a = np.radians(degrees)
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.full(a.size, z)], axis=-1)


def _rot(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rz(yaw) Ry(pitch) Rx(roll), written out from the elementary rotations."""
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


BASE = _ring(R_BASE, BASE_DEG, 0.0)
# every leg spans the same horizontal distance d; at neutral it is L_NEUTRAL long
D_HORIZONTAL = float(np.hypot(*(_ring(R_PLATFORM, PLATFORM_DEG, 0.0) - BASE)[0, :2]))
HEIGHT = math.sqrt(L_NEUTRAL**2 - D_HORIZONTAL**2)
LOCAL = _ring(R_PLATFORM, PLATFORM_DEG, 0.0)  # platform frame: origin at the joints' centroid
ORIGIN = np.array([0.0, 0.0, -HEIGHT])  # FRD: the platform is above the base, z negative


def _lengths(pose: np.ndarray) -> np.ndarray:
    """Independent leg lengths |B_i - (O + p + R q_i)|."""
    joints = ORIGIN + pose[:3] + LOCAL @ _rot(*pose[3:]).T
    return np.linalg.norm(BASE - joints, axis=1)


def _within(pose: np.ndarray, lo=L_MIN, hi=L_MAX) -> bool:
    ln = _lengths(pose)
    return bool(np.all((ln >= lo) & (ln <= hi)))


pose_in_box = st.tuples(
    st.floats(-0.25, 0.25),
    st.floats(-0.25, 0.25),
    st.floats(-0.2, 0.15),
    st.floats(-0.4, 0.4),
    st.floats(-0.4, 0.4),
    st.floats(-0.7, 0.7),
).map(np.array)

any_float = st.one_of(
    st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False),
    st.floats(-0.5, 0.5),
    st.sampled_from([np.nan, np.inf, -np.inf, 1e3, -1e3, 1e300, 0.0, math.pi, -math.pi]),
)


# --------------------------------------------------------------------------- geometry / preset
def test_preset_matches_its_documented_layout():
    jp = HEX.joint_points(np.zeros(6))
    np.testing.assert_allclose(jp.base_joints, BASE, atol=1e-15)
    np.testing.assert_allclose(jp.platform_joints, ORIGIN + LOCAL, atol=1e-15)
    assert GEOMETRY.neutral_height == pytest.approx(HEIGHT, abs=1e-15)
    np.testing.assert_allclose(HEX.neutral, L_NEUTRAL, atol=1e-15)  # mid-stroke
    lim = HEX.limits
    np.testing.assert_array_equal(lim.lower, L_MIN)
    np.testing.assert_array_equal(lim.upper, L_MAX)
    np.testing.assert_array_equal(lim.max_speed, 0.3)
    np.testing.assert_array_equal(lim.max_accel, 3.0)
    with pytest.raises(ValueError):
        lim.upper[0] = 2.0  # read-only: nobody widens a limit by accident
    # mirror-symmetric left to right: the joint sets are their own mirror images
    for pts in (jp.base_joints, jp.platform_joints):
        mirrored = pts * np.array([1.0, -1.0, 1.0])
        dist = np.linalg.norm(pts[:, None, :] - mirrored[None, :, :], axis=-1)
        assert np.all(dist.min(axis=1) < 1e-12)


def test_neutral_height_and_neutral_length_agree():
    data = GEOMETRY.to_dict()
    data["neutral_height"] = 0.65
    g = Stewart6Geometry.from_dict(data)
    want = math.hypot(D_HORIZONTAL, 0.65)
    np.testing.assert_allclose(Stewart6(g).inverse(np.zeros(6)), want, atol=1e-14)
    del data["neutral_height"]
    data["neutral_length"] = want
    assert Stewart6Geometry.from_dict(data).neutral_height == pytest.approx(0.65, abs=1e-14)


def test_pure_heave_up_lengthens_every_actuator_equally():
    zs = np.linspace(0.0, -0.15, 16)  # FRD: negative z is up
    poses = np.zeros((zs.size, 6))
    poses[:, 2] = zs
    lengths = HEX.inverse(poses)
    want = np.broadcast_to(np.hypot(D_HORIZONTAL, HEIGHT - zs)[:, None], lengths.shape)
    np.testing.assert_allclose(lengths, want, rtol=0, atol=1e-14)
    assert (np.diff(lengths, axis=0) > 0).all()


def test_park_is_retracted_plus_margin_and_straight_down():
    park = HEX.park
    np.testing.assert_array_equal(park.lengths, L_MIN + 0.01)
    # pure heave down to the height where every leg is 0.61 m long
    z = HEIGHT - math.sqrt((L_MIN + 0.01) ** 2 - D_HORIZONTAL**2)
    np.testing.assert_allclose(park.pose, [0, 0, z, 0, 0, 0], atol=1e-10)
    assert park.pose[2] > 0
    np.testing.assert_allclose(_lengths(park.pose), park.lengths, atol=1e-10)
    assert HEX.reachable(park.pose)


# --------------------------------------------------------------------------- inverse / forward
@SETTINGS
@given(pose_in_box)
def test_inverse_matches_independent_leg_lengths(pose):
    np.testing.assert_allclose(HEX.inverse(pose), _lengths(pose), rtol=0, atol=1e-14)


@SETTINGS
@given(pose_in_box)
def test_reachable_is_every_length_within_its_stroke(pose):
    # in this box the platform stays above the base and upright: lengths alone decide
    assert HEX.reachable(pose) == _within(pose)


@SETTINGS
@given(pose_in_box)
def test_forward_inverse_round_trip(pose):
    assume(HEX.reachable(pose))
    np.testing.assert_allclose(HEX.forward(HEX.inverse(pose)), pose, rtol=0, atol=1e-9)


def test_forward_inverse_round_trip_batch_over_workspace():
    rng = np.random.default_rng(1)
    lim = np.array([0.3, 0.3, 0.2, 0.5, 0.5, 0.85])
    poses = rng.uniform(-lim, lim, (20000, 6))
    poses = poses[HEX.reachable(poses)]
    assert len(poses) > 500
    np.testing.assert_allclose(HEX.forward(HEX.inverse(poses)), poses, rtol=0, atol=1e-9)
    # the clamp's boundary poses too
    edge, _ = HEX.clamp(rng.uniform(-2 * lim, 2 * lim, (300, 6)))
    np.testing.assert_allclose(HEX.forward(HEX.inverse(edge)), edge, rtol=0, atol=1e-9)


def test_forward_with_guess_and_nonconvergence():
    pose = np.array([0.1, -0.05, -0.08, 0.1, -0.1, 0.4])
    lengths = HEX.inverse(pose)
    np.testing.assert_allclose(HEX.forward(lengths, guess=pose + 0.01), pose, atol=1e-9)
    # one Newton step from neutral cannot get there: reported as NaN, not a wrong pose
    assert np.isnan(HEX.forward(lengths, max_iter=1)).all()
    assert np.isnan(HEX.forward(np.full(6, np.nan))).all()
    assert np.isnan(HEX.forward(np.r_[lengths[:5], -0.7])).all()
    # lengths no pose can hold: NaN, not garbage
    assert np.isnan(HEX.forward([0.6, 0.6, 0.6, 0.6, 0.6, 5.0])).all()


def test_non_finite_poses_give_nan_without_warnings():
    poses = np.array(
        [
            [0.0, 0.0, -0.1, 0.0, 0.0, 0.0],
            [np.nan, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, np.inf, 0.0, 0.0],
            [3.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lengths = HEX.inverse(poses)
        reach = HEX.reachable(poses)
    assert np.isfinite(lengths[[0, 3]]).all() and np.isnan(lengths[1:3]).all()
    assert reach.tolist() == [True, False, False, False]


def test_mirror_solutions_are_not_reachable():
    # the platform mirrored below the base has the neutral lengths, and so has it upside down
    below = np.array([0.0, 0.0, 2 * HEIGHT, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(_lengths(below), L_NEUTRAL, atol=1e-14)
    # rolled 97 deg, the platform's top facing sideways-down: the lengths are within the stroke
    flipped = np.array([-0.15, -0.2, 0.13, 1.7, -0.29, -0.53])
    assert _within(flipped) and _rot(*flipped[3:])[2, 2] < 0
    for pose in (below, flipped):
        assert not HEX.reachable(pose)
        out, clamped = HEX.clamp(pose)
        assert clamped and HEX.reachable(out)


def _line_conditioning(pose: np.ndarray) -> float:
    """Independently: 1 / cond of the legs' unit lines ``[u_i, (R q_i x u_i) / L_NEUTRAL]``
    (the README's measure: moments over the mean leg length at neutral)."""
    centre = ORIGIN + pose[:3]
    joints = centre + LOCAL @ _rot(*pose[3:]).T
    u = joints - BASE
    u /= np.linalg.norm(u, axis=1)[:, None]
    s = np.linalg.svd(np.hstack([u, np.cross(joints - centre, u) / L_NEUTRAL]), compute_uv=False)
    return float(s[-1] / s[0])


def test_a_singular_pose_within_the_stroke_is_not_reachable():
    """Heave 0.21 m down and yaw 90 deg: every actuator inside its stroke (0.629 and
    0.898 m), but at the quarter turn the legs' lines cannot hold the platform (a hexapod's
    classic singularity; forward kinematics there does not converge). It was reachable, and
    the clamp returned it as it was: the platform commanded into a singularity. A pose is
    reachable now only where the legs hold it as firmly as a geometry must at neutral
    (line conditioning at least 0.01)."""
    pose = np.array([0.0, 0.0, 0.21, 0.0, 0.0, math.pi / 2])
    assert _within(pose)
    assert _line_conditioning(pose) < 1e-9
    assert not HEX.reachable(pose)
    out, clamped = HEX.clamp(pose)
    assert clamped and HEX.reachable(out) and _within(out, L_MIN - 1e-12, L_MAX + 1e-12)
    assert _line_conditioning(out) >= 0.01
    # the pose scaled toward neutral: still pure heave and yaw, short of the quarter turn
    assert out[[0, 1, 3, 4]].tolist() == [0.0] * 4 and 0.0 < out[5] < math.pi / 2
    assert out[2] / out[5] == pytest.approx(pose[2] / pose[5], rel=1e-12)


def test_batch_shapes_match_single_calls():
    rng = np.random.default_rng(2)
    poses = rng.uniform(-0.1, 0.1, (2, 3, 6))
    assert HEX.inverse(poses).shape == (2, 3, 6)
    assert HEX.reachable(poses).shape == (2, 3)
    assert HEX.clamp(poses)[0].shape == (2, 3, 6)
    assert HEX.forward(HEX.inverse(poses)).shape == (2, 3, 6)
    jp = HEX.joint_points(poses)
    assert jp.base_joints.shape == jp.platform_joints.shape == (2, 3, 6, 3)
    for i in range(2):
        for j in range(3):
            np.testing.assert_array_equal(HEX.inverse(poses[i, j]), HEX.inverse(poses)[i, j])
            assert HEX.reachable(poses[i, j]) == HEX.reachable(poses)[i, j]
    with pytest.raises(ConfigError, match="shape"):
        HEX.inverse(np.zeros(5))


@SETTINGS
@given(pose_in_box)
def test_joint_points_are_the_rigid_body_and_the_leg_lengths(pose):
    jp = HEX.joint_points(pose)
    np.testing.assert_allclose(jp.base_joints, BASE, atol=1e-15)
    np.testing.assert_allclose(
        jp.platform_joints, ORIGIN + pose[:3] + LOCAL @ _rot(*pose[3:]).T, atol=1e-14
    )
    legs = np.linalg.norm(jp.platform_joints - jp.base_joints, axis=1)
    np.testing.assert_allclose(legs, HEX.inverse(pose), atol=1e-14)
    assert jp.platform_joints.mean(axis=0) == pytest.approx(ORIGIN + pose[:3], abs=1e-14)


# --------------------------------------------------------------------------- clamp
@settings(max_examples=300, deadline=None)
@given(st.tuples(*[any_float] * 6).map(np.array))
def test_clamp_always_reachable_finite_and_a_multiple_of_the_input(pose):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out, clamped = HEX.clamp(pose)
    assert out.shape == (6,) and np.isfinite(out).all()
    assert HEX.reachable(out)
    ln = HEX.inverse(out)
    assert (ln >= L_MIN).all() and (ln <= L_MAX).all()
    if HEX.reachable(pose):
        assert not clamped and np.array_equal(out, pose)
        return
    assert clamped
    if not np.isfinite(pose).all():
        assert np.array_equal(out, np.zeros(6))
        return
    # the whole pose scaled toward neutral (angles first expressed in [-pi, pi))
    w = pose.copy()
    w[3:] = (w[3:] + math.pi) % (2 * math.pi) - math.pi
    big = np.abs(w).max()
    s = float((out / big) @ (w / big) / ((w / big) @ (w / big)))
    assert 0.0 <= s <= 1.0
    np.testing.assert_allclose(out, s * w, rtol=0, atol=1e-15 * max(1.0, big))


@SETTINGS
@given(pose_in_box, st.floats(1.05, 50.0))
def test_clamp_stops_where_the_line_from_neutral_first_leaves_the_stroke(pose, factor):
    big = pose * factor
    assume(np.all(np.abs(big[3:]) < math.pi) and not _within(big))
    out, clamped = HEX.clamp(big)
    assert clamped
    s = float(out @ big / (big @ big))
    # independently: every pose on the way from neutral to the result is within the stroke
    # (sampled), and the result is on the boundary: some actuator at a length limit
    assert all(_within(t * big, L_MIN - 1e-12, L_MAX + 1e-12) for t in np.linspace(0, s, 200))
    ln = _lengths(out)
    assert min(np.min(np.abs(ln - L_MIN)), np.min(np.abs(ln - L_MAX))) < 1e-9
    assert not HEX.reachable(big * min(1.0, s * (1 + 1e-9)))


def test_clamp_of_far_out_and_unwrapped_inputs():
    # 1 km forward: along the surge axis to the edge of the workspace
    out, clamped = HEX.clamp([1000.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert clamped and 0.25 < out[0] < 0.35 and np.all(out[1:] == 0)
    # an unwrapped but reachable rotation is the same pose: returned as is
    same = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.2 + 4 * math.pi])
    out, clamped = HEX.clamp(same)
    assert not clamped and np.array_equal(out, same)
    # 1e300 in every coordinate still ends on the boundary, not at neutral
    out, clamped = HEX.clamp(np.full(6, 1e300))
    assert clamped and HEX.reachable(out) and np.abs(out[:3]).max() > 0


def test_clamp_batch_and_clamp_inverse_equal_single_calls():
    rng = np.random.default_rng(3)
    poses = rng.uniform(-1, 1, (50, 6))
    out, flags = HEX.clamp(poses)
    for k in range(50):
        single, flag = HEX.clamp(poses[k])
        np.testing.assert_array_equal(out[k], single)
        assert flags[k] == flag
        pose, clamped, lengths = HEX.clamp_inverse(poses[k])
        np.testing.assert_array_equal(pose, single)
        assert clamped == flag
        np.testing.assert_array_equal(lengths, HEX.inverse(single))


def test_per_leg_limits_are_honoured():
    data = GEOMETRY.to_dict()
    data["length_max"] = [0.9, 0.9, 0.9, 0.9, 0.9, 0.8]
    hexapod = Stewart6(Stewart6Geometry.from_dict(data))
    rng = np.random.default_rng(4)
    out, _ = hexapod.clamp(rng.uniform(-0.5, 0.5, (500, 6)))
    ln = hexapod.inverse(out)
    assert (ln[:, 5] <= 0.8).all() and (ln[:, :5] <= 0.9).all() and (ln >= 0.6).all()
    assert np.isclose(ln[:, 5], 0.8, atol=1e-9).any()  # leg 6's own limit binds


# --------------------------------------------------------------------------- workspace
ENVELOPE = {a.axis: a for a in single_axis_envelope(HEX)}


@pytest.mark.parametrize("axis", ["sway", "roll", "yaw"])
def test_reach_is_symmetric_where_the_layout_is(axis):
    # mirror-symmetric about the x-z plane: sway, roll and yaw reach as far either way
    a = ENVELOPE[axis]
    assert a.negative > 0.05
    assert a.negative == pytest.approx(a.positive, abs=1e-8)


def test_heave_reach_is_where_the_stroke_ends():
    # pure heave keeps every leg the same length: closed forms
    up = math.sqrt(L_MAX**2 - D_HORIZONTAL**2) - HEIGHT
    down = HEIGHT - math.sqrt(L_MIN**2 - D_HORIZONTAL**2)
    assert ENVELOPE["heave"].negative == pytest.approx(up, abs=1e-8)
    assert ENVELOPE["heave"].positive == pytest.approx(down, abs=1e-8)


def test_the_readme_gives_the_preset_s_reach():
    """The README's single-axis reach of ``seat``, each figure to its printed digits. It said
    "surge and sway about +-0.3 m"; sway reaches 0.282 m (leg pairs at 0, 120, 240 deg)."""
    import re
    from pathlib import Path

    text = " ".join((Path(__file__).parents[1] / "README.md").read_text().split())
    found = re.search(
        r"reaches surge ([\d.]+) m back and forward, sway \+-([\d.]+) m, heave ([\d.]+) m up "
        r"and ([\d.]+) m down, roll \+-([\d.]+) deg, pitch ([\d.]+) deg nose up and ([\d.]+) "
        r"down, yaw \+-([\d.]+) deg from the stroke alone",
        text,
    )
    assert found, "the README's sentence on the seat preset's reach"
    e = ENVELOPE
    deg = math.degrees
    expected = [
        (e["surge"].negative, e["surge"].positive),
        (e["sway"].negative, e["sway"].positive),
        (e["heave"].negative,),
        (e["heave"].positive,),
        (deg(e["roll"].negative), deg(e["roll"].positive)),
        (deg(e["pitch"].positive),),
        (deg(e["pitch"].negative),),
        (deg(e["yaw"].negative), deg(e["yaw"].positive)),
    ]
    for printed, values in zip(found.groups(), expected, strict=True):
        half_digit = 0.5 * 10.0 ** -len(printed.split(".")[1])
        for v in values:
            assert abs(v - float(printed)) <= half_digit + 1e-12, (printed, v)


@pytest.mark.parametrize("j", range(6))
def test_every_single_axis_edge_is_an_actuator_limit(j):
    a = ENVELOPE[AXES[j]]
    for sign, value in ((-1, a.negative), (1, a.positive)):
        inside = np.zeros(6)
        inside[j] = sign * value
        assert _within(inside)
        outside = inside.copy()
        outside[j] = sign * (value + 1e-6)
        assert not _within(outside)


# --------------------------------------------------------------------------- TOML and validation
def test_dict_and_toml_round_trip(tmp_path):
    assert Stewart6Geometry.from_dict(GEOMETRY.to_dict()) == GEOMETRY
    path = tmp_path / "g.toml"
    GEOMETRY.to_toml(path)
    assert Stewart6Geometry.from_toml(path) == GEOMETRY
    assert Stewart6Geometry.preset(str(path)) == GEOMETRY


def test_output_table_maps_the_stroke_to_the_range(tmp_path):
    text = (
        _preset_text()
        + '\n[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 4095\n'
        + "sign = [1, 1, 1, 1, 1, -1]\n"
    )
    path = tmp_path / "out.toml"
    path.write_text(text)
    g = Stewart6Geometry.from_toml(path)
    drive = g.output.to_drive(np.array([[L_MIN] * 6, [L_MAX] * 6, [0.75] * 6]))
    np.testing.assert_array_equal(drive[0], [0, 0, 0, 0, 0, 4095])  # retracted
    np.testing.assert_array_equal(drive[1], [4095, 4095, 4095, 4095, 4095, 0])  # extended
    np.testing.assert_array_equal(drive[2], [2048, 2048, 2048, 2048, 2048, 2048])  # 2047.5
    assert Stewart6Geometry.from_dict(g.to_dict()) == g
    g.to_toml(tmp_path / "again.toml")
    assert Stewart6Geometry.from_toml(tmp_path / "again.toml") == g


@pytest.mark.parametrize(
    "extra", ["drive_max = 400", "drive_min = -5", "drive_max = [300, 300, 300, 300, 300, 301]"]
)
def test_output_drive_range_past_the_integer_range_is_refused(tmp_path, extra):
    """README: "no value past range_lo..range_hi is ever sent". With the span 0.65..0.85 m on
    0..300 and drive_max = 400, the fully extended actuator (0.90 m) mapped to
    (0.90 - 0.65) / 0.20 * 300 = 375, and the drive range let it through."""
    path = tmp_path / "out.toml"
    path.write_text(
        _preset_text()
        + '\n[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 300\n'
        + f"span_min = 0.65\nspan_max = 0.85\n{extra}\n"
    )
    with pytest.raises(ConfigError) as err:
        Stewart6Geometry.from_toml(path)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path}: [output]: fields 'drive_min'/'drive_max'")
    assert "range_lo..range_hi 0..300" in msg


def _preset_text() -> str:
    from importlib import resources

    return (resources.files("motionbase") / "presets" / "stewart6_seat.toml").read_text()


def _edit(text: str, field: str, value: str | None) -> str:
    """The preset's text with one top-level field replaced (or removed when value is None)."""
    lines = []
    for line in text.splitlines():
        if line.split("=")[0].strip() == field:
            if value is None:
                continue
            line = f"{field} = {value}"
        lines.append(line)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("max_speed", "true", r"'max_speed'.*expected a number.*True"),
        ("max_accel", "false", r"'max_accel'.*expected a number"),
        ("length_min", '"0.6"', r"'length_min'.*expected a number.*'0.6'"),
        ("base_radius", '"0.5"', r"'base_radius'.*expected a number"),
        ("base_radius", "true", r"'base_radius'.*expected a number"),
        ("max_accel", '[3, 3, 3, 3, 3, "3"]', r"'max_accel'.*leg 6.*expected a number"),
        ("max_speed", "[0.3, 0.3, true, 0.3, 0.3, 0.3]", r"'max_speed'.*leg 3.*expected a num"),
        ("length_max", "[0.9, 0.9]", r"'length_max'.*list of 2"),
        ("max_speed", None, r"missing field 'max_speed'.*never defaulted"),
        ("max_accel", None, r"missing field 'max_accel'"),
        ("length_min", None, r"missing field 'length_min'"),
        ("length_max", None, r"missing field 'length_max'"),
        ("length_min", "0.95", r"'length_min'/'length_max'.*min < max"),
        ("max_speed", "inf", r"'max_speed'.*finite"),
        ("length_max", "nan", r"'length_max'.*finite"),
        ("max_accel", "-3.0", r"'max_accel'.*> 0"),
        ("max_speed", "0", r"'max_speed'.*> 0"),
        ("neutral_length", "0.95", r"'neutral_height'.*not inside its stroke"),
        ("neutral_length", "0.2", r"'neutral_length'.*cannot span"),
        ("base_half_angle_deg", "60.0", r"'base_half_angle_deg'.*between 0 and 60"),
        ("platform_half_angle_deg", "0", r"'platform_half_angle_deg'.*between 0 and 60"),
        ("park_margin", "0.2", r"'park_margin'"),
        ("park_margin", "0", r"'park_margin'.*> 0"),
        ("kind", '"rus6"', r"'kind'.*'rus6' file"),
        ("name", "3", r"'name'.*string"),
        ("platform_radius", "-0.35", r"'platform_radius'.*> 0"),
    ],
)
def test_toml_errors_are_one_line_naming_file_and_field(tmp_path, field, value, match):
    path = tmp_path / "bad.toml"
    path.write_text(_edit(_preset_text(), field, value))
    with pytest.raises(ConfigError, match=match) as info:
        Stewart6Geometry.from_toml(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(str(path))


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("lenght_max = 0.9", r"unknown field 'lenght_max'"),
        ("neutral_height = 0.6", r"either 'neutral_height' or 'neutral_length'"),
        ("base_half_angle = 0.2", r"either 'base_half_angle' or 'base_half_angle_deg'"),
        ('[output]\nunit = "deg"', r"'unit'.*'range'"),
        (
            '[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 4095\ngear_ratio = 2',
            r"'gear_ratio'.*only unit 'range'",
        ),
        ('[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 4095.0', r"'range_hi'.*integer"),
        ('[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 9\nsign = true', r"'sign'"),
        (
            '[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 9\nspan_min = 0.95',
            r"'span_min'/'span_max'",
        ),
    ],
)
def test_more_toml_errors(tmp_path, extra, match):
    path = tmp_path / "bad.toml"
    path.write_text(_preset_text() + "\n" + extra + "\n")
    with pytest.raises(ConfigError, match=match) as info:
        Stewart6Geometry.from_toml(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_other_files_and_presets(tmp_path):
    from importlib import resources

    rus6 = resources.files("motionbase") / "presets" / "rus6_ceart.toml"
    with pytest.raises(ConfigError, match=r"rus6_ceart.toml.*'kind'.*'rus6' file"):
        Stewart6Geometry.from_toml(str(rus6))
    with pytest.raises(ConfigError, match="unknown stewart6 preset"):
        Stewart6Geometry.preset("nope")
    with pytest.raises(ConfigError, match="not found"):
        Stewart6Geometry.from_toml(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="Stewart6Geometry"):
        Stewart6("seat")  # type: ignore[arg-type]


def test_constructor_is_as_strict_as_the_file():
    kw = {
        f: getattr(GEOMETRY, f)
        for f in ("base_radius", "base_half_angle", "platform_radius", "platform_half_angle")
    }
    kw.update(neutral_height=GEOMETRY.neutral_height, length_min=0.6, length_max=0.9)
    assert Stewart6Geometry(**kw, max_speed=0.3, max_accel=3.0).length_min == (0.6,) * 6
    with pytest.raises(ConfigError, match=r"'max_speed'.*expected a number"):
        Stewart6Geometry(**kw, max_speed=True, max_accel=3.0)
    with pytest.raises(ConfigError, match=r"'max_accel'.*leg 1.*expected a number"):
        Stewart6Geometry(**kw, max_speed=0.3, max_accel=np.array([True] * 6))
    with pytest.raises(TypeError):
        Stewart6Geometry(**kw)  # the limits have no defaults


def test_actuator_jacobian_is_the_legs_velocity_relation() -> None:
    """``Robot.actuator_jacobian`` (central differences through the inverse kinematics)
    against the legs' velocity relation written out here: a leg lengthens at
    ``u_i . (p_dot + omega x R q_i)`` (``u_i`` its unit vector from the base joint), with
    ``omega = E(roll, pitch, yaw) [roll, pitch, yaw]_dot`` for ``R = Rz Ry Rx``."""
    from motionbase.platform.robot import robot_spec

    robot = robot_spec("stewart6").make(GEOMETRY)
    rng = np.random.default_rng(11)
    poses = rng.uniform(-1, 1, (40, 6)) * [0.06, 0.06, 0.05, 0.12, 0.12, 0.25]
    poses = np.array([p for p in poses if _within(p, L_MIN + 0.01, L_MAX - 0.01)])
    assert len(poses) >= 20
    q, J = robot.actuator_jacobian(poses)
    assert q.shape == (len(poses), 6) and J.shape == (len(poses), 6, 6)
    for pose, q_i, J_i in zip(poses, q, J, strict=True):
        roll, pitch, yaw = pose[3:]
        arm = LOCAL @ _rot(roll, pitch, yaw).T  # R q_i
        leg = ORIGIN + pose[:3] + arm - BASE
        u = leg / np.linalg.norm(leg, axis=1, keepdims=True)
        cp, sp, cy, sy = math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
        E = np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])
        # u . (omega x r) = omega . (r x u)
        expected = np.hstack([u, np.cross(arm, u) @ E])
        np.testing.assert_allclose(q_i, _lengths(pose), atol=1e-12)
        np.testing.assert_allclose(J_i, expected, rtol=1e-6, atol=1e-7)
    one_q, one_J = robot.actuator_jacobian(poses[0])  # one pose: no batch axis
    np.testing.assert_array_equal(one_q, q[0])
    np.testing.assert_array_equal(one_J, J[0])


def test_platform_joints_at_one_point_are_refused():
    """A platform radius of 1e-6 m left the rotations unconstrained and loaded."""
    data = GEOMETRY.to_dict()
    data["platform_radius"] = 1e-6
    with pytest.raises(ConfigError, match=r"^g\.toml: field 'platform_radius': the actuators"):
        Stewart6Geometry.from_dict(data, source="g.toml")


def test_base_joints_at_one_point_are_refused_naming_the_base():
    """A base radius of 1e-6 m loaded and `workspace` said yaw 180 deg each way (the lines
    all pass through the base centre); refused now, naming base_radius, not platform_radius."""
    data = GEOMETRY.to_dict()
    data["base_radius"] = 1e-6
    with pytest.raises(ConfigError, match=r"^g\.toml: field 'base_radius': the actuators"):
        Stewart6Geometry.from_dict(data, source="g.toml")


def test_vertical_actuators_are_refused_as_parallel_not_as_joints_at_one_point():
    """Both circles 0.35 m and both half angles 30 deg: base joint k at -30 deg and its
    platform joint at -(60 - 30) = -30 deg on the same radius, straight above it. Every
    actuator vertical: nothing holds sideways motion or yaw. It was refused saying the
    platform joints (radius 0.35 m) were 'too close to one point'."""
    data = GEOMETRY.to_dict()
    data.update(base_radius=0.35, base_half_angle=math.radians(30.0))
    data["platform_half_angle"] = math.radians(30.0)
    data.pop("neutral_height")
    data["neutral_length"] = 0.75
    with pytest.raises(ConfigError) as err:
        Stewart6Geometry.from_dict(data, source="g.toml")
    msg = str(err.value)
    assert msg.startswith("g.toml: fields 'base_radius'/'platform_radius' and the half angles:")
    assert "nearly parallel" in msg and "0 m sideways" in msg and "one point" not in msg


def test_a_kind_field_the_other_fields_contradict_is_named(tmp_path, capsys):
    """``kind = "rus6"`` over the seat preset's fields was refused as "a 6-UPS Stewart platform
    geometry file ..., not a 6-RUS geometry", and ``kind = "stewart6"`` over ceart's fields
    as "unknown field 'angle_max_deg'": the field at fault, kind, went unnamed."""
    from importlib import resources

    from motionbase.cli import main

    ceart = (resources.files("motionbase") / "presets" / "rus6_ceart.toml").read_text()
    cases = (
        (_edit(_preset_text(), "kind", '"rus6"'), "'rus6'", "6-UPS Stewart", "'stewart6'"),
        (_edit(ceart, "kind", '"stewart6"'), "'stewart6'", "6-RUS", "'rus6'"),
    )
    for i, (text, said, fields, fix) in enumerate(cases):
        path = tmp_path / f"k{i}.toml"
        path.write_text(text)
        assert main(["workspace", "--platform", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err
        assert f"{path}: field 'kind': {said}, but the other fields are those of a {fields}" in err
        assert f"fix kind = {fix} or the fields" in err


def test_a_park_pose_near_a_singularity_is_refused_saying_so():
    """A small platform (0.117 m circle) on a wide base (1.44 m): the legs hold it at neutral
    but, retracted to length_min + 0.01 m, lean so far that they barely hold its rotations.
    That park pose exists (pure heave, every leg the same length) and the old message said
    "no reachable pose holds the actuators" there."""
    data = {
        "base_radius": 1.44,
        "base_half_angle_deg": 23.5,
        "platform_radius": 0.117,
        "platform_half_angle_deg": 51.26,
        "neutral_length": 1.8227,
        "length_min": 1.4096,
        "length_max": 2.5558,
        "max_speed": 0.3,
        "max_accel": 3.0,
    }
    geometry = Stewart6Geometry.from_dict(data, source="p.toml")  # the file's checks pass
    # independently: the layout of the geometry docstring, each leg from base angle
    # c - 23.5 deg to platform angle c - (60 - 51.26) deg, c = 0, 120, 240 deg (and mirrored)
    c = np.repeat([0.0, 120.0, 240.0], 2)
    side = np.tile([-1.0, 1.0], 3)
    base = _ring(1.44, list(c + side * 23.5), 0.0)
    plat = _ring(0.117, list(c + side * (60.0 - 51.26)), 0.0)
    d = float(np.hypot(*(plat - base)[0, :2]))
    park_height = math.sqrt((1.4096 + 0.01) ** 2 - d * d)

    def conditioning(height: float) -> float:
        joints = plat - [0.0, 0.0, height]
        u = joints - base
        u /= np.linalg.norm(u, axis=1)[:, None]
        m = np.cross(joints - joints.mean(axis=0), u) / geometry.line_scale
        s = np.linalg.svd(np.hstack([u, m]), compute_uv=False)
        return float(s[-1] / s[0])

    assert conditioning(math.sqrt(1.8227**2 - d * d)) >= 0.01 > conditioning(park_height)
    with pytest.raises(ConfigError) as err:
        Stewart6(geometry)
    msg = str(err.value)
    assert "field 'park_margin': the parked pose" in msg and "barely hold" in msg
    assert "no reachable pose" not in msg and "\n" not in msg
