"""Files written whole or not at all: what a Ctrl-C, a SIGTERM or a full disk leaves behind.

:func:`whole_file` yields a temporary path beside the file to write and renames it onto the
file at the end (one atomic step); :func:`whole_folder` does the same for a set of files
(the objective motion cueing test's JSON, tables and plots): they are written into a
staging folder beside the folder and moved into it at the end, with the stop signals held
back while they move. A writing that fails or is interrupted leaves the old file or folder
as it was, and no temporary file.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
from collections.abc import Iterator
from pathlib import Path

from motionbase.stopping import STOP_SIGNALS

__all__ = ["folder_problem", "whole_file", "whole_folder"]


def folder_problem(folder: str | os.PathLike[str]) -> str:
    """Why files cannot be written in ``folder`` (created if missing), or ``""``: the
    nearest part of its path that exists must be a folder, writable. Creates nothing."""
    existing = Path(folder)
    try:
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent  # the nearest part of the path that is there
    except OSError as exc:  # (a name too long: pathlib raises where os.path says False)
        return f"{existing}: {exc.strerror or exc}"
    if not existing.is_dir():
        return f"{existing} is not a folder"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"the folder {existing} is not writable"
    return ""


def _part_name(final: Path) -> Path:
    return final.with_name(f".{final.name}.{os.getpid()}.part")


@contextlib.contextmanager
def whole_file(path: str | os.PathLike[str]) -> Iterator[Path]:
    """The path to write ``path``'s new content to; renamed onto ``path`` when the block
    ends without an error (onto the link's target when ``path`` is a symbolic link).

    Raises
    ------
    OSError
        From the rename (the caller's block raises its own).
    """
    final = Path(os.path.realpath(path))
    part = _part_name(final)
    try:
        yield part
        os.replace(part, final)
    finally:
        with contextlib.suppress(OSError):  # (gone once renamed)
            part.unlink()


@contextlib.contextmanager
def whole_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A staging folder to write a set of files in; when the block ends without an error,
    they are moved into ``path``, the stop signals held back meanwhile: a new folder is
    the staging folder renamed (one step); into a folder that is there, the files move one
    by one (files of other names there are kept). The staging folder is removed whatever
    happens.
    """
    final = Path(os.path.realpath(path))
    fresh = not final.exists()
    # beside a new folder (renamed onto it at the end); inside one that is there
    staging = _part_name(final) if fresh else final / f".motionbase.{os.getpid()}.part"
    try:  # (made inside: a stop signal as mkdir returns still removes it)
        staging.mkdir(parents=True)
        yield staging
        held = _hold(STOP_SIGNALS)
        try:
            if fresh and not final.exists():
                os.rename(staging, final)
            else:
                for item in sorted(staging.iterdir()):
                    os.replace(item, final / item.name)
        finally:
            _release(held)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _hold(signals: tuple[signal.Signals, ...]) -> set[signal.Signals] | None:
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, set(signals))


def _release(before: set[signal.Signals] | None) -> None:
    if before is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)
