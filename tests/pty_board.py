"""A fake Arduino for serial tests: the far end of a real pseudo-terminal pair.

It prints the sketch's ready line (``Rolling``) until the host first speaks, then records
every byte it receives (and, in ``chunks``, when each read returned it); :meth:`Board.close`
makes the port vanish as an unplugged board does.
"""

from __future__ import annotations

import os
import pty
import select
import threading
import time
import tty

#: Device ends of closed boards, kept open (see :meth:`Board.close`).
_RETIRED: list[int] = []


class Board:
    """The board's side of a pty pair; ``path`` is the host's device."""

    def __init__(self, ready: bool = True) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.ready = ready
        self.data = bytearray()
        self.chunks: list[tuple[float, bytes]] = []  # (time.monotonic() of the read, bytes)
        self.stop = threading.Event()
        self.got_first = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            if self.ready and not self.got_first.is_set():
                os.write(self.master, b"Rolling\r\n")
            r, _, _ = select.select([self.master], [], [], 0.02)
            if r:
                try:
                    chunk = os.read(self.master, 4096)
                except OSError:
                    return
                if chunk:
                    self._keep(chunk)
                    self.got_first.set()

    def _keep(self, chunk: bytes) -> None:
        self.chunks.append((time.monotonic(), chunk))
        self.data += chunk

    def close(self) -> None:
        """Stop reading, take the bytes still in the pty (a host that has finished wrote
        them all; the reader thread could stop before it had read them: a test then saw a
        run's last frames missing on a loaded machine) and close the board's end (the port
        vanishes)."""
        if self.stop.is_set():
            return  # closed already
        self.stop.set()
        self.thread.join(2)
        while select.select([self.master], [], [], 0)[0]:
            try:
                chunk = os.read(self.master, 4096)
            except OSError:
                break
            if not chunk:
                break
            self._keep(chunk)
        try:
            os.close(self.master)  # the port vanishes: its path is gone, writes fail
        except OSError:
            pass
        # The device's end stays open until this process ends: that keeps the terminal's
        # number from being given to another test's pty while the host tries to reopen the
        # vanished path (a motor output's serial drive did, reached another test's board
        # and took its place as the host that board waited for; seen under parallel tests).
        _RETIRED.append(self.slave)
