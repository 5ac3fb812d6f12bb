"""Run ``motionbase ARGS`` in a process of its own and send it a signal once it is ready."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path


def signalled(
    args: Sequence[str],
    ready: Callable[[subprocess.Popen], object],
    sig: int = signal.SIGINT,
    timeout_s: float = 60.0,
    env: Mapping[str, str] | None = None,
    group: bool = False,
) -> tuple[int, str]:
    """Start ``python -m motionbase.cli ARGS``, call ``ready(proc)`` (it waits for the
    moment to stop the program), send ``sig``, and wait for the program to end. ``env``:
    environment variables to set for it. ``group``: run it in a process group of its own and
    send the signal to the whole group (its child processes too), as ``timeout`` and
    service managers do.

    Returns
    -------
    (int, str)
        The exit status (negative: killed by that signal) and what it wrote on stderr.
    """
    proc = subprocess.Popen(
        [sys.executable, "-m", "motionbase.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=None if env is None else {**os.environ, **env},
        start_new_session=group,
    )
    try:
        ready(proc)
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, err.decode()


def handlers_installed(
    pid: int, signals: Sequence[int] = (signal.SIGHUP, signal.SIGTERM, signal.SIGQUIT)
) -> bool:
    """True once the process catches ``signals`` (``/proc/PID/status``)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = int(next(ln.split()[1] for ln in text.splitlines() if ln.startswith("SigCgt")), 16)
    return all(caught >> (s - 1) & 1 for s in signals)
