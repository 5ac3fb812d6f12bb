"""Teleoperation end to end: cursor file -> calibration -> kinematics -> serial (a real pty)."""

from __future__ import annotations

import bisect
import math
import select
import socket
import threading
from pathlib import Path

import numpy as np
import pytest
from pty_board import Board
from test_teleop_jumps import rod_errors

from motionbase.cli import main
from motionbase.errors import SourceError
from motionbase.io.cursor_input import FileCursor, UdpCursor
from motionbase.io.mcap_source import read_messages
from motionbase.io.servo_protocol import decode
from motionbase.pipeline import StopRequest
from motionbase.platform import CursorCalibration, Rrr3, Rrr3Geometry
from motionbase.teleop import run_teleop

L, A_LEN, B_LEN, H = 0.26, 0.04445, 0.0889, 0.08573
BASE = np.array([[0.0, 0.0], [L, 0.0], [L / 2, L * math.sqrt(3) / 2]])
HOME = (L / 2, L * math.sqrt(3) / 6)
K = 2e-5  # m per pixel of the test's calibration
U0, V0 = 600.0, 400.0  # the pixel that maps to home


def cal_xy(u, v):
    return HOME[0] + (u - U0) * K, HOME[1] - (v - V0) * K


def expected_servo(x, y, phi=0.0, modes=(1, -1, -1)):
    """Law of cosines IK + the thesis's Processing servo mapping, written independently."""
    r = H / math.sqrt(3)
    c1 = (x - r * math.cos(math.pi / 6 + phi), y - r * math.sin(math.pi / 6 + phi))
    c2 = (c1[0] + H * math.cos(phi), c1[1] + H * math.sin(phi))
    c3 = (c1[0] + H * math.cos(phi + math.pi / 3), c1[1] + H * math.sin(phi + math.pi / 3))
    C = [c1, c2, c3]
    out = []
    for i in range(3):
        xc, yc = C[i][0] - BASE[i][0], C[i][1] - BASE[i][1]
        d = math.hypot(xc, yc)
        th = math.atan2(yc, xc) + modes[i] * math.acos(
            (d * d + A_LEN**2 - B_LEN**2) / (2 * A_LEN * d)
        )
        deg = math.degrees(math.atan2(math.sin(th), math.cos(th)))
        if i == 2:
            deg = deg + 225 if deg < 0 else deg - 135
        out.append(math.floor(deg + 0.5))
    return tuple(out)


def write_csv(path, duration=1.2, omega=2.0):
    rows = []
    for i in range(int(round(duration * 100)) + 1):
        t = i / 100
        rows.append((t, U0 + 300 * math.sin(omega * t), V0 - 300 * (1 - math.cos(omega * t))))
    path.write_text("t,x,y\n" + "".join(f"{t!r},{u!r},{v!r}\n" for t, u, v in rows))
    return rows


def linear_cal():
    """The calibration of :func:`cal_xy`, fitted over pixels far beyond the tests' cursor
    paths (off its pixels' box a calibration holds the box's edge)."""
    px = np.array([[u, v] for u in (-9000.0, U0, 9000.0) for v in (-9000.0, V0, 9000.0)])
    return CursorCalibration.fit(px, np.array([cal_xy(u, v) for u, v in px]))


def write_calibration(path):
    linear_cal().to_toml(path)


def test_teleop_file_to_pty_sends_exactly_the_predicted_servo_commands(tmp_path):
    rows = write_csv(tmp_path / "cursor.csv")
    write_calibration(tmp_path / "cal.toml")
    times = [r[0] for r in rows]
    expected, targets = [], []
    k = 0
    while k / 50 <= rows[-1][0] + 1e-9:
        j = bisect.bisect_right(times, k / 50 + 1e-9) - 1
        targets.append(cal_xy(rows[j][1], rows[j][2]))
        expected.append(expected_servo(*targets[-1]))
        k += 1
    board = Board()
    try:
        rc = main([
            "teleop", "--input", f"file:{tmp_path / 'cursor.csv'}", "--serial", board.path,
            "--calibration", str(tmp_path / "cal.toml"), "--rate", "50", "--rrr3", "udesc",
            "--out", str(tmp_path / "run.mcap"),
        ])  # fmt: skip
        assert rc == 0
        home = "".join(f"{d}{c}" for d, c in zip(expected_servo(*HOME), "pqr", strict=True))
        for _ in range(200):  # let the reader drain the last frame
            if board.data.endswith(home.encode()):
                break
            threading.Event().wait(0.01)
    finally:
        board.close()
    got = decode(bytes(board.data))
    assert [i for i, _ in got] == [0, 1, 2] * (len(got) // 3)
    frames = [tuple(v for _, v in got[i : i + 3]) for i in range(0, len(got), 3)]

    def dedupe(seq):
        return [s for n, s in enumerate(seq) if n == 0 or s != seq[n - 1]]

    log = read_messages(tmp_path / "run.mcap")
    logged = [tuple(m["servo_deg"]) for m in log["/planar/actuators"]]
    assert dedupe(frames) == dedupe(logged)
    assert len(set(expected)) > 10  # the path really moves the servos
    # while the input lasts, exactly the predicted commands; then it stops and goes home
    assert logged[: len(expected)] == expected
    assert logged[-1] == frames[-1] == expected_servo(*HOME)
    assert log["/health"][-1]["rate_limited"] == 0 and log["/health"][-1]["held"] == 0
    np.testing.assert_allclose([m["target"] for m in log["/cursor"]], targets, atol=1e-12)


def far_file(tmp_path, target_px):
    p = tmp_path / "far.csv"
    p.write_text(
        f"0,{U0},{V0}\n0.1,{target_px[0]},{target_px[1]}\n2.0,{target_px[0]},{target_px[1]}\n"
    )
    return FileCursor(p)


def test_unreachable_targets_are_clamped_or_held(tmp_path):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    cal = linear_cal()

    class Recorder:
        def __init__(self):
            self.frames = []

        def write(self, servo, t=None):
            self.frames.append(tuple(servo))
            return True

    far = (U0 + 5000, V0)  # 10 cm to the right of home: outside the workspace
    rec = Recorder()
    stats = run_teleop(far_file(tmp_path, far), rrr3, cal, sink=rec, realtime=False, clamp=False)
    assert stats.held > 50 and stats.clamps == 0
    home_cmd = tuple(rrr3.to_servo(rrr3.inverse(rrr3.home)))
    assert set(rec.frames) == {home_cmd}  # never moved: the last safe pose was home

    rec = Recorder()
    stats = run_teleop(far_file(tmp_path, far), rrr3, cal, sink=rec, realtime=False)
    assert stats.clamps > 50 and stats.held == 0
    assert len(set(rec.frames)) > 1  # it moved, to the edge of the workspace
    edge, _ = rrr3.clamp(np.array([*cal_xy(*far), 0.0]))
    end = 100  # the last tick of the file (2.0 s at 50 Hz)
    assert rec.frames[end] == tuple(rrr3.to_servo(rrr3.inverse(edge)))
    assert rec.frames[-1] == home_cmd  # then home


def test_joint_speed_and_acceleration_are_limited(tmp_path):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    cal = linear_cal()
    from motionbase.io.mcap_log import McapLogger

    out = tmp_path / "jump.mcap"
    with McapLogger(out, {"test": True}) as log:
        stats = run_teleop(
            far_file(tmp_path, (U0 + 700, V0 - 700)), rrr3, cal, logger=log, realtime=False
        )
    assert stats.rate_limited > 0
    th = np.array([m["angles"] for m in read_messages(out)["/planar/actuators"]])
    dt = 1 / 50
    speed = np.max(np.abs(np.diff(th, axis=0)), axis=1) / dt
    g = rrr3.geometry
    assert speed.max() <= g.max_speed * 1.1
    assert np.max(np.diff(speed)) <= g.max_accel * dt * 1.1
    # and it arrives: the pose at the end of the file (2.0 s) is the (reachable) target
    assert np.allclose(
        read_messages(out)["/planar/pose"][100]["pose"][:2], cal_xy(U0 + 700, V0 - 700)
    )


def test_udp_cursor_lines():
    src = UdpCursor("127.0.0.1", 0).open()
    try:
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        assert src.read(0.0) is None
        tx.sendto(b"100 200\n", ("127.0.0.1", src.port))
        tx.sendto(b"garbage\n300.5 400.25\nnan 3\n", ("127.0.0.1", src.port))
        for _ in range(100):
            if src.read(0.0) == (300.5, 400.25):
                break
            threading.Event().wait(0.01)
        assert src.read(0.0) == (300.5, 400.25)
        assert src.rejected == 2 and src.received == 2
        tx.close()
    finally:
        src.close()


def test_file_cursor_errors(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("t,x,y\n0,1,2\n0.1,abc,3\n")
    with pytest.raises(SourceError, match="line 3"):
        FileCursor(p)
    p.write_text("0,1,2\n-1,1,2\n")
    with pytest.raises(SourceError, match="backwards"):
        FileCursor(p)
    with pytest.raises(SourceError, match="cannot read"):
        FileCursor(tmp_path / "missing.csv")
    p.write_bytes(bytes(range(192, 256)) * 4)  # not UTF-8 (a binary file given by mistake)
    with pytest.raises(SourceError, match="not a text CSV"):
        FileCursor(p)
    assert main(["teleop", "--input", "joystick", "--duration", "0.1"]) == 2


def _sender(port, points, period_s, stop):
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for p in points:
            if stop.is_set():
                return
            tx.sendto(f"{p[0]} {p[1]}\n".encode(), ("127.0.0.1", port))
            stop.wait(period_s)
    finally:
        tx.close()


def test_stale_udp_input_holds_position_then_resumes():
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
    cal = linear_cal()
    goal = (U0 + 1200, V0 - 400)  # 2.4 cm right, 0.8 cm up: reachable, about 0.4 s away
    assert rrr3.reachable(np.array([*cal_xy(*goal), 0.0]))
    src = UdpCursor("127.0.0.1", 0).open()

    class Log:
        def __init__(self):
            self.m = {}

        def add(self, topic, t, d):
            self.m.setdefault(topic, []).append((t, d))

    class Sender:
        """Sends the goal once at the first tick, then silence (the input goes stale), then
        again every tick from tick 60 on (fresh input)."""

        def __init__(self):
            self.tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.k = 0

        def write(self, servo, t=None):
            if self.k == 0 or self.k >= 60:
                self.tx.sendto(f"{goal[0]} {goal[1]}\n".encode(), ("127.0.0.1", src.port))
                for _ in range(200):  # loopback: make sure it has arrived before the next read
                    r, _, _ = select.select([src._sock], [], [], 0.01)
                    if r:
                        break
            self.k += 1
            return True

    log, sender = Log(), Sender()
    try:
        stats = run_teleop(
            src, rrr3, cal, sink=sender, logger=log, realtime=False, duration_s=2.0,
            stale_timeout_s=0.1,
        )  # fmt: skip
    finally:
        sender.tx.close()
        src.close()
    poses = np.array([d["pose"] for _, d in log.m["/planar/pose"]])
    q = np.array([d["angles"] for _, d in log.m["/planar/actuators"]])
    target = np.array([*cal_xy(*goal), 0.0])
    assert stats.watchdog_fades == 1 and 40 < stats.stale_ticks < 60
    # held: stopped short of the goal, at rest, before fresh input returned at tick 60
    assert np.array_equal(q[55], q[59]) and not np.allclose(poses[59], target, atol=1e-3)
    # resumed and arrived (by the end of the run's 2 s, tick 100)
    np.testing.assert_allclose(poses[100], target, atol=1e-9)
    v = np.diff(q, axis=0) * 50
    assert np.abs(v).max() <= rrr3.geometry.max_speed * (1 + 1e-9)
    assert np.abs(np.diff(v, axis=0)).max() * 50 <= rrr3.geometry.max_accel * (1 + 1e-6)


def test_sigint_parks_the_robot_at_home(tmp_path):
    import signal
    import subprocess
    import sys

    from motionbase.io.mcap_source import read_metadata

    out = tmp_path / "sig.mcap"
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    cmd = [sys.executable, "-m", "motionbase.cli", "teleop", "--input", f"udp:127.0.0.1:{port}"]
    cmd += ["--out", str(out), "--duration", "60"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stop = threading.Event()
    # a gaze-like stream toward the right edge of the default screen mapping
    pts = [(700 + 20 * i, 357) for i in range(30)]
    th = threading.Thread(target=_sender, args=(port, pts * 100, 0.02, stop), daemon=True)
    try:
        th.start()
        for _ in range(600):  # wait until the robot has moved away from home
            if out.exists() and out.stat().st_size > 20000:
                break
            threading.Event().wait(0.05)
        threading.Event().wait(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        stop.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "stopped by SIGINT" in stdout
    log = read_messages(out)
    geometry = Rrr3Geometry.from_dict(read_metadata(out)["geometry"])
    rrr3 = Rrr3(geometry)
    servo = [tuple(m["servo_deg"]) for m in log["/planar/actuators"]]
    home = tuple(rrr3.to_servo(rrr3.inverse(rrr3.home)))
    assert len(set(servo)) > 3  # it had moved
    assert servo[-1] == home
    np.testing.assert_allclose(log["/planar/pose"][-1]["pose"], rrr3.home, atol=1e-9)
    q = np.array([m["angles"] for m in log["/planar/actuators"]])
    v = np.diff(q, axis=0) * 50
    assert np.abs(v).max() <= geometry.max_speed * (1 + 1e-9)
    assert np.abs(np.diff(v, axis=0)).max() * 50 <= geometry.max_accel * (1 + 1e-6)
    assert log["/health"][-1]["estops"] == 1


# --------------------------------------------------------------------------- stopping


DT = 1 / 50  # the loop period of these tests, s


def assert_stops_within_limits(q, geometry):
    """Speed and acceleration of the commanded joint angles ``q`` (one row per tick), by
    plain finite differences; after the last command the servos hold it (one more row)."""
    q = np.vstack([q, q[-1:]])
    v = np.diff(q, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    peak_v, peak_a = np.abs(v).max(axis=1), np.abs(a).max(axis=1)
    i, j = int(peak_v.argmax()), int(peak_a.argmax())
    assert peak_v[i] <= geometry.max_speed * (1 + 1e-9), f"{peak_v[i]:.3g} rad/s at tick {i + 1}"
    assert peak_a[j] <= geometry.max_accel * (1 + 1e-6), (
        f"{peak_a[j]:.3g} rad/s^2 at tick {j + 1} of {len(q) - 1}"
    )


def speed_at(q, i):
    """The fastest joint's speed (rad/s) from tick i - 1 to tick i."""
    return float(np.abs(q[i] - q[i - 1]).max()) / DT


class DictLog:
    def __init__(self):
        self.m = {}

    def add(self, topic, t, d):
        self.m.setdefault(topic, []).append((t, d))


def test_end_of_input_brakes_to_rest_within_the_limits_then_goes_home(tmp_path):
    # the cursor circles fast right up to the last row of the file
    write_csv(tmp_path / "fast.csv", duration=1.2, omega=8.0)
    write_calibration(tmp_path / "cal.toml")
    board = Board()
    try:
        rc = main([
            "teleop", "--input", f"file:{tmp_path / 'fast.csv'}", "--serial", board.path,
            "--calibration", str(tmp_path / "cal.toml"), "--rate", "50", "--rrr3", "udesc",
            "--out", str(tmp_path / "run.mcap"),
        ])  # fmt: skip
        assert rc == 0
        home = expected_servo(*HOME)
        tail = "".join(f"{d}{c}" for d, c in zip(home, "pqr", strict=True)).encode()
        for _ in range(200):  # let the reader drain the last frame
            if board.data.endswith(tail):
                break
            threading.Event().wait(0.01)
    finally:
        board.close()
    got = decode(bytes(board.data))
    frames = [tuple(v for _, v in got[i : i + 3]) for i in range(0, len(got), 3)]
    log = read_messages(tmp_path / "run.mcap")
    geometry = Rrr3Geometry.preset("udesc")
    q = np.array([m["angles"] for m in log["/planar/actuators"]])
    servo = [tuple(m["servo_deg"]) for m in log["/planar/actuators"]]
    t = [m["t"] for m in log["/planar/actuators"]]
    end = t.index(log["/cursor"][-1]["t"])  # the last tick with input
    assert end == 60
    # fast at the end of the input: stopping dead there would break the acceleration limit
    assert speed_at(q, end) > geometry.max_accel * DT
    assert_stops_within_limits(q, geometry)
    # then home, at rest: the last frame on the wire and in the log is home
    assert frames[-1] == servo[-1] == servo[-2] == expected_servo(*HOME)
    np.testing.assert_allclose(log["/planar/pose"][-1]["pose"], [*HOME, 0.0], atol=1e-9)
    # every command logged is what the board received (the sink skips repeats)
    assert [s for n, s in enumerate(servo) if n == 0 or s != servo[n - 1]] == [
        f for n, f in enumerate(frames) if n == 0 or f != frames[n - 1]
    ]
    assert log["/health"][-1]["estops"] == 0


@pytest.mark.parametrize("how", ["estop", "duration", "before start"])
def test_a_stop_at_any_moment_parks_at_home_within_the_limits(tmp_path, how):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
    cal = linear_cal()
    write_csv(tmp_path / "fast.csv", duration=5.0, omega=8.0)
    stop = StopRequest()
    if how == "before start":
        stop.set("test", estop=True)

    class Sink:
        def __init__(self):
            self.frames = []

        def write(self, servo, t=None):
            self.frames.append(tuple(servo))
            if how == "estop" and t >= 1.0 - 1e-9:
                stop.set("test", estop=True)
            return True

    log, sink = DictLog(), Sink()
    stats = run_teleop(
        FileCursor(tmp_path / "fast.csv"), rrr3, cal, sink=sink, logger=log, realtime=False,
        stop=stop, duration_s=1.0 if how == "duration" else None,
    )  # fmt: skip
    q = np.array([d["angles"] for _, d in log.m["/planar/actuators"]])
    home = tuple(rrr3.to_servo(rrr3.inverse(rrr3.home)))
    if how == "before start":
        assert sink.frames == [home]  # the first tick's home, nothing else
        assert stats.stopped_by == "test"
        return
    assert speed_at(q, 50) > rrr3.geometry.max_accel * DT  # moving fast when stopped
    assert_stops_within_limits(q, rrr3.geometry)
    assert sink.frames[-1] == home and q.shape[0] > 55
    np.testing.assert_allclose(log.m["/planar/pose"][-1][1]["pose"], rrr3.home, atol=1e-9)
    assert stats.estops == (how == "estop")
    assert stats.stopped_by == {"estop": "test", "duration": "duration"}[how]


def test_no_time_left_to_go_home_still_comes_to_rest_within_the_limits(tmp_path):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
    cal = linear_cal()
    write_csv(tmp_path / "fast.csv", duration=5.0, omega=8.0)
    log = DictLog()
    run_teleop(
        FileCursor(tmp_path / "fast.csv"), rrr3, cal, logger=log, realtime=False,
        duration_s=1.0, max_park_s=0.1,
    )  # fmt: skip
    q = np.array([d["angles"] for _, d in log.m["/planar/actuators"]])
    assert_stops_within_limits(q, rrr3.geometry)
    assert np.array_equal(q[-1], q[-2])  # at rest
    assert not np.allclose(log.m["/planar/pose"][-1][1]["pose"], rrr3.home, atol=1e-3)


def _signalled_teleop(tmp_path, sig: str, ready) -> tuple[int, str, str, list, Path]:
    """Run ``motionbase teleop`` (a fast cursor file, a pseudo-terminal board) in a process
    of its own, call ``ready(proc, board)``, send ``sig``; return its exit status, stdout,
    stderr, the servo frames the board got and the log's path."""
    import signal
    import subprocess
    import sys

    write_csv(tmp_path / "fast.csv", duration=60.0, omega=8.0)
    write_calibration(tmp_path / "cal.toml")
    out = tmp_path / "sig.mcap"
    cmd = [sys.executable, "-m", "motionbase.cli", "teleop", "--input"]
    cmd += [f"file:{tmp_path / 'fast.csv'}", "--calibration", str(tmp_path / "cal.toml")]
    cmd += ["--rrr3", "udesc", "--out", str(out)]
    board = Board()
    proc = None
    try:
        proc = subprocess.Popen(
            cmd + ["--serial", board.path], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        ready(proc, board)
        proc.send_signal(getattr(signal, sig))
        stdout, stderr = proc.communicate(timeout=60)
        threading.Event().wait(0.1)  # the last bytes
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        board.close()
    got = decode(bytes(board.data))
    frames = [tuple(v for _, v in got[i : i + 3]) for i in range(0, len(got), 3)]
    return proc.returncode, stdout, stderr, frames, out


@pytest.mark.parametrize("after_s", [0.2, 0.5, 0.9])
def test_a_sigterm_while_teleop_starts_stops_it_cleanly(tmp_path, after_s):
    """A SIGTERM while the command still imports the teleoperation code (about a second):
    it used to kill the process (status -15, no log); now the stop is routed from the start,
    as for the other jobs: exit 0, "stopped by SIGTERM", and the board got at most the home
    command."""
    status, stdout, stderr, frames, _ = _signalled_teleop(
        tmp_path, "SIGTERM", lambda proc, board: threading.Event().wait(after_s)
    )
    assert status == 0, (status, stderr)
    assert "stopped by SIGTERM" in stdout and not stderr.strip(), stderr
    robot = Rrr3(Rrr3Geometry.preset("udesc"))
    home = tuple(int(round(v)) for v in robot.to_servo(robot.inverse(robot.home)))
    assert not frames or frames[-1] == home, frames[-3:]


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"])
def test_every_stop_signal_to_a_teleop_process_parks_within_the_limits(tmp_path, sig):
    def moving(proc, board) -> None:
        for _ in range(3000):  # until about a second of motion reached the board
            if len(board.data) > 50 * 12 or proc.poll() is not None:
                break
            threading.Event().wait(0.01)
        assert proc.poll() is None, proc.communicate()

    status, stdout, stderr, frames, out = _signalled_teleop(tmp_path, sig, moving)
    assert status == 0, (status, stderr)
    assert f"stopped by {sig}" in stdout
    log = read_messages(out)
    geometry = Rrr3Geometry.preset("udesc")
    q = np.array([m["angles"] for m in log["/planar/actuators"]])
    t = [m["t"] for m in log["/planar/actuators"]]
    end = t.index(log["/cursor"][-1]["t"])  # the last tick before the stop
    assert speed_at(q, end) > geometry.max_accel * DT  # moving fast when stopped
    assert_stops_within_limits(q, geometry)
    assert frames[-1] == tuple(log["/planar/actuators"][-1]["servo_deg"]) == expected_servo(*HOME)
    np.testing.assert_allclose(log["/planar/pose"][-1]["pose"], [*HOME, 0.0], atol=1e-9)


def test_a_full_disk_mid_run_parks_the_robot_then_says_so_in_one_line(tmp_path):
    """The log's file may not grow beyond 40 kB (RLIMIT_FSIZE: writes past it fail with
    EFBIG, as on a full disk): the robot, moving fast, brakes and goes home through the
    serial link, then the error is one line and the exit status 2."""
    import subprocess
    import sys

    write_csv(tmp_path / "fast.csv", duration=60.0, omega=8.0)
    write_calibration(tmp_path / "cal.toml")
    limited = (
        "import resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (40000, 40000)); "
        "from motionbase.cli import main; sys.exit(main(sys.argv[1:]))"
    )
    board = Board()
    try:
        proc = subprocess.run(
            [sys.executable, "-c", limited, "teleop", "--input", f"file:{tmp_path / 'fast.csv'}",
             "--calibration", str(tmp_path / "cal.toml"), "--rrr3", "udesc", "--serial",
             board.path, "--out", str(tmp_path / "full.mcap")],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        threading.Event().wait(0.1)  # the last bytes
    finally:
        board.close()
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "MCAP log" in lines[0] and "parked at home" in lines[0], lines
    got = decode(bytes(board.data))
    frames = np.array([[v for _, v in got[i : i + 3]] for i in range(0, len(got), 3)])
    assert len(frames) > 100  # it ran, and moved
    assert tuple(frames[-1]) == expected_servo(*HOME)
    # integer degrees on the wire: a frame moves at most the speed limit (+1 deg of rounding)
    step = math.degrees(Rrr3Geometry.preset("udesc").max_speed * DT) + 1
    assert np.abs(np.diff(frames, axis=0)).max() <= step


def test_a_serial_link_failing_mid_motion_parks_through_the_log_then_says_so(tmp_path):
    """The serial sink fails (an OSError) while the robot moves fast: the run does not stop
    dead; it brakes and goes home within the limits (what the log, the remaining sink,
    records), and then raises one SinkError naming the failed link."""
    from motionbase.errors import SinkError

    rrr3 = Rrr3(Rrr3Geometry.preset("udesc_symmetric"))
    cal = linear_cal()
    write_csv(tmp_path / "fast.csv", duration=5.0, omega=8.0)

    class FailingLink:
        url = "serial:/dev/ttyFAKE"

        def write(self, servo, t=None):
            if t >= 1.0 - 1e-9:
                raise OSError(5, "Input/output error")
            return True

    log = DictLog()
    with pytest.raises(SinkError, match="ttyFAKE") as info:
        run_teleop(
            FileCursor(tmp_path / "fast.csv"), rrr3, cal, sink=FailingLink(), logger=log,
            realtime=False,
        )  # fmt: skip
    assert "\n" not in str(info.value)
    q = np.array([d["angles"] for _, d in log.m["/planar/actuators"]])
    assert speed_at(q, 50) > rrr3.geometry.max_accel * DT  # moving fast when it failed
    assert q.shape[0] > 55
    assert_stops_within_limits(q, rrr3.geometry)
    np.testing.assert_allclose(log.m["/planar/pose"][-1][1]["pose"], rrr3.home, atol=1e-9)


def test_a_flood_of_cursor_datagrams_cannot_hold_a_read_back():
    """Another process sending cursor lines as fast as it can: read() drained the socket
    until it was empty, which a flood never lets happen, so one read lasted as long as the
    flood (1.7 s of a 2 s flood, from a second process) and the teleop loop stood still. A
    read takes a bounded share of what is queued (here 40 datagrams of 300 lines, 84 kB,
    waiting; a read takes 16 kB at most); the rest waits for the next ticks."""
    src = UdpCursor("127.0.0.1", 0).open()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for i in range(40):
            tx.sendto(f"{i:2d} 200\n".encode() * 300, ("127.0.0.1", src.port))
        first = src.read(0.0)
        after_one = src.received
        reads = 1
        while src.read(0.01 * reads) != (39.0, 200.0):
            reads += 1
            assert reads < 1000
    finally:
        tx.close()
        src.close()
    assert first is not None and first != (39.0, 200.0) and after_one <= 300 * 8
    assert src.received == 40 * 300


def test_a_thousand_hertz_tracker_is_read_to_its_latest_point_every_tick():
    """A research eye tracker sends 1000 points a second: 20 wait at each tick of a 50 Hz
    loop. A read took 16, so the point in use fell behind by 4 a tick, until the socket's
    buffer overflowed: the robot followed the gaze a quarter of a second late (measured
    from a second process). A read takes all 20, and the latest is in use."""
    src = UdpCursor("127.0.0.1", 0).open()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for tick in range(3):
            for i in range(20):
                tx.sendto(f"{100 * tick + i} 200\n".encode(), ("127.0.0.1", src.port))
            assert src.read(0.02 * tick) == (100.0 * tick + 19, 200.0)
    finally:
        tx.close()
        src.close()
    assert src.received == 60


def test_teleop_job_to_the_board_goes_in_real_time_even_when_not_asked(tmp_path):
    """``teleop_job(..., serial_url=BOARD, realtime=False)``: the board's servos are motors,
    so the run is paced in real time all the same, as ``stream --fast --serial`` is. It ran
    as fast as the processor went: 1.2 s of cursor input, its braking and the way home on
    the board in a few hundredths of a second. (The frames' spread on the board is a lower
    bound: a slow machine only spreads them more.)"""
    from motionbase.teleop import teleop_job

    write_csv(tmp_path / "fast.csv", duration=1.2, omega=2.0)
    write_calibration(tmp_path / "cal.toml")
    board = Board()
    try:
        stats = teleop_job(
            f"file:{tmp_path / 'fast.csv'}", serial_url=board.path,
            calibration_path=str(tmp_path / "cal.toml"), rate_hz=50.0, realtime=False,
        )  # fmt: skip
    finally:
        board.close()
    assert stats.stopped_by == "end of input" and stats.ticks > 60
    spread = board.chunks[-1][0] - board.chunks[0][0]
    assert spread >= 1.0, f"1.2 s of input reached the board in {spread:.3f} s"


def test_a_board_that_vanishes_mid_motion_is_not_said_parked(tmp_path):
    """The board's pseudo-terminal closes (a USB cable pulled) while the robot moves fast:
    the run braked and went home in its log, then said "(the robot was parked at home)",
    while the robot, which got no command since, was wherever the last frame had put it.
    One line saying it was not parked, exit status 2; the frames the board got before it
    vanished kept the speed limit."""
    import subprocess
    import sys

    write_csv(tmp_path / "fast.csv", duration=60.0, omega=8.0)
    write_calibration(tmp_path / "cal.toml")
    board = Board()
    cmd = [sys.executable, "-m", "motionbase.cli", "teleop", "--input"]
    cmd += [f"file:{tmp_path / 'fast.csv'}", "--calibration", str(tmp_path / "cal.toml")]
    cmd += ["--rrr3", "udesc", "--serial", board.path]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(3000):  # until about a second of motion reached the board
            if len(board.data) > 50 * 12 or proc.poll() is not None:
                break
            threading.Event().wait(0.01)
        board.close()
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 2, (stdout, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and board.path in lines[0], lines
    assert "not parked" in lines[0] and "parked at home" not in lines[0], lines[0]
    got = decode(bytes(board.data))
    frames = np.array([[v for _, v in got[i : i + 3]] for i in range(0, len(got) // 3 * 3, 3)])
    assert len(set(map(tuple, frames))) > 10  # it moved
    step = math.degrees(Rrr3Geometry.preset("udesc").max_speed * DT) + 1
    assert np.abs(np.diff(frames, axis=0)).max() <= step


def test_far_jumps_across_the_screen_keep_every_leg_at_its_rod_length(tmp_path):
    """The gaze jumps between the screen's corners and mid-edges (the default calibration:
    the screen onto the largest valid rectangle), on the thesis's robot as built. Each tick
    the crank tips that the commanded angles put in place must lie one rod length from
    the platform joints of the logged pose: otherwise no pose holds those angles and the
    servos push the linkage against itself. The approach planned at 80 % of the limits
    broke this on 10 of 324 ticks (by up to a degree; the logged pose froze meanwhile):
    the limiter trimmed the planned step where the path bends in actuator space."""
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    cal = CursorCalibration.default(rrr3, 1310, 715)
    corners = [(0, 0), (1310, 715), (1310, 0), (0, 715), (655, 0), (655, 715), (0, 357)]
    corners += [(1310, 357)]
    p = tmp_path / "jumps.csv"
    p.write_text("".join(f"{0.9 * k},{u},{v}\n" for k, (u, v) in enumerate(corners + [(0, 0)])))
    log = DictLog()
    run_teleop(FileCursor(p), rrr3, cal, logger=log, realtime=False)
    poses = np.array([d["pose"] for _, d in log.m["/planar/pose"]])
    q = np.array([d["angles"] for _, d in log.m["/planar/actuators"]])
    assert len(poses) > 8 * 45
    worst = float(np.abs(rod_errors(rrr3.geometry, poses, q)).max())
    assert worst < 1e-9, f"a rod {worst * 1e3:.3f} mm off its length"
    assert_stops_within_limits(q, rrr3.geometry)
