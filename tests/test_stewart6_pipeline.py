"""The 6-UPS Stewart platform as a robot plug-in: through the pipeline and every command.

The robot (``Stewart6Robot``) is the third implementation of the robot interface, added
without touching the pipeline. Expectations are independent of the code under test: leg
lengths |B_i - (O + p + R q_i)| from ``test_stewart6.py``'s own rotation matrices and the
preset's layout as its comments describe it, speed and acceleration limits measured on the logged
commands (read back by the ``mcap`` library's reader) and on the frames a loopback UDP
drive received, and the mirror symmetry of the layout.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motionbase.cli import main
from motionbase.errors import ConfigError
from motionbase.io.motor_output import mapping_for
from motionbase.platform.robot import load_geometry, robot_spec
from motionbase.platform.stewart6 import Stewart6Robot
from motionbase.platform.stewart6_geometry import Stewart6Geometry

sys.path.insert(0, str(Path(__file__).parent))
from drive_wire import UdpDrive, check_wire_limits, read_complete_log  # noqa: E402

# the preset's layout and the independent leg lengths, written out in test_stewart6.py
from test_stewart6 import HEIGHT, L_MAX, L_MIN, _lengths, _within  # noqa: E402

GEOMETRY = Stewart6Geometry.preset("seat")
ROBOT = Stewart6Robot(GEOMETRY)
V_MAX, A_MAX = 0.30, 3.0  # the preset's speed and acceleration limits


POSES = st.tuples(*[st.floats(-0.4, 0.4)] * 3, *[st.floats(-0.8, 0.8)] * 3).map(
    lambda t: np.array(t)
)


def _solve(target):
    cue, pose, q = np.empty(6), np.empty(6), np.empty(6)
    target = np.ascontiguousarray(target, dtype=float)
    clamped = ROBOT.solve_kernel(ROBOT.kernel_params, target, cue, pose, q)  # as the stages do
    return clamped, cue, pose, q


# --------------------------------------------------------------------------- the robot
def test_robot_interface_values():
    assert robot_spec("stewart6").robot_type is Stewart6Robot
    assert ROBOT.n == 6 and ROBOT.actuator_unit == "m"
    np.testing.assert_array_equal(ROBOT.limits.lower, L_MIN)
    np.testing.assert_array_equal(ROBOT.limits.upper, L_MAX)
    np.testing.assert_array_equal(ROBOT.limits.max_speed, V_MAX)
    np.testing.assert_array_equal(ROBOT.limits.max_accel, A_MAX)
    # parked: every actuator 1 cm above its minimum length, the platform straight below
    np.testing.assert_array_equal(ROBOT.park_angles, L_MIN + 0.01)
    np.testing.assert_allclose(_lengths(ROBOT.park_pose), L_MIN + 0.01, atol=1e-10)
    np.testing.assert_allclose(ROBOT.park_pose[[0, 1, 3, 4, 5]], 0.0, atol=1e-10)
    assert ROBOT.park_pose[2] > 0  # heave down (FRD)
    np.testing.assert_array_equal(ROBOT.park_cue, ROBOT.park_pose)
    np.testing.assert_array_equal(ROBOT.neutral_pose, np.zeros(6))


@settings(max_examples=200, deadline=None)
@given(POSES)
def test_solve_kernel_is_clamp_then_independent_leg_lengths(target):
    clamped, cue, pose, q = _solve(target)
    # the commanded pose is reachable, the lengths are its own, inside the stroke
    assert np.isfinite(pose).all() and ROBOT.reachable(pose)
    np.testing.assert_allclose(q, _lengths(pose), atol=1e-12)
    assert np.all((q >= L_MIN) & (q <= L_MAX))
    # the cue told to the washout is the pose the platform renders
    np.testing.assert_array_equal(cue, pose)
    # a reachable target is rendered as it is
    if _within(target) and np.cos(target[3]) * np.cos(target[4]) > 0:
        assert not clamped
        np.testing.assert_array_equal(pose, target)
    else:
        assert clamped


@settings(max_examples=100, deadline=None)
@given(POSES)
def test_forward_of_inverse_is_the_pose(target):
    pose = ROBOT.clamp(target)[0]
    np.testing.assert_allclose(ROBOT.forward(ROBOT.inverse(pose), guess=np.zeros(6)), pose,
                               atol=1e-8)  # fmt: skip


def test_clamp_of_non_finite_and_far_poses_is_reachable():
    for target in ([np.nan] * 6, [np.inf, 0, 0, 0, 0, 0], [1e300] * 6, [0, 0, -5, 0, 0, 0]):
        clamped, _, pose, q = _solve(np.array(target, dtype=float))
        assert clamped and np.isfinite(q).all() and ROBOT.reachable(pose)
        assert np.all((q >= L_MIN) & (q <= L_MAX))


def test_output_mapping_is_millimetres_of_length():
    m = mapping_for(ROBOT)
    assert m.unit == "mm"
    lengths = np.array([0.6, 0.65, 0.7, 0.75, 0.8, 0.9])
    np.testing.assert_allclose(m.to_drive(lengths), 1000 * lengths, rtol=1e-15)
    assert m.in_range(m.to_drive(lengths)).all()
    assert not m.in_range(m.to_drive(lengths + 0.001)).all()  # beyond the stroke: never sent
    assert not m.in_range(m.to_drive(lengths - 0.001))[0]


# --------------------------------------------------------------------------- --platform
def test_platform_names_select_the_robot(tmp_path):
    assert load_geometry("stewart6") == ("stewart6", GEOMETRY)
    assert load_geometry("seat") == ("stewart6", GEOMETRY)
    assert load_geometry(None)[0] == "rus6"
    assert load_geometry("ceart")[0] == "rus6"
    # a file says which robot it is for by its kind, or else by its fields
    path = tmp_path / "mine.toml"
    GEOMETRY.to_toml(path)
    robot, g = load_geometry(str(path))
    assert robot == "stewart6" and g.base_radius == GEOMETRY.base_radius
    text = path.read_text().replace('kind = "stewart6"\n', "")
    assert "kind" not in text
    bare = tmp_path / "bare.toml"
    bare.write_text(text)
    assert load_geometry(str(bare))[0] == "stewart6"
    # the other mode's robot: one line saying what to do
    with pytest.raises(ConfigError, match="drop --planar"):
        load_geometry("stewart6", planar=True)
    with pytest.raises(ConfigError, match="without --planar"):
        load_geometry(str(path), planar=True)
    # a preset of the other mode's robot is named as such (it used to be "unknown rrr3
    # preset 'ceart' (nor any other robot's)")
    with pytest.raises(
        ConfigError, match=r"--platform ceart: a preset of the .* \(drop --planar\)"
    ):
        load_geometry("ceart", planar=True)
    with pytest.raises(ConfigError, match=r"--platform udesc: a preset of the .* \(add --planar\)"):
        load_geometry("udesc")


def test_cli_platform_errors_are_one_line(capsys):
    assert main(["workspace", "--platform", "nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "stewart6" in err and "seat" in err


def test_workspace_prints_a_symmetric_reach(capsys, tmp_path):
    png = tmp_path / "ws.png"
    assert main(["workspace", "--platform", "stewart6", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "6-UPS" in out and "600 .. 900 mm" in out
    rows = {ln.split()[0]: ln.split()[1:3] for ln in out.splitlines() if ln.split()}
    # mirror-symmetric left to right: sway, roll and yaw reach as far either way
    for axis in ("sway", "roll", "yaw"):
        lo, hi = (float(v) for v in rows[axis])
        assert lo == hi and lo > 0
    # pure heave keeps the legs equal: closed form (the table prints mm resolution)
    d2 = 0.75**2 - HEIGHT**2
    assert float(rows["heave"][0]) == pytest.approx(math.sqrt(L_MAX**2 - d2) - HEIGHT, abs=6e-4)
    assert float(rows["heave"][1]) == pytest.approx(HEIGHT - math.sqrt(L_MIN**2 - d2), abs=6e-4)
    assert png.read_bytes()[:4] == b"\x89PNG"


# --------------------------------------------------------------------------- a whole flight
@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp("stewart6") / "F.mcap"
    # the first minute: the take-off run, rotation and climb (the whole 200 s adds a minute
    # of test time and only the cruise)
    assert (
        main(["fly", "c1723", "--platform", "stewart6", "--duration", "60", "--out", str(out)]) == 0
    )
    return out


def _metadata(path: Path) -> dict:
    from motionbase.io.mcap_source import read_metadata

    return read_metadata(path)


def _check_log_limits(messages: dict, dt: float) -> np.ndarray:
    act = messages["/platform/actuators"]
    t = np.array([m["t"] for m in act])
    q = np.array([m["angles"] for m in act])
    assert np.isfinite(q).all()
    assert np.all((q >= L_MIN) & (q <= L_MAX))
    np.testing.assert_allclose(np.diff(t), dt, rtol=1e-6)
    v = np.diff(q, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    assert np.abs(v).max() <= V_MAX * (1 + 1e-9)
    assert np.abs(a).max() <= A_MAX * (1 + 1e-6)
    return q


def test_fly_logs_lengths_within_the_stroke_and_limits(flight):
    messages = read_complete_log(flight)
    config = _metadata(flight)["pipeline_config"]
    assert config["robot"] == "stewart6"
    dt = 1.0 / config["pipeline"]["rate_hz"]
    q = _check_log_limits(messages, dt)
    # the flight moved the legs, from rest at park (one tick moves at most a dt^2) back to park
    assert np.all(np.abs(q[0] - (L_MIN + 0.01)) <= A_MAX * dt**2)
    np.testing.assert_array_equal(q[-1], L_MIN + 0.01)
    assert messages["/platform/pose"][-1]["phase"] == "parked"
    assert np.ptp(q, axis=0).min() > 0.1
    # every logged length is the logged pose's, by the independent formula
    poses = np.array([m["pose"] for m in messages["/platform/pose"]])
    for k in range(0, len(poses), 997):
        np.testing.assert_allclose(q[k], _lengths(poses[k]), atol=1e-9)


def test_the_summary_sets_each_actuator_s_range_used_against_its_stroke(tmp_path):
    """The end-of-run summary printed ``peak |length|`` per actuator: the longest length
    only, so a leg that retracted toward its 600 mm minimum and never extended past neutral
    showed 750 mm. It prints the range each actuator used in the flight now, the lowest and
    highest lengths logged in the running phase."""
    from motionbase import app

    out = tmp_path / "f.mcap"
    result = app.fly("c1723", platform="stewart6", duration_s=20.0, out=out, progress=False)
    messages = read_complete_log(out)
    running = np.array([m["phase"] == "running" for m in messages["/platform/pose"]])
    q = np.array([m["angles"] for m in messages["/platform/actuators"]])[running]
    low, high = 1000.0 * q.min(axis=0), 1000.0 * q.max(axis=0)
    leg = int(np.argmin(low))
    assert low[leg] < 700.0 < 745.0 < high[leg] < 760.0  # (this flight: leg 4, 661..750 mm)
    text = result.summary_text()
    assert "length used mm (limits)" in text
    for i in range(6):
        assert f"{i + 1:>8}  {low[i]:7.1f}..{high[i]:<7.1f} ( 600.0..900.0)" in text


def test_the_scene_draws_each_leg_at_the_logged_pose(flight):
    """``/platform/scene``: each leg is a line from its base joint to its platform joint at
    the logged pose, whose length is the logged actuator length (by the independent leg
    formula: the drawing is the mechanism the drives realise)."""
    messages = read_complete_log(flight)
    poses = {m["t"]: np.array(m["pose"]) for m in messages["/platform/pose"]}
    lengths = {m["t"]: np.array(m["angles"]) for m in messages["/platform/actuators"]}
    scenes = messages["/platform/scene"]
    assert len(scenes) > 100
    for scene in scenes[::25]:
        legs = [e for e in scene["entities"] if e["id"].startswith("leg")]
        assert [e["id"] for e in legs] == [f"leg{i + 1}" for i in range(6)]
        ends = np.array([[(v["x"], v["y"], v["z"]) for v in e["lines"][0]["points"]] for e in legs])
        np.testing.assert_allclose(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1),
                                   _lengths(poses[scene["t"]]), atol=1e-9)  # fmt: skip
        np.testing.assert_allclose(
            np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1), lengths[scene["t"]], atol=1e-6
        )


def test_replay_check_is_identical(flight, capsys):
    assert main(["replay", str(flight), "--check"]) == 0
    out = capsys.readouterr().out
    assert "check: identical to the recording" in out


def test_replay_with_other_washout_keeps_the_recorded_robot(flight, tmp_path):
    out = tmp_path / "R.mcap"
    assert main(["replay", str(flight), "--washout", "gentle", "--out", str(out)]) == 0
    assert _metadata(out)["pipeline_config"]["robot"] == "stewart6"


def test_report_runs_in_lengths(flight, tmp_path, capsys):
    folder = tmp_path / "rep"
    assert main(["report", str(flight), "--out", str(folder)]) == 0
    text = (folder / "summary.txt").read_text()
    assert "6-UPS" in text and "actuator length [mm]" in text
    rows = [
        ln.split() for ln in text.splitlines() if ln.strip()[:2] in {f"{i}:" for i in range(1, 7)}
    ]
    assert len(rows) == 6
    for row in rows:  # "1:  610.0 .. 823.1  (600.0 .. 900.0)"
        lo, hi = float(row[1]), float(row[3])
        assert 600.0 <= lo <= hi <= 900.0
        assert row[4:] == ["(600.0", "..", "900.0)"]
    assert len(list(folder.glob("*.png"))) >= 5


def test_output_to_a_udp_drive_keeps_the_limits(tmp_path):
    drive = UdpDrive()
    try:
        out = tmp_path / "O.mcap"
        argv = ["fly", "c1723", "--platform", "stewart6", "--duration", "8", "--out", str(out),
                "--output", drive.url(100)]  # fmt: skip
        assert main(argv) == 0
        drive.drain()
        frames = list(drive.frames)
    finally:
        drive.close()
    assert len(frames) > 300
    t = np.array([a for a, _ in frames])
    # the drive's frames: six lengths in mm, four decimals (the default mapping is mm)
    q = np.array([[float(x) for x in f.decode().strip().split(",")] for _, f in frames]) / 1000
    assert np.all((q >= L_MIN) & (q <= L_MAX))
    check_wire_limits(t, q, V_MAX, A_MAX, "stewart6 drive")
    np.testing.assert_allclose(q[-1], L_MIN + 0.01, atol=1e-7)  # the last frame: parked
    _check_log_limits(
        read_complete_log(out), 1.0 / _metadata(out)["pipeline_config"]["pipeline"]["rate_hz"]
    )
