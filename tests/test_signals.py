"""Signals end to end: SIGTERM to a real ``motionbase fly`` mid-flight parks the platform
within the limits and exits cleanly; SIGKILL leaves a readable log of safe commands."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_faults import check_logged_commands, park_angles

from motionbase import app
from motionbase.io.mcap_source import McapSource
from motionbase.pipeline import Pipeline

# --------------------------------------------------------------------------- signals


def _start_fly(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "motionbase.cli", "fly", "c1723", "--realtime", "--out", str(out)]
        + list(extra),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_flight(proc: subprocess.Popen, out: Path, size: int) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < size):
        assert proc.poll() is None, "the run ended before the signal"
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before the signal"


@pytest.mark.parametrize("planar", [False, True], ids=["rus6", "rrr3"])
def test_sigterm_mid_flight_parks_within_limits_and_exits_cleanly(tmp_path, planar):
    out = tmp_path / "term.mcap"
    proc = _start_fly(out, *(["--planar"] if planar else []))
    try:
        _wait_for_flight(proc, out, 200_000)  # a few seconds of flight on disk (lz4 log)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "stopped by SIGTERM" in stdout
    assert "Traceback" not in stderr
    with McapSource(out) as src:
        assert not src.truncated
    config, q, msgs = check_logged_commands(out)
    assert np.array_equal(q[-1], park_angles(config))  # last command: park, exactly
    pose_topic = "/planar/pose" if planar else "/platform/pose"
    phases = [m["phase"] for m in msgs[pose_topic]]
    assert phases[-1] == "parked"
    # the flight was well under way (not over) when the E-stop came, and parking took no
    # longer than the limits allow: stop from full speed, cross the range, stop again
    first_stop = phases.index("stopping")
    assert "running" in phases[:first_stop]
    pipeline = Pipeline(config)
    lim = pipeline.robot.limits
    vmax, amax = lim.max_speed, lim.max_accel
    span = lim.upper - lim.lower + vmax**2 / (2 * amax)
    bound = float(np.max(2 * vmax / amax + span / vmax)) + 3 * config.dt
    assert (len(phases) - first_stop) * config.dt <= bound
    health = msgs["/health"][-1]
    assert health["estops"] == 1
    assert 0.0 <= health["worst_overrun_s"] < 1.0  # measured in a paced run (value not judged)


def test_sigkill_leaves_a_readable_log_whose_commands_are_all_safe(tmp_path):
    out = tmp_path / "killed.mcap"
    proc = _start_fly(out, "--planar")
    try:
        _wait_for_flight(proc, out, 120_000)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    with McapSource(out) as src:
        states = list(src)
        assert src.truncated
    assert len(states) > 120
    check_logged_commands(out)  # whatever survived is a safe, gap-free command sequence
    result = app.replay(out, progress=False)  # the recover path reads what survived
    assert any("truncated" in n for n in result.notes)
