"""Planar 3-RRR kinematics: checked against geometry computed independently in the tests."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from motionbase.errors import ConfigError
from motionbase.platform.rrr3 import (
    SERVO_RANGE,
    TYPE1,
    TYPE2,
    Rrr3,
    UnreachablePoseError,
)
from motionbase.platform.rrr3_geometry import Rrr3Geometry

GEOM = Rrr3Geometry.preset("udesc")
R = Rrr3(GEOM)
SYM = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
L, A_LEN, B_LEN, H = 0.26, 0.04445, 0.0889, 0.08573
BASE = np.array([[0.0, 0.0], [L, 0.0], [L / 2, L * math.sqrt(3) / 2]])


def ref_platform_joints(x, y, phi):
    """Thesis appendix A.1, lines 29-31 (G, H, I)."""
    c1 = np.array(
        [
            x - math.cos(math.pi / 6 + phi) * H * math.sqrt(3) / 3,
            y - math.sin(math.pi / 6 + phi) * H * math.sqrt(3) / 3,
        ]
    )
    c2 = c1 + H * np.array([math.cos(phi), math.sin(phi)])
    c3 = c1 + H * np.array([math.cos(phi + math.pi / 3), math.sin(phi + math.pi / 3)])
    return np.array([c1, c2, c3])


def ref_inverse(pose, modes):
    """Law of cosines: theta = atan2(yc, xc) + m acos((d^2 + a^2 - b^2) / (2 a d))."""
    C = ref_platform_joints(*pose)
    out = []
    for i in range(3):
        xc, yc = C[i] - BASE[i]
        d = math.hypot(xc, yc)
        cosd = (d * d + A_LEN**2 - B_LEN**2) / (2 * A_LEN * d)
        if abs(cosd) > 1:
            return None
        th = math.atan2(yc, xc) + modes[i] * math.acos(cosd)
        out.append(math.atan2(math.sin(th), math.cos(th)))
    return np.array(out)


def processing_servo(theta):
    """The thesis's Processing mapping (appendix A.2): P1 = th1, P2 = th2, P3 = th3 -135/+225."""
    t1, t2, t3 = np.degrees(theta)
    t3 = t3 + 180 + 45 if t3 < 0 else t3 - 135
    return [math.floor(v + 0.5) for v in (t1, t2, t3)]


near_home = st.tuples(st.floats(-0.03, 0.03), st.floats(-0.03, 0.03), st.floats(-0.35, 0.35)).map(
    lambda d: R.home + np.array(d)
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(near_home)
def test_inverse_matches_law_of_cosines(pose):
    ref = ref_inverse(pose, GEOM.modes)
    th = R.inverse(pose)
    if ref is None:
        assert np.isnan(th).any()
    else:
        np.testing.assert_allclose(np.angle(np.exp(1j * (th - ref))), 0.0, atol=1e-9)


@settings(max_examples=150, deadline=None)
@given(near_home)
def test_joint_points_distance_invariants(pose):
    th = R.inverse(pose)
    assume(np.isfinite(th).all())
    A, B, C = R.joint_points(pose)
    np.testing.assert_allclose(A, BASE)
    np.testing.assert_allclose(np.linalg.norm(B - A, axis=-1), A_LEN, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(C - B, axis=-1), B_LEN, rtol=1e-9)
    for i, j in ((0, 1), (1, 2), (0, 2)):
        assert np.linalg.norm(C[i] - C[j]) == pytest.approx(H, rel=1e-12)
    np.testing.assert_allclose(C.mean(axis=0), pose[:2], atol=1e-15)
    np.testing.assert_allclose(C, ref_platform_joints(*pose), atol=1e-15)
    d = C[1] - C[0]
    assert math.atan2(d[1], d[0]) == pytest.approx(pose[2], abs=1e-12)


@settings(max_examples=120, deadline=None)
@given(near_home, st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_forward_inverse_round_trip(pose, noise):
    assume(R.reachable(pose))
    # Near a direct (type II) singularity two assembly modes meet, and Newton from a guess a
    # fixed distance away may land on the other one: that is the physics, not a bug. Ask the
    # round trip where the modes are well apart (twice the refusal margin).
    assume(R.singularity(pose).type2 > 2 * GEOM.type2_margin)
    th = R.inverse(pose)
    guess = pose + np.array(noise) * np.array([0.002, 0.002, 0.02])
    back = R.forward(th, guess=guess)
    np.testing.assert_allclose(back, pose, atol=1e-10)
    # and the inverse of the forward result gives the angles again
    np.testing.assert_allclose(R.inverse(back), th, atol=1e-9)


def test_forward_batch_from_home_and_all_assembly_modes():
    rng = np.random.default_rng(3)
    poses = R.home + rng.uniform(-1, 1, (200, 3)) * [0.01, 0.01, 0.1]
    ok = R.reachable(poses)
    assert ok.sum() > 100
    th_ok = R.inverse(poses[ok])
    guess = poses[ok] + rng.uniform(-1, 1, (ok.sum(), 3)) * [0.001, 0.001, 0.01]
    np.testing.assert_allclose(R.forward(th_ok, guess=guess), poses[ok], atol=1e-10)
    # from home, Newton may land on another assembly mode (the thesis's robot has two close
    # to home), but what it returns always closes the three loops with these angles
    from_home = R.forward(th_ok)
    conv = np.isfinite(from_home).all(axis=1)
    _, Bh, Ch = R.joint_points(from_home[conv], angles=th_ok[conv])
    np.testing.assert_allclose(np.linalg.norm(Ch - Bh, axis=-1), B_LEN, rtol=1e-9)

    th = R.inverse(R.home)
    sols = R.forward_all(th)
    assert 2 <= len(sols) <= 6
    assert np.min(np.linalg.norm(sols - R.home, axis=1)) < 1e-10
    for sol in sols:  # every assembly mode closes all three loops with these angles
        A, B, C = R.joint_points(sol, angles=th)
        np.testing.assert_allclose(np.linalg.norm(C - B, axis=-1), B_LEN, rtol=1e-9)


def test_jacobians_against_finite_differences():
    rng = np.random.default_rng(7)
    poses = R.home + rng.uniform(-1, 1, (40, 3)) * [0.02, 0.02, 0.2]
    poses = poses[R.reachable(poses)]
    assert len(poses) > 10
    eps = 1e-7
    for pose in poses:
        Jx, Jq = R.jacobians(pose)
        J = np.linalg.solve(Jq, Jx)
        fd = np.empty((3, 3))
        for k in range(3):
            dp = np.zeros(3)
            dp[k] = eps
            diff = R.inverse(pose + dp) - R.inverse(pose - dp)
            fd[:, k] = np.angle(np.exp(1j * diff)) / (2 * eps)
        np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-5)
        assert np.allclose(Jq - np.diag(np.diag(Jq)), 0)


def test_pose_near_type1_singularity_is_refused():
    # chain 1 almost stretched: C1 at distance (a + b)(1 - 1e-4) from A1 along 30 deg
    phi = 0.0
    c1_local = GEOM.platform_points[0]
    d = (A_LEN + B_LEN) * (1 - 1e-4)
    C1 = d * np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    pose = np.array([C1[0] - c1_local[0], C1[1] - c1_local[1], phi])
    assert np.isfinite(R.inverse(pose)).all()  # a real solution exists ...
    sing = R.singularity(pose)
    assert sing.type1[0] < 0.05  # crank and rod nearly aligned (measured by the numpy path)
    assert R.status(pose) & TYPE1  # ... and it is refused
    assert not R.reachable(pose)
    clamped, was = R.clamp(pose)
    assert was and R.reachable(clamped)


def test_pose_near_type2_singularity_is_refused():
    # walk the phi = 0 slice and find neighbours where det(Jx) changes sign while the
    # inverse kinematics stays real and far from type I: a type II singularity lies between.
    g = Rrr3Geometry.preset("udesc")
    loose = Rrr3(
        Rrr3Geometry(
            **{**g.__dict__, "type2_margin": 0.0, "servo_min_deg": (0, 0, 0), "name": "loose"}
        )
    )
    xs = np.linspace(0.06, 0.2, 141)
    for y in np.linspace(0.03, 0.15, 61):
        poses = np.stack([xs, np.full_like(xs, y), np.zeros_like(xs)], -1)
        s = loose.singularity(poses)
        fine = (loose.status(poses) & (TYPE1 | 1)) == 0
        sign = np.sign(s.det_jx)
        idx = np.flatnonzero(fine[:-1] & fine[1:] & (sign[:-1] != sign[1:]))
        if idx.size:
            break
    else:
        pytest.fail("no type II crossing found in the slice")
    lo, hi = poses[idx[0]].copy(), poses[idx[0] + 1].copy()
    s_lo = np.sign(loose.singularity(lo).det_jx)
    for _ in range(60):
        mid = (lo + hi) / 2
        if np.sign(loose.singularity(mid).det_jx) == s_lo:
            lo = mid
        else:
            hi = mid
    # at the singular pose Jx has a null vector: the platform can move with locked motors
    Jx, _ = R.jacobians(mid)
    assert np.linalg.svd(Jx, compute_uv=False)[-1] < 1e-9
    assert R.status(mid) & TYPE2
    assert not R.reachable(mid)


def test_servo_mapping_matches_thesis_processing_code():
    rng = np.random.default_rng(11)
    poses = R.home + rng.uniform(-1, 1, (300, 3)) * [0.02, 0.02, 0.2]
    poses = poses[R.reachable(poses)]
    assert len(poses) > 50
    for pose in poses:
        th = R.inverse(pose)
        assert R.to_servo(th).tolist() == processing_servo(th)


def test_servo_out_of_range_is_refused_not_clipped():
    th = np.radians([92.0, 88.0, 100.0])  # servo 3: 100 - 135 = -35 deg: out of range
    with pytest.raises(UnreachablePoseError, match="servo 3"):
        R.to_servo(th)
    deg, ok = R.to_servo_masked(np.stack([th, np.radians([92.0, 88.0, 200.0])]))
    assert ok.tolist() == [[True, True, False], [True, True, True]]
    assert deg[1].tolist() == [92, 88, 65]
    with pytest.raises(UnreachablePoseError):
        R.to_servo([np.nan, 0.1, 0.1])
    # a pose needing such an angle is refused by status
    lim = R.angle_limits
    assert lim.shape == (3, 2)
    np.testing.assert_allclose(np.degrees(lim[2]), [135.0, 315.0])


def test_clamp_moves_along_segment_toward_home():
    target = R.home + np.array([0.2, 0.1, 0.0])
    out, was = R.clamp(target)
    assert was and R.reachable(out)
    d = target - R.home
    f = np.dot(out - R.home, d) / np.dot(d, d)
    np.testing.assert_allclose(out, R.home + f * d, atol=1e-12)  # on the segment
    assert not R.reachable(R.home + (f + 1e-4) * d)  # and at its edge
    inside = R.home + np.array([0.005, -0.003, 0.05])
    out2, was2 = R.clamp(inside)
    assert not was2 and np.array_equal(out2, inside)
    out3, was3 = R.clamp([np.nan, 0.1, 0.0])
    assert was3 and np.array_equal(out3, R.home)
    assert R.clamp_one(*target)[:3] == pytest.approx(tuple(out))


def test_workspace_sweep_agrees_with_pointwise_checks():
    ws = R.workspace(nx=40, ny=40, nphi=13)
    assert ws.status.shape == (40, 40, 13)
    X, Y, P = np.meshgrid(ws.x, ws.y, ws.phi, indexing="ij")
    st_ = R.status(np.stack([X, Y, P], -1))
    np.testing.assert_array_equal(st_, ws.status)
    assert (ws.total >= ws.slice_at(0.0)).all()
    assert ws.slice_at(0.0).sum() > 0
    x0, x1, y0, y1 = R.inscribed_rectangle(0.0)
    xs, ys = np.linspace(x0, x1, 30), np.linspace(y0, y1, 30)
    Xg, Yg = np.meshgrid(xs, ys)
    assert R.reachable(np.stack([Xg, Yg, 0 * Xg], -1)).all()


def test_geometry_round_trips_and_errors(tmp_path):
    g = Rrr3Geometry.preset("udesc")
    assert Rrr3Geometry.from_dict(g.to_dict()) == g
    assert Rrr3Geometry.from_dict(g.to_dict()).to_dict() == g.to_dict()
    p = tmp_path / "g.toml"
    g.to_toml(p)
    assert Rrr3Geometry.from_toml(p) == g
    assert (g.base_side, g.crank, g.rod, g.platform_side) == (L, A_LEN, B_LEN, H)
    bad = g.to_dict()
    bad["crankk"] = 1.0
    with pytest.raises(ConfigError, match="unknown field 'crankk'"):
        Rrr3Geometry.from_dict(bad)
    bad = g.to_dict()
    bad["rod"] = -0.1
    with pytest.raises(ConfigError, match="'rod'"):
        Rrr3Geometry.from_dict(bad)
    bad = g.to_dict()
    bad["modes"] = [1, 0, 1]
    with pytest.raises(ConfigError, match="modes"):
        Rrr3Geometry.from_dict(bad)
    bad = g.to_dict()
    bad["servo"]["max_deg"] = [180, 200, 180]
    with pytest.raises(ConfigError, match="servo 2"):
        Rrr3Geometry.from_dict(bad)
    with pytest.raises(ConfigError, match="unknown rrr3 preset"):
        Rrr3Geometry.preset("nope")
    # a geometry whose home is out of the servo ranges is refused by Rrr3
    with pytest.raises(ConfigError, match="home pose"):
        Rrr3(Rrr3Geometry(modes=(1, 1, 1)))


def test_a_file_whose_home_pose_is_out_of_reach_is_named_not_the_preset_it_was_copied_from(
    tmp_path,
):
    """A copy of a preset with a rod too short for chain 1 to reach its platform joint at
    home: the error named the preset the copy came from ("rrr3 geometry 'udesc_symmetric'"),
    as if the shipped preset were broken, and not the file (fly --planar, workspace
    --planar, teleop said the same)."""
    from motionbase.config import preset_path

    text = preset_path("rrr3", "udesc_symmetric").read_text()
    # chain 1 at home: motor axis at the origin, its platform joint h/sqrt(3) from the home
    # point (L/2, L sqrt(3)/6) toward the origin, so L/sqrt(3) - h/sqrt(3) away from it
    reach_needed = (L - H) / math.sqrt(3)
    rod = reach_needed - A_LEN - 0.002  # the crank and the rod together fall 2 mm short
    assert A_LEN + rod > H / math.sqrt(3)  # (not the simpler "too short to reach" check)
    lines = [f"rod = {rod!r}" if ln.startswith("rod =") else ln for ln in text.splitlines()]
    path = tmp_path / "mine.toml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError) as err:
        Rrr3Geometry.from_toml(path)
    message = str(err.value)
    assert message.startswith(f"{path}: home pose") and "unreachable" in message
    assert "udesc_symmetric" not in message


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["safety"].update(max_speed=True), r"'max_speed'.*True"),
        (lambda d: d["safety"].update(max_accel="20"), r"'max_accel'.*'20'"),
        (lambda d: d["safety"].pop("max_speed"), r"\[safety\]: missing field 'max_speed'"),
        (lambda d: d["safety"].pop("max_accel"), r"\[safety\]: missing field 'max_accel'"),
        (lambda d: d["servo"].pop("min_deg"), r"\[servo\]: missing field 'min_deg'"),
        (lambda d: d["servo"].update(max_deg=[180, "180", 180]), r"'servo.max_deg'.*'180'"),
        (lambda d: d["servo"].update(min_deg=[0, False, 0]), r"'servo.min_deg'.*False"),
        (lambda d: d["servo"].update(zero_deg=["0", 0, 135]), r"'servo.zero_deg'.*'0'"),
        (lambda d: d.update(crank="0.04445"), r"'crank'.*'0.04445'"),
        (lambda d: d.update(modes=[1, -1]), r"'modes'.*3 values"),
    ],
)
def test_geometry_types_are_strict_and_limits_never_default(edit, match):
    """Issue 13, item 12: no bool or string is read as a number; a missing limit is an error."""
    data = Rrr3Geometry.preset("udesc").to_dict()
    edit(data)
    with pytest.raises(ConfigError, match=r"^g.toml.*" + match):
        Rrr3Geometry.from_dict(data, source="g.toml")


def test_a_6rus_or_washout_file_given_as_planar_geometry_is_named_for_what_it_is():
    from motionbase.config import preset_path, read_toml

    with pytest.raises(ConfigError, match=r"^c.toml: this is a 6-RUS geometry file"):
        Rrr3Geometry.from_dict(read_toml(preset_path("rus6", "ceart")), source="c.toml")
    with pytest.raises(ConfigError, match=r"^w.toml: this is a washout parameter file"):
        Rrr3Geometry.from_dict(read_toml(preset_path("washout", "gentle")), source="w.toml")


def test_symmetric_mode_is_better_conditioned():
    def cond(r):
        Jx, Jq = r.jacobians(r.home)
        return np.linalg.cond(np.linalg.solve(Jq, Jx))

    assert cond(SYM) < cond(R) / 5
    assert SYM.to_servo(SYM.inverse(SYM.home)).tolist() == [90, 90, 90]


def test_servo_range_bit_agrees_with_servo_mapping():
    narrow = Rrr3(
        Rrr3Geometry(servo_min_deg=(70, 70, 50), servo_max_deg=(110, 110, 100), name="narrow")
    )
    rng = np.random.default_rng(5)
    poses = R.home + rng.uniform(-1, 1, (4000, 3)) * [0.03, 0.03, 0.4]
    st_ = narrow.status(poses)
    only_servo = poses[st_ == SERVO_RANGE]
    assert len(only_servo) > 20
    _, ok = narrow.to_servo_masked(narrow.inverse(only_servo))
    assert (~ok.all(axis=1)).all()
    assert (R.status(only_servo) == 0).all()  # the full 0..180 range accepts them
    _, ok_valid = narrow.to_servo_masked(narrow.inverse(poses[st_ == 0]))
    assert ok_valid.all()


def test_actuator_jacobian_is_by_the_cue_pose() -> None:
    """The planar robot's ``actuator_jacobian`` differentiates by the *cue* pose: the
    kinematics' own Jacobian ``Jq^-1 Jx`` times the planar mapping (surge, sway and yaw
    scaled; heave, roll and pitch not rendered, so their columns are zero)."""
    from motionbase.platform.robot import robot_spec

    robot = robot_spec("rrr3").make(GEOM)
    rng = np.random.default_rng(5)
    cues = rng.uniform(-1, 1, (30, 6)) * [0.1, 0.1, 0.3, 0.3, 0.3, 0.3]
    poses = robot.pose_from_cue(cues)
    keep = R.reachable(poses)
    assert keep.sum() >= 10
    q, J = robot.actuator_jacobian(cues[keep])
    for pose, q_i, J_i in zip(poses[keep], q, J, strict=True):
        Jx, Jq = R.jacobians(pose)
        mapping = np.zeros((3, 6))
        mapping[[0, 1, 2], [0, 1, 5]] = robot.scale
        np.testing.assert_allclose(J_i, np.linalg.solve(Jq, Jx) @ mapping, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(np.exp(1j * q_i), np.exp(1j * R.inverse(pose)), atol=1e-12)


@pytest.mark.parametrize(
    ("force", "rates", "axis", "sign"),
    [
        ((2.0, 0.0), (0.0, 0.0, 0.0), 0, 1.0),  # forward: toward +x (motor 1 to motor 2)
        ((0.0, 2.0), (0.0, 0.0, 0.0), 1, -1.0),  # right: to the right of +x, seen from above
        ((0.0, 0.0), (0.0, 0.0, 0.3), 2, -1.0),  # yaw right (nose right): clockwise from above
    ],
    ids=["surge", "sway", "yaw"],
)
def test_the_planar_robot_moves_as_the_aircraft_does_not_its_mirror_image(
    force, rates, axis, sign
) -> None:
    """The cue is in FRD base axes (y right, z down, yaw turning the nose right); the
    thesis's plane is z up (y to the left of x seen from above, phi counter-clockwise). A
    right push moved the platform toward +y, to the left, and a right yaw turned it
    counter-clockwise: the aircraft's motion mirrored. Through the whole pipeline (the
    classical washout's onset), from home at rest."""
    from motionbase.app import load_config
    from motionbase.pipeline import Pipeline
    from motionbase.state import AircraftState

    g = 9.80665
    pipeline = Pipeline(load_config(planar=True))
    home = np.array(pipeline.robot.neutral_pose)
    n = 3 * 120  # past the soft start, level flight
    for i in range(n):
        pipeline.step(AircraftState(i / 120, [0.0, 0.0, -g], [0.0, 0.0, 0.0]))
    for i in range(n, n + 60):  # half a second of the push
        out = pipeline.step(AircraftState(i / 120, [*force, -g], list(rates)))
    moved = out.platform_pose - home
    assert sign * moved[axis] > 1e-3
    assert np.abs(np.delete(moved, axis)).max() < 1e-9
