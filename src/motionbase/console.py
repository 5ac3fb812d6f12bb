"""Lines for the user, on an output that may have gone away.

A job that moves the platform says what it does as it goes (the wiring check's steps) and
at its end (a summary). Its terminal may close under it (SIGHUP; then every write fails
with EIO), or the reader of its pipe may go away (``| head``; EPIPE). Neither may stop the
job, crash it, or turn its exit status into a traceback's: the job parks and ends as it
would have, and what it had left to say is lost. :func:`tell` is the one place that prints
such lines.
"""

from __future__ import annotations

import os
import sys
from typing import TextIO

__all__ = ["tell"]


def tell(text: str, stream: TextIO | None = None) -> bool:
    """Print ``text`` and a newline on ``stream`` at once; never raise for a lost output.

    When the output is gone (an ``OSError``: a closed terminal, a broken pipe), its file
    descriptor is pointed at the null device: the later lines, and the flush at the
    interpreter's exit, go nowhere instead of failing again.

    Parameters
    ----------
    text : str
        The line (or lines) to print.
    stream : file, optional
        Where to print; default ``sys.stdout`` as it is at the call.

    Returns
    -------
    bool
        True when the line was written, False when the output was gone.
    """
    out = sys.stdout if stream is None else stream
    try:
        print(text, file=out, flush=True)
    except OSError:
        _to_null(out)
        return False
    return True


def _to_null(stream: TextIO) -> None:
    """Point ``stream``'s file descriptor at the null device (when it has one)."""
    try:
        fd = stream.fileno()
    except (OSError, ValueError):  # not a file (a test's capture), or closed
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, fd)
    finally:
        os.close(null)
