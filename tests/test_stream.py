"""`motionbase stream`: real pymavlink senders on loopback UDP and real logs, end to end."""

from __future__ import annotations

import math
import os
import re
import socket
import threading
from pathlib import Path

import numpy as np
import pytest
from test_mavlink_source import BIN, TLOG, att_values, f32, imu_values, send_good, sender

from motionbase import app
from motionbase.io.mcap_source import McapSource, read_messages
from motionbase.pipeline import PipelineConfig


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _arr(msgs, key):
    return np.array([m[key] for m in msgs], dtype=float)


def check_actuators_safe(path: Path) -> tuple[np.ndarray, np.ndarray, PipelineConfig]:
    """Every command finite, within angle, speed and acceleration limits."""
    msgs = read_messages(path)
    config = PipelineConfig.from_dict(McapSource(path).metadata["pipeline_config"])
    g = config.geometry
    angles = _arr(msgs["/platform/actuators"], "angles")
    t = _arr(msgs["/platform/actuators"], "t")
    assert np.isfinite(angles).all()
    lo, hi = np.asarray(g.angle_min), np.asarray(g.angle_max)
    assert (angles >= lo).all() and (angles <= hi).all()
    speed = np.diff(angles, axis=0) / np.diff(t)[:, None]
    assert (np.abs(speed) <= np.asarray(g.max_speed) + 1e-6).all()
    accel = np.diff(speed, axis=0) / np.diff(t)[1:, None]
    assert (np.abs(accel) <= np.asarray(g.max_accel) + 1e-3).all()
    return t, angles, config


def test_logged_states_are_what_the_sender_sent(tmp_path):
    port = free_udp_port()
    out = tmp_path / "live.mcap"
    with sender(port, send_good) as sent:
        result = app.stream(
            f"udpin:127.0.0.1:{port}", duration_s=3.0, out=out, rate_hz=100, progress=False
        )
    assert len(sent) > 200
    states = [m for m in read_messages(out)["/aircraft/state"] if m["fresh"]]
    assert len(states) > 150
    n = len(sent) + 10
    f_table = {f32(imu_values(i)[0]): i for i in range(n)}
    w_table = {f32(imu_values(i)[1]): i for i in range(n)}
    a_table = {f32(att_values(i)): i for i in range(n)}
    for m in states:
        # SI units and FRD axes as sent (HIGHRES_IMU and ATTITUDE are SI already)
        i = f_table[tuple(m["specific_force"])]
        assert w_table[tuple(m["angular_velocity"])] == i
        assert abs(a_table[tuple(m["attitude"])] - i) <= 1
    check_actuators_safe(out)
    assert "0 rejected" in "\n".join(result.notes)
    assert result.summary.stopped_by == "duration"  # not "end of source": the link is live


def test_silent_sender_fades_to_neutral_and_resumes_without_a_jump(tmp_path):
    port = free_udp_port()
    out = tmp_path / "gap.mcap"
    # send 0-3 s, silence 3-5.5 s, send again 5.5-8 s
    with sender(port, send_good, phases=((0.0, 3.0), (5.5, 8.0))):
        app.stream(f"udpin:127.0.0.1:{port}", duration_s=8.0, out=out, rate_hz=100, progress=False)
    t, angles, config = check_actuators_safe(out)
    msgs = read_messages(out)
    pose = _arr(msgs["/platform/pose"], "pose")
    fresh = np.array([m["fresh"] for m in msgs["/aircraft/state"]])
    t_state = _arr(msgs["/aircraft/state"], "t")
    stale_t = t_state[~fresh]
    gap = stale_t[(stale_t > 2.0) & (stale_t < 7.0)]
    assert len(gap) > 100, "the silence was not seen"
    gap_start, gap_end = gap.min(), gap.max()
    # the washout's input faded to level flight within the fade time after the watchdog fired,
    # and the platform went back toward neutral through the washout's own filters
    fade = np.array([m["fade"] for m in msgs["/platform/pose"]])
    settled = (t > gap_start + config.fade_s + 0.05) & (t < gap_end)
    assert settled.sum() > 50 and (fade[settled] == 0.0).all()
    late = (t > gap_end - 0.5) & (t < gap_end)
    assert np.abs(pose[late, :3]).max() < 0.03 and np.degrees(np.abs(pose[late, 3:]).max()) < 1.0
    # fades and resumes smoothly: no tick in or after the gap needs the safety stage's limits
    after = (t > gap_start) & (t < gap_end + 2.0)
    limited = np.array([m["rate_limited"] for m in msgs["/platform/pose"]])
    assert not limited[after].any()
    speed = np.abs(np.diff(angles, axis=0)) / np.diff(t)[:, None]
    assert speed[after[1:]].max() < 0.5 * min(config.geometry.max_speed)
    health = msgs["/health"][-1]
    assert health["watchdog_fades"] >= 1


def test_other_systems_and_garbage_never_reach_the_platform(tmp_path):
    port = free_udp_port()
    out = tmp_path / "noisy.mcap"
    marker_f = (3.0, -2.0, -5.0)  # what the intruder sends: far from the real sender's values

    def intruder(mav, i):
        mav.highres_imu_send(i * 10_000, *marker_f, 1.0, 1.0, 1.0, 0, 0, 0, 1013, 0, 0, 20, 0x3F)

    stop = threading.Event()

    def garbage():
        rng = np.random.default_rng(1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            while not stop.wait(0.02):
                s.sendto(rng.integers(0, 256, 64, dtype=np.uint8).tobytes(), ("127.0.0.1", port))

    th = threading.Thread(target=garbage, daemon=True)
    th.start()
    try:
        with sender(port, send_good), sender(port, intruder, sysid=42):
            result = app.stream(f"udpin:127.0.0.1:{port}", duration_s=3.0, out=out, progress=False)
    finally:
        stop.set()
        th.join(5)
    states = read_messages(out)["/aircraft/state"]
    forces = np.array([m["specific_force"] for m in states])
    assert not np.any(np.all(np.isclose(forces, marker_f), axis=1))
    notes = "\n".join(result.notes)
    # the intruder was counted (a check that "other system 0" is absent also passed with no
    # stats line at all)
    assert re.search(r"rejected \(other system [1-9]\d*,", notes), notes
    check_actuators_safe(out)


@pytest.mark.parametrize("log", [TLOG, BIN])
def test_real_logs_stream_to_finite_angles_within_limits(log, flight_data, streamed):
    result, out = streamed(flight_data / log)
    assert result.summary.samples > 10_000
    t, angles, _ = check_actuators_safe(out)
    assert np.ptp(angles, axis=0).min() > np.radians(1)  # the flight does move every crank


def test_a_log_streamed_in_real_time_is_paced_by_the_loop(flight_data, tmp_path):
    """A log in real time (``stream LOG`` without ``--fast``) is paced by the pipeline's
    loop, not by the source (which never waits on a log): two seconds of the log take at
    least two seconds, and the log's metadata says it ran in real time."""
    import time

    from motionbase.io.mavlink_source import MavlinkSource

    assert not MavlinkSource(str(flight_data / TLOG)).paces_itself
    out = tmp_path / "rt.mcap"
    wall0 = time.monotonic()
    result = app.stream(str(flight_data / TLOG), duration_s=2.0, out=out, progress=False)
    wall = time.monotonic() - wall0
    config = PipelineConfig.from_dict(McapSource(out).metadata["pipeline_config"])
    assert wall >= (result.summary.samples - 1) * config.dt >= 2.0
    assert McapSource(out).metadata["source"]["realtime"] is True
    assert result.summary.stopped_by == "duration"  # the log goes on beyond the 2 s
    check_actuators_safe(out)


def _swaying(i: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Strong planar manoeuvring at 100 Hz (surge, sway and yaw at 0.5 Hz): the 3-RRR's
    servos travel tens of degrees each way."""
    s = math.sin(math.pi * i / 100)
    return (8.0 * s, 8.0 * s, -9.80665), (0.0, 0.0, 1.5 * s)


def test_a_log_streamed_fast_to_the_3rrr_board_still_moves_it_in_real_time(tmp_path):
    """``stream LOG --fast --planar --serial PORT``: the servos are motors, so the run goes
    at the pipeline's pace in real time, as with ``--output`` (``--fast`` aside). It ran as
    fast as the processor went: 3 s of the log and the ramps in about 0.1 s of wall time,
    the board's servos travelling hundreds of degrees at several times their speed limit.
    Checked on the frames the board received (a pty), with their arrival times: their
    travel over the wall time, and their speed and acceleration over sliding windows; the
    last frame is park (the home pose, every servo at 90 deg: the udesc_symmetric
    geometry's servo zero)."""
    import subprocess
    import sys

    from drive_wire import check_wire_limits
    from pty_board import Board
    from test_mavlink_source import _crafted_tlog

    from motionbase.io.servo_protocol import ServoDecoder

    log = _crafted_tlog(tmp_path / "sway.tlog", lambda i: i * 10, n=300, values=_swaying)
    board = Board()
    try:
        cmd = [sys.executable, "-m", "motionbase", "stream", "--mavlink", str(log), "--fast"]
        cmd += ["--planar", "--serial", board.path, "--out", str(tmp_path / "run.mcap")]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    finally:
        board.close()
    assert proc.returncode == 0, proc.stderr
    assert "stopped by end of source" in proc.stdout
    # frames: servos 1, 2, 3 in order, each stamped with the read that completed it; a
    # command lost or refused (a frame whose start the board missed, seen under load)
    # leaves an incomplete frame out rather than shifting the rest
    decoder, servo, stamps, part = ServoDecoder(), [], [], []
    for arrival, chunk in board.chunks:
        for motor, deg in decoder.feed(chunk):
            part = part + [deg] if motor == len(part) else ([deg] if motor == 0 else [])
            if len(part) == 3:
                servo.append(part)
                stamps.append(arrival)
                part = []
    t, deg = np.array(stamps), np.array(servo, dtype=float)
    assert len(t) > 50, f"{len(t)} frames; {decoder.dropped} commands refused"
    assert tuple(deg[-1]) == (90.0, 90.0, 90.0)  # home
    vmax, amax = 4.5, 20.0  # udesc_symmetric's limits: rad/s, rad/s^2
    travel = np.radians(np.abs(np.diff(deg, axis=0)).sum(axis=0))
    assert travel.max() > 1.0  # it swayed
    # 0.05 s: the board's reads may lag (a loaded machine); 2 deg: whole servo degrees
    allowed = vmax * (t[-1] - t[0] + 0.05) + np.radians(2.0)
    assert np.all(travel <= allowed), f"{travel} rad in {t[-1] - t[0]:.3f} s on the board"
    check_wire_limits(t, np.radians(deg), vmax, amax, "the 3-RRR's board")


# --------------------------------------------------------------------------- where the log goes


@pytest.mark.parametrize("home", ["", "relative/dir"])
def test_an_empty_or_relative_home_logs_under_the_accounts_home(home, monkeypatch):
    """With ``HOME=""`` the default log folder was ``/.local/share/...`` (``expanduser``
    gives "/" for an empty HOME), outside any user's folder; a relative HOME would put it
    under the working directory. The account's home (the password database) is used."""
    import pwd

    from motionbase.app import user_recordings_dir

    monkeypatch.delenv("XDG_DATA_HOME", raising=False)
    monkeypatch.setenv("HOME", home)
    account = Path(pwd.getpwuid(os.getuid()).pw_dir)
    assert user_recordings_dir() == account / ".local/share/motionbase/recordings"


@pytest.mark.parametrize("xdg", [False, True], ids=["home", "XDG_DATA_HOME"])
def test_stream_without_out_logs_to_the_user_data_folder(xdg, tmp_path):
    """No `recordings/` left in the folder the command ran from (a checkout, say): the log goes
    to the per-user data folder, created on demand, and the summary says where."""
    import os
    import subprocess
    import sys

    cwd, home = tmp_path / "checkout", tmp_path / "home"
    cwd.mkdir()
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "XDG_DATA_HOME"}
    env["HOME"] = str(home)
    folder = home / ".local" / "share" / "motionbase" / "recordings"
    if xdg:
        env["XDG_DATA_HOME"] = str(tmp_path / "xdg")
        folder = tmp_path / "xdg" / "motionbase" / "recordings"
    url = f"udpin:127.0.0.1:{free_udp_port()}"
    proc = subprocess.run(
        [sys.executable, "-m", "motionbase.cli", "stream", "--mavlink", url, "--duration", "1"],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert list(cwd.iterdir()) == []
    logs = list(folder.glob("stream-*.mcap"))
    assert len(logs) == 1, list(tmp_path.rglob("*.mcap"))
    assert f"log: {logs[0]} (" in proc.stdout
    assert read_messages(logs[0])["/platform/actuators"]  # a real log of the run


def test_mpc_live_with_a_solver_failing_now_and_then_and_a_silence(tmp_path):
    """``stream --cueing mpc`` from a real sender over loopback, with a solver of 20
    iterations (it fails now and then, as one with a time budget does under load) and the
    sender silent for 2 s: each tick's solver status, iterations, solve time and fallback
    go to ``/cueing/mpc``; the blend to the fallback and back never turns at once (the
    weight accelerates no more than the smoothstep over blend_s; it zig-zagged, and the
    limiter had to cap the actuators); no command needs the limiter; the platform fades
    through the silence and parks within limits; ``replay --check`` gives the same run."""
    import dataclasses

    from motionbase.config import write_toml
    from motionbase.washout.mpc_params import MpcParams

    params = dataclasses.replace(MpcParams.load("tuned_ceart"), max_iter=20, time_limit_ms=0.0)
    write_toml(tmp_path / "mpc20.toml", params.to_dict())
    port, out = free_udp_port(), tmp_path / "mpc.mcap"
    with sender(port, send_good, phases=((0.0, 3.0), (5.0, 7.5))):
        args = {"cueing": "mpc", "washout": str(tmp_path / "mpc20.toml"), "progress": False}
        result = app.stream(f"udpin:127.0.0.1:{port}", duration_s=8.0, out=out, **args)
    check_actuators_safe(out)
    msgs = read_messages(out)
    diag = msgs["/cueing/mpc"]
    assert len(diag) == len(msgs["/platform/pose"])  # every tick, the park ramps too
    failed = np.array([d["fallback"] for d in diag])
    assert 0 < failed.sum() < len(diag), failed.sum()  # now and then
    for d in diag:
        assert (d["status"] in ("solved", "solved inaccurate")) != d["fallback"], d
        assert 0 <= d["iterations"] <= 20 and d["solve_time_s"] > 0.0
    weight = _arr(diag, "weight")
    assert np.abs(np.diff(weight, 2)).max() <= 6.0 * (0.01 / params.blend_s) ** 2 * (1 + 1e-9)
    assert not any(m["rate_limited"] for m in msgs["/platform/pose"])
    assert msgs["/health"][-1]["watchdog_fades"] >= 1
    assert any("the solver failed on" in n for n in result.notes)
    assert not app.replay(out, check=True, progress=False).failed
