"""6-RUS kinematics: closed-form inverse, forward Newton, joint points, Jacobian, clamp, geometry.

Expectations come from outside the code under test: DESIGN.md's table of the ceart platform,
rigid-body motion computed with scipy's Rotation, the leg lengths, finite differences.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from motionbase.errors import ConfigError
from motionbase.platform import JointPoints, Rus6, Rus6Geometry

GEOMETRY = Rus6Geometry.preset("ceart")
RUS6 = Rus6(GEOMETRY)
SETTINGS = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.filter_too_much]
)

# DESIGN.md "Geometry defaults": per leg, pivot angle on a 0.4064 m circle, joint angle on a
# 0.400 m circle, crank direction at angle 0 (degrees from +x toward +y). Mirror-symmetric
# about the x-z plane: one leg pair at the front, two at the rear corners.
DESIGN_PIVOT_DEG = [150, 90, 30, -30, -90, -150]
DESIGN_JOINT_DEG = [130, 110, 10, -10, -110, -130]
DESIGN_CRANK_DIR_DEG = [-120, 0, 120, -120, 0, 120]
CRANK, ROD = 0.184, 0.724


def _ring(radius: float, degrees: list[float]) -> np.ndarray:
    a = np.radians(degrees)
    return np.stack([radius * np.cos(a), radius * np.sin(a)], axis=-1)


pose_in_box = st.tuples(
    st.floats(-0.15, 0.15),
    st.floats(-0.15, 0.15),
    st.floats(-0.12, 0.07),
    st.floats(-0.2, 0.2),
    st.floats(-0.2, 0.2),
    st.floats(-0.5, 0.5),
).map(np.array)

finite_big = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
any_float = st.one_of(
    finite_big,
    st.floats(-0.4, 0.4),
    st.sampled_from([np.nan, np.inf, -np.inf, 1e3, -1e3, 1e300, 0.0]),
)


def _expected_angle(pivot, cdir, joint, r, rod):
    """Crank angle closing one leg, found by root finding on |joint - tip| = rod."""

    def gap(t):
        tip = pivot + r * (math.cos(t) * cdir + math.sin(t) * np.array([0.0, 0.0, -1.0]))
        return np.linalg.norm(joint - tip) - rod

    return brentq(gap, -math.pi / 2, math.pi / 2, xtol=1e-14)


# --------------------------------------------------------------------------- geometry / preset
def test_ceart_preset_matches_design_table():
    jp = RUS6.joint_points(np.zeros(6))
    np.testing.assert_allclose(jp.pivots[:, :2], _ring(0.4064, DESIGN_PIVOT_DEG), atol=1e-12)
    np.testing.assert_allclose(jp.pivots[:, 2], 0.0, atol=1e-15)
    np.testing.assert_allclose(
        jp.platform_joints[:, :2], _ring(0.400, DESIGN_JOINT_DEG), atol=1e-12
    )
    # neutral: cranks horizontal and pointing along DESIGN's last column
    tip_dir = (jp.crank_tips - jp.pivots) / CRANK
    np.testing.assert_allclose(tip_dir[:, :2], _ring(1.0, DESIGN_CRANK_DIR_DEG), atol=1e-12)
    np.testing.assert_allclose(tip_dir[:, 2], 0.0, atol=1e-12)
    # the platform's height closes each rod over its crank tip (crank horizontal, tip at the
    # pivots' height): z = -sqrt(rod^2 - h^2), h the horizontal tip-to-joint distance from the
    # design table; about 0.648 m above the pivots (FRD: z negative), rods leaning about 26 deg
    # (it compared with those rounded figures to 1 mm and 0.6 deg)
    tips = _ring(0.4064, DESIGN_PIVOT_DEG) + CRANK * _ring(1.0, DESIGN_CRANK_DIR_DEG)
    h = np.linalg.norm(_ring(0.400, DESIGN_JOINT_DEG) - tips, axis=1)
    np.testing.assert_allclose(jp.platform_joints[:, 2], -np.sqrt(ROD**2 - h**2), atol=1e-12)
    rod = jp.platform_joints - jp.crank_tips
    lean = np.degrees(np.arccos(-rod[:, 2] / np.linalg.norm(rod, axis=1)))
    np.testing.assert_allclose(lean, np.degrees(np.arcsin(h / ROD)), atol=1e-9)
    assert np.ptp(h) < 1e-12  # one height for the six joints: the platform is level
    lo, hi = RUS6.angle_limits
    assert lo.shape == hi.shape == (6,)
    np.testing.assert_allclose(lo, -math.pi / 3)
    np.testing.assert_allclose(hi, math.pi / 3)
    np.testing.assert_allclose(GEOMETRY.max_speed, 3.0)
    np.testing.assert_allclose(GEOMETRY.max_accel, 30.0)


def test_neutral_pose_gives_configured_neutral_angle():
    # ceart is configured with neutral_angle_deg = 0: cranks horizontal
    np.testing.assert_allclose(RUS6.inverse(np.zeros(6)), 0.0, atol=1e-12)
    # a geometry configured with neutral cranks at 10 degrees
    data = GEOMETRY.to_dict()
    del data["neutral_height"]
    data["neutral_angle_deg"] = 10.0
    g10 = Rus6Geometry.from_dict(data)
    np.testing.assert_allclose(Rus6(g10).inverse(np.zeros(6)), math.radians(10.0), atol=1e-12)
    # a geometry configured by neutral height: compare with independent root finding
    data = GEOMETRY.to_dict()
    data["neutral_height"] = 0.62
    g = Rus6Geometry.from_dict(data)
    got = Rus6(g).inverse(np.zeros(6))
    pivots = np.c_[_ring(0.4064, DESIGN_PIVOT_DEG), np.zeros(6)]
    joints = np.c_[_ring(0.400, DESIGN_JOINT_DEG), np.full(6, -0.62)]
    cdirs = np.c_[_ring(1.0, DESIGN_CRANK_DIR_DEG), np.zeros(6)]
    want = [_expected_angle(pivots[i], cdirs[i], joints[i], CRANK, ROD) for i in range(6)]
    np.testing.assert_allclose(got, want, atol=1e-10)
    assert (got < 0).all()  # platform lower than the horizontal-crank height: cranks lowered


def test_pure_heave_up_raises_all_cranks():
    zs = np.linspace(0.0, -0.19, 20)  # FRD: negative z is up
    poses = np.zeros((zs.size, 6))
    poses[:, 2] = zs
    angles = RUS6.inverse(poses)
    assert (np.diff(angles, axis=0) > 0).all()
    tips = RUS6.joint_points(poses).crank_tips
    assert (np.diff(tips[..., 2], axis=0) < 0).all()  # tips rise (z decreases)
    # and down lowers them
    assert (RUS6.inverse([0, 0, 0.05, 0, 0, 0]) < 0).all()


def test_park_pose():
    park = RUS6.park_pose
    assert park[2] > 0 and np.all(park[[0, 1, 3, 4, 5]] == 0)
    np.testing.assert_allclose(RUS6.inverse(park), RUS6.angle_limits[0] + math.radians(5))
    assert RUS6.reachable(park)


# --------------------------------------------------------------------------- inverse / forward
@SETTINGS
@given(pose_in_box)
def test_forward_inverse_round_trip(pose):
    assume(RUS6.reachable(pose))
    back = RUS6.forward(RUS6.inverse(pose))
    np.testing.assert_allclose(back, pose, rtol=0, atol=1e-9)


def test_forward_inverse_round_trip_batch_over_workspace():
    rng = np.random.default_rng(1)
    lim = np.array([0.3, 0.3, 0.2, 0.5, 0.35, 0.85])
    poses = rng.uniform(-lim, lim, (20000, 6))
    poses = poses[RUS6.reachable(poses)]
    assert len(poses) > 300
    back = RUS6.forward(RUS6.inverse(poses))
    np.testing.assert_allclose(back, poses, rtol=0, atol=1e-9)
    # the clamp's boundary poses too
    edge, _ = RUS6.clamp(rng.uniform(-2 * lim, 2 * lim, (300, 6)))
    np.testing.assert_allclose(RUS6.forward(RUS6.inverse(edge)), edge, rtol=0, atol=1e-9)


def test_forward_with_guess_and_nonconvergence():
    pose = np.array([0.1, -0.05, -0.08, 0.1, -0.1, 0.4])
    angles = RUS6.inverse(pose)
    np.testing.assert_allclose(RUS6.forward(angles, guess=pose + 0.01), pose, atol=1e-9)
    # one Newton step from neutral cannot get there: reported as NaN, not a wrong pose
    assert np.isnan(RUS6.forward(angles, max_iter=1)).all()
    assert np.isnan(RUS6.forward(np.full(6, np.nan))).all()


def test_unreachable_gives_nan_rows_without_warnings():
    poses = np.array(
        [
            [0.0, 0.0, -0.1, 0.0, 0.0, 0.0],
            [0.0, 0.0, -5.0, 0.0, 0.0, 0.0],  # far above: no leg closes
            [3.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [np.nan, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, np.inf, 0.0, 0.0],
            [0.05, 0.0, 0.0, 0.0, 0.1, 0.0],
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        angles = RUS6.inverse(poses)
        reach = RUS6.reachable(poses)
        jac = RUS6.jacobian(poses)
        jp = RUS6.joint_points(poses)
    assert np.isfinite(angles[[0, 5]]).all()
    assert np.isnan(angles[1:5]).all()
    assert reach.tolist() == [True, False, False, False, False, True]
    assert np.isnan(jac.matrix[1:5]).all() and np.isnan(jac.margin[1:5]).all()
    assert np.isnan(jp.crank_tips[1:5]).all()


def test_reachable_checks_crank_limits():
    # 0.125 m down closes every leg but needs cranks below -60 degrees
    pose = np.array([0.0, 0.0, 0.125, 0.0, 0.0, 0.0])
    angles = RUS6.inverse(pose)
    assert np.isfinite(angles).all() and (angles < RUS6.angle_limits[0]).all()
    assert not RUS6.reachable(pose)


def test_batch_shapes_match_single_calls():
    rng = np.random.default_rng(2)
    poses = rng.uniform(-0.05, 0.05, (2, 3, 6))
    assert RUS6.inverse(poses).shape == (2, 3, 6)
    assert RUS6.reachable(poses).shape == (2, 3)
    assert RUS6.forward(RUS6.inverse(poses)).shape == (2, 3, 6)
    assert RUS6.jacobian(poses).matrix.shape == (2, 3, 6, 6)
    assert RUS6.jacobian(poses).margin.shape == (2, 3)
    jp = RUS6.joint_points(poses)
    assert isinstance(jp, JointPoints) and all(a.shape == (2, 3, 6, 3) for a in jp)
    clamped, flags = RUS6.clamp(poses)
    assert clamped.shape == (2, 3, 6) and flags.shape == (2, 3)
    np.testing.assert_array_equal(RUS6.inverse(poses)[1, 2], RUS6.inverse(poses[1, 2]))
    assert isinstance(RUS6.reachable(poses[0, 0]), bool)
    with pytest.raises(ConfigError, match="shape"):
        RUS6.inverse(np.zeros(5))


# --------------------------------------------------------------------------- joint points
@SETTINGS
@given(pose_in_box)
def test_joint_points_leg_lengths_and_rigid_body(pose):
    assume(RUS6.reachable(pose))
    jp = RUS6.joint_points(pose)
    np.testing.assert_allclose(np.linalg.norm(jp.crank_tips - jp.pivots, axis=-1), CRANK)
    np.testing.assert_allclose(
        np.linalg.norm(jp.platform_joints - jp.crank_tips, axis=-1), ROD, rtol=1e-12
    )
    # rigid body: neutral joints moved by exactly the commanded translation and Z-Y-X rotation
    neutral = RUS6.joint_points(np.zeros(6)).platform_joints
    centroid = neutral.mean(axis=0)
    rot = Rotation.from_euler("ZYX", [pose[5], pose[4], pose[3]])  # intrinsic: Rz Ry Rx
    expected = centroid + pose[:3] + rot.apply(neutral - centroid)
    np.testing.assert_allclose(jp.platform_joints, expected, atol=1e-14)
    np.testing.assert_allclose(jp.pivots, RUS6.joint_points(np.zeros(6)).pivots)
    # the crank tips lie in the vertical plane of their crank direction
    cdir = np.c_[_ring(1.0, DESIGN_CRANK_DIR_DEG), np.zeros(6)]
    normal = np.cross(cdir, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(
        np.einsum("ij,ij->i", jp.crank_tips - jp.pivots, normal), 0, atol=1e-14
    )


# --------------------------------------------------------------------------- Jacobian
@SETTINGS
@given(pose_in_box)
def test_jacobian_matches_finite_differences(pose):
    assume(RUS6.reachable(pose))
    h = 1e-6
    steps = np.eye(6) * h
    fd = (RUS6.inverse(pose + steps) - RUS6.inverse(pose - steps)).T / (2 * h)
    res = RUS6.jacobian(pose)
    np.testing.assert_allclose(res.matrix, fd, rtol=1e-5, atol=1e-6)
    assert 0.0 < res.margin <= 1.0
    assert res.margin == min(res.transmission, res.conditioning)


@SETTINGS
@given(pose_in_box, st.tuples(*[st.floats(-1, 1)] * 3).map(np.array))
def test_jacobian_angular_velocity_matches_finite_rotation(pose, omega):
    assume(RUS6.reachable(pose) and np.linalg.norm(omega) > 1e-3)
    h = 1e-6
    rot = Rotation.from_euler("ZYX", pose[[5, 4, 3]])

    def rotated(sign):
        r = Rotation.from_rotvec(sign * h * omega) * rot  # omega in base axes
        ypr = r.as_euler("ZYX")
        return np.r_[pose[:3], ypr[::-1]]

    fd = (RUS6.inverse(rotated(1)) - RUS6.inverse(rotated(-1))) / (2 * h)
    J = RUS6.jacobian(pose, angular="omega").matrix
    np.testing.assert_allclose(J[:, 3:] @ omega, fd, rtol=1e-5, atol=1e-6)


def test_singularity_margin_falls_to_zero_at_the_closure_limit():
    # with wide crank limits, heave up until the legs stop closing: there each rod is
    # perpendicular to its crank tip's path (checked from the joint points), and the margin
    # must reach 0
    data = GEOMETRY.to_dict()
    data["angle_min"] = [-3.1] * 6
    data["angle_max"] = [3.1] * 6
    wide = Rus6(Rus6Geometry.from_dict(data))
    lo, hi = -0.4, 0.0  # unreachable, reachable
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if wide.reachable([0, 0, mid, 0, 0, 0]) else (mid, hi)
    edge = np.array([0.0, 0.0, hi, 0.0, 0.0, 0.0])
    jp = wide.joint_points(edge)
    crank = (jp.crank_tips - jp.pivots) / CRANK
    rod = (jp.platform_joints - jp.crank_tips) / ROD
    axis = np.cross(np.c_[_ring(1.0, DESIGN_CRANK_DIR_DEG), np.zeros(6)], [0.0, 0.0, 1.0])
    tip_path = np.cross(axis, crank)
    np.testing.assert_allclose(np.einsum("ij,ij->i", tip_path, rod), 0.0, atol=1e-5)
    res = wide.jacobian(edge)
    assert res.transmission < 1e-3 and res.margin < 1e-3
    assert wide.jacobian(np.zeros(6)).margin > 0.1
    heights = np.linspace(hi, 0.0, 50)
    poses = np.zeros((50, 6))
    poses[:, 2] = heights
    # moving away from the singularity, transmission rises
    assert (np.diff(wide.jacobian(poses[:10]).transmission) > 0).all()


def test_jacobian_modes_agree_at_zero_orientation():
    pose = np.array([0.05, -0.02, -0.03, 0.0, 0.0, 0.0])  # Euler rates == angular velocity here
    np.testing.assert_allclose(
        RUS6.jacobian(pose).matrix, RUS6.jacobian(pose, angular="omega").matrix, rtol=1e-14
    )


# --------------------------------------------------------------------------- clamp
@settings(max_examples=200, deadline=None)
@given(st.tuples(*[any_float] * 6).map(np.array))
def test_clamp_always_reachable_and_finite(pose):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out, clamped = RUS6.clamp(pose)
    assert out.shape == (6,) and np.isfinite(out).all()
    assert RUS6.reachable(out)
    angles = RUS6.inverse(out)
    lo, hi = RUS6.angle_limits
    assert np.isfinite(angles).all() and (angles >= lo).all() and (angles <= hi).all()
    if RUS6.reachable(pose):
        assert not clamped and np.array_equal(out, pose)
    else:
        assert clamped
    if not np.isfinite(pose).all():
        assert np.array_equal(out, np.zeros(6))


@SETTINGS
@given(pose_in_box, st.floats(1.5, 1e3))
def test_clamp_keeps_rotation_and_scales_translation(pose, factor):
    assume(RUS6.reachable(pose) and np.linalg.norm(pose[:3]) > 1e-3)
    big = pose.copy()
    big[:3] *= factor
    assume(not RUS6.reachable(big))
    out, clamped = RUS6.clamp(big)
    assert clamped
    np.testing.assert_array_equal(out[3:], pose[3:])  # rotation untouched
    s = out[:3] @ big[:3] / (big[:3] @ big[:3])
    np.testing.assert_allclose(out[:3], s * big[:3], atol=1e-15)  # along the way to neutral
    assert 1 / factor - 1e-12 <= s < 1  # at least as far out as the reachable original


def test_clamp_scales_rotation_when_rotation_alone_is_unreachable():
    out, clamped = RUS6.clamp([0.1, 0.0, 0.0, 0.0, 0.0, math.radians(80)])
    assert clamped and np.all(out[:5] == 0)
    assert math.radians(45) < out[5] < math.radians(80)
    # the scale found is the largest reachable one (to machine precision)
    assert not RUS6.reachable([0, 0, 0, 0, 0, out[5] * (1 + 1e-9)])


def test_clamp_wraps_equivalent_angles():
    # an unwrapped but reachable rotation is the same pose: returned as is
    same = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.2 + 4 * math.pi])
    out, clamped = RUS6.clamp(same)
    assert not clamped and np.array_equal(out, same)
    # with too much translation the rotation is kept, expressed in [-pi, pi)
    out, clamped = RUS6.clamp([2.0, 0.0, 0.0, 0.0, 0.0, 0.2 + 4 * math.pi])
    assert clamped and RUS6.reachable(out)
    np.testing.assert_allclose(out[3:], [0, 0, 0.2], atol=1e-12)
    assert 0 < out[0] < 0.31 and out[1] == out[2] == 0


def test_clamp_batch_equals_single():
    rng = np.random.default_rng(3)
    poses = rng.uniform(-1, 1, (50, 6))
    out, flags = RUS6.clamp(poses)
    for k in range(50):
        single, flag = RUS6.clamp(poses[k])
        np.testing.assert_array_equal(out[k], single)
        assert flags[k] == flag


# --------------------------------------------------------------------------- TOML and validation
def test_dict_and_toml_round_trip(tmp_path):
    assert Rus6Geometry.from_dict(GEOMETRY.to_dict()) == GEOMETRY
    path = tmp_path / "g.toml"
    GEOMETRY.to_toml(path)
    assert Rus6Geometry.from_toml(path) == GEOMETRY
    GEOMETRY.to_toml(tmp_path / "deg.toml", units="deg")
    text = (tmp_path / "deg.toml").read_text()
    assert "chi_a_deg" in text and "max_speed_deg_s" in text
    back = Rus6Geometry.from_toml(tmp_path / "deg.toml")
    for f in ("chi_a", "beta", "angle_min", "park_angle", "max_speed", "neutral_height"):
        np.testing.assert_allclose(getattr(back, f), getattr(GEOMETRY, f), rtol=1e-14)
    # the loaded path is also accepted by preset()
    assert Rus6Geometry.preset(str(path)) == GEOMETRY


def _bad(**changes):
    data = GEOMETRY.to_dict()
    for k, v in changes.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    return data


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"crank": [0.184] * 5 + [-0.1]}, r"'crank'.*leg 6.*> 0"),
        ({"rb": -0.3}, r"'rb'.*>"),
        ({"rod": 0.3}, r"'rod'.*too short"),
        ({"rod": 3.0}, r"'rod'.*too long"),
        ({"chi_a": [0.5] * 5}, r"'chi_a'.*6 numbers"),
        ({"beta": None, "beta_deg": [1, 2, 3]}, r"'beta_deg'.*6 numbers"),
        ({"rodd": 0.7}, r"unknown field 'rodd'"),
        ({"rb": None}, r"missing field 'rb'"),
        ({"neutral_height": None}, r"neutral_height"),
        ({"neutral_angle_deg": 0.0}, r"either 'neutral_height' or 'neutral_angle_deg'"),
        ({"angle_min": [1.2] * 6}, r"angle_min"),
        ({"park_angle": 2.0}, r"'park_angle'.*outside"),
        ({"park_angle": [-0.9] * 6}, r"'park_angle'.*expected a number"),
        ({"crank": [0.184] * 5 + [0.19]}, r"'park_angle'.*pure-heave"),
        ({"park_angle": 0.1, "park_angle_deg": 5.0}, r"either 'park_angle' or 'park_angle_deg'"),
        ({"max_speed": [0.0] * 6}, r"'max_speed'"),
        ({"max_accel": "fast"}, r"'max_accel'"),
        ({"neutral_height": 0.2}, r"'rod'"),
        ({"kind": "rrr3"}, r"'kind'"),
        ({"chi_j": [0.5] * 6, "chi_j_deg": [30.0] * 6}, r"either 'chi_j' or 'chi_j_deg'"),
    ],
)
def test_validation_errors_name_the_field(changes, match):
    with pytest.raises(ConfigError, match=match):
        Rus6Geometry.from_dict(_bad(**changes), source="test.toml")


def test_toml_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("rb = 0.35\nrodd = 1\n")
    with pytest.raises(ConfigError, match=r"bad.toml.*unknown field 'rodd'"):
        Rus6Geometry.from_toml(bad)
    with pytest.raises(ConfigError, match="unknown rus6 preset"):
        Rus6Geometry.preset("nope")
    with pytest.raises(ConfigError, match="not found"):
        Rus6Geometry.from_toml(tmp_path / "missing.toml")


def test_park_angle_defaults_but_speed_and_accel_limits_never_do():
    data = GEOMETRY.to_dict()
    del data["park_angle"]
    g = Rus6Geometry.from_dict(data)
    assert g.park_angle == pytest.approx(math.radians(-55.0), abs=1e-15)
    # a limit that moves motors is never guessed (issue 13, item 12)
    for k in ("max_speed", "max_accel"):
        data = GEOMETRY.to_dict()
        del data[k]
        with pytest.raises(ConfigError, match=rf"g.toml: missing field '{k}'") as err:
            Rus6Geometry.from_dict(data, source="g.toml")
        assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("max_speed", True),  # once became 1.0 rad/s
        ("max_speed", "3.0"),
        ("max_accel", [30.0] * 5 + ["30"]),
        ("angle_min_deg", ["-60"] * 6),
        ("angle_max", [True] * 6),
        ("crank", "0.184"),
        ("max_speed_deg_s", False),
    ],
)
def test_wrong_types_are_refused_not_converted(field, value):
    data = _bad(**{field: value})
    if field.endswith("_deg") or field.endswith("_deg_s"):
        data.pop(field.rsplit("_deg", 1)[0])
    with pytest.raises(ConfigError, match=rf"g.toml: field '{field}': expected"):
        Rus6Geometry.from_dict(data, source="g.toml")


def test_a_washout_or_planar_file_is_named_for_what_it_is():
    from motionbase.config import preset_path, read_toml

    with pytest.raises(ConfigError, match=r"w.toml: this is a washout parameter file.*--washout"):
        Rus6Geometry.from_dict(read_toml(preset_path("washout", "default")), source="w.toml")
    with pytest.raises(ConfigError, match=r"r.toml: this is a 3-RRR geometry file.*--planar"):
        Rus6Geometry.from_dict(read_toml(preset_path("rrr3", "udesc")), source="r.toml")


@settings(max_examples=40, deadline=None)
@given(
    st.floats(0.97, 1.03),
    st.floats(0.9, 1.1),
    st.floats(-0.2, 0.2),
    st.floats(0.5, 5.0),
)
def test_round_trip_is_exact_for_any_valid_geometry(tmp_path_factory, scale, rod_scale, ang, speed):
    data = GEOMETRY.to_dict()
    data["rb"] *= scale
    data["rp"] /= scale
    data["rod"] = [r * rod_scale for r in data["rod"]]
    data["chi_j"] = [a + ang / 10 for a in data["chi_j"]]
    data["max_speed"] = [speed] * 6
    data["neutral_height"] *= 1 + ang / 20
    try:
        g = Rus6Geometry.from_dict(data)
    except ConfigError:
        assume(False)
    assert Rus6Geometry.from_dict(g.to_dict()) == g
    path = tmp_path_factory.mktemp("g") / "g.toml"
    g.to_toml(path)
    assert Rus6Geometry.from_toml(path) == g


@pytest.mark.parametrize(("rp", "e"), [(1e-6, 0.0), (1e-3, 0.0), (0.0, 1e-6)])
def test_platform_joints_at_one_point_are_refused(rp, e):
    """Joints at (nearly) one point leave the platform's rotations free: refused at load.

    rp = 1e-6 with e = 0 loaded, and `workspace` reported 180 deg of roll, pitch and yaw (the
    rods hardly change length when the platform turns about the point they meet at).
    """
    data = GEOMETRY.to_dict()
    data["rp"], data["e"] = rp, e
    if rp == 0.0:
        data["rp"] = 1e-9
    del data["park_angle"]
    with pytest.raises(ConfigError, match=r"^g\.toml: fields 'rp'/'e': the rods barely hold"):
        Rus6Geometry.from_dict(data, source="g.toml")


def test_a_small_but_real_platform_still_loads():
    data = GEOMETRY.to_dict()
    data["rp"], data["e"] = 0.05, 0.01
    del data["park_angle"]
    Rus6Geometry.from_dict(data, source="g.toml")


@pytest.mark.parametrize(
    ("angle", "says"),
    [
        (-88.0, "the cranks cannot be commanded"),  # inside the limits, the other assembly
        (100.0, "100 deg is outside leg 1's limits -89 .. 89 deg"),
        (150.0, "outside leg 1's limits"),
        (360.0, "outside leg 1's limits"),
        (1e300, "outside leg 1's limits"),
    ],
)
def test_neutral_angle_the_inverse_kinematics_never_commands_is_refused(angle, says):
    """neutral_angle_deg = 1e300 loaded with the cranks at -22 deg, -88 at -62.8 deg; 100
    (limits +-89) was refused naming neutral_height, a field the file does not have."""
    data = GEOMETRY.to_dict()
    del data["neutral_height"], data["angle_min"], data["angle_max"], data["park_angle"]
    data.update(neutral_angle_deg=angle, angle_min_deg=-89.0, angle_max_deg=89.0)
    data["park_angle_deg"] = -60.0
    with pytest.raises(ConfigError, match=r"^g\.toml: field 'neutral_angle_deg': ") as caught:
        Rus6Geometry.from_dict(data, source="g.toml")
    assert says in str(caught.value)


@pytest.mark.parametrize("unit", ["mm", "m"])
def test_a_linear_drive_unit_for_cranks_is_refused(unit):
    """unit = "mm" loaded on the 6-RUS: the drives got 1000 x the motor angle in rad as mm."""
    data = GEOMETRY.to_dict()
    data["output"] = {"unit": unit}
    with pytest.raises(ConfigError, match=rf"^g\.toml: table 'output': field 'unit': '{unit}'"):
        Rus6Geometry.from_dict(data, source="g.toml")


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("crank", -1.0, r"field 'crank': leg 1 must be > 0 m, got -1 "),
        ("crank", [0.184] * 5 + [0.0], r"field 'crank': leg 6 must be > 0 m, got 0"),
        ("rod", 1e300, r"field 'rod': leg 1 rod 1e\+300 m is too long for the platform"),
    ],
)
def test_neutral_angle_path_names_the_bad_length(field, value, match):
    """With neutral_angle_deg, a negative crank was reported as a rod too short, a zero crank
    on one leg as legs needing different heights, and a rod of 1e300 m as too short."""
    data = GEOMETRY.to_dict()
    del data["neutral_height"]
    data.update(neutral_angle_deg=0.0, **{field: value})
    with pytest.raises(ConfigError, match=rf"^g\.toml: {match}"):
        Rus6Geometry.from_dict(data, source="g.toml")
