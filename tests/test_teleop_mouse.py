"""The real mouse window under Xvfb: the pointer drives the robot through the calibration.

Needs ``Xvfb``, ``xdotool`` and Tk (``apt-get install -y xvfb xdotool python3-tk``). Without
them the test is skipped with that reason, or fails when ``MOTIONBASE_REQUIRE_DISPLAY=1``
(``.ci/run`` installs them and sets it): the ``display_tools`` fixture of ``conftest.py``.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.platform import CursorCalibration, Rrr3, Rrr3Geometry

L = 0.26  # base side of the udesc presets, m (DESIGN.md)
HOME = np.array([L / 2, L * math.sqrt(3) / 6])


@pytest.fixture
def xvfb(display_tools):
    """A private Xvfb on a free display number (Xvfb picks it: -displayfd): the display's
    name and the Xvfb process."""
    xvfb = display_tools["Xvfb"]
    r, w = os.pipe()
    proc = subprocess.Popen(
        [xvfb, "-displayfd", str(w), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        pass_fds=(w,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(w)
    try:
        with os.fdopen(r) as fh:
            number = fh.readline().strip()
        if not number:
            pytest.fail("Xvfb started but reported no display number")
        yield f":{number}", proc
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture
def display(xvfb):
    """The private Xvfb's display name."""
    return xvfb[0]


def _xdotool(env, *args: str) -> str:
    out = subprocess.run(
        ["xdotool", *args], env=env, capture_output=True, text=True, timeout=10, check=False
    )
    return out.stdout.strip()


def _wait_window(env, proc, timeout_s: float = 60.0) -> str:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        wid = _xdotool(env, "search", "--name", "motionbase teleop")
        if wid:
            return wid.splitlines()[0]
        if proc.poll() is not None:
            pytest.fail(f"teleop exited before its window appeared: {proc.stderr.read()}")
        time.sleep(0.1)
    pytest.fail("the teleop window did not appear within 60 s")


def _run_with_pointer(display, tmp_path: Path, points, end):
    """``motionbase teleop --input mouse`` on ``display``, the pointer moved to ``points``
    in turn, then ``end(env, window id, teleop process)``; its log and output."""
    out = tmp_path / "mouse.mcap"
    env = dict(os.environ, DISPLAY=display)
    cmd = [sys.executable, "-m", "motionbase.cli", "teleop", "--input", "mouse"]
    # ``end`` ends the run; the duration is only a watchdog (3 s, it could end a run on a
    # loaded machine before the pointer had made its moves and the Escape came)
    cmd += ["--serial", "none", "--duration", "60", "--out", str(out)]
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True,  # its process group, for a Ctrl-C sent to the whole group
    )  # fmt: skip
    try:
        wid = _wait_window(env, proc)
        for u, v in points:
            _xdotool(env, "mousemove", "--window", wid, str(u), str(v))
            time.sleep(1.5)  # the robot arrives (its speed limit), with room for a busy machine
        end(env, wid, proc)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    return out, stdout, stderr


def _escape(env, wid, proc):
    _xdotool(env, "key", "--window", wid, "Escape")


def _assert_parked(log, rrr3):
    """The run ended at home, at rest, within the joint limits (50 Hz ticks)."""
    q = np.array([m["angles"] for m in log["/planar/actuators"]])
    servo = [tuple(m["servo_deg"]) for m in log["/planar/actuators"]]
    home_servo = tuple(rrr3.to_servo(rrr3.inverse(rrr3.home)))
    assert servo[-1] == home_servo and servo[-2] == home_servo
    np.testing.assert_allclose(log["/planar/pose"][-1]["pose"], rrr3.home, atol=1e-9)
    v = np.diff(q, axis=0) * 50
    g = rrr3.geometry
    assert np.abs(v).max() <= g.max_speed * (1 + 1e-9)
    assert np.abs(np.diff(v, axis=0)).max() * 50 <= g.max_accel * (1 + 1e-6)


def _settled(log, pixel):
    """The last logged pose and cursor target while the pointer was at ``pixel``."""
    cur = [m for m in log["/cursor"] if tuple(m["pixel"]) == tuple(float(p) for p in pixel)]
    assert cur, f"the log never saw the pointer at {pixel}"
    t_last = cur[-1]["t"]
    pose = next(m["pose"] for m in log["/planar/pose"] if m["t"] == t_last)
    return np.array(cur[-1]["target"]), np.array(pose)


def test_mouse_window_pointer_drives_the_robot(display, tmp_path):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))  # the teleop default
    # inside the window: near the middle, a little to the right, and far off to the upper left
    points = [(360, 400), (400, 380), (60, 80)]
    out, stdout, _ = _run_with_pointer(display, tmp_path, points, _escape)
    assert "stopped by key Escape" in stdout
    log = read_messages(out)
    meta = read_metadata(out)
    cal = CursorCalibration.from_dict(meta["calibration"])
    w, h = meta["input"]["size_px"]

    # the view is a similarity with y up that shows the whole base triangle
    corners = cal(np.array([[0.0, h], [w, 0.0]]))
    assert (corners[0] < 0).all() and corners[1][0] > L and corners[1][1] > L * math.sqrt(3) / 2
    t1, t2 = cal(np.array([points[0], points[1]], dtype=float))
    du, dv = points[1][0] - points[0][0], points[1][1] - points[0][1]
    k = (t2[0] - t1[0]) / du
    assert k > 0 and np.isclose(t2[1] - t1[1], -k * dv, rtol=1e-6)

    # reachable pointer positions: the target is the calibrated pointer and the robot's
    # centre arrived on it
    for p in points[:2]:
        target, pose = _settled(log, p)
        np.testing.assert_allclose(target, cal(np.array(p, dtype=float)), atol=1e-12)
        assert rrr3.reachable(np.array([*target, 0.0]))
        np.testing.assert_allclose(pose, [*target, 0.0], atol=1e-9)

    # an unreachable pointer position: clamped toward home, on the segment home -> target
    target, pose = _settled(log, points[2])
    assert not rrr3.reachable(np.array([*target, 0.0]))
    assert rrr3.reachable(pose)
    d_t, d_p = target - HOME, pose[:2] - HOME
    assert abs(d_t[0] * d_p[1] - d_t[1] * d_p[0]) < 1e-9 * np.hypot(*d_t)
    assert 0 < np.dot(d_p, d_t) < np.dot(d_t, d_t)

    # Escape parked the robot at home, at rest, within the joint limits
    _assert_parked(log, rrr3)
    assert log["/health"][-1]["estops"] == 1


# The mouse window lost mid-run: the pointer first takes the robot far from home (to the
# edge of the workspace, toward the upper left), then the window goes; the robot parks.
FAR = [(60, 80)]


def _assert_lost_window_parked(out, stdout, reason):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
    assert f"(stopped by {reason})" in stdout
    log = read_messages(out)
    poses = np.array([m["pose"] for m in log["/planar/pose"]])
    assert np.hypot(*(poses[:, :2] - HOME).T).max() > 0.01  # it had left home
    _assert_parked(log, rrr3)
    health = log["/health"][-1]
    assert health["stopped_by"] == reason
    assert health["estops"] == 0 and health["park_ticks"] > 0


def test_display_going_away_parks_the_robot(xvfb, tmp_path):
    """The X server killed mid-run (``xvfb-run``'s, by the Ctrl-C sent to the whole process
    group; a remote display dropped): Xlib ends the process Tk is in, which is not the one
    that parks the robot."""
    display, server = xvfb

    def kill_display(env, wid, proc):
        os.kill(server.pid, signal.SIGKILL)
        server.wait()

    out, stdout, _ = _run_with_pointer(display, tmp_path, FAR, kill_display)
    _assert_lost_window_parked(out, stdout, "the mouse window losing its X display")


def _window_pid(pid: int) -> int:
    """The mouse window's process: the child of ``pid`` started by multiprocessing's spawn."""
    for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
            return int(child)
    pytest.fail(f"no mouse window process among the children of {pid}")


def test_window_process_killed_parks_the_robot(display, tmp_path):
    def kill_window(env, wid, proc):
        os.kill(_window_pid(proc.pid), signal.SIGKILL)

    out, stdout, _ = _run_with_pointer(display, tmp_path, FAR, kill_window)
    _assert_lost_window_parked(out, stdout, "the mouse window's process ending, killed by SIGKILL")


def test_window_that_stops_answering_parks_the_robot(display, tmp_path):
    """The window's process stopped (as by a display that hangs): the run goes on without
    waiting for it (its drawings are not sent while it has not drawn the last one), then
    takes it as gone and parks."""

    def stop_window(env, wid, proc):
        os.kill(_window_pid(proc.pid), signal.SIGSTOP)

    out, stdout, _ = _run_with_pointer(display, tmp_path, FAR, stop_window)
    _assert_lost_window_parked(out, stdout, "the mouse window not answering for 5 s")


def test_ctrl_c_to_the_group_leaves_the_window_to_the_parking(display, tmp_path):
    """A Ctrl-C reaches every process of the terminal's group: the window's process ignores
    it (no KeyboardInterrupt there), the run stops by it and parks."""

    def ctrl_c(env, wid, proc):
        os.killpg(proc.pid, signal.SIGINT)

    out, stdout, stderr = _run_with_pointer(display, tmp_path, FAR, ctrl_c)
    assert "(stopped by SIGINT)" in stdout
    assert "KeyboardInterrupt" not in stderr and "Traceback" not in stderr
    _assert_parked(read_messages(out), Rrr3(Rrr3Geometry.preset("udesc_symmetric")))


def test_no_display_is_one_line(tmp_path):
    """Without a display the mouse window cannot open: one line, exit status 2 (nothing
    to start: no Xvfb needed)."""
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    cmd = [sys.executable, "-m", "motionbase.cli", "teleop", "--input", "mouse"]
    res = subprocess.run(
        [*cmd, "--serial", "none", "--duration", "1"], env=env, capture_output=True,
        text=True, timeout=120, check=False,
    )  # fmt: skip
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "cannot open the mouse window" in res.stderr
    assert "xvfb-run" in res.stderr


def test_a_window_left_open_ends_with_its_program(display):
    """A program that opens the mouse window and never closes it still exits: the window's
    process ignores the SIGTERM that multiprocessing's exit handler sends before it waits
    for its processes, so the window is closed before that handler runs."""
    script = (
        "from motionbase.io.cursor_input import TkCursor\n"
        "from motionbase.platform import Rrr3, Rrr3Geometry\n"
        "window = TkCursor(Rrr3(Rrr3Geometry.preset('udesc_symmetric'))).open()\n"
        "print('opened')\n"
    )
    env = dict(os.environ, DISPLAY=display)
    res = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=60,
        check=False,
    )  # fmt: skip
    assert (res.returncode, res.stdout) == (0, "opened\n"), res.stderr


def test_a_window_that_cannot_start_is_said(display):
    """A program read from stdin: multiprocessing's ``spawn`` cannot start the window's
    process (it reruns the main file, and there is none), which ends at once; opening says
    so (the workspace drawing, some 100 kB, had been the process's argument, and the
    start had waited for ever to write it to the process that had ended)."""
    script = (
        "from motionbase.io.cursor_input import TkCursor\n"
        "from motionbase.platform import Rrr3, Rrr3Geometry\n"
        "TkCursor(Rrr3(Rrr3Geometry.preset('udesc_symmetric'))).open()\n"
    )
    env = dict(os.environ, DISPLAY=display)
    res = subprocess.run(
        [sys.executable, "-"], input=script, env=env, capture_output=True, text=True,
        timeout=60, check=False,
    )  # fmt: skip
    assert res.returncode == 1
    assert "SourceError: cannot open the mouse window: its process ended" in res.stderr
