"""Start-up: a flight imports only what it uses and, once numba's cache is filled, compiles
nothing.

``scipy.signal`` takes about a second to import and nothing in a run needs it (the washout's
filters are designed with ``scipy.linalg``, which numba imports anyway; the perception models
that use ``scipy.signal`` serve ``report``, ``omct`` and the tuner, and import it there).
"""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).parent


def test_a_flight_does_not_import_scipy_signal(tmp_path):
    code = (
        "import sys\n"
        "from motionbase.cli import main\n"
        f"code = main(['fly', 'c1723', '--duration', '1', '--out', {str(tmp_path / 'f.mcap')!r}])\n"
        "print(code, 'scipy.signal' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split()[-2:] == ["0", "False"], out.stdout + out.stderr


#: Runs a command in this process and prints how many functions numba compiled for it.
_COUNT_COMPILES = """
import sys
from numba.core import event
compiled = []
class Count(event.Listener):
    def on_start(self, e):
        compiled.append(e.data["dispatcher"].py_func.__qualname__)
    def on_end(self, e):
        pass
event.register("numba:compile", Count())
from motionbase.cli import main
code = main(sys.argv[1:])
print(code, compiled)
"""


def test_python_dash_m_motionbase_is_the_command():
    """``python -m motionbase`` runs the command line, as the ``motionbase`` script does: its
    version, and a user mistake's one line and exit 2."""
    ok = subprocess.run(
        [sys.executable, "-m", "motionbase", "--version"], capture_output=True, text=True
    )
    assert ok.returncode == 0 and ok.stdout.startswith("motionbase "), ok.stderr
    bad = subprocess.run(
        [sys.executable, "-m", "motionbase", "fly", "no_such_script"],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr


@pytest.mark.parametrize("robot", [[], ["--planar"], ["--platform", "stewart6"]])
def test_a_second_process_compiles_nothing(tmp_path, robot):
    # Every compiled function of a flight comes from numba's on-disk cache once a first
    # process has filled it: a function compiled in every process (typed-list methods built
    # from Python, a kernel without cache=True) costs up to a second of each start-up.
    args = ["fly", "c1723", "--duration", "0.5", "--out", str(tmp_path / "f.mcap"), *robot]
    for _ in range(2):
        out = subprocess.run(
            [sys.executable, "-c", _COUNT_COMPILES, *args], capture_output=True, text=True
        )
    assert out.stdout.splitlines()[-1:] == ["0 []"], out.stdout + out.stderr


def test_a_plug_in_kernel_of_another_signature_is_refused_by_name():
    from motionbase import stages
    from motionbase.washout.classical import ClassicalWashout

    with pytest.raises(TypeError, match="is not a numba function that compiles as"):
        stages.kernel_list(ClassicalWashout.step_kernel, stages.SOLVE_LIST)
    with pytest.raises(TypeError, match="is not a numba function that compiles as"):
        stages.kernel_list(len, stages.STEP_LIST)
    held = stages.kernel_list(ClassicalWashout.step_kernel, stages.STEP_LIST)
    assert len(held) == 1


def test_a_lazily_compiled_plug_in_kernel_is_compiled_for_its_list():
    import numba
    import numpy as np

    from motionbase import stages

    @numba.njit
    def track(params, state, achieved):  # a plug-in's kernel without a signature
        state[:] = params[0] * achieved

    held = stages.kernel_list(track, stages.TRACK_LIST)
    state = np.zeros(3)
    held[0](np.array([2.0]), state, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(state, [2.0, 4.0, 6.0])


def in_a_fresh_process(test):
    """Run ``test`` in a new interpreter (its arguments: strings and paths): in this one, an
    earlier test of the same worker may have loaded the kernel it watches, and a kernel
    first loaded mid-run then passed unseen (teleop's, until the order of the tests
    changed)."""

    @functools.wraps(test)
    def in_its_own(**kwargs):
        args = ", ".join(
            f"{k}={f'Path({str(v)!r})' if isinstance(v, Path) else repr(v)}"
            for k, v in kwargs.items()
        )
        code = (
            f"import sys; from pathlib import Path; sys.path.insert(0, {str(HERE)!r}); "
            f"import test_startup as t; t.{test.__name__}.__wrapped__({args})"
        )
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr[-4000:]

    return in_its_own


def _overload_counts() -> dict[str, int]:
    """How many compiled versions each numba function of motionbase has loaded so far."""
    import numba.core.registry

    counts = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("motionbase"):
            for attr, value in vars(module).items():
                if isinstance(value, numba.core.registry.CPUDispatcher):
                    counts[f"{name}.{attr}"] = len(value.overloads)
    return counts


def _assert_loaded_nothing_since(before: dict[str, int]) -> None:
    """Assert no compiled version was loaded since ``before``; the message names them (the
    test may run without pytest's assertion rewriting: :func:`in_a_fresh_process`)."""
    after = _overload_counts()
    loaded = {k: (before.get(k, 0), n) for k, n in after.items() if n != before.get(k, 0)}
    assert not loaded, f"compiled versions loaded (before, after): {loaded}"


def _run_loading_nothing(pipeline, source):
    """``run(pipeline, source)``; asserts that no compiled code was loaded after its first tick."""
    from motionbase.pipeline import run

    first_tick: list[dict[str, int]] = []

    def at_first_tick(out) -> None:
        if not first_tick:
            first_tick.append(_overload_counts())

    summary = run(pipeline, source, [], progress=at_first_tick)
    _assert_loaded_nothing_since(first_tick[0])
    return summary


def _manoeuvre(rate_hz: float):
    """Two seconds level, then four of a hard oscillation on every axis."""
    import math

    from motionbase.state import AircraftState

    g = 9.80665
    for k in range(int(6 * rate_hz)):
        t = k / rate_hz
        a = 0.0 if t < 2.0 else math.sin(2 * math.pi * 0.7 * t)
        yield AircraftState(t, (12 * a, -12 * a, -g - 8 * a), (2 * a, -2 * a, 1.5 * a))


@pytest.mark.parametrize("robot", ["ceart", "stewart6", "udesc_symmetric"])
@in_a_fresh_process
def test_after_the_warm_up_a_run_loads_no_compiled_code(robot):
    # Loading a compiled function from numba's cache takes milliseconds: one loaded at the
    # first rate-limited tick, or at the end of the run (the loop's parked check), makes a
    # late tick. The run loads what its own loop uses before its first tick.
    from motionbase.app import load_config
    from motionbase.pipeline import Pipeline

    planar = robot == "udesc_symmetric"
    pipeline = Pipeline(load_config(platform=robot, planar=planar, rate_hz=200))  # warms up
    summary = _run_loading_nothing(pipeline, _manoeuvre(200))
    assert summary.running_samples > 0 and pipeline.parked
    assert planar or summary.health.rate_limited > 0  # the limiter's path was taken


@in_a_fresh_process
def test_after_the_warm_up_an_mpc_run_loads_no_compiled_code():
    # The MPC's actuator rows clamp the planned poses out of reach (the robot's clamp on a
    # batch of poses): first loaded where a hard manoeuvre's plan first left the reach.
    from motionbase.app import load_config
    from motionbase.pipeline import Pipeline

    pipeline = Pipeline(load_config(cueing="mpc", rate_hz=100))
    summary = _run_loading_nothing(pipeline, _manoeuvre(100))
    assert summary.running_samples > 0 and pipeline.parked
    assert pipeline.cueing._legs.clamped_points > 0  # the clamp's path was taken


@pytest.mark.parametrize("robot", ["ceart", "stewart6", "rrr3"])
@in_a_fresh_process
def test_after_the_warm_up_a_command_run_loads_no_compiled_code(robot):
    # The same for the command pipeline (output --test, teleop): a wiring sweep, unpaced.
    from motionbase.commanding import CommandPipeline, SweepSource
    from motionbase.platform.robot import load_geometry, robot_spec

    planar = robot == "rrr3"
    name, geometry = load_geometry(None if planar else robot, planar=planar)
    machine = robot_spec(name).make(geometry)
    pipeline = CommandPipeline(machine, rate_hz=200, mode="actuators")
    sweep = SweepSource(machine, range_=0.01, speed=0.2, rate_hz=200, lead_s=pipeline.soft_start_s)
    summary = _run_loading_nothing(pipeline, sweep)
    assert name == robot.replace("ceart", "rus6") and summary.samples > 200 and pipeline.parked


@pytest.mark.parametrize("robot", ["rrr3", "ceart"])
@in_a_fresh_process
def test_teleoperation_loads_no_compiled_code_once_built(robot):
    # Teleop's pipeline (robot poses) is built before its window opens: a kernel first used
    # in the run stalled it there, on a fresh install for seconds (the limiter's kernel for
    # the far jumps' plan, 1.5 s; the brake stage at the first tick without input or the
    # stop; the run's peak tracker). Far jumps, ticks without input, then the stop.
    from motionbase.commanding import Command, CommandPipeline
    from motionbase.pipeline import run
    from motionbase.platform.robot import load_geometry, robot_spec

    planar = robot == "rrr3"
    name, geometry = load_geometry(None if planar else robot, planar=planar)
    machine = robot_spec(name).make(geometry)
    pipeline = CommandPipeline(machine, rate_hz=200, mode="poses")
    before = _overload_counts()
    home = np.array(machine.park_pose, dtype=float)
    far = home.copy()
    far[0] += 0.03  # (reachable from home on both robots)
    edge = home.copy()
    edge[:2] += 0.5  # (out of reach: clamped to the edge, then routed via neutral)

    def commands():
        for k in range(500):
            target = None if 150 <= k < 200 else (far if (k // 50) % 2 else home)
            target = edge if k >= 400 else target
            yield Command(k / 200, None if target is None else target.copy())

    summary = run(pipeline, commands(), [])
    _assert_loaded_nothing_since(before)
    assert pipeline.parked and summary.health.rate_limited > 0 and pipeline.no_input >= 50
    assert summary.health.clamps > 0


@pytest.mark.parametrize("robot", ["ceart", "stewart6", "udesc_symmetric"])
@in_a_fresh_process
def test_the_logs_first_scene_loads_no_compiled_code(robot, tmp_path):
    # The first /platform/scene used to load the robot's compiled joint_points and build
    # its template at the first tick (4-7 ms: a late first tick at 1 kHz); the log's scene
    # builder draws once when it is made.
    from motionbase.app import load_config
    from motionbase.io.pipeline_log import PipelineLog
    from motionbase.pipeline import Pipeline
    from motionbase.state import AircraftState

    planar = robot == "udesc_symmetric"
    pipeline = Pipeline(load_config(platform=robot, planar=planar, rate_hz=200))
    out = pipeline.step(AircraftState(0.0, (0.0, 0.0, -9.80665), (0.0, 0.0, 0.0)))
    with PipelineLog(tmp_path / "a.mcap", {}, robot=pipeline.robot) as log:
        assert log._scene is not None  # drawn once already, when made
        before = _overload_counts()
        log.write(out)
        _assert_loaded_nothing_since(before)


@pytest.mark.parametrize("robot", ["ceart", "rrr3"])
@in_a_fresh_process
def test_a_drive_ramped_by_its_output_loads_no_compiled_code_once_open(robot):
    # fly/stream --output and output --test: the output's sender thread ramps the drive toward
    # each command (the drive-side ramp's kernel); that kernel was first loaded by the first
    # ramped frame, seconds into a wiring check (compiled there on a fresh install), while
    # the sender's frames stopped. Open, a frame at park, then a burst to a far command.
    from drive_wire import UdpDrive

    from motionbase.app import load_config
    from motionbase.io.motor_output import open_outputs
    from motionbase.pipeline import Pipeline

    planar = robot == "rrr3"
    machine = Pipeline(load_config(planar=planar, rate_hz=200)).robot
    drive = UdpDrive(n=machine.n)
    try:
        (sink,) = open_outputs([drive.url(200)], machine, command_dt=1 / 200)
        park = np.array(machine.park_angles, dtype=float)
        far = park + np.radians(8.0) * np.resize([1.0, -1.0], machine.n)
        with sink:
            before = _overload_counts()
            sink.write(park)
            _wait_for(lambda: len(drive.frames) >= 5)
            for a in np.linspace(0.0, 1.0, 50):  # 50 ticks' worth of motion in a burst
                sink.write(park + a * (far - park))
            _wait_for(lambda: sink.ramped > 0)
        _assert_loaded_nothing_since(before)
    finally:
        drive.close()


def _wait_for(pred, timeout: float = 30.0) -> None:
    """Wait until ``pred()`` (a watchdog, not a bound: fails after ``timeout`` s)."""
    import time

    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.005)


def _stderr_at_a_terminal(code: str) -> tuple[str, str]:
    """Run ``python -c code`` with stderr on a pseudo-terminal; (stdout, what it wrote there)."""
    import os
    import pty

    leader, follower = pty.openpty()
    try:
        proc = subprocess.run(
            [sys.executable, "-c", code],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=follower,
            text=True,
            timeout=120,
        )
    finally:
        os.close(follower)
    seen = b""
    while True:
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # the terminal's other end is closed: all was read
            break
        if not chunk:
            break
        seen += chunk
    os.close(leader)
    return proc.stdout, seen.decode()


#: Two functions that numba compiles in this process (no cache), after the CLI's notice is set.
_COMPILE_TWO = """
import numba
from motionbase import cli
cli._notice_compiling()
numba.njit(lambda x: x + 1)(1)
numba.njit(lambda x: x * 2.0)(2.0)
print("compiled")
"""


def test_compiling_is_said_once_at_a_terminal_and_never_into_a_pipe():
    """A fresh installation's first run compiles for half a minute or more; at a terminal it
    says so, once however many functions it compiles. Into a pipe (a log, a test) it says
    nothing, and a process that compiles nothing (the cache filled: the test above) never
    triggers it."""
    from motionbase.cli import COMPILING_NOTICE

    out, seen = _stderr_at_a_terminal(_COMPILE_TWO)
    assert out.strip() == "compiled"
    assert seen.count(COMPILING_NOTICE) == 1 and seen.strip() == COMPILING_NOTICE, seen
    piped = subprocess.run(
        [sys.executable, "-c", _COMPILE_TWO], capture_output=True, text=True, check=True
    )
    assert piped.stdout.strip() == "compiled" and piped.stderr == ""
