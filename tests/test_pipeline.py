"""The main job end to end: JSBSim -> washout -> clamp -> IK -> safety -> MCAP, and replays."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from drive_wire import states_of_a_killed_run
from mcap.reader import make_reader

from motionbase import app
from motionbase.app import load_config
from motionbase.io.jsbsim_source import available_scripts
from motionbase.io.mcap_source import McapSource, read_messages
from motionbase.pipeline import Pipeline, PipelineConfig, run
from motionbase.platform import Rrr3, Rus6

REPO = Path(__file__).resolve().parents[1]
# the recordings kept in the repository: not fly's default outputs (recordings/<script>.mcap,
# <script>_planar.mcap), which a user's own flights leave there (of any robot, any length)
RECORDINGS = sorted(
    p
    for p in (REPO / "recordings").glob("*.mcap")
    if p.stem.removesuffix("_planar") not in available_scripts()
)


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> tuple[Path, app.JobResult]:
    out = tmp_path_factory.mktemp("fly") / "c1723.mcap"
    result = app.fly("c1723", duration_s=12.0, out=out, progress=False)
    return out, result


def _array(messages, key):
    return np.array([m[key] for m in messages], dtype=float)


def test_every_actuator_angle_is_finite_within_limits_and_speed(flight):
    path, result = flight
    msgs = read_messages(path)
    config = PipelineConfig.from_dict(McapSource(path).metadata["pipeline_config"])
    rus6 = Rus6(config.geometry)
    lo, hi = rus6.angle_limits
    angles = _array(msgs["/platform/actuators"], "angles")
    t = _array(msgs["/platform/actuators"], "t")
    assert angles.shape[1] == 6 and len(angles) > 12 * 120
    assert np.isfinite(angles).all()
    assert (angles >= lo).all() and (angles <= hi).all()
    dt = np.diff(t)
    assert np.allclose(dt, 1 / 120, rtol=1e-6)  # the fixed pipeline rate
    speed = np.diff(angles, axis=0) / dt[:, None]
    assert (np.abs(speed) <= np.asarray(config.geometry.max_speed) + 1e-6).all()
    accel = np.diff(speed, axis=0) / dt[1:, None]
    assert (np.abs(accel) <= np.asarray(config.geometry.max_accel) + 1e-3).all()
    # the run starts and ends parked
    assert np.allclose(angles[0], config.geometry.park_angle, atol=np.radians(1))
    assert np.array_equal(angles[-1], np.full(6, config.geometry.park_angle))
    assert result.summary.samples == len(angles)


def test_forward_kinematics_of_logged_angles_gives_the_logged_pose(flight):
    path, _ = flight
    msgs = read_messages(path)
    config = PipelineConfig.from_dict(McapSource(path).metadata["pipeline_config"])
    rus6 = Rus6(config.geometry)
    angles = _array(msgs["/platform/actuators"], "angles")
    poses = _array(msgs["/platform/pose"], "pose")
    recovered = rus6.forward(angles, guess=poses + 1e-3)  # not the answer itself
    assert np.isfinite(recovered).all()
    assert np.abs(recovered - poses).max() < 1e-6


def test_the_log_opens_with_the_mcap_reader_and_every_message_validates(flight):
    path, _ = flight
    counts: dict[str, int] = {}
    validators: dict[int, jsonschema.protocols.Validator] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None  # a cleanly finished file has its summary
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            if schema.id not in validators:
                # the schema stored in the file itself, not our module's copy
                doc = json.loads(schema.data)
                validators[schema.id] = jsonschema.Draft202012Validator(doc)
            validators[schema.id].validate(json.loads(message.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    for topic in (
        "/aircraft/state",
        "/washout/pose",
        "/platform/pose",
        "/platform/actuators",
        "/tf",
    ):
        assert counts.get(topic, 0) > 1000, topic
    assert counts["/health"] >= 1
    config = json.loads(meta["motionbase"]["config"])
    assert config["pipeline_config"]["robot"] == "rus6"
    assert config["source"]["script"] == "c1723"


def test_platform_cues_follow_the_aircraft(flight):
    """During the run the platform moves, and its pitch follows the forward specific force."""
    path, _ = flight
    msgs = read_messages(path)
    poses = _array(msgs["/washout/pose"], "pose")
    assert np.abs(poses).max() > 1e-3  # the flight does move the platform
    fx = np.array([m["specific_force"][0] for m in msgs["/aircraft/state"]])
    pitch = poses[: len(fx), 4]
    # tilt coordination: sustained forward specific force pitches the nose up
    assert np.corrcoef(fx, pitch)[0, 1] > 0


def test_replay_check_reproduces_a_fresh_flight_exactly(flight):
    path, _ = flight
    result = app.replay(path, check=True, progress=False)
    assert not result.failed, "\n".join(result.notes)


def test_replay_check_reports_a_difference(flight, tmp_path):
    path, _ = flight
    result = app.replay(path, check=True, washout="gentle", progress=False)
    assert result.failed
    text = "\n".join(result.notes)
    assert "DIFF" in text and "/washout/pose" in text


def test_a_stopped_replay_check_says_it_was_not_made(flight):
    """A replay with ``--check`` that a stop signal ends early has replayed a part of the
    recording: the check fails, saying why, instead of listing differences."""
    from motionbase.stopping import StopRequest

    path, _ = flight
    stop = StopRequest()
    stop.set("SIGTERM")
    result = app.replay(path, check=True, progress=False, stop=stop)
    assert result.failed
    assert "check: not made, the replay was stopped (SIGTERM)" in result.notes
    assert not any("DIFF" in note for note in result.notes)


@pytest.mark.parametrize("recording", RECORDINGS, ids=[p.name for p in RECORDINGS])
def test_every_recording_replays_identically(recording):
    result = app.replay(recording, check=True, progress=False)
    assert not result.failed, "\n".join(result.notes)


def test_recordings_cover_both_robots():
    robots = {McapSource(p).metadata["pipeline_config"]["robot"] for p in RECORDINGS}
    assert robots == {"rus6", "rrr3"}


def test_planar_flight_sends_servo_degrees_of_the_safe_angles(tmp_path):
    out = tmp_path / "planar.mcap"
    app.fly("c1723", planar=True, duration_s=6.0, out=out, progress=False)
    msgs = read_messages(out)
    config = PipelineConfig.from_dict(McapSource(out).metadata["pipeline_config"])
    rrr3 = Rrr3(config.geometry)
    angles = _array(msgs["/planar/actuators"], "angles")
    servo = np.array([m["servo_deg"] for m in msgs["/planar/actuators"]])
    assert np.isfinite(angles).all()
    assert (servo >= 0).all() and (servo <= 180).all()
    assert np.array_equal(servo, rrr3.to_servo(angles))
    poses = _array(msgs["/planar/pose"], "pose")
    # every logged pose is reachable and realises the logged angles
    diff = np.angle(np.exp(1j * (rrr3.inverse(poses) - angles)))  # angles compare modulo 2 pi
    assert np.abs(diff).max() < 1e-9


@pytest.mark.parametrize("planar", [True, False], ids=["rrr3", "rus6"])
def test_the_summary_names_the_cue_axes_the_robot_drops(tmp_path, planar):
    """The planar robot renders surge, sway and yaw; fly, stream and replay dropped the
    cue's heave, roll and pitch without a word (only report and omct said so). The 6-RUS
    renders all six: no such line."""
    result = app.fly(
        "c1723", planar=planar, duration_s=0.5, out=tmp_path / "a.mcap", progress=False
    )
    dropped = [line for line in result.summary_text().splitlines() if "does not render" in line]
    if not planar:
        assert dropped == []
        return
    (line,) = dropped
    assert "heave, roll, pitch" in line and "3-RRR" in line
    msgs = read_messages(tmp_path / "a.mcap")  # the log has what was dropped
    assert len(msgs["/washout/pose"][0]["pose"]) == 6 and len(msgs["/planar/pose"][0]["pose"]) == 3


def _fly_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "motionbase.cli", "fly", *args]


def test_a_killed_run_leaves_a_readable_log(tmp_path):
    out = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        _fly_cmd("--realtime", "--out", str(out)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30
        # wait until a few seconds of flight are on disk, then kill without warning
        while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 150_000):
            time.sleep(0.1)
        assert proc.poll() is None, "the run ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=10)
    # the log's writer process outlives the run: it finishes the file with what it was given
    states = states_of_a_killed_run(out)
    assert len(states) > 120  # more than a second survived
    t = np.array([s.t for s in states])
    assert np.all(np.diff(t) > 0)  # gap-free
    # and the replay command reads it
    result = app.replay(out, progress=False)
    assert result.summary.samples >= len(states)


@pytest.mark.parametrize("busy_wait", [False, True], ids=["sleeping", "busy-waiting"])
def test_the_loop_paces_a_realtime_flight(busy_wait):
    """A real-time flight (``fly --realtime``) is paced by the pipeline's loop alone: the
    JSBSim source never waits, yet the run takes at least its simulated length, and between
    the ticks the loop sleeps or keeps its processor. (How late the ticks come is a figure
    of the machine: ``python benchmarks/bench_load.py --paced`` prints it.)

    Sleeping or not is read from the loop thread's voluntary context switches (the times
    it gave up its processor to wait), which, unlike its share of the processor, does not
    depend on what else the machine is running."""
    from motionbase.io.jsbsim_source import JsbsimSource

    class Clocked:
        def __init__(self) -> None:
            self.arrivals: list[float] = []

        def write(self, out) -> None:
            self.arrivals.append(time.monotonic())

    sink = Clocked()
    with JsbsimSource("c1723", duration_s=2.0) as source:
        assert not getattr(source, "paces_itself", False)
        pipeline = Pipeline(load_config(rate_hz=source.rate_hz))
        wall0 = time.monotonic()
        switches0 = _voluntary_switches()
        summary = run(pipeline, source, [sink], paced=True, busy_wait=busy_wait)
        switches1 = _voluntary_switches()
    dt = pipeline.dt
    assert summary.samples == len(sink.arrivals) >= 240
    # tick k is due k periods after the first: the last came at least that long after the start
    assert sink.arrivals[-1] - wall0 >= (summary.samples - 1) * dt
    assert np.all(np.diff(sink.arrivals) > 0.0)
    if switches0 is None or switches1 is None:
        return  # not counted on this system
    switches = switches1 - switches0
    if busy_wait:
        assert switches < summary.samples / 4, switches  # it kept the processor between ticks
    else:
        assert switches > summary.samples / 4, switches  # it slept between ticks


def _voluntary_switches() -> int | None:
    """This thread's voluntary context switches so far (None where the system does not
    count them per thread)."""
    import resource

    who = getattr(resource, "RUSAGE_THREAD", None)
    return None if who is None else resource.getrusage(who).ru_nvcsw


def test_the_summary_reports_the_flight_and_the_parking_apart(flight):
    """The end-of-run peaks are the flight's (the running phase), not the park angle or the
    soft start's speed; the ramps from and back to park are reported on their own line."""
    path, result = flight
    s = result.summary
    msgs = read_messages(path)
    phases = [m["phase"] for m in msgs["/platform/pose"]]
    q = _array(msgs["/platform/actuators"], "angles")
    config = PipelineConfig.from_dict(McapSource(path).metadata["pipeline_config"])
    dt = config.dt
    park = np.full(6, config.geometry.park_angle)
    v = np.abs(np.diff(np.vstack([park, q]), axis=0)) / dt  # speeds from rest at park
    running = np.array([p == "running" for p in phases])
    starting = np.array([p == "starting" for p in phases])
    stopping = ~running & ~starting
    assert s.running_samples == running.sum() > 0
    np.testing.assert_allclose(s.peak_angle, np.abs(q[running]).max(axis=0), rtol=1e-12)
    np.testing.assert_array_equal(s.angle_range[0], q[running].min(axis=0))
    np.testing.assert_array_equal(s.angle_range[1], q[running].max(axis=0))
    np.testing.assert_allclose(s.peak_speed, v[running].max(axis=0), rtol=1e-9)
    np.testing.assert_allclose(s.start_peak_speed, v[starting].max(axis=0), rtol=1e-9)
    np.testing.assert_allclose(s.stop_peak_speed, v[stopping].max(axis=0), rtol=1e-9)
    assert s.start_s == pytest.approx(starting.sum() * dt) and s.stop_s == pytest.approx(
        stopping.sum() * dt
    )
    # not the park angle (55 deg below horizontal), which every run's ramps reach
    assert np.all(s.peak_angle < abs(config.geometry.park_angle) - np.radians(5))
    text = result.summary_text()
    assert f"flight ({s.running_samples} samples at full motion)" in text
    low, high = np.degrees(q[running].min(axis=0)), np.degrees(q[running].max(axis=0))
    assert f"{low[0]:7.1f}..{high[0]:<7.1f} (" in text
    assert "parking: start ramp" in text and "way back to park" in text


def test_cli_fly_prints_a_summary_and_writes_the_default_path(tmp_path):
    proc = subprocess.run(
        _fly_cmd("c1723", "--duration", "2"),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "recordings" / "c1723.mcap").exists()
    assert "samples" in proc.stdout and "clamped" in proc.stdout
    assert "recordings/c1723.mcap" in proc.stdout


def test_cli_user_mistakes_exit_2_with_one_line(tmp_path):
    bad = tmp_path / "notmcap.mcap"
    bad.write_text("hello")
    for args in (
        ["replay", str(bad)],
        ["replay", str(tmp_path / "missing.mcap")],
        ["fly", "no_such_script"],
        ["fly", "--platform", "no_such_preset"],
        ["fly", "--duration", "-3"],
        ["fly", "--busy-wait"],  # busy-waiting paces a --realtime flight
        ["stream", "--mavlink", "flight.tlog", "--fast", "--busy-wait"],
    ):
        proc = subprocess.run(
            [sys.executable, "-m", "motionbase.cli", *args],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 2, (args, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in proc.stderr, (args, proc.stderr)
