"""Teleoperation end to end: cursor file -> calibration -> kinematics -> serial (a real pty)."""

from __future__ import annotations

import bisect
import math
import select
import socket
import threading

import numpy as np
import pytest
from pty_board import Board

from motionbase.cli import main
from motionbase.errors import SourceError
from motionbase.io.cursor_input import FileCursor, UdpCursor
from motionbase.io.mcap_source import read_messages
from motionbase.io.servo_protocol import decode
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


def write_calibration(path):
    px = np.array([[u, v] for u in (0.0, 600.0, 1310.0) for v in (0.0, 400.0, 715.0)])
    pts = np.array([cal_xy(u, v) for u, v in px])
    CursorCalibration.fit(px, pts).to_toml(path)


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
        for _ in range(100):  # let the reader drain the last frame
            if len(board.data) and board.data.endswith(b"r"):
                break
            threading.Event().wait(0.01)
    finally:
        board.close()
    got = decode(bytes(board.data))
    assert [i for i, _ in got] == [0, 1, 2] * (len(got) // 3)
    frames = [tuple(v for _, v in got[i : i + 3]) for i in range(0, len(got), 3)]

    def dedupe(seq):
        return [s for n, s in enumerate(seq) if n == 0 or s != seq[n - 1]]

    assert dedupe(frames) == dedupe(expected)
    assert len(set(expected)) > 10  # the path really moves the servos
    log = read_messages(tmp_path / "run.mcap")
    assert [tuple(m["servo_deg"]) for m in log["/planar/actuators"]] == expected
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
    px = np.array([[u, v] for u in (0.0, 600.0, 1310.0) for v in (0.0, 400.0, 715.0)])
    cal = CursorCalibration.fit(px, np.array([cal_xy(u, v) for u, v in px]))

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
    assert rec.frames[-1] == tuple(rrr3.to_servo(rrr3.inverse(edge)))


def test_joint_speed_and_acceleration_are_limited(tmp_path):
    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    px = np.array([[u, v] for u in (0.0, 600.0, 1310.0) for v in (0.0, 400.0, 715.0)])
    cal = CursorCalibration.fit(px, np.array([cal_xy(u, v) for u, v in px]))
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
    # and it arrives: the last pose is the (reachable) target
    assert np.allclose(
        read_messages(out)["/planar/pose"][-1]["pose"][:2], cal_xy(U0 + 700, V0 - 700)
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
    px = np.array([[u, v] for u in (0.0, 600.0, 1310.0) for v in (0.0, 400.0, 715.0)])
    cal = CursorCalibration.fit(px, np.array([cal_xy(u, v) for u, v in px]))
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
    # resumed and arrived
    np.testing.assert_allclose(poses[-1], target, atol=1e-9)
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
