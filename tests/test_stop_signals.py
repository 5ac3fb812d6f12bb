"""Every stop signal reaches the StopRequest of a loop outside the pipeline (teleop, the
motor-drive wiring check) through ``stopping.install_signal_stop``; the handlers go back
after."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from signalled import handlers_installed, signalled

from motionbase.pipeline import StopRequest
from motionbase.stopping import install_signal_stop

ALL = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)


def _deliver(sig: int, stop: StopRequest) -> None:
    os.kill(os.getpid(), sig)  # handled in the main thread at its next bytecode
    for _ in range(200):
        if stop:
            return
        time.sleep(0.005)


@pytest.mark.parametrize("sig", ALL, ids=lambda s: signal.Signals(s).name)
def test_each_stop_signal_raises_the_request_and_the_handlers_go_back(sig):
    before = {s: signal.getsignal(s) for s in ALL}
    stop = StopRequest()
    restore = install_signal_stop(stop)
    try:
        _deliver(sig, stop)
    finally:
        restore()
    assert stop and stop.reason == signal.Signals(sig).name
    assert {s: signal.getsignal(s) for s in ALL} == before


@pytest.mark.parametrize("after_s", [0.3, 1.0, 2.0])
def test_ctrl_c_during_a_measurement_is_one_line_and_exit_130(after_s, tmp_path):
    """``omct`` moves nothing: Ctrl-C simply ends it, at any moment, with one line and
    exit 130, also while it loads matplotlib (whose imports turn the KeyboardInterrupt
    into a RuntimeError) or numba compiles its kernels (whose callbacks drop it)."""
    args = ["omct", "--out", str(tmp_path / "o")]
    fresh = {"NUMBA_CACHE_DIR": str(tmp_path / "numba")}  # compiles as a fresh install does
    status, err = signalled(args, lambda _: time.sleep(after_s), env=fresh)
    assert err.strip() == "motionbase omct: interrupted"
    assert status == 130


def _drawing(tmp_path):
    """Wait until ``omct`` draws: its staging folder (``.o.PID.part``) is in ``tmp_path``."""

    def ready(proc: subprocess.Popen) -> None:
        deadline = time.monotonic() + 240  # a watchdog, not a bound
        while not list(tmp_path.glob(".o.*.part")):
            assert proc.poll() is None, "omct ended before it drew"
            assert time.monotonic() < deadline, "omct never began to draw"
            time.sleep(0.005)

    return ready


def _computing(sig: int):
    """A second after ``omct`` catches ``sig`` (a loaded machine took over a second to start
    Python itself, and the signal's default action killed it before a word)."""

    def ready(proc: subprocess.Popen) -> None:
        deadline = time.monotonic() + 120  # a watchdog, not a bound
        while not handlers_installed(proc.pid, [sig]):
            assert proc.poll() is None, "omct ended before it caught the signal"
            assert time.monotonic() < deadline, "omct never caught the signal"
            time.sleep(0.005)
        time.sleep(1.0)

    return ready


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
@pytest.mark.parametrize("when", ["computing", "drawing"])
def test_a_sigterm_ends_a_measurement_as_ctrl_c_does_and_leaves_no_part_file(sig, when, tmp_path):
    """SIGTERM or SIGHUP (a closed terminal) to ``omct`` while it computes (a second after
    it started: the test takes many) or draws (once its staging folder is there): one line
    naming the signal, exit 128 + its number, and no folder or temporary file left (its
    default action used to kill it without a word, a staging folder left behind). (The
    signal came after fixed times, and a run that had ended by then passed unchecked.)"""
    args = ["omct", "--rate", "30", "--out", str(tmp_path / "o")]
    ready = _computing(sig) if when == "computing" else _drawing(tmp_path)
    status, err = signalled(args, ready, sig, timeout_s=240)
    assert err.strip() == f"motionbase omct: interrupted ({sig.name})"
    assert status == 128 + sig
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_while_the_command_imports_is_one_line_and_exit_130(tmp_path):
    """A Ctrl-C that lands while the command still imports numpy (a few tenths of a second
    after it starts; before, a traceback): made to land there every time by raising the
    KeyboardInterrupt from the import of numpy itself."""
    code = (
        "import builtins, runpy, sys\n"
        "real = builtins.__import__\n"
        "def ctrl_c_at_numpy(name, *args, **kwargs):\n"
        "    if name == 'numpy':\n"
        "        raise KeyboardInterrupt\n"
        "    return real(name, *args, **kwargs)\n"
        "builtins.__import__ = ctrl_c_at_numpy\n"
        f"sys.argv = ['motionbase', 'omct', '--out', {str(tmp_path / 'o')!r}]\n"
        "runpy.run_module('motionbase.cli', run_name='__main__')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.stderr.strip() == "motionbase omct: interrupted"
    assert done.returncode == 130
    assert not (tmp_path / "o").exists()


def _signalled_at_numpy(module: str, args: list[str], sig: int) -> subprocess.CompletedProcess:
    """``python -m MODULE ARGS`` with ``sig`` sent to itself while it imports numpy (a few
    tenths of a second after it starts, before any job has routed the stop signals). The
    signal's handler is first made Python's default, as a terminal's shell starts a command
    (under ``nohup`` or in a background job, SIGHUP or SIGINT come ignored, and stay so)."""
    default = "signal.default_int_handler" if sig == signal.SIGINT else "signal.SIG_DFL"
    code = (
        "import builtins, os, runpy, signal, sys\n"
        f"signal.signal({int(sig)}, {default})\n"
        "real = builtins.__import__\n"
        "def signal_at_numpy(name, *args, **kwargs):\n"
        "    if name == 'numpy' and 'numpy' not in sys.modules:\n"
        f"        os.kill(os.getpid(), {int(sig)})\n"
        "    return real(name, *args, **kwargs)\n"
        "builtins.__import__ = signal_at_numpy\n"
        f"sys.argv = ['motionbase', *{args!r}]\n"
        f"runpy.run_module({module!r}, run_name='__main__')\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    ("module", "sig"),
    [
        ("motionbase.cli", signal.SIGTERM),
        ("motionbase", signal.SIGTERM),
        ("motionbase", signal.SIGINT),
    ],
)
def test_a_stop_signal_while_the_command_imports_ends_a_measurement_as_ctrl_c_does(
    module, sig, tmp_path
):
    """SIGTERM while the command still imports (its default action would kill the process
    without a word), or Ctrl-C: remembered, and the job that moves nothing then ends at once
    as Ctrl-C ends it, one line naming the signal, exit 128 + its number (``python -m
    motionbase.cli``, and ``python -m motionbase``, the ``motionbase`` command's entry)."""
    done = _signalled_at_numpy(module, ["omct", "--out", str(tmp_path / "o")], sig)
    by = "" if sig == signal.SIGINT else f" ({sig.name})"
    assert done.stderr.strip() == f"motionbase omct: interrupted{by}"
    assert done.returncode == 128 + sig
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT], ids=lambda s: s.name)
def test_a_stop_signal_while_the_command_imports_stops_a_flight_before_it_moves(sig, tmp_path):
    """SIGHUP (a closed terminal) or Ctrl-C while ``fly`` still imports: the flight is
    stopped before its first tick, as a stop signal a moment later stops it: exit 0,
    "stopped by SIGHUP", and the log holds the one park tick."""
    from mcap.reader import make_reader

    out = tmp_path / "f.mcap"
    args = ["fly", "c1723", "--duration", "5", "--out", str(out)]
    done = _signalled_at_numpy("motionbase", args, sig)
    assert done.returncode == 0, done.stderr
    assert f"stopped by {sig.name}" in done.stdout and "Traceback" not in done.stderr
    with out.open("rb") as f:
        topics = [channel.topic for _, channel, _ in make_reader(f).iter_messages()]
    assert "/aircraft/state" not in topics  # the source was never read
    assert topics.count("/platform/pose") == 1


def test_a_finalizer_that_fails_after_ctrl_c_adds_nothing_to_the_one_line():
    """A Ctrl-C that lands inside a library's constructor (llvmlite's, while numba compiles)
    leaves a half-built object whose finalizer fails when the process exits; Python would
    print "Exception ignored in ..." and a traceback after the one line. Made to happen every
    time with a command whose object fails so."""
    code = (
        "import sys\n"
        "from motionbase import cli\n"
        "class HalfBuilt:\n"
        "    def __del__(self):\n"
        "        raise AttributeError('no attribute _as_parameter_')\n"
        "def command(args):\n"
        "    global left\n"
        "    left = HalfBuilt()  # finalized at exit\n"
        "    raise KeyboardInterrupt\n"
        "cli.COMMANDS[:] = [(n, h, a, command if n == 'workspace' else r)\n"
        "                   for n, h, a, r in cli.COMMANDS]\n"
        "sys.exit(cli.main(['workspace']))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.stderr.strip() == "motionbase workspace: interrupted"
    assert done.returncode == 130


def test_an_object_that_ctrl_c_left_half_built_is_never_freed():
    """Freed, an LLVM module that a Ctrl-C left half built (llvmlite's, while numba compiles)
    crashes the process inside LLVM: the shell saw -11 after the line "interrupted" (CI, a
    fresh numba cache, Ctrl-C after 1 s). Made to happen every time with an object whose
    finalizer crashes the process, held by the frame the Ctrl-C cut short."""
    code = (
        "import os, signal, sys\n"
        "from motionbase import cli\n"
        "class HalfBuilt:\n"
        "    def __del__(self):\n"
        "        os.kill(os.getpid(), signal.SIGSEGV)\n"
        "def command(args):\n"
        "    module = HalfBuilt()  # a local of the frame Ctrl-C ends\n"
        "    raise KeyboardInterrupt\n"
        "cli.COMMANDS[:] = [(n, h, a, command if n == 'workspace' else r)\n"
        "                   for n, h, a, r in cli.COMMANDS]\n"
        "sys.exit(cli.main(['workspace']))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.stderr.strip() == "motionbase workspace: interrupted"
    assert done.returncode == 130


def test_an_error_after_a_swallowed_ctrl_c_ends_the_block_as_ctrl_c():
    """Compiled code can swallow the KeyboardInterrupt and fail later with an error of its
    own that does not name it (numba: "no compiled object yet"): inside
    ``insistent_ctrl_c`` that error comes out as a KeyboardInterrupt caused by it."""
    from motionbase.stopping import insistent_ctrl_c

    with pytest.raises(KeyboardInterrupt) as caught:
        with insistent_ctrl_c(period_s=30.0):
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5.0)
            except KeyboardInterrupt:
                pass  # swallowed, as a C callback does
            raise RuntimeError("no compiled object yet")
    assert isinstance(caught.value.__cause__, RuntimeError)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(ValueError):  # without a Ctrl-C an error is itself
        with insistent_ctrl_c():
            raise ValueError("a bug")


def test_an_error_caused_by_ctrl_c_counts_as_ctrl_c():
    from motionbase.cli import _raised_by_ctrl_c

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__") from exc
    except RuntimeError as wrapped:
        assert _raised_by_ctrl_c(wrapped)
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise ValueError("raised while handling it") from None
    except ValueError as hidden:
        assert _raised_by_ctrl_c(hidden)  # the context is still there
    assert not _raised_by_ctrl_c(RuntimeError("a bug"))


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")  # none reported
def test_ctrl_c_is_not_lost_in_a_c_callback():
    """A KeyboardInterrupt raised while C code runs a Python callback is printed and dropped
    by Python (numba's compiler works through such callbacks); inside
    ``insistent_ctrl_c`` the Ctrl-C comes again until the Python code it stops sees it."""
    import ctypes
    import threading

    from motionbase.stopping import insistent_ctrl_c

    callback = ctypes.CFUNCTYPE(None)(lambda: time.sleep(0.5))  # the signal lands in here
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with insistent_ctrl_c(period_s=0.05):
            threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT)).start()
            callback()  # drops the first KeyboardInterrupt ("Exception ignored ...")
            reached.append(True)  # the Ctrl-C was lost here
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:  # plain Python work: the next one stops it
                time.sleep(0.01)
    assert reached  # the callback did drop it
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
