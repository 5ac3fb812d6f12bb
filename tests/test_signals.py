"""Signals end to end, on real ``motionbase fly --output udp:...`` processes and a loopback drive.

Every way a run can be asked to stop (SIGINT, SIGTERM, SIGHUP, SIGQUIT, a closed terminal),
at start-up while the program still loads and in mid-flight, parks the platform and closes
the log: the last frame on the wire is the park command and the MCAP log reads back complete
with the ``mcap`` library's reader. A stop moves at the soft-start pace; a second signal while
stopping is an E-stop, within the speed and acceleration limits. SIGKILL leaves a readable log
of safe commands. (The runs of each group go at once: each takes seconds of real time.)
"""

from __future__ import annotations

import os
import pty
import select
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from drive_wire import UdpDrive, check_wire_limits, read_complete_log, states_of_a_killed_run
from signalled import handlers_installed
from test_faults import check_logged_commands
from test_mcap_log import _process_state

from motionbase import app
from motionbase.platform import Rus6Geometry
from motionbase.stopping import StopRequest, install_signal_stop

GEOMETRY = Rus6Geometry.preset("ceart")
PARK = np.full(6, GEOMETRY.park_angle)
WIRE_TOL = np.radians(1e-4)  # the drive frame's four decimals of a degree
STOP_SIGNALS = ["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"]
#: in flight Ctrl-Z (SIGTSTP) stops too: it used to suspend the run, the platform moving
IN_FLIGHT = [*STOP_SIGNALS, "SIGTSTP"]


@dataclass
class Run:
    """One ``motionbase fly`` process with its drive, its log and what it printed."""

    out: Path
    drive: UdpDrive
    proc: subprocess.Popen
    stdout: str = ""
    stderr: str = ""
    pty_master: int | None = None
    tty_text: bytearray = field(default_factory=bytearray)
    vehicle: subprocess.Popen | None = None  # a MAVLink sender for ``stream``

    def finish(self, timeout: float = 240) -> None:
        """Wait for the exit (a watchdog against a run that never stops, not a timing check)."""
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
        self.stdout, self.stderr = out or "", err or ""
        self.drive.drain()
        self.drive.close()
        if self.vehicle is not None:
            self.vehicle.kill()
            self.vehicle.wait()


def start_fly(tmp: Path, name: str, *, on_pty: bool = False) -> Run:
    """``motionbase fly c1723 --output udp:...`` for 60 s of flight (stopped by a signal)."""
    drive = UdpDrive()
    out = tmp / f"{name}.mcap"
    cmd = [sys.executable, "-m", "motionbase.cli", "fly", "c1723", "--duration", "60"]
    cmd += ["--out", str(out), "--output", drive.url()]
    if not on_pty:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        return Run(out, drive, proc)
    # a terminal of its own (its controlling terminal, so closing it sends SIGHUP)
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        cmd,
        stdin=slave,
        stdout=slave,
        stderr=slave,
        preexec_fn=lambda: os.login_tty(0),  # new session, fd 0 its controlling terminal
    )
    os.close(slave)
    run = Run(out, drive, proc, pty_master=master)
    threading.Thread(target=_read_tty, args=(run,), daemon=True).start()
    return run


def start_stream(tmp: Path, name: str) -> Run:
    """``motionbase stream --output udp:...`` from a MAVLink vehicle sending at 100 Hz (its
    own process, ``mavlink_sender.py``) on loopback."""
    from test_stream import free_udp_port

    port = free_udp_port()
    drive = UdpDrive()
    out = tmp / f"{name}.mcap"
    cmd = [sys.executable, "-m", "motionbase.cli", "stream", "--mavlink"]
    cmd += [f"udpin:127.0.0.1:{port}", "--out", str(out), "--output", drive.url()]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    script = Path(__file__).with_name("mavlink_sender.py")
    vehicle = subprocess.Popen(
        [sys.executable, str(script), str(port), "100", "[[0, 600]]"],
        stdout=subprocess.DEVNULL,
    )
    return Run(out, drive, proc, vehicle=vehicle)


def _read_tty(run: Run) -> None:
    """Keep reading the terminal (a full pty would block the run's progress bar)."""
    while run.pty_master is not None:
        try:
            ready, _, _ = select.select([run.pty_master], [], [], 0.05)
            if ready:
                run.tty_text += os.read(run.pty_master, 4096)
        except (OSError, ValueError, TypeError):
            return


def wait_for(pred, proc: subprocess.Popen, what: str, timeout: float = 120) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if proc.poll() is not None:
            out, err = proc.communicate()
            raise AssertionError(f"the run ended before {what}: {out} {err}")
        assert time.monotonic() < end, f"never saw {what}"
        time.sleep(0.002)


def flying(drive: UdpDrive) -> bool:
    """The drive has had frames for 5 s at 100 Hz: the soft start (2 s from the first one)
    is long over, the platform is in full motion."""
    return drive.count() >= 500


def check_parked_and_logged(run: Run) -> dict:
    """The common promises: park last on the wire, limits on the wire, a complete log ending
    parked, on the park command exactly. Returns the log's messages."""
    t, q = run.drive.angles()
    assert len(t) > 0, "nothing on the wire"
    np.testing.assert_allclose(q[-1], PARK, atol=WIRE_TOL)  # the last frame: park
    check_wire_limits(t, q, GEOMETRY.max_speed, GEOMETRY.max_accel)
    msgs = read_complete_log(run.out)  # finished: summary and footer, every message
    assert np.array_equal(msgs["/platform/actuators"][-1]["angles"], PARK)
    assert msgs["/platform/pose"][-1]["phase"] == "parked"
    return msgs


# --------------------------------------------------------------------------- start-up


def test_a_stop_signal_while_the_program_loads_moves_nothing(tmp_path):
    """Sent as soon as the handlers are in (before numba, the kernels and JSBSim load): the
    run stops before its first tick; the drive gets the park command only, the log is
    complete and holds one park tick."""
    runs = {}
    for name in STOP_SIGNALS:
        run = start_fly(tmp_path, name)
        wait_for(lambda r=run: handlers_installed(r.proc.pid), run.proc, "the stop handlers")
        run.proc.send_signal(getattr(signal, name))
        runs[name] = run
    for name, run in runs.items():
        run.finish()
        assert run.proc.returncode == 0, (name, run.stderr)
        assert f"stopped by {name}" in run.stdout, run.stdout
        assert "Traceback" not in run.stderr
        msgs = check_parked_and_logged(run)
        t, q = run.drive.angles()
        assert np.allclose(q, PARK, atol=WIRE_TOL), f"{name}: the drive moved"
        assert "/aircraft/state" not in msgs  # the source was never read
        assert [m["phase"] for m in msgs["/platform/pose"]] == ["parked"]
        assert msgs["/health"][-1]["estops"] == 0


# --------------------------------------------------------------------------- mid-flight


@pytest.fixture(scope="module")
def stopped_in_flight(tmp_path_factory) -> dict[str, Run]:
    """Runs stopped in full flight: by each stop signal (Ctrl-Z too), by SIGINT twice (the
    second while parking), by closing the run's terminal, and a live MAVLink ``stream`` by
    Ctrl-C."""
    tmp = tmp_path_factory.mktemp("signals")
    runs = {name: start_fly(tmp, name) for name in [*IN_FLIGHT, "SIGINT twice"]}
    runs["terminal closed"] = start_fly(tmp, "tty", on_pty=True)
    runs["stream SIGINT"] = start_stream(tmp, "stream")
    for name, run in runs.items():
        wait_for(lambda r=run: flying(r.drive), run.proc, "full motion")
        if name == "terminal closed":
            master, run.pty_master = run.pty_master, None
            os.close(master)  # the kernel sends SIGHUP to the session
            continue
        run.proc.send_signal(getattr(signal, name.split()[-1 if "stream" in name else 0]))
        if name == "SIGINT twice":
            n = run.drive.count()
            wait_for(lambda r=run, n=n: r.drive.count() > n + 20, run.proc, "parking")
            run.proc.send_signal(signal.SIGINT)
    for run in runs.values():
        run.finish()
    return runs


@pytest.mark.parametrize("name", [*IN_FLIGHT, "terminal closed", "stream SIGINT"])
def test_a_stop_signal_in_flight_parks_at_the_soft_start_pace(stopped_in_flight, name):
    run = stopped_in_flight[name]
    if name != "terminal closed":  # (a closed terminal hears nothing more)
        assert run.proc.returncode == 0, run.stderr
        assert f"stopped by {name.split()[-1]}" in run.stdout, run.stdout
        assert "Traceback" not in run.stderr
    msgs = check_parked_and_logged(run)
    check_logged_commands(run.out)  # every command safe, in the speed and accel limits
    poses = msgs["/platform/pose"]
    phases = [m["phase"] for m in poses]
    first_stop = phases.index("stopping")
    assert "running" in phases[:first_stop]  # it was flying when the signal came
    config = app.load_config(rate_hz=100.0 if "stream" in name else 120.0)
    ramp = poses[first_stop:]
    # a stop, not an E-stop: the soft ramp back to park, as long as the soft start and far
    # below the speed limit (the limiter never had to act)
    assert msgs["/health"][-1]["estops"] == 0
    assert len(ramp) * config.dt >= config.soft_start_s - config.dt
    assert not any(m["rate_limited"] for m in ramp)
    q = np.array([m["angles"] for m in msgs["/platform/actuators"][first_stop - 1 :]])
    speed = np.abs(np.diff(q, axis=0)).max() / config.dt
    assert speed < 0.5 * GEOMETRY.max_speed[0]


def test_a_second_sigint_while_parking_is_an_e_stop_within_the_limits(stopped_in_flight):
    run = stopped_in_flight["SIGINT twice"]
    assert run.proc.returncode == 0, run.stderr
    assert "stopped by SIGINT, then an E-stop (SIGINT while stopping)" in run.stdout
    msgs = check_parked_and_logged(run)
    check_logged_commands(run.out)  # within the limits, in the log as on the wire
    assert msgs["/health"][-1]["estops"] == 1
    phases = [m["phase"] for m in msgs["/platform/pose"]]
    ramp = msgs["/platform/pose"][phases.index("stopping") :]
    # the E-stop heads for park at once, at the actuators' limits: the limiter shapes it
    assert any(m["rate_limited"] for m in ramp)


# --------------------------------------------------------------------------- in process


def test_install_signal_stop_first_signal_stops_a_second_e_stops_and_restores():
    previous = signal.getsignal(signal.SIGHUP)
    stop = StopRequest()
    restore = install_signal_stop(stop)
    try:
        os.kill(os.getpid(), signal.SIGHUP)
        assert stop and not stop.estop and stop.reason == "SIGHUP"
        os.kill(os.getpid(), signal.SIGQUIT)
        assert stop.estop and stop.reason == "SIGHUP"
        assert stop.estop_reason == "SIGQUIT while stopping"
    finally:
        restore()
    assert signal.getsignal(signal.SIGHUP) == previous


# --------------------------------------------------------------------------- SIGKILL


def test_sigkill_leaves_a_readable_log_whose_commands_are_all_safe(tmp_path):
    out = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase.cli", "fly", "c1723", "--realtime", "--planar"]
        + ["--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        wait_for(lambda: out.exists() and out.stat().st_size >= 120_000, proc, "the flight")
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    # the log's writer process outlives the run and finishes the file with what it was given
    states = states_of_a_killed_run(out)
    assert len(states) > 120
    check_logged_commands(out)  # whatever survived is a safe, gap-free command sequence
    result = app.replay(out, progress=False)
    assert result.summary.samples >= len(states)


_FLY_FROM_A_SCRIPT = (
    "import sys\nfrom motionbase import app\n"
    "r = app.fly('c1723', realtime=True, duration_s=4, out=sys.argv[1], progress=False)\n"
    "print(r.summary_text())"
)


@pytest.mark.parametrize("via", ["cli", "library"])
def test_ctrl_z_suspends_a_run_that_drives_no_motors(via, tmp_path):
    """``fly --realtime`` without ``--output`` drives nothing: Ctrl-Z (SIGTSTP) suspends it as
    it does any program, and once continued it flies to its end. It used to stop it (a
    ``replay --check`` stopped so said "check: not made" and exited 1), though only a run
    that drives motors has a platform to leave moving. The same from a script calling
    ``app.fly`` (whose own signal routing stopped it on Ctrl-Z)."""
    out = tmp_path / "offline.mcap"
    cmd = [sys.executable, "-m", "motionbase", "fly", "c1723", "--realtime", "--duration", "4"]
    if via == "library":
        cmd = [sys.executable, "-c", _FLY_FROM_A_SCRIPT]
    proc = subprocess.Popen(
        [*cmd, *(["--out"] if via == "cli" else []), str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a group of its own whose parent is in its session, as a shell's job: Linux lets
        # no SIGTSTP suspend a process in an orphaned group (pytest's may be one)
        process_group=0,
    )
    try:
        wait_for(out.exists, proc, "the log")  # (the signals are routed before it is made)
        proc.send_signal(signal.SIGTSTP)
        wait_for(lambda: _process_state(proc.pid) == "T", proc, "the run suspended")
        proc.send_signal(signal.SIGCONT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, stderr
    assert "stopped by duration" in stdout
