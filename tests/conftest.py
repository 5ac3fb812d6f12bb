"""What some tests need from outside the repository, and how they say when it is missing.

Real flight logs
    ``vtol.tlog`` and ``erle_plane_329.BIN`` are real MAVLink logs that the repository does not
    ship. The environment variable ``MOTIONBASE_TEST_DATA`` names the folder holding them; a
    test that reads them takes the :func:`flight_data` fixture, which skips the test (with that
    reason) when the variable is unset, and fails it when the variable names a folder without
    the logs. ``.ci/run`` sets it to ``../shared/data``.

A virtual screen
    The teleop mouse-window test needs ``Xvfb``, ``xdotool`` and Tk. Without them it is skipped
    with the reason, unless ``MOTIONBASE_REQUIRE_DISPLAY=1`` (``.ci/run`` sets it, after
    installing them), which turns the skip into a failure.

Ctrl-C as a terminal gives it
    A shell without job control starts a background command (``pytest ... &``) with SIGINT
    ignored, and the programs the tests start inherit that: the tests of Ctrl-C would then
    see nothing happen. :func:`pytest_configure` gives the test run Python's own SIGINT handler
    back; the processes the tests start get the default disposition (a handler does not
    survive ``exec``), so Python installs its handler in them too.

The code under test in the processes the tests start
    ``PYTHONPATH=src pytest ...`` names the worktree's code relative to the current folder; a
    process a test starts in another folder (``cwd=tmp_path``) then imported the installed
    ``motionbase`` instead, another checkout's. :func:`pytest_configure` makes the entries
    absolute.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
from pathlib import Path

import pytest

#: The environment variable naming the folder of real flight logs.
FLIGHT_DATA_ENV = "MOTIONBASE_TEST_DATA"
#: The logs that folder must hold.
FLIGHT_LOGS = ("vtol.tlog", "erle_plane_329.BIN")
#: Set to 1 to fail, instead of skip, a test whose virtual screen cannot start.
REQUIRE_DISPLAY_ENV = "MOTIONBASE_REQUIRE_DISPLAY"


def pytest_configure(config):
    """Undo an inherited ``SIGINT`` ignore (a background start); make ``PYTHONPATH``
    absolute (see the module notes)."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if os.environ.get("PYTHONPATH"):
        parts = os.environ["PYTHONPATH"].split(os.pathsep)
        os.environ["PYTHONPATH"] = os.pathsep.join(os.path.abspath(p) for p in parts if p)


@pytest.fixture(scope="session")
def streamed(tmp_path_factory):
    """``motionbase stream LOG --fast`` with its defaults, run once per log for all the tests
    that read it (a real log takes tens of seconds): ``streamed(path) -> (result, log path)``.
    The tests only read the log."""
    runs: dict[Path, tuple] = {}

    def stream(log: Path) -> tuple:
        if log not in runs:
            from motionbase import app

            out = tmp_path_factory.mktemp("streamed") / "log.mcap"
            runs[log] = (app.stream(str(log), realtime=False, out=out, progress=False), out)
        return runs[log]

    return stream


@pytest.fixture
def flight_data() -> Path:
    """The folder of real flight logs (``$MOTIONBASE_TEST_DATA``, absolute).

    Skips the test when the variable is unset or empty; fails it when the folder lacks one of
    :data:`FLIGHT_LOGS` (the variable is set, so the logs were meant to be there).
    """
    value = os.environ.get(FLIGHT_DATA_ENV, "")
    if not value:
        pytest.skip(
            f"{FLIGHT_DATA_ENV} is unset: set it to the folder holding the real flight logs "
            f"{' and '.join(FLIGHT_LOGS)} (.ci/run sets it to ../shared/data)"
        )
    folder = Path(value).expanduser().resolve()
    missing = [name for name in FLIGHT_LOGS if not (folder / name).is_file()]
    if missing:
        pytest.fail(
            f"{FLIGHT_DATA_ENV}={value} has no {' and no '.join(missing)}: "
            "point it at the folder holding the real flight logs, or unset it to skip these tests"
        )
    return folder


@pytest.fixture
def display_tools() -> dict[str, str]:
    """Paths of ``Xvfb`` and ``xdotool``, with Tk importable.

    Skips the test, naming what is missing, when they are not all there; fails it instead
    when ``MOTIONBASE_REQUIRE_DISPLAY`` is set (to anything but 0), as on a machine that
    must run it (``.ci/run``).
    """
    tools = {name: shutil.which(name) for name in ("Xvfb", "xdotool")}
    missing = [name for name, path in tools.items() if path is None]
    if importlib.util.find_spec("tkinter") is None:
        missing.append("tkinter")
    if missing:
        reason = (
            f"{' and '.join(missing)} missing: the mouse-window test draws a real Tk window on "
            "a virtual screen (apt-get install xvfb xdotool python3-tk)"
        )
        if os.environ.get(REQUIRE_DISPLAY_ENV, "") not in ("", "0"):
            pytest.fail(f"{reason}; {REQUIRE_DISPLAY_ENV} is set, so this machine must run it")
        pytest.skip(reason)
    return {name: str(path) for name, path in tools.items()}


@pytest.fixture
def fresh_logger(monkeypatch):
    """The library's logger as a fresh process has it: no handler, propagating (pytest's
    capture sees its records). ``cli.main`` then installs its own warning handler on the
    stderr of the moment, this test's; an earlier test's ``cli.main`` left one otherwise."""
    import logging

    log = logging.getLogger("motionbase")
    monkeypatch.setattr(log, "handlers", [])
    monkeypatch.setattr(log, "propagate", True)
    return log
