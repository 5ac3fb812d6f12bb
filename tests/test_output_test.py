"""``motionbase output --test`` asked to stop mid-sweep, in a real subprocess of the CLI.

The drive is :class:`drive_wire.UdpDrive`, a UDP listener on loopback that records each
datagram with its arrival time and decodes the frames with its own parser, in degrees (the
mapping of a geometry without an ``[output]`` table) turned into radians.
"""

from __future__ import annotations

import fcntl
import math
import os
import pty
import re
import signal
import socket
import subprocess
import sys
import termios
import time
from subprocess import PIPE
from urllib.parse import quote

import numpy as np
import pytest
from drive_wire import UdpDrive, check_sweep, check_wire_limits, frame_format, sweep_holds

from motionbase.platform import Rus6Geometry
from motionbase.platform.robot import robot_spec

GEOMETRY = Rus6Geometry.preset("ceart")  # the command's default --platform
ROBOT = robot_spec("rus6").make(GEOMETRY)


def windowed_rates(t: np.ndarray, q: np.ndarray, window_s: float):
    """Speeds over windows of at least ``window_s`` (rad/s, per motor) and the accelerations
    between consecutive such windows (rad/s^2): plain finite differences of the received
    values over their arrival times."""
    j = np.searchsorted(t, t + window_s)
    ok = j < len(t)
    i, j = np.flatnonzero(ok), j[ok]
    v = (q[j] - q[i]) / (t[j] - t[i])[:, None]
    mid = 0.5 * (t[i] + t[j])
    k = np.searchsorted(mid, mid + window_s)
    ok = k < len(mid)
    a = (v[k[ok]] - v[ok]) / (mid[k[ok]] - mid[ok])[:, None]
    return v, a


def sweep_at_the_drive(args: list[str], n: int, rate_hz: float = 200.0, attempts: int = 3):
    """Run ``motionbase output --test`` (a real subprocess) against a UDP drive of ``n``
    motors; return the process and the frames (arrival times s, values as the drive parsed
    them).

    A gap of more than 10 periods between frames means the machine stalled the sender (a
    virtual machine's host took its processor while the pipeline's went on): the drive is then
    ramped from where it stood toward the latest command (``test_motor_output.py``; the
    sweep's own drive: the outage test below) and may cut a sweep's corner. Such a run is
    made again, up to ``attempts`` times; the one returned had no gap.
    """
    for _ in range(attempts):
        rx = UdpDrive(n=n)
        cmd = [sys.executable, "-m", "motionbase.cli", "output", "--test", rx.url(rate_hz), *args]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
            rx.drain()
        finally:
            rx.close()
        assert proc.returncode == 0, proc.stderr
        t, q = rx.angles()
        if len(t) > 1 and np.diff(t).max() < 10.0 / rate_hz:
            return proc, t, q
    pytest.fail(f"the machine stalled the sender in each of {attempts} runs (frame gaps)")


def start_mid_sweep(rx: UdpDrive) -> subprocess.Popen:
    """``motionbase output --test`` to the drive ``rx`` at 60 deg/s, returned once motor 1 is
    on its way up with the others at neutral: mid-sweep."""
    cmd = [sys.executable, "-m", "motionbase.cli", "output", "--test", rx.url()]
    cmd += ["--speed-deg-s", "60", "--range-deg", "5"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    neutral = np.asarray(GEOMETRY.neutral_angle, dtype=float)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"the test ended before motor 1 moved: {proc.communicate()}")
        if rx.count():
            dev = np.degrees(rx.angles(rx.count() - 1)[1][-1] - neutral)
            if 1.0 < dev[0] < 4.0 and np.all(np.abs(dev[1:]) < 1e-3):
                return proc
        time.sleep(0.002)
    proc.kill()
    proc.wait()
    pytest.fail("the sweep never reached motor 1")


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"])
def test_a_stop_mid_sweep_ramps_back_to_park_within_the_limits_and_exits_0(sig):
    rx = UdpDrive()
    neutral = np.asarray(GEOMETRY.neutral_angle, dtype=float)
    proc = None
    try:
        proc = start_mid_sweep(rx)
        proc.send_signal(getattr(signal, sig))
        stdout, stderr = proc.communicate(timeout=60)
        rx.drain()  # the last datagrams
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        rx.close()
    assert proc.returncode == 0, (proc.returncode, stderr)
    stopped = [line for line in stdout.splitlines() if "stopped" in line]
    assert len(stopped) == 1 and sig in stopped[0], stdout
    assert "Traceback" not in stderr
    t, q = rx.angles()
    park = np.full(6, GEOMETRY.park_angle)
    # the last frame on the wire is the park command (to the format's 1e-4 deg)
    np.testing.assert_allclose(q[-1], park, atol=math.radians(1e-4))
    # stopped mid-sweep: motor 1 had moved on its own, motor 6 never did
    away = np.abs(q - neutral) > math.radians(0.01)
    alone = away.sum(axis=1) == 1
    assert np.any(alone & away[:, 0]) and not np.any(alone & away[:, 5])
    # Speeds and accelerations of the frames, from their values and arrival times, over
    # windows of at least 0.2 s (the sender thread samples the commands on its own clock, so
    # single frames repeat or skip one). A variation J in a frame's lag behind its command (one
    # 10 ms sender period plus the scheduler's delay) moves a speed estimate by at most
    # 2 v J / 0.2 s and an acceleration by twice that per 0.2 s: 0.5 rad/s and 5 rad/s^2 for
    # J = 50 ms at this test's 60 deg/s (1.05 rad/s; the sweep accelerates at 15 rad/s^2 at
    # most). Tolerance: 10 % of the geometry's limits (3 rad/s, 30 rad/s^2).
    v, a = windowed_rates(t, q, 0.2)
    assert np.all(np.abs(v) <= 1.1 * np.asarray(GEOMETRY.max_speed))
    assert np.all(np.abs(a) <= 1.1 * np.asarray(GEOMETRY.max_accel))
    # and it did move: the test is not vacuous
    assert np.abs(v).max() > 0.5


def test_a_second_signal_mid_sweep_is_an_e_stop_said_as_fly_says_it():
    """Ctrl-C twice mid-sweep: the first stops the sweep (back to park at the soft-start
    pace), the second, while it parks, is an E-stop, said in the words of ``fly``'s summary
    ("stopped by SIGINT, then an E-stop (SIGINT while stopping)"; ``test_signals.py``); the
    drive parks within the limits and the command exits 0. It used to say only "stopped by
    SIGINT"."""
    rx = UdpDrive()
    proc = None
    try:
        proc = start_mid_sweep(rx)
        proc.send_signal(signal.SIGINT)
        n = rx.count()
        while rx.count() < n + 20:  # (0.2 s of parking)
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.002)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
        rx.drain()
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        rx.close()
    assert proc.returncode == 0, (proc.returncode, stderr)
    assert "Traceback" not in stderr
    stopped = [line for line in stdout.splitlines() if "stopped" in line]
    assert stopped[0] == "output test stopped by SIGINT: moving back to park", stdout
    assert stopped[-1].startswith(
        "output test stopped by SIGINT, then an E-stop (SIGINT while stopping): "
    ), stdout
    assert len(stopped) == 2, stdout
    t, q = rx.angles()
    np.testing.assert_allclose(q[-1], np.full(6, GEOMETRY.park_angle), atol=math.radians(1e-4))
    check_wire_limits(t, q, ROBOT.limits.max_speed, ROBOT.limits.max_accel, "an E-stop")


@pytest.mark.parametrize("returns", [True, False], ids=["returns", "never returns"])
def test_a_drive_that_vanishes_mid_sweep_is_ramped_as_a_flight_s_drive_is(returns):
    """The drive vanishes (its port refuses: send errors) while the cranks rise from park
    toward neutral, where the sweep's commands run furthest (55 deg): half a second of the
    sweep later it returns, or never does. As with ``fly --output``: the first frame after
    its return is within one frame's travel of the last one it got (at most two frames at
    full speed, plus a first step from rest), and from there the frames keep the speed and
    acceleration limits and end on park; a drive that never returns is waited for, then
    said not to be parked. The wiring check's drive used to get the latest command as it
    was: 30 deg and more in one frame on its return, and no word when it never came back."""
    rate = 100.0
    drive = UdpDrive()
    cmd = [sys.executable, "-m", "motionbase.cli", "output", "--test", drive.url(rate)]
    proc = subprocess.Popen(
        [*cmd, "--speed-deg-s", "60"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    park = np.full(6, GEOMETRY.park_angle)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the cranks on their way up from park
            assert proc.poll() is None, proc.communicate()
            n = drive.count()
            if n and np.all(drive.angles(n - 1)[1][-1] - park > math.radians(3.0)):
                break
            time.sleep(0.002)
        else:
            pytest.fail("the cranks never left park")
        drive.vanish()
        n_before = drive.count()
        time.sleep(0.5)  # the sweep goes on: 30 deg at 60 deg/s
        if returns:
            drive.come_back()
        stdout, stderr = proc.communicate(timeout=120)
        drive.drain()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        drive.close()
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    assert "link is down" in stderr and re.search(r"[1-9]\d* send errors", stdout), stdout
    parked = "may not be at the last command"
    t, q = drive.angles()
    if not returns:
        assert len(t) == n_before and parked in stderr, stderr
        return
    assert parked not in stderr, stderr
    lim = ROBOT.limits
    period = 1.0 / rate
    last_before, first_after = q[n_before - 1], q[n_before]
    reach = 2 * lim.max_speed * period + lim.max_accel * period**2
    assert np.all(np.abs(first_after - last_before) <= reach), np.degrees(first_after - last_before)
    after_t = np.r_[t[n_before - 1], t[n_before:]]
    after_q = np.vstack([last_before, q[n_before:]])
    check_wire_limits(after_t, after_q, lim.max_speed, lim.max_accel, "after the outage")
    np.testing.assert_allclose(q[-1], park, atol=math.radians(1e-4))
    # not vacuous: the sweep had gone on without the drive, far from where it was left
    assert np.degrees(np.abs(q[n_before:] - last_before).max()) > 20.0


def test_a_reader_that_goes_away_neither_stops_nor_crashes_the_sweep():
    """``motionbase output --test URL | head -2``: the reader of the output goes away after
    two lines, so the next line meets a broken pipe. Printing progress is no part of the
    sweep: it runs to its end (every motor in turn to +5 deg and -5 deg exactly, the others
    at neutral: :func:`drive_wire.check_sweep`) and parks, and the command exits 0 without a
    word on stderr. The line used to be printed from inside the sweep's source, so the
    broken pipe ended the sweep as a failing source: parked, then a traceback and exit
    status 1."""
    drive = UdpDrive()
    cmd = [sys.executable, "-m", "motionbase.cli", "output", "--test", drive.url()]
    proc = subprocess.Popen([*cmd, "--speed-deg-s", "60"], stdout=PIPE, stderr=PIPE)
    try:
        assert proc.stdout is not None and proc.stderr is not None
        head = [proc.stdout.readline() for _ in range(2)]
        proc.stdout.close()  # `head -2` has what it wanted
        err = proc.stderr.read().decode()
        proc.wait(timeout=120)
        drive.drain()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        drive.close()
    assert head[0].startswith(b"output test on ") and head[1].startswith(b"moving from park")
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    _, q = drive.angles()
    neutral = np.asarray(GEOMETRY.neutral_angle, dtype=float)
    check_sweep(q, neutral, math.radians(5), atol=math.radians(1e-4))  # (the wire's 4 decimals)
    np.testing.assert_allclose(q[-1], np.full(6, GEOMETRY.park_angle), atol=math.radians(1e-4))


def _own_terminal() -> None:
    """In the child: a session of its own whose controlling terminal is its stdin, so that
    closing the terminal's other end hangs the session up (SIGHUP), as closing a terminal
    window does."""
    os.setsid()
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def test_a_terminal_closed_mid_sweep_parks_the_drive_and_exits_0():
    """The terminal of ``motionbase output --test`` closes mid-sweep: the kernel sends
    SIGHUP, which stops the sweep, and every line printed after it meets an I/O error. The
    drive is parked, and the command exits 0 without a traceback (stderr is a pipe here, to
    see that). The run's last line used to raise ``OSError: [Errno 5]`` after the park, so
    the command ended with a traceback and exit status 1."""
    drive = UdpDrive()
    master, slave = pty.openpty()
    cmd = [sys.executable, "-m", "motionbase.cli", "output", "--test", drive.url()]
    proc = subprocess.Popen(
        [*cmd, "--speed-deg-s", "60"],
        stdin=slave,
        stdout=slave,
        stderr=PIPE,
        preexec_fn=_own_terminal,
    )
    os.close(slave)
    park = np.full(6, GEOMETRY.park_angle)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the cranks on their way up from park
            assert proc.poll() is None, proc.communicate()
            n = drive.count()
            if n and np.all(drive.angles(n - 1)[1][-1] - park > math.radians(3.0)):
                break
            time.sleep(0.002)
        else:
            pytest.fail("the cranks never left park")
        os.close(master)  # the terminal closes
        master = -1
        _, err = proc.communicate(timeout=120)
        drive.drain()
    finally:
        if master >= 0:
            os.close(master)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        drive.close()
    assert proc.returncode == 0, err
    assert b"Traceback" not in err and b"Exception ignored" not in err, err
    _, q = drive.angles()
    np.testing.assert_allclose(q[-1], park, atol=math.radians(1e-4))
    # stopped by the hang-up: the sweep never reached motor 6
    neutral = np.asarray(GEOMETRY.neutral_angle, dtype=float)
    assert np.all(sweep_holds(q, neutral, math.radians(5), atol=math.radians(1e-3))[5] < 0)


def test_a_stop_before_the_sweep_starts_sends_only_park():
    from motionbase.app import output_test
    from motionbase.pipeline import StopRequest
    from motionbase.platform.robot import robot_spec

    rx = UdpDrive()
    stop = StopRequest()
    stop.set("test")
    try:
        lines = output_test(
            rx.url(), robot_spec("rus6").make(GEOMETRY), stop=stop, echo=lambda s: None
        )
        rx.drain()  # the last datagrams
    finally:
        rx.close()
    assert sum("stopped by test" in line for line in lines) == 1
    assert not any(line.startswith("motor ") for line in lines)
    _, q = rx.angles()
    assert len(q) >= 1
    np.testing.assert_allclose(q, np.full_like(q, GEOMETRY.park_angle), atol=math.radians(1e-4))


@pytest.mark.parametrize("platform", ["rrr3", "udesc_symmetric"])  # the robot, or its preset
def test_the_sweep_drives_any_robot_of_the_registry_the_planar_3rrr_too(platform):
    """``output --test --platform rrr3``: the 3-RRR's servos (servo degrees, the default
    mapping of its geometry: ``direction * (theta - zero_deg)`` of its ``[servo]`` table,
    90 at home on every servo of this preset; the joint angles in the base frame, 92, 212
    and 332 deg, were sent before) are swept one at a time by +-5 deg about home, each
    reaching +5 deg and -5 deg exactly and going no further
    (:func:`drive_wire.check_sweep`), the frames within the servos' 0..180 deg, speed and
    acceleration limits, the last frame home (its park). A 3-RRR geometry preset names the
    planar robot as well (``output`` has no --planar)."""
    from motionbase.platform import Rrr3, Rrr3Geometry

    args = ["--platform", platform, "--speed-deg-s", "60", "--rate", "200"]
    proc, t, q = sweep_at_the_drive(args, n=3)
    stdout = proc.stdout
    assert [f"motor {i}:" in stdout for i in (1, 2, 3)] == [True] * 3
    geometry = Rrr3Geometry.preset("udesc_symmetric")  # the planar default
    rrr3 = Rrr3(geometry)
    lo = rrr3.angle_limits[:, 0]
    theta = np.degrees(lo + np.mod(rrr3.inverse(rrr3.home) - lo, 2 * math.pi))
    servo = np.mod(np.array(geometry.servo_direction) * (theta - geometry.servo_zero_deg), 360)
    np.testing.assert_allclose(servo, 90.0, atol=0.05)  # the preset's own words
    home = np.radians(servo)  # (the drive's parser reads degrees into radians)
    np.testing.assert_allclose(q[-1], home, atol=math.radians(1e-4))
    assert np.all(q >= np.radians(geometry.servo_min_deg) - 1e-6)
    assert np.all(q <= np.radians(geometry.servo_max_deg) + 1e-6)
    lim = robot_spec("rrr3").make(geometry).limits
    check_wire_limits(t, q, lim.max_speed, lim.max_accel, "the 3-RRR's sweep")
    # motor 1 to +5 deg and -5 deg, then motor 2, then motor 3, the others at home (to the
    # wire's four decimals of a degree)
    holds = check_sweep(q, home, math.radians(5.0), atol=math.radians(1e-4))
    assert np.all(np.diff(holds.ravel()) > 0), holds


def test_a_sweep_through_a_drive_of_three_of_six_motors_says_which_it_does_not_reach():
    """A Stewart platform on two three-motor boards: the wiring check of the first board's
    URL (a frame of motors 1..3) swept motors 4..6 too, saying "motor 4: length +1 mm", with
    nothing on the wire moving: a motor that seemed miswired. The check says first which
    motors this output does not carry, and sweeps only the others: motors 1..3 each reach
    +-1 mm on the wire in turn (their sweeps are the whole sweep: it took twice as long)."""
    from motionbase.app import output_test
    from motionbase.platform import Stewart6Geometry

    robot = robot_spec("stewart6").make(Stewart6Geometry.preset("seat"))
    rx = UdpDrive(n=3)
    try:
        lines = output_test(
            rx.url(200.0), "stewart6", range_mm=1.0, speed_mm_s=300.0, echo=lambda s: None
        )
        rx.drain()
    finally:
        rx.close()
    notes = [s for s in lines if "4, 5, 6" in s]
    assert len(notes) == 1 and "not swept" in notes[0], lines
    swept = [s.split(":")[0] for s in lines if s.startswith("motor ")]
    assert swept == ["motor 1", "motor 2", "motor 3"], lines
    _, q = rx.angles()
    mm = np.degrees(q)  # (the drive's parser reads degrees into radians)
    neutral = 1000.0 * robot.inverse(np.zeros(6))[:3]
    check_sweep(mm, neutral, 1.0, atol=1e-4)


def test_the_sweep_drives_a_linear_actuator_platform_in_millimetres():
    """``output --test --platform stewart6``: each of the Stewart platform's linear actuators
    (millimetres, the default mapping for linear actuators) is swept by +-10 mm about its
    length at the neutral pose, one at a time (exactly, and no further), within the stroke and
    the speed and acceleration limits; the last frame is park."""
    from motionbase.platform import Stewart6Geometry
    from motionbase.platform.robot import robot_spec

    robot = robot_spec("stewart6").make(Stewart6Geometry.preset("seat"))
    args = ["--platform", "stewart6", "--range-mm", "10", "--speed-mm-s", "150", "--rate", "200"]
    _, t, q = sweep_at_the_drive(args, n=6)
    mm = np.degrees(q)  # the drive's parser reads degrees into radians: undo it
    neutral = 1000.0 * robot.inverse(np.zeros(6))
    park = 1000.0 * robot.park_angles
    np.testing.assert_allclose(mm[-1], park, atol=1e-3)
    lim = robot.limits
    lo, hi = 1000.0 * lim.lower, 1000.0 * lim.upper
    assert np.all(mm >= lo - 1e-3) and np.all(mm <= hi + 1e-3)
    check_wire_limits(t, mm / 1000.0, lim.max_speed, lim.max_accel, "the Stewart sweep")
    # to +10 mm and -10 mm one actuator at a time, in turn, the others at neutral (to the
    # wire's four decimals of a millimetre)
    holds = check_sweep(mm, neutral, 10.0, atol=1e-4)
    assert np.all(np.diff(holds.ravel()) > 0), holds


@pytest.mark.parametrize(
    ("platform", "option", "needle"),
    [
        (
            "ceart",
            "--range-mm",
            "--range-mm/--speed-mm-s: the rus6 platform's actuators are rotary",
        ),
        ("ceart", "--speed-mm-s", "give --range-deg/--speed-deg-s instead"),
        ("stewart6", "--range-deg", "actuators are linear; give --range-mm/--speed-mm-s"),
    ],
)
def test_the_sweep_options_of_the_other_actuator_kind_are_refused(platform, option, needle, capsys):
    """``--range-mm`` on the rotary 6-RUS (or ``--range-deg`` on the Stewart platform's
    linear actuators) used to be ignored and the whole sweep ran at the default range: one
    line, exit 2, before any frame is sent."""
    from motionbase import cli

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    try:
        port = sock.getsockname()[1]
        args = ["output", "--test", f"udp:127.0.0.1:{port}", "--platform", platform]
        code = cli.main([*args, option, "5"])
        err = capsys.readouterr().err
        assert code == 2
        assert needle in err and len(err.strip().splitlines()) == 1, err
        with pytest.raises(socket.timeout):
            sock.recv(4096)  # nothing was sent
    finally:
        sock.close()


@pytest.mark.parametrize(
    ("platform", "args", "needle"),
    [
        ("rrr3", ["--range-deg", "15"], "choose a smaller --range-deg"),
        ("udesc", ["--range-deg", "5"], "choose a smaller --range-deg"),
        ("stewart6", ["--range-mm", "200"], "+-200 mm about neutral leaves the length limits"),
    ],
)
def test_a_sweep_the_robot_cannot_follow_is_refused_before_anything_is_sent(
    platform, args, needle, capsys
):
    """The wiring check moves one actuator at a time, the others held at neutral; a parallel
    robot's platform must follow, and past some offset it cannot: the 3-RRR has no pose
    with servo 1 at +15 deg from home and servos 2 and 3 at home (nor the thesis's own
    ``udesc`` robot, which sits at a fold of its assembly, with servo 1 at +0.1 deg: all its
    assemblies are found here by :meth:`Rrr3.forward_all`, a search over every
    orientation). Only the servo limits were checked, and the drive was sent the servo
    angles, pushing the linkage against itself. Refused now, one line, exit 2, nothing
    sent. A range past the Stewart platform's stroke is refused in millimetres and names
    --range-mm (it said "+-11.4592 deg ... --range-deg")."""
    from motionbase import cli
    from motionbase.platform import Rrr3, Rrr3Geometry

    if platform != "stewart6":  # the independent check: no assembly at all there
        preset = "udesc_symmetric" if platform == "rrr3" else "udesc"
        rrr3 = Rrr3(Rrr3Geometry.preset(preset))
        lo = rrr3.angle_limits[:, 0]
        home = lo + np.mod(rrr3.inverse(rrr3.home) - lo, 2 * math.pi)
        assert len(rrr3.forward_all(home, n_phi=7200)) > 0  # home itself is assembled
        offset = 15.0 if platform == "rrr3" else 0.1
        q = home.copy()
        q[0] += math.radians(offset)  # servo 1, the first one swept
        assert len(rrr3.forward_all(q, n_phi=7200)) == 0, rrr3.forward_all(q)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    try:
        port = sock.getsockname()[1]
        fmt = quote(frame_format(6 if platform == "stewart6" else 3), safe="")
        url = f"udp:127.0.0.1:{port}?format={fmt}"
        code = cli.main(["output", "--test", url, "--platform", platform, *args])
        err = capsys.readouterr().err
        assert code == 2
        assert needle in err and len(err.strip().splitlines()) == 1, err
        assert "deg" not in err if platform == "stewart6" else "mm" not in err
        with pytest.raises(socket.timeout):
            sock.recv(4096)  # nothing was sent
    finally:
        sock.close()


def test_a_range_output_never_sends_a_value_past_its_range(tmp_path, capsys):
    """A 12-bit drive (``unit = "range"``, 0..4095) whose span is +-45 deg of a crank that
    parks at -55 deg (``ceart``): the park command maps to (-55 + 45) / 90 * 4095 = -455,
    outside 0..4095, and was sent (the default drive range was the crank range's image,
    -682..4777). Now the run is refused before a frame is sent, naming the park command; a
    span that holds the park sends only values within 0..4095."""
    from motionbase import cli
    from motionbase.config import preset_path

    def geometry(span: float) -> str:
        path = tmp_path / f"span{span:g}.toml"
        table = '[output]\nunit = "range"\nrange_lo = 0\nrange_hi = 4095\n'
        table += f"span_min_deg = {-span}\nspan_max_deg = {span}\n"
        path.write_text(preset_path("rus6", "ceart").read_text() + "\n" + table)
        return str(path)

    fmt = quote("text:" + ",".join(f"{{{i}}}" for i in range(1, 7)) + "\\n", safe="")
    rx = UdpDrive()
    try:
        url = f"udp:127.0.0.1:{rx.port}?rate=200&format={fmt}"
        code = cli.main(["output", "--test", url, "--platform", geometry(45.0)])
        err = capsys.readouterr().err
        assert code == 2 and "park command" in err and len(err.strip().splitlines()) == 1, err
        time.sleep(0.3)
        assert rx.count() == 0  # nothing was sent
        # +-58 deg holds park (-55 deg): every value on the wire within 0..4095, park last
        args = ["--platform", geometry(58.0), "--speed-deg-s", "60", "--range-deg", "5"]
        assert cli.main(["output", "--test", url, *args]) == 0
        rx.drain()
    finally:
        rx.close()
    values = np.array([[int(x) for x in f.strip().split(b",")] for _, f in rx.frames])
    assert len(values) > 100
    assert values.min() >= 0 and values.max() <= 4095
    park = round((-55.0 + 58.0) / 116.0 * 4095.0)  # the span's straight line at park
    assert np.all(np.abs(values[-1] - park) <= 1), values[-1]


def test_a_sweep_end_the_drive_cannot_be_sent_is_refused(tmp_path, capsys):
    """An ``[output]`` drive range of -60..3 deg (or a frame field that stops there) with
    the default +-5 deg sweep: the ends at +5 deg were held, each motor stopped short at
    3 deg and the check ended "exit 0" as if it had shown +5 and -5. Refused now, naming
    the motor and its drive value, one line, exit 2, nothing sent; --range-deg 3 runs."""
    from motionbase import cli
    from motionbase.config import preset_path

    path = tmp_path / "narrow.toml"
    table = '[output]\nunit = "deg"\ndrive_min = -60.0\ndrive_max = 3.0\n'
    path.write_text(preset_path("rus6", "ceart").read_text() + "\n" + table)
    rx = UdpDrive()
    try:
        args = ["output", "--test", rx.url(200.0), "--platform", str(path)]
        code = cli.main([*args, "--speed-deg-s", "60"])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert "motor 1 at +5 deg" in err and "choose a smaller --range-deg" in err, err
        time.sleep(0.3)
        assert rx.count() == 0  # nothing was sent
        assert cli.main([*args, "--speed-deg-s", "60", "--range-deg", "3"]) == 0
        rx.drain()
    finally:
        rx.close()
    _, q = rx.angles()
    np.testing.assert_allclose(np.degrees(q).max(), 3.0, atol=1e-4)  # each +3 deg, exactly


def test_a_url_without_a_format_drives_the_3rrr_s_three_servos():
    """``output --test udp:HOST:PORT --platform rrr3`` (no ``format``) was refused with
    "text format 'A{1}B{2}C{3}D{4}E{5}F{6}\\n': placeholder {4}: the motor number must be
    1..3": the default frame had six fields whatever the robot. The 3-RRR's frames are now
    ``A{1}B{2}C{3}\\n``: integer servo degrees, read here by a parser of that frame, from
    home (90 on each servo), one servo at a time 5 deg each way, back to home last."""
    from motionbase.app import output_test
    from motionbase.platform import Rrr3, Rrr3Geometry

    geometry = Rrr3Geometry.preset("udesc_symmetric")
    rrr3 = Rrr3(geometry)
    lo = rrr3.angle_limits[:, 0]
    theta = np.degrees(lo + np.mod(rrr3.inverse(rrr3.home) - lo, 2 * math.pi))
    home = np.array(geometry.servo_direction) * (theta - geometry.servo_zero_deg)  # servo deg
    rx = UdpDrive(n=3)
    try:
        output_test(
            f"udp:127.0.0.1:{rx.port}", "rrr3", speed_deg_s=60.0, rate_hz=200.0,
            echo=lambda s: None,
        )  # fmt: skip
        rx.drain()
    finally:
        rx.close()
    frames = [f for _, f in rx.frames]
    assert frames
    values = []
    for f in frames:
        m = re.fullmatch(rb"A(-?\d+)B(-?\d+)C(-?\d+)\n", f)
        assert m is not None, f
        values.append([int(x) for x in m.groups()])
    deg = np.array(values, dtype=float)
    np.testing.assert_array_equal(deg[-1], [90, 90, 90])  # home, the 3-RRR's park
    np.testing.assert_array_equal(deg[-1], np.round(home))
    dev = deg - np.round(home)
    assert np.abs(dev).max() <= 5 + 1  # 5 deg each way, rounded to whole degrees
    for i in range(3):  # each servo reaches +5 and -5 deg (to the rounding) in turn
        assert dev[:, i].max() >= 4 and dev[:, i].min() <= -4, i


def test_the_url_s_rate_sets_the_sweep_s_rate_and_a_bad_or_contradicting_one_is_refused(
    capsys, tmp_path
):
    """``output --test 'udp:...?rate=R'`` used to run at 100 Hz whatever R was (``rate=nan``
    too): the command line's default overrode the URL. The URL's rate is now the sweep's
    when ``--rate`` is not given, and a URL rate that is not a number, or differs from
    ``--rate``, is one line, exit 2, with nothing sent. So is the ``rate_hz`` of the URL's
    frame-format file (``--rate`` overrode it without a word: 50 Hz frames to a drive
    whose file said 200)."""
    from motionbase import cli
    from motionbase.app import output_test
    from motionbase.pipeline import StopRequest

    stop = StopRequest()
    stop.set("test")  # a stop before the sweep starts: the command parks at once
    rx = UdpDrive()
    try:
        lines = output_test(rx.url(50.0), "ceart", stop=stop, echo=lambda s: None)
        rx.drain()
    finally:
        rx.close()
    assert "frames sent at 50 Hz" in lines[-1], lines
    drive_file = tmp_path / "drive.toml"
    drive_file.write_text('text = "A{1}B{2}C{3}D{4}E{5}F{6}\\n"\nrate_hz = 200.0\n')
    for query, extra, needle in [
        ("rate=nan", [], "rate"),
        ("rate=50", ["--rate", "100"], "give the rate once"),
        (f"format={drive_file}", ["--rate", "50"], "format file's rate 200.0 Hz"),
    ]:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.3)
        try:
            url = f"udp:127.0.0.1:{sock.getsockname()[1]}?{query}"
            code = cli.main(["output", "--test", url, *extra])
            err = capsys.readouterr().err
            assert code == 2 and needle in err and len(err.strip().splitlines()) == 1, err
            with pytest.raises(socket.timeout):
                sock.recv(4096)
        finally:
            sock.close()
