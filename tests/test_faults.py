"""Fault injection end to end: a failing source, a vanishing serial port, a full disk, an
unwritable output, SIGTERM and SIGKILL, and configuration mistakes through the CLI.

In every case: no actuator command outside the limits (checked on the log), a clear one-line
message (exit status 2 for what a user can fix), and a log that reads back up to the fault.
"""

from __future__ import annotations

import math
import os
import re
import resource
import shutil
import signal
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from drive_wire import UdpDrive, check_wire_limits, read_complete_log, states_of_a_killed_run
from pty_board import Board

from motionbase import app, cli
from motionbase.errors import SinkError, SourceError
from motionbase.io.mcap_log import McapLogger
from motionbase.io.mcap_source import McapSource, read_messages
from motionbase.io.serial_link import ServoSerialSink
from motionbase.pipeline import Pipeline, PipelineConfig, run
from motionbase.platform import Rus6Geometry
from motionbase.safety import MAX_SAMPLE_TIME_S
from motionbase.state import AircraftState
from motionbase.washout.classical import ClassicalWashout

G = 9.80665
SPEED_TOL = 1e-9  # rad/s, rounding only
ACCEL_TOL = 1e-6  # rad/s^2


def check_logged_commands(path: Path) -> tuple[PipelineConfig, np.ndarray, dict]:
    """Every logged actuator command is finite, in limits and in speed/acceleration limits."""
    msgs = read_messages(path)
    with McapSource(path) as src:
        config = PipelineConfig.from_dict(src.metadata["pipeline_config"])
    pipeline = Pipeline(config)  # the limits and park exactly as the run had them
    lim = pipeline.robot.limits
    topic = "/planar/actuators" if config.robot == "rrr3" else "/platform/actuators"
    q = np.array([m["angles"] for m in msgs[topic]], dtype=float)
    t = np.array([m["t"] for m in msgs[topic]], dtype=float)
    assert len(q) > 0
    assert np.isfinite(q).all()
    assert (q >= lim.lower).all() and (q <= lim.upper).all()
    park = pipeline.robot.park_angles
    q0 = np.vstack([park, park, q])
    assert np.allclose(np.diff(t), config.dt, rtol=1e-6)  # a gap-free, fixed-rate record
    v = np.diff(q0, axis=0) / config.dt
    assert (np.abs(v) - lim.max_speed).max() <= SPEED_TOL
    a = np.diff(v, axis=0) / config.dt
    assert (np.abs(a) - lim.max_accel).max() <= ACCEL_TOL
    return config, q, msgs


def park_angles(config: PipelineConfig) -> np.ndarray:
    return Pipeline(config).robot.park_angles


def cli_run(*args: str, cwd: Path, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "motionbase.cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        **kw,
    )


def assert_one_line_error(proc_or_text, *needles: str) -> str:
    text = proc_or_text if isinstance(proc_or_text, str) else proc_or_text.stderr
    assert "Traceback" not in text, text
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, text
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


# --------------------------------------------------------------------------- a failing source


class FailingSource:
    """A fake source: strong manoeuvring for ``n`` samples, then it raises ``error``."""

    rate_hz = 120.0
    duration_s = None

    def __init__(self, n: int, error: Exception) -> None:
        self.n = n
        self.error = error
        self.fresh = True

    def describe(self) -> dict:
        return {"kind": "failing test source", "n": self.n}

    def __iter__(self):
        dt = 1.0 / self.rate_hz
        for i in range(self.n):
            t = i * dt
            s = math.sin(2 * math.pi * 0.7 * t)
            yield AircraftState(t, [25 * s, 20 * s, -G + 10 * s], [3 * s, 3 * s, 3 * s])
        raise self.error


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_a_source_that_raises_mid_run_parks_and_reports_one_clear_error(tmp_path, planar):
    out = tmp_path / "fail.mcap"
    config = app.load_config(planar=planar)
    n = 600  # 5 s: in full motion when it fails
    source = FailingSource(n, SourceError("MAVLink link lost: no heartbeat for 3 s"))
    with pytest.raises(SourceError) as info:
        app._drive("test", config, source, out, paced=False, progress=False)
    message = str(info.value)
    assert "\n" not in message
    assert "MAVLink link lost" in message and "parked" in message
    config, q, msgs = check_logged_commands(out)
    with McapSource(out) as src:
        assert not src.truncated  # the log was finished properly
    assert len(msgs["/aircraft/state"]) == n  # every sample before the fault is logged
    assert len(q) > n  # and the park ramp after it
    assert np.array_equal(q[-1], park_angles(config))
    assert msgs["/health"][-1]["samples"] == len(q)


def test_a_source_bug_parks_then_propagates_unchanged(tmp_path):
    out = tmp_path / "bug.mcap"
    source = FailingSource(300, ZeroDivisionError("a bug in a source"))
    with pytest.raises(ZeroDivisionError):
        app._drive("test", app.load_config(), source, out, paced=False, progress=False)
    config, q, _ = check_logged_commands(out)
    assert np.array_equal(q[-1], park_angles(config))


class BuggyCue(ClassicalWashout):
    """A cueing plug-in with a bug: the classical washout for ``n`` ticks, then it raises
    on every call, as a plug-in's bug would."""

    name = "test_buggy"
    step_kernel = None  # the pipeline calls advance (a Python plug-in)

    def __init__(self, params, dt: float, n: int) -> None:
        super().__init__(params, dt)
        self.n = n
        self.calls = 0

    def advance(self, u: np.ndarray, out: np.ndarray) -> bool:
        self.calls += 1
        if self.calls > self.n:
            out[:] = np.nan  # half-written, as a failing computation may leave it
            raise ZeroDivisionError("a bug in a cueing plug-in")
        return super().advance(u, out)


@pytest.mark.parametrize("when", ["start", "flight"])
def test_a_cueing_bug_parks_softly_without_calling_it_again_then_propagates(when):
    """The pipeline's own step raising (here its cueing plug-in) ends the run like a
    failing source: the platform goes back to park at the soft-start pace from the last
    cue pose, through the remaining stages (the plug-in is not called again), and then
    the exception propagates unchanged."""
    config = app.load_config()
    n = 120 if when == "start" else 600  # 1 s into the 2 s soft start, or in full motion
    cue = BuggyCue(config.make_cueing().params, config.dt, n)
    pipeline = Pipeline(config, cueing=cue)
    outputs = []

    class ListSink:
        def write(self, out):
            outputs.append(out)

    with pytest.raises(ZeroDivisionError):
        run(pipeline, FailingSource(2 * n, RuntimeError("unreached")), [ListSink()])
    assert cue.calls == n + 1  # the park ramp did not call it again
    q = np.array([o.angles for o in outputs])
    lim = pipeline.robot.limits
    park = pipeline.robot.park_angles
    assert np.isfinite(q).all() and (q >= lim.lower).all() and (q <= lim.upper).all()
    assert np.array_equal(q[-1], park) and outputs[-1].phase == "parked"
    after = outputs[n:]
    assert len(after) * config.dt >= 0.5 * config.soft_start_s  # a soft ramp, not a jump
    # the held cue stops at once, so the limiter brakes the motion it had (at most the
    # time to stop from full speed); after that the blend alone paces the way to park
    brake_ticks = math.ceil(float(np.max(lim.max_speed / lim.max_accel)) / config.dt) + 1
    limited = [i for i, o in enumerate(after) if o.rate_limited]
    assert max(limited, default=0) < brake_ticks, limited
    v = np.diff(np.vstack([park, park, q]), axis=0) / config.dt
    assert (np.abs(v) - lim.max_speed).max() <= SPEED_TOL
    a = np.diff(v, axis=0) / config.dt
    assert (np.abs(a) - lim.max_accel).max() <= ACCEL_TOL


LATE_BUG_SCRIPT = """
import sys

from motionbase.__main__ import main
from motionbase.washout.classical import ClassicalWashout
from motionbase.washout.cueing import CUEINGS, CueingSpec, register_cueing


class LateBug(ClassicalWashout):
    \"\"\"The classical washout, until call {fail_after} since its reset: then it raises.\"\"\"

    name = "late_bug"
    step_kernel = None  # the pipeline calls advance
    calls = 0

    def reset(self):
        super().reset()
        self.calls = 0

    def advance(self, u, out):
        self.calls += 1
        if self.calls > {fail_after}:
            raise ZeroDivisionError("a bug in a cueing plug-in")
        return super().advance(u, out)


classical = CUEINGS["classical"]
register_cueing(CueingSpec("late_bug", LateBug, classical.params_class, classical.preset_kind))
sys.exit(main())
"""


def test_a_cueing_bug_that_shows_only_in_the_park_ramp_still_parks_the_drive(tmp_path):
    """A cueing plug-in whose bug shows only once the flight has ended (here: on its call
    half a second into the ramp back to park; the flight is 3 s at 120 Hz, 360 calls) is
    handled as one that fails in flight: the ramp goes on without it and parks the drive,
    then the exception propagates unchanged. The park ramp used to call the plug-in
    unguarded: the exception left the loop at once, and the drive stayed where the ramp
    was (50 deg from park), its last frame not the park command. Run as a script that
    registers the plug-in and calls the ``motionbase`` command, as the README shows; a
    loopback UDP drive."""
    script = tmp_path / "late_bug.py"
    script.write_text(LATE_BUG_SCRIPT.format(fail_after=3 * 120 + 60))
    drive, out = UdpDrive(), tmp_path / "bug.mcap"
    cmd = [sys.executable, str(script), "fly", "c1723", "--duration", "3", "--cueing"]
    cmd += ["late_bug", "--out", str(out), "--output", drive.url()]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        drive.drain()
    finally:
        drive.close()
    assert proc.returncode == 1, proc.stderr  # a bug: raised unchanged (a traceback)
    assert proc.stderr.rstrip().endswith("ZeroDivisionError: a bug in a cueing plug-in")
    geometry = Rus6Geometry.preset("ceart")
    t, q = drive.angles()
    assert np.abs(q - geometry.park_angle).max() > math.radians(20)  # it flew
    np.testing.assert_allclose(q[-1], geometry.park_angle, atol=math.radians(1e-4))
    check_wire_limits(t, q, geometry.max_speed, geometry.max_accel, "late cueing bug")
    log = read_complete_log(out)
    assert len(log["/aircraft/state"]) == 360
    assert log["/platform/pose"][-1]["phase"] == "parked"
    assert log["/health"][-1]["estops"] == 0  # a soft stop: the plug-in's bug is no E-stop
    assert np.array_equal(log["/platform/actuators"][-1]["angles"], np.full(6, geometry.park_angle))


# --------------------------------------------------------------------------- serial port


class PacedSource(FailingSource):
    """Samples about every 2 ms of wall time, so serial frames (50 Hz) go out."""

    def __iter__(self):
        dt = 1.0 / self.rate_hz
        for i in range(self.n):
            time.sleep(0.002)
            t = i * dt
            s = math.sin(2 * math.pi * 0.7 * t)
            yield AircraftState(t, [25 * s, 20 * s, -G], [3 * s, 3 * s, 3 * s])


def test_a_vanishing_serial_port_parks_the_logged_platform_and_says_so(tmp_path):
    board = Board()
    out = tmp_path / "serial.mcap"
    config = app.load_config(planar=True)
    vanish_at = 400
    count = 0

    def on_output(_o) -> None:
        nonlocal count
        count += 1
        if count == vanish_at:
            board.close()

    sink = ServoSerialSink(board.path, ready_timeout_s=2.0)
    try:
        with pytest.raises(SinkError) as info:
            app._drive(
                "test",
                config,
                PacedSource(1200, RuntimeError("unused")),
                out,
                paced=False,
                progress=False,
                extra_sinks=[sink],
                on_output=on_output,
            )
    finally:
        board.close()
    message = str(info.value)
    assert "vanished" in message and "parked" in message and "\n" not in message
    assert sink.frames_sent > 0
    config, q, msgs = check_logged_commands(out)
    assert np.array_equal(q[-1], park_angles(config))
    # it stopped soon after the port went (not at the end of the source)
    assert len(msgs["/aircraft/state"]) < 1200
    with McapSource(out) as src:
        assert not src.truncated


# --------------------------------------------------------------------------- disk and output


def test_a_full_disk_ends_with_one_line_and_a_log_readable_up_to_the_fault(tmp_path):
    out = tmp_path / "full.mcap"
    limit = 600_000  # bytes: a few seconds of flight, then the "disk" is full

    def small_disk() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    proc = cli_run("fly", "c1723", "--out", str(out), cwd=tmp_path, preexec_fn=small_disk)
    assert proc.returncode == 2, proc.stderr
    line = assert_one_line_error(proc, str(out), "cannot write the MCAP log")
    assert "disk full" in line or "too large" in line.lower()
    assert out.stat().st_size <= limit
    with McapSource(out) as src:
        states = list(src)
        assert src.truncated
    assert len(states) > 120  # more than a second survived
    check_logged_commands(out)


class ActingSink:
    """A test sink that does :meth:`act` at its ``n``-th tick and nothing else."""

    label = "acting-test-sink"

    def __init__(self, n: int) -> None:
        self.n = n

    def __enter__(self) -> ActingSink:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def write(self, out) -> None:
        self.n -= 1
        if self.n == 0:
            self.act()

    def act(self) -> None:
        raise NotImplementedError


class BrokenSink(ActingSink):
    """A sink with a bug that is not ours: it raises a plain ``struct.error`` at tick ``n``."""

    label = "broken-test-sink"

    def act(self) -> None:
        struct.pack("<Q", 2**64)  # what an unrepresentable log time did to the log


def test_any_failing_sink_parks_through_the_others_then_one_clear_error(tmp_path):
    out = tmp_path / "broken.mcap"
    config = app.load_config()
    drive = UdpDrive()
    try:
        with pytest.raises(SinkError) as info:
            app._drive(
                "test", config, FailingSource(900, RuntimeError("unused")), out, paced=False,
                progress=False, extra_sinks=[BrokenSink(360)], outputs=[drive.url()],
            )  # fmt: skip
        drive.drain()
    finally:
        drive.close()
    message = str(info.value)
    assert "\n" not in message
    assert "broken-test-sink" in message and "parked" in message and "error" in message
    assert isinstance(info.value.__cause__, struct.error)
    t, q = drive.angles()
    np.testing.assert_allclose(q[-1], park_angles(config), atol=math.radians(1e-4))
    check_wire_limits(t, q, config.geometry.max_speed, config.geometry.max_accel)
    msgs = read_complete_log(out)  # the log, a sink too, was closed properly
    assert len(msgs["/aircraft/state"]) < 900  # it stopped at the failure, not at the end
    config, q_log, _ = check_logged_commands(out)
    assert np.array_equal(q_log[-1], park_angles(config))


class WriterKiller(ActingSink):
    """A sink that kills this process's MCAP writer processes (``kill -9``) at tick ``n``:
    the log's writer vanishes mid-run, as after an out-of-memory kill."""

    label = "writer-killer"

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self.killed: list[int] = []

    def act(self) -> None:
        for task in Path("/proc/self/task").iterdir():
            for pid in (task / "children").read_text().split():
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
                if b"log_writer.py" in cmdline:
                    os.kill(int(pid), signal.SIGKILL)
                    self.killed.append(int(pid))


def test_a_vanished_log_writer_parks_through_the_drives_then_one_clear_error(tmp_path):
    out = tmp_path / "vanished.mcap"
    config = app.load_config()
    drive = UdpDrive()
    killer = WriterKiller(360)
    try:
        with pytest.raises(SinkError) as info:
            app._drive(
                "test", config, FailingSource(900, RuntimeError("unused")), out, paced=False,
                progress=False, extra_sinks=[killer], outputs=[drive.url()],
            )  # fmt: skip
        drive.drain()
    finally:
        drive.close()
    assert len(killer.killed) == 1
    message = str(info.value)
    assert "\n" not in message
    assert str(out) in message and "writer process" in message and "parked" in message
    t, q = drive.angles()
    np.testing.assert_allclose(q[-1], park_angles(config), atol=math.radians(1e-4))
    check_wire_limits(t, q, config.geometry.max_speed, config.geometry.max_accel)
    with McapSource(out) as src:  # readable up to the last chunk the writer finished
        states = list(src)
        assert src.truncated
    assert len(states) < 360  # (how much is on disk depends on how far the writer had got)


@pytest.mark.parametrize("real_time", [True, False], ids=["real time", "offline"])
def test_a_stopped_log_writer_gives_one_line_not_a_hang(tmp_path, real_time):
    """``fly --output URL``, its log's writer process stopped (SIGSTOP: as a disk that does
    not answer holds it), then Ctrl-C: the drive parks within the limits, and the run ends
    with one line naming the writer, exit status 2. It used to park and then wait for the
    stopped writer forever to close the log, deaf to SIGINT and SIGTERM alike (only
    SIGKILL ended it). Once it runs again the writer finishes the file on its own. So does
    an offline ``fly`` (no drive; 600 s of flight, as fast as it goes), which waits for the
    writer's pipe: it waited forever too, deaf to SIGINT and SIGTERM."""
    from test_signals import wait_for

    drive, out = UdpDrive(), tmp_path / "stalled.mcap"
    cmd = [sys.executable, "-m", "motionbase", "fly", "c1723", "--out", str(out)]
    cmd += ["--duration", "60", "--output", drive.url()] if real_time else ["--duration", "600"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    writers: list[int] = []
    try:
        if real_time:
            wait_for(lambda: drive.count() >= 250, proc, "motion")  # 2.5 s of frames at 100 Hz
        else:  # in flight: seconds of it on disk
            wait_for(lambda: out.exists() and out.stat().st_size > 100_000, proc, "the log")
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
        writers = [int(pid) for pid in children]
        assert len(writers) == 1  # the log's writer process, the run's only child
        os.kill(writers[0], signal.SIGSTOP)
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=60)  # a watchdog against the hang, not a timing check
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            pytest.fail("the run never ended once parked (it waited for the stopped writer)")
    finally:
        for pid in writers:  # the writer holds the run's stdout and stderr too
            os.kill(pid, signal.SIGCONT)
        if proc.poll() is None:
            proc.kill()
        stdout, stderr = proc.communicate(timeout=60)
        drive.drain()
        drive.close()
    assert proc.returncode == 2, (stdout, stderr)
    assert_one_line_error(stderr, str(out), "writer process", "readable up to")
    if real_time:
        geometry = Rus6Geometry.preset("ceart")
        t, q = drive.angles()
        np.testing.assert_allclose(q[-1], geometry.park_angle, atol=math.radians(1e-4))
        check_wire_limits(t, q, geometry.max_speed, geometry.max_accel, "a stalled log")
    assert len(states_of_a_killed_run(out)) > 200  # the writer, continued, finished it


def test_a_log_whose_folder_vanishes_mid_run_is_said_to_be_gone_and_exits_1(tmp_path):
    """``fly --output URL --out FOLDER/x.mcap`` with FOLDER removed mid-flight: the writer
    goes on writing a file that no longer has a name, so nothing of the run is kept. The
    flight goes on and parks the drive within the limits, then one warning line says the
    log is gone, the summary does not give it a size, and the exit status is 1 (the run was
    fine, its log was lost). The summary used to say ``log: .../x.mcap (0.00 MB)`` and the
    command exited 0."""
    folder = tmp_path / "gone"
    out = folder / "x.mcap"
    drive = UdpDrive()
    cmd = [sys.executable, "-m", "motionbase.cli", "fly", "c1723", "--duration", "4"]
    cmd += ["--output", drive.url(), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while drive.count() < 300:  # 3 s of frames at 100 Hz: flying, the log being written
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the drive got no frames"
            time.sleep(0.01)
        assert out.exists()
        shutil.rmtree(folder)
        stdout, stderr = proc.communicate(timeout=120)
        drive.drain()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        drive.close()
    assert proc.returncode == 1, (proc.returncode, stdout, stderr)
    line = assert_one_line_error(stderr, "WARNING", str(out), "gone")
    assert "parked" in line
    (log_line,) = [ln for ln in stdout.splitlines() if ln.startswith("log: ")]
    assert str(out) in log_line and "gone" in log_line and "MB" not in log_line, log_line
    assert "stopped by duration" in stdout  # the flight itself ran to its end
    config = app.load_config()
    t, q = drive.angles()
    np.testing.assert_allclose(q[-1], park_angles(config), atol=math.radians(1e-4))
    check_wire_limits(t, q, config.geometry.max_speed, config.geometry.max_accel)
    assert not folder.exists()


def test_dev_full_and_an_uncreatable_folder_are_one_line_errors(tmp_path):
    proc = cli_run("fly", "--duration", "1", "--out", "/dev/full", cwd=tmp_path)
    assert proc.returncode == 2
    assert_one_line_error(proc, "/dev/full", "No space left")
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    bad = blocker / "sub" / "x.mcap"
    proc = cli_run("fly", "--duration", "1", "--out", str(bad), cwd=tmp_path)
    assert proc.returncode == 2
    assert_one_line_error(proc, str(bad), "--out")


# --------------------------------------------------------------------------- configuration


PRESETS = Path(app.__file__).parent / "presets"


def _edited(tmp_path: Path, preset: str, name: str, pattern: str, repl: str) -> Path:
    text = (PRESETS / preset).read_text()
    new, n = re.subn(pattern, repl, text, count=1, flags=re.M)
    assert n == 1, pattern
    path = tmp_path / name
    path.write_text(new)
    return path


FIX_WORDS = ("fix", "choose", "check", "remove", "add", "use", "give", "see --help")


def _case_files(tmp_path: Path) -> list[tuple[list[str], tuple[str, ...]]]:
    """(CLI arguments, words the one-line message must contain)."""
    neg = _edited(tmp_path, "rus6_ceart.toml", "neg.toml", r"^crank = 0\.184", "crank = -0.184")
    unk = _edited(
        tmp_path, "rus6_ceart.toml", "unk.toml", r"^rod = 0\.724", "rod = 0.724\nrods = 1"
    )
    spd = _edited(
        tmp_path, "rus6_ceart.toml", "speed.toml", r"^max_speed = 3\.0", "max_speed = -3.0"
    )
    rng = _edited(
        tmp_path, "rus6_ceart.toml", "range.toml", r"^angle_max_deg = 60\.0", "angle_max_deg = -70"
    )
    wneg = _edited(
        tmp_path,
        "washout_default.toml",
        "wneg.toml",
        r"^specific_force_gain = .*$",
        "specific_force_gain = [0.5, -0.5, 0.3]",
    )
    wunk = _edited(tmp_path, "washout_default.toml", "wunk.toml", r"^g = ", "gg = 1\ng = ")
    pneg = _edited(tmp_path, "rrr3_udesc.toml", "pneg.toml", r"^crank = 0\.04445", "crank = -0.04")
    syntax = tmp_path / "syntax.toml"
    syntax.write_text("crank = = 1\n")
    return [
        (["--platform", str(neg)], ("neg.toml", "crank")),
        (["--platform", str(unk)], ("unk.toml", "rods")),
        (["--platform", str(spd)], ("speed.toml", "max_speed")),
        (["--platform", str(rng)], ("range.toml", "angle_m")),
        (["--platform", str(syntax)], ("syntax.toml",)),
        (["--washout", str(wneg)], ("wneg.toml", "specific_force_gain")),
        (["--washout", str(wunk)], ("wunk.toml", "gg")),
        (["--washout", str(tmp_path / "missing.toml")], ("missing.toml", "not found")),
        (["--planar", "--platform", str(pneg)], ("pneg.toml", "crank")),
        (["--platform", "no_such_preset"], ("no_such_preset", "ceart")),
        (["--washout", "no_such_preset"], ("no_such_preset", "default")),
        (["--duration", "abc"], ("--duration", "abc")),
        (["--duration", "-3"], ("--duration",)),
        (["--duration", "nan"], ("--duration",)),
        (["--duration", "inf"], ("--duration",)),
        # shorter than one sample of c1723 (1/120 s): it flew nothing and exited 0
        (["--duration", "0.001"], ("--duration", "0.001", "one sample")),
    ]


def test_configuration_mistakes_give_one_line_naming_file_field_and_fix(tmp_path, capsys):
    """In-process ``cli.main`` (same code path as the console script, much faster)."""
    for args, needles in _case_files(tmp_path):
        try:
            code = cli.main(["fly", *args, "--out", str(tmp_path / "x.mcap")])
        except SystemExit as exc:  # argparse errors exit through SystemExit
            code = exc.code
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        line = assert_one_line_error(err, *needles)
        assert any(w in line.lower() for w in FIX_WORDS), (args, line)
        assert not (tmp_path / "x.mcap").exists(), args  # nothing was flown


def test_configuration_mistake_through_the_console_script(tmp_path):
    bad = _edited(tmp_path, "rus6_ceart.toml", "bad.toml", r"^rod = 0\.724", "rod = -1.0")
    proc = cli_run("fly", "--platform", str(bad), cwd=tmp_path)
    assert proc.returncode == 2
    line = assert_one_line_error(proc, "bad.toml", "'rod'")
    assert "fix" in line
    assert proc.stdout == ""


# --------------------------------------------------------------------------- crafted times


RATE = 120.0
N_CRAFTED = 360  # 3 s of samples


def _strong(k: int) -> tuple[list[float], list[float]]:
    """Strong manoeuvring (the cranks work at their speed limits), sample ``k`` at 120 Hz."""
    s = math.sin(2 * math.pi * 0.7 * k / RATE)
    return [25 * s, 20 * s, -G + 10 * s], [3 * s, 3 * s, 3 * s]


def _times(kind: str) -> list[float]:
    dt = 1 / RATE
    t = [k * dt for k in range(N_CRAFTED)]
    half = N_CRAFTED // 2
    if kind == "jump 1e6 s":
        t = t[:half] + [x + 1e6 for x in t[half:]]
    elif kind == "gap 10 s":
        t = t[:half] + [x + 10.0 for x in t[half:]]
    elif kind == "squeezed to 1 ms":
        t = [k * 1e-3 for k in range(N_CRAFTED)]  # while the recording says 120 Hz
    elif kind == "10 samples back in time":
        t = [x - 0.5 if half - 30 <= k < half - 20 else x for k, x in enumerate(t)]
    elif kind == "one sample at 2e10 s":
        t[half] = 2e10
    return t


CRAFTED = ["jump 1e6 s", "gap 10 s", "squeezed to 1 ms", "10 samples back in time",
           "one sample at 2e10 s"]  # fmt: skip


def write_crafted(path: Path, times: list[float]) -> None:
    """A recording of strong manoeuvring whose samples carry ``times`` as the source's own
    time (``source_t``, what a replay reads); the MCAP log time stays the sample's index at
    120 Hz, as the recording's metadata says."""
    with McapLogger(path, {"rate_hz": RATE, "source": {"kind": "crafted times"}}) as logger:
        for k, t in enumerate(times):
            f, w = _strong(k)
            msg = {"t": k / RATE, "source_t": t, "specific_force": f, "angular_velocity": w,
                   "attitude": [0.0, 0.0, 0.0]}  # fmt: skip
            logger.add("/aircraft/state", k / RATE, msg)


@dataclass
class Replayed:
    returncode: int | None
    stdout: str
    stderr: str
    froze: bool
    drive: UdpDrive
    out: Path


@pytest.fixture(scope="module")
def crafted_replays(tmp_path_factory) -> dict[str, Replayed]:
    """``motionbase replay REC --platform ceart --output udp:...`` of each crafted recording,
    to a loopback drive, all at once (each takes the recording's length in real time)."""
    root = tmp_path_factory.mktemp("crafted")
    started = {}
    for k, kind in enumerate(CRAFTED):
        rec, out = root / f"rec{k}.mcap", root / f"replay{k}.mcap"
        write_crafted(rec, _times(kind))
        drive = UdpDrive()
        cmd = [sys.executable, "-m", "motionbase.cli", "replay", str(rec), "--platform", "ceart"]
        cmd += ["--out", str(out), "--output", drive.url()]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started[kind] = (proc, drive, out)
    results = {}
    for kind, (proc, drive, out) in started.items():
        froze = False
        try:
            stdout, stderr = proc.communicate(timeout=240)  # a watchdog, not a timing check
        except subprocess.TimeoutExpired:
            froze = True
            proc.send_signal(signal.SIGKILL)
            stdout, stderr = proc.communicate()
        drive.drain()
        drive.close()
        results[kind] = Replayed(proc.returncode, stdout, stderr, froze, drive, out)
    return results


@pytest.mark.parametrize("kind", CRAFTED)
def test_replay_to_drives_keeps_the_limits_on_the_wire_whatever_the_recorded_times(
    crafted_replays, kind
):
    """The loop paces a replay with drives on its own clock at the recorded rate: a jump or a
    gap in the recording's times is the validation stage's business (a time jump resets the
    washout and fades back in; a sample back in time or beyond what a log time holds is
    rejected and held), never a wait; the frames on the wire keep the speed and acceleration
    limits in wall-clock time; the last frame is the park command; the log is complete."""
    r = crafted_replays[kind]
    assert not r.froze, f"{kind}: the replay froze (killed)"
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    geometry = Rus6Geometry.preset("ceart")
    t, q = r.drive.angles()
    assert len(t) > 100
    np.testing.assert_allclose(q[-1], geometry.park_angle, atol=math.radians(1e-4))
    check_wire_limits(t, q, geometry.max_speed, geometry.max_accel, kind)
    log = read_complete_log(r.out)
    assert len(log["/aircraft/state"]) == N_CRAFTED  # every sample went through
    assert log["/platform/pose"][-1]["phase"] == "parked"
    health = log["/health"][-1]
    times = [m["t"] for m in log["/platform/actuators"]]
    assert np.all(np.diff(times) > 0) and times[-1] <= MAX_SAMPLE_TIME_S
    expected = {  # (time jumps, rejected samples)
        "jump 1e6 s": (1, 0),
        "gap 10 s": (1, 0),
        "squeezed to 1 ms": (0, 0),
        "10 samples back in time": (0, 10),
        "one sample at 2e10 s": (0, 1),
    }[kind]
    assert (health["time_jumps"], health["rejected_inputs"]) == expected
    if kind == "one sample at 2e10 s":
        assert "outside" in health["last_rejection"]
    assert "rejected inputs" in r.stdout and "stopped by end of source" in r.stdout


def test_a_recording_that_claims_an_absurdly_slow_rate_is_refused(tmp_path, capsys):
    """A replay to drives is paced at the recording's rate: one of 0.001 Hz would make the
    loop wait 1000 s between ticks, deaf to a stop meanwhile. Refused: one line, exit 2."""
    rec = tmp_path / "slow.mcap"
    with McapLogger(rec, {"rate_hz": 0.001}) as logger:
        for k in range(5):
            msg = {"specific_force": [0.0, 0.0, -G], "angular_velocity": [0.0, 0.0, 0.0],
                   "attitude": [0.0, 0.0, 0.0]}  # fmt: skip
            logger.add("/aircraft/state", 1000.0 * k, msg)
    drive = UdpDrive()
    try:
        code = cli.main(["replay", str(rec), "--platform", "ceart", "--output", drive.url()])
    finally:
        drive.close()
    assert code == 2
    assert_one_line_error(capsys.readouterr().err, "rate_hz 0.001", "below 10 Hz")
    assert drive.count() == 0
