"""A robot plug-in written outside motionbase (``heave3_robot.py``), through every command.

The robot is the hobbyist's first platform: a plate on three vertical linear actuators (one
at the front centre, two at the rear corners) that renders heave, roll and pitch. It is
registered as a user would, at run time (``ROBOTS["heave3"] = SPEC``), with its preset in
``tests/data``, and motionbase's source names it nowhere.

Expectations are independent of the code under test: actuator lengths from the plate's
corners rotated by rotation matrices written out here, the single-axis reach from the
stroke and the lever arms by hand (``asin(half stroke / arm)``), speed and acceleration
limits measured on the frames a loopback UDP drive received.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from motionbase import app
from motionbase.cli import main
from motionbase.config import check_file_kind, read_toml
from motionbase.errors import ConfigError
from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.pipeline import PipelineConfig
from motionbase.platform.robot import ROBOTS, load_geometry, robot_spec
from motionbase.report import robot_reach

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
import heave3_robot  # noqa: E402
from drive_wire import UdpDrive  # noqa: E402

# the preset, as its file says (tests/data/heave3_garage.toml)
WHEELBASE, TRACK, L0, L_MIN, L_MAX = 0.90, 0.80, 0.475, 0.40, 0.55
V_MAX, A_MAX, PARK = 0.20, 2.0, 0.41
HALF_STROKE = 0.075  # the neutral length sits mid-stroke
# attachment points in the plate frame (origin: their centroid), m: front, rear left, right
CORNERS = np.array(
    [[2 * WHEELBASE / 3, 0, 0], [-WHEELBASE / 3, -TRACK / 2, 0], [-WHEELBASE / 3, TRACK / 2, 0]]
)


@pytest.fixture
def registered(monkeypatch):
    """The plug-in registered for one test (and gone after it, for the other tests)."""
    monkeypatch.setitem(ROBOTS, "heave3", heave3_robot.SPEC)
    return robot_spec("heave3").make(load_geometry("heave3")[1])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _lengths(z, roll, pitch):
    """Each actuator's length: the neutral length plus the height of its corner of the tilted
    plate (FRD: height is -z)."""
    corners = (_ry(pitch) @ _rx(roll) @ CORNERS.T).T + [0, 0, z]
    return L0 - corners[:, 2]


def _within(q, slack=0.0):
    """Every length within the stroke (``slack``, m: the rounding of the lengths by hand
    against the robot's own, for a pose the clamp put on the stroke's edge)."""
    return bool(np.all((q >= L_MIN - slack) & (q <= L_MAX + slack)))


#: The robot built directly (its kinematics need no registration)
ROBOT = heave3_robot.Heave3Robot(heave3_robot.Heave3Geometry.preset("garage"))
POSES = st.tuples(st.floats(-0.2, 0.2), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))


# --------------------------------------------------------------------------- the robot
def test_plugin_robot_values(registered):
    robot = registered
    assert robot.n == 3 and robot.actuator_unit == "m"
    np.testing.assert_array_equal(robot.limits.lower, L_MIN)
    np.testing.assert_array_equal(robot.limits.max_speed, V_MAX)
    np.testing.assert_allclose(robot.park_angles, PARK, atol=1e-15)
    np.testing.assert_allclose(_lengths(*robot.park_pose), PARK, atol=1e-15)
    np.testing.assert_allclose(robot.park_cue, [0, 0, L0 - PARK, 0, 0, 0], atol=1e-15)


@settings(max_examples=150, deadline=None)
@given(POSES, st.tuples(*[st.floats(-1, 1)] * 3))
def test_solve_kernel_renders_heave_roll_pitch_and_drops_the_rest(p, other):
    robot = ROBOT
    cue_in = np.array([other[0], other[1], p[0], p[1], p[2], other[2]])
    cue, pose, q = np.empty(6), np.empty(3), np.empty(3)
    clamped = robot.solve_kernel(robot.kernel_params, cue_in, cue, pose, q)
    # the commanded lengths are the pose's, by hand, inside the stroke
    np.testing.assert_allclose(q, _lengths(*pose), atol=1e-12)
    assert _within(q)
    # a target inside the stroke is rendered as it is; surge, sway, yaw never count as clamped
    if _within(_lengths(*p)):
        assert not clamped and np.array_equal(pose, p)
    else:
        assert clamped
        # scaled toward neutral as a whole, never one axis alone
        k = int(np.argmax(np.abs(p)))
        scale = pose[k] / p[k]
        assert 0 <= scale < 1
        np.testing.assert_allclose(pose, scale * np.array(p), atol=1e-15)
        # to the edge of the stroke: a little further out is past it
        assert not _within(_lengths(*(np.array(p) * (scale + 1e-9))))
    # the cue it realises: its own axes the pose, the others the cue's (no wind-up there)
    np.testing.assert_array_equal(cue[[2, 3, 4]], pose)
    np.testing.assert_array_equal(cue[[0, 1, 5]], cue_in[[0, 1, 5]])


@settings(max_examples=150, deadline=None)
@given(POSES)
def test_forward_of_inverse_is_the_pose(p):
    robot = ROBOT
    pose = robot.clamp(np.array(p))[0]
    np.testing.assert_allclose(robot.forward(robot.inverse(pose)), pose, atol=1e-12)


def test_clamp_of_far_and_non_finite_poses_is_reachable():
    robot = ROBOT
    for p in ([np.nan, 0, 0], [np.inf, 0, 0], [1e300, 1e300, -1e300], [-5, 0, 0], [0, 3, 3]):
        pose, clamped = robot.clamp(np.array(p, dtype=float))
        assert clamped and np.isfinite(pose).all() and _within(_lengths(*pose), 1e-15)
        assert robot.reachable(pose)


# --------------------------------------------------------------------------- --platform
def test_the_plugins_presets_and_files_select_it(registered, tmp_path):
    """The plug-in's presets live in its own folder (RobotSpec.preset_dir), and a file of its
    geometry says which robot it is for by its kind, though its fields (length_min,
    park_margin) are also a Stewart platform's."""
    expected = heave3_robot.Heave3Geometry.preset("garage")
    assert load_geometry("heave3") == ("heave3", expected)
    assert load_geometry("garage") == ("heave3", expected)
    path = tmp_path / "mine.toml"
    path.write_text((HERE / "data" / "heave3_garage.toml").read_text())
    assert load_geometry(str(path)) == ("heave3", expected)
    with pytest.raises(ConfigError, match="unknown rus6 preset 'nosuch'.*garage"):
        load_geometry("nosuch")


def test_a_file_named_as_a_plugin_preset_is_refused(registered, tmp_path, monkeypatch):
    """A bare name that is a file in the working directory and a plug-in's preset is
    refused, as for motionbase's own presets (before, the stray file silently won)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "garage").write_text((HERE / "data" / "heave3_garage.toml").read_text())
    with pytest.raises(ConfigError, match=r"'garage' is both a preset and a file.*\./garage"):
        load_geometry("garage")
    assert load_geometry("./garage")[0] == "heave3"


def test_a_plugin_geometry_refuses_other_files_by_name(registered):
    presets = Path(app.__file__).parent / "presets"
    washout = presets / "washout_default.toml"
    with pytest.raises(ConfigError, match=r"washout_default.toml: this is a washout .*heave3"):
        heave3_robot.Heave3Geometry.from_toml(washout)
    with pytest.raises(ConfigError, match="this is a 6-UPS Stewart platform geometry file"):
        heave3_robot.Heave3Geometry.from_toml(presets / "stewart6_seat.toml")
    # a heave3 table without kind, whose fields a Stewart platform's file also has, is its own
    table = read_toml(HERE / "data" / "heave3_garage.toml")
    del table["kind"]
    check_file_kind("mine.toml", table, "heave3")


# --------------------------------------------------------------------------- commands
def test_fly_logs_the_plugin_robot(registered, tmp_path):
    """fly: the log holds the robot's own pose (3 values) and its lengths, both valid
    against the schemas the file stores for them, which take 3 values, no more or fewer;
    the lengths are the pose's by hand unless the limiter held them; /tf is the plate
    frame of that pose, by hand."""
    out = tmp_path / "fly.mcap"
    result = app.fly("c1723", platform="heave3", duration_s=12, out=out, progress=False)
    assert not result.failed and result.actuator_unit == "m"
    log = read_messages(out)
    poses, actuators = log["/platform/pose"], log["/platform/actuators"]
    assert len(poses) == len(actuators) > 1000
    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    stored = {
        c.topic: json.loads(summary.schemas[c.schema_id].data) for c in summary.channels.values()
    }
    for topic, field in (("/platform/pose", "pose"), ("/platform/actuators", "angles")):
        for msg in log[topic][::50]:
            jsonschema.validate(msg, stored[topic])
        for wrong in (2, 6):  # the 6-DOF platforms' six is not this robot's
            with pytest.raises(jsonschema.ValidationError):
                jsonschema.validate({**log[topic][0], field: [0.0] * wrong}, stored[topic])
    q = np.array([m["angles"] for m in actuators])
    assert _within(q)
    free = [i for i, m in enumerate(poses) if not m["rate_limited"] and not m["held"]]
    by_hand = np.array([_lengths(*poses[i]["pose"]) for i in free])
    np.testing.assert_allclose(q[free], by_hand, atol=1e-12)
    # /tf: the plate frame at its neutral origin plus the heave, turned by roll and pitch
    tf = [m for m in log["/tf"] if m["child_frame_id"] == "platform"]
    assert len(tf) == len(poses)
    for msg, pose in list(zip(tf, poses, strict=True))[::50]:
        z, roll, pitch = pose["pose"]
        x = msg["translation"]
        np.testing.assert_allclose([x["x"], x["y"], x["z"]], [0, 0, z - L0], atol=1e-12)
        cr, sr, cp, sp = (
            math.cos(roll / 2),
            math.sin(roll / 2),
            math.cos(pitch / 2),
            math.sin(pitch / 2),
        )
        q = msg["rotation"]
        np.testing.assert_allclose(
            [q["w"], q["x"], q["y"], q["z"]], [cr * cp, sr * cp, cr * sp, -sr * sp], atol=1e-12
        )
    assert log["/platform/scene"]


def test_replay_check_report_workspace_omct_through_the_cli(registered, tmp_path, capsys):
    rec = tmp_path / "fly.mcap"
    assert main(["fly", "c1723", "--platform", "heave3", "--duration", "8", "--out", str(rec)]) == 0
    assert read_metadata(rec)["pipeline_config"]["robot"] == "heave3"
    again = tmp_path / "again.mcap"
    assert main(["replay", str(rec), "--out", str(again), "--check"]) == 0
    assert "check: identical to the recording" in capsys.readouterr().out
    assert main(["report", str(rec), "--out", str(tmp_path / "report")]) == 0
    summary = (tmp_path / "report" / "summary.txt").read_text()
    assert "reach (+) [m | deg]" in summary and "n/a" in summary
    assert main(["workspace", "--platform", "heave3"]) == 0
    assert "heave        0.075      0.075" in capsys.readouterr().out
    assert main(["omct", "--platform", "garage", "--out", str(tmp_path / "omct")]) == 0
    assert (tmp_path / "omct" / "omct.json").is_file()


def test_tune_refuses_a_robot_that_lacks_axes_by_name(registered, tmp_path, capsys):
    """The tuner scores the cue on all six axes against the robot's reach: a robot that
    drops three of them is refused, naming them (it failed deep in the scoring, on the
    robot pose's shape)."""
    out = tmp_path / "tuned.toml"
    args = ["tune", "--platform", "heave3", "--scripts", "c1723@0:20", "--holdout", "none"]
    assert main([*args, "--budget", "2", "--workers", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "does not render surge, sway, yaw" in err
    assert not out.exists()


def test_reach_is_in_cue_terms(registered):
    """The single-axis reach of the plug-in, by hand: heave half the stroke, roll and pitch
    the angle that takes one corner half the stroke up (its lever arm: half the track, two
    thirds of the wheelbase), surge, sway and yaw nothing."""
    reach = robot_reach(registered)
    expected = [0, 0, HALF_STROKE, math.asin(HALF_STROKE / (TRACK / 2))]
    expected += [math.asin(HALF_STROKE / (2 * WHEELBASE / 3)), 0]
    np.testing.assert_allclose(reach[1], expected, atol=1e-5)
    np.testing.assert_allclose(reach[0], -np.array(expected), atol=1e-5)


def test_a_plugin_with_read_only_kernel_params_runs(registered, monkeypatch):
    """A plug-in that freezes its packed parameters (the docs: "do not change them") and
    does not call the shipped robots' private _finish() still drives the pipeline."""

    class Frozen(heave3_robot.Heave3Robot):
        def __init__(self, geometry):
            super().__init__(geometry)
            self.kernel_params.setflags(write=False)

    monkeypatch.setattr(heave3_robot, "Frozen", Frozen, raising=False)
    spec = heave3_robot.SPEC
    frozen = type(spec)(**{**spec.__dict__, "robot_class": "heave3_robot:Frozen"})
    monkeypatch.setitem(ROBOTS, "heave3", frozen)
    config = PipelineConfig.from_dict(
        {**_config_dict(registered), "robot": "heave3"}, source="test"
    )
    from motionbase.pipeline import Pipeline

    pipeline = Pipeline(config)
    assert _within(pipeline.command)


class _CueOf3(heave3_robot.Heave3Robot):  # the robot pose given as the park cue
    def __init__(self, geometry):
        super().__init__(geometry)
        self.park_cue = self.park_pose


class _ParkPastTheStop(heave3_robot.Heave3Robot):
    def __init__(self, geometry):
        super().__init__(geometry)
        self.park_angles = np.full(3, L_MIN - 0.01)


class _LimitsOf6(heave3_robot.Heave3Robot):
    def __init__(self, geometry):
        super().__init__(geometry)
        self.limits = type(self.limits).broadcast(6, L_MIN, L_MAX, V_MAX, A_MAX)


@pytest.mark.parametrize(
    "cls, needle",
    [
        (_CueOf3, "park_cue has 3 values, expected 6: the cue pose"),
        (_ParkPastTheStop, "park_angles [0.39, 0.39, 0.39] are outside the actuator limits"),
        (_LimitsOf6, "limits.lower has 6 values, expected 3"),
    ],
    ids=["park cue of 3", "park past the stop", "limits of 6"],
)
def test_a_plugin_mistake_is_one_line_naming_it(registered, monkeypatch, tmp_path, cls, needle):
    """A robot class whose attributes the pipeline cannot use is refused when it is made,
    naming the plug-in: before, a park cue of the robot pose's 3 values ran from a wrong
    park (heave read as surge), a park past the stop held every park command, and limits
    of the wrong size were a traceback."""
    monkeypatch.setattr(heave3_robot, cls.__name__, cls, raising=False)
    spec = heave3_robot.SPEC
    wrong = type(spec)(**{**spec.__dict__, "robot_class": f"heave3_robot:{cls.__name__}"})
    monkeypatch.setitem(ROBOTS, "heave3", wrong)
    out = tmp_path / "x.mcap"
    with pytest.raises(ConfigError) as err:
        app.fly("c1723", platform="heave3", duration_s=1, out=out, progress=False)
    assert f"robot 'heave3' (heave3_robot:{cls.__name__}): {needle}" in str(err.value)
    assert not out.exists()


def _config_dict(robot):
    from motionbase.washout import WashoutParams

    return PipelineConfig(
        robot="heave3", geometry=robot.geometry, cueing_params=WashoutParams.preset("default")
    ).to_dict()


def test_a_recording_of_an_unregistered_robot_says_to_register_it(registered, tmp_path):
    data = _config_dict(registered)
    ROBOTS.pop("heave3")
    with pytest.raises(ConfigError, match=r"got 'heave3' \(a robot plug-in's\? register it"):
        PipelineConfig.from_dict(data, source="rec.mcap: metadata")


# --------------------------------------------------------------------------- drives
def _mm_frames(drive):
    """The lengths of every frame the drive received, m."""
    return np.array([np.array(f.decode().split(","), dtype=float) / 1000 for _, f in drive.frames])


def test_output_test_and_fly_output_to_a_udp_drive(tmp_path):
    """The user's way: a script registers the plug-in and calls motionbase.cli.main();
    the drive (three lengths in mm on loopback UDP) gets frames inside the stroke that end
    parked: the wiring check sweeps each motor to neutral +- 20 mm, the others at neutral;
    the flight's logged commands keep the speed and acceleration limits (measured on the
    log's source times, not on arrival times)."""
    script = tmp_path / "mb.py"
    script.write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(HERE)!r})\n"
        "import heave3_robot\n"
        "heave3_robot.register()\n"
        "from motionbase.cli import main\n"
        "sys.exit(main())\n"
    )
    src = str(Path(app.__file__).parents[1])
    env = {"PYTHONPATH": src, "PATH": "/usr/bin:/bin"}
    log = tmp_path / "o.mcap"
    frames = []
    for args in (
        ["output", "--test", "URL", "--platform", "heave3", "--range-mm", "20",
         "--speed-mm-s", "100"],
        ["fly", "c1723", "--platform", "heave3", "--duration", "4", "--realtime", "--output", "URL",
         "--out", str(log)],
    ):  # fmt: skip
        drive = UdpDrive(n=3)
        try:
            run = [a.replace("URL", drive.url(100)) for a in args]
            done = subprocess.run(
                [sys.executable, str(script), *run], env=env, capture_output=True, text=True,
                timeout=300,
            )  # fmt: skip
            assert done.returncode == 0, done.stderr
            q = _mm_frames(drive)
        finally:
            drive.close()
        assert len(q) > 100 and _within(q)
        np.testing.assert_allclose(q[-1], PARK, atol=1e-7)  # parked at the end
        frames.append(q)
    sweep = frames[0]
    for i in range(3):
        others = np.delete(sweep, i, axis=1)
        for end in (L0 - 0.02, L0 + 0.02):
            held = np.abs(sweep[:, i] - end) < 1e-7
            assert held.any() and np.allclose(others[held], L0, atol=1e-7), (i, end)
    msgs = read_messages(log)["/platform/actuators"]
    t = np.array([m["t"] for m in msgs])
    q = np.array([m["angles"] for m in msgs])
    v = np.diff(q, axis=0) / np.diff(t)[:, None]
    a = np.diff(v, axis=0) / np.diff(t)[1:, None]
    assert np.abs(v).max() <= V_MAX * (1 + 1e-9) and np.abs(a).max() <= A_MAX * (1 + 1e-6)


def test_a_stop_signal_while_the_user_s_script_imports_stops_the_job_as_it_starts(tmp_path):
    """The README's way to begin the user's script: ``catch_early_stops()`` first. A SIGTERM
    that comes while it imports the plug-in (numpy, numba) stops the wiring check as it
    starts: the drive gets park alone, the command says so and exits 0. Without that line
    the signal killed the process (a Ctrl-C: a traceback)."""
    script = tmp_path / "mb.py"
    script.write_text(
        "import os, signal, sys\n"
        "from motionbase.stopping import catch_early_stops\n"
        "catch_early_stops()\n"
        "os.kill(os.getpid(), signal.SIGTERM)  # (as if it came now, while importing)\n"
        f"sys.path.insert(0, {str(HERE)!r})\n"
        "import heave3_robot\n"
        "heave3_robot.register()\n"
        "from motionbase.cli import main\n"
        "sys.exit(main())\n"
    )
    env = {"PYTHONPATH": str(Path(app.__file__).parents[1]), "PATH": "/usr/bin:/bin"}
    drive = UdpDrive(n=3)
    try:
        args = ["output", "--test", drive.url(100), "--platform", "heave3"]
        done = subprocess.run(
            [sys.executable, str(script), *args], env=env, capture_output=True, text=True,
            timeout=300,
        )  # fmt: skip
        drive.drain()
        q = _mm_frames(drive)
    finally:
        drive.close()
    assert done.returncode == 0, done.stderr
    assert "stopped by SIGTERM" in done.stdout and "Traceback" not in done.stderr
    assert len(q) >= 1 and np.all(np.abs(q - PARK) < 1e-7)


# --------------------------------------------------------------------------- the README
def _readme_robot() -> str:
    """The code block of the README's "Adding a robot" example."""
    text = (HERE.parent / "README.md").read_text()
    start = text.index("Adding a robot takes")
    block = text[text.index("```python\n", start) + len("```python\n") :]
    return block[: block.index("```\n")]


def test_the_readme_robot_example_runs(tmp_path, monkeypatch, capsys):
    """The README's example, saved as my_robot.py with its preset beside it, imported (which
    registers it) and flown, replayed with --check; its lengths, forward kinematics, clamp
    and reach as this file computes them by hand."""
    (tmp_path / "my_robot.py").write_text(_readme_robot())
    (tmp_path / "presets").mkdir()
    preset = (HERE / "data" / "heave3_garage.toml").read_text()
    preset = "\n".join(x for x in preset.splitlines() if not x.startswith("park_margin"))
    (tmp_path / "presets" / "heave3_garage.toml").write_text(preset)
    monkeypatch.setitem(ROBOTS, "heave3", heave3_robot.SPEC)  # (restored after the test)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "my_robot", raising=False)
    import my_robot

    assert ROBOTS["heave3"].robot_class == "my_robot:Heave3Robot"
    robot = robot_spec("heave3").make(load_geometry("garage")[1])
    assert isinstance(robot, my_robot.Heave3Robot)
    rng = np.random.default_rng(7)
    poses = rng.uniform([-0.2, -0.5, -0.5], [0.2, 0.5, 0.5], (300, 3))
    np.testing.assert_allclose(robot.inverse(poses), [_lengths(*p) for p in poses], atol=1e-12)
    safe, moved = robot.clamp(poses)
    assert all(_within(_lengths(*p), 1e-15) for p in safe) and robot.reachable(safe).all()
    assert np.array_equal(moved, [not _within(_lengths(*p)) for p in poses])
    np.testing.assert_allclose(robot.forward(robot.inverse(safe)), safe, atol=1e-12)
    pose, moved = robot.clamp(np.array([np.nan, 0.0, 0.0]))
    assert moved and np.array_equal(pose, np.zeros(3))
    np.testing.assert_allclose(robot_reach(robot), robot_reach(ROBOT), atol=1e-5)
    rec = tmp_path / "fly.mcap"
    assert main(["fly", "c1723", "--platform", "heave3", "--duration", "6", "--out", str(rec)]) == 0
    assert main(["replay", str(rec), "--out", str(tmp_path / "again.mcap"), "--check"]) == 0
    assert "check: identical to the recording" in capsys.readouterr().out
