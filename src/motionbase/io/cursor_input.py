"""Cursor sources for teleoperation: a CSV file, UDP text lines, or the mouse in a Tk window.

Every source gives screen pixels ``(u, v)`` (u right, v down) and shares one small interface:

``open()`` / ``close()`` (or ``with``), ``read(t) -> (u, v) | None`` (the latest cursor at loop
time ``t`` s since the start; None before the first), ``finished(t) -> bool``, ``size_px``
(window size for a default calibration) and ``show(...)`` (draws the robot; a no-op except for
the mouse window), ``describe()`` for the log. Live sources (UDP, mouse) set ``watchdog = True``
and keep ``updated_t``, the loop time (s) at which their latest *new* point arrived, so the
teleop loop can hold position when the input goes stale.

- :class:`FileCursor`: a CSV of ``t,x,y`` rows (seconds, pixels), looked up by time, so a
  replay gives the same targets at the same loop ticks however the loop is paced.
- :class:`UdpCursor`: text datagrams of ``x y`` lines in pixels (Opengazer's format), bound to
  127.0.0.1 by default; malformed lines (not two numbers), datagrams longer than 4096 bytes
  and those of a second sender are counted and ignored (one warning each), and a read takes
  256 datagrams or 16 kB at most (a flood on the port cannot hold the loop back).
- :class:`TkCursor`: a Tk window showing the workspace, the target and the links, in a process
  of its own; it works on a headless machine under Xvfb (``xvfb-run motionbase teleop``).
  The pointer is polled while it is inside the window (a resting pointer is live input;
  outside the window the input goes stale). Escape or space E-stops (the robot parks at
  home); closing the window, losing its display or its process ends the input (it parks too).
"""

from __future__ import annotations

import atexit
import bisect
import contextlib
import csv
import logging
import math
import multiprocessing
import signal
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np

from motionbase import mouse_window
from motionbase.errors import ConfigError, SourceError
from motionbase.io.net_address import bind_fix, check_host_port

__all__ = ["FileCursor", "UdpCursor", "TkCursor", "open_cursor_source", "DEFAULT_SIZE_PX"]

_log = logging.getLogger("motionbase")

#: Window size assumed for file and UDP input without a calibration (the thesis's window).
DEFAULT_SIZE_PX = (1310, 715)


class _Base:
    size_px: tuple[int, int] = DEFAULT_SIZE_PX
    rejected = 0
    watchdog = False  #: True for live sources, which keep ``updated_t``
    updated_t: float | None = None  #: loop time of the latest new point, s

    def open(self) -> Any:
        return self

    def close(self) -> None:
        pass

    def __enter__(self) -> Any:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def finished(self, t: float) -> bool:
        return False

    def show(self, **state: Any) -> None:
        """Draw the robot (mouse window only)."""

    def describe(self) -> dict[str, Any]:
        return {"kind": type(self).__name__}


#: The longest line of a cursor CSV, characters (a ``t,x,y`` row takes a few dozen).
MAX_CSV_LINE = 1024


class FileCursor(_Base):
    """Cursor positions replayed from a CSV of ``t,x,y`` (s, pixels; header optional).

    Parameters
    ----------
    path : str or Path
        The CSV. Times must be finite and non-decreasing; the first row's time is the start.
    size_px : (int, int)
        Window size the pixels refer to (for a default calibration).
    """

    def __init__(self, path: str | Path, size_px: tuple[int, int] = DEFAULT_SIZE_PX) -> None:
        self.path = Path(path)
        self.size_px = size_px
        rows: list[tuple[float, float, float]] = []
        try:
            # UTF-8, with or without the byte order mark spreadsheets write ("CSV UTF-8")
            with self.path.open(newline="", encoding="utf-8-sig") as fh:
                for n, rec in enumerate(csv.reader(self._lines(fh)), start=1):
                    if not rec or not "".join(rec).strip() or rec[0].lstrip().startswith("#"):
                        continue
                    if n == 1 and rec[0].strip().lower() == "t":
                        continue
                    try:
                        t, x, y = (float(v) for v in rec[:3])
                        if len(rec) < 3:
                            raise ValueError
                    except ValueError:
                        raise SourceError(
                            f"{self.path}: line {n}: expected 't,x,y' numbers, got {rec!r}"
                        ) from None
                    if not all(math.isfinite(v) for v in (t, x, y)):
                        raise SourceError(f"{self.path}: line {n}: values must be finite")
                    if rows and t < rows[-1][0]:
                        raise SourceError(f"{self.path}: line {n}: time goes backwards")
                    rows.append((t, x, y))
        except OSError as exc:
            raise SourceError(f"{self.path}: cannot read the cursor file: {exc.strerror}") from None
        except (UnicodeDecodeError, csv.Error):
            raise SourceError(
                f"{self.path}: not a text CSV of cursor positions; --input file: takes UTF-8 "
                "text of 't,x,y' lines (s, pixels)"
            ) from None
        if not rows:
            raise SourceError(f"{self.path}: no cursor rows (expected 't,x,y' lines)")
        if rows[-1][0] == rows[0][0]:  # the run would end on its first tick
            raise SourceError(
                f"{self.path}: every row ({len(rows)}) is at t = {rows[0][0]:g} s, so the input "
                "lasts no time; add a row with a later time, s (the last row's time ends it)"
            )
        t0 = rows[0][0]
        self.times = [r[0] - t0 for r in rows]
        self.pixels = [(r[1], r[2]) for r in rows]
        self.duration_s = self.times[-1]

    def _lines(self, fh: Any) -> Any:
        """The file's lines, each at most :data:`MAX_CSV_LINE` characters: a longer one
        is no ``t,x,y`` row (/dev/zero's one line never ends, and was read until the
        memory ran out)."""
        for n, line in enumerate(iter(lambda: fh.readline(MAX_CSV_LINE + 1), ""), start=1):
            if len(line) > MAX_CSV_LINE:
                raise SourceError(
                    f"{self.path}: line {n} is longer than {MAX_CSV_LINE} characters: not a "
                    "CSV of cursor positions; --input file: takes 't,x,y' lines (s, pixels)"
                )
            yield line

    def read(self, t: float) -> tuple[float, float] | None:
        k = bisect.bisect_right(self.times, t + 1e-9) - 1
        return self.pixels[k] if k >= 0 else None

    def finished(self, t: float) -> bool:
        return t > self.duration_s + 1e-9

    def describe(self) -> dict[str, Any]:
        return {"kind": "file", "path": str(self.path), "rows": len(self.times)}


#: Datagrams one :meth:`UdpCursor.read` takes at most: Opengazer sends some 30 a second,
#: research trackers 1000 or more (at 16 a read, a 50 Hz loop fell a quarter second behind).
MAX_DATAGRAMS_PER_READ = 256
#: Bytes one read takes at most (a datagram of many lines is slow to parse: 4 of the longest).
MAX_BYTES_PER_READ = 16384
#: The longest cursor datagram taken, bytes; a longer one is refused whole (cut there, its
#: last line would read as another number).
MAX_DATAGRAM = 4096


class UdpCursor(_Base):
    """Cursor or gaze points as UDP text lines ``x y`` (pixels), e.g. from Opengazer.

    Parameters
    ----------
    host, port : str, int
        Address to bind (127.0.0.1 by default: not reachable from other machines).
    size_px : (int, int)
        Screen size the pixels refer to (for a default calibration).
    stale_timeout_s : float
        One sender at a time: while the sender of the latest point sent one within this
        time, s (of loop time), the datagrams of any other address are refused; two
        interleaved streams would make the robot shake between their points.
    deadband_px : float
        A point less than this far from the one in use, pixels, is not taken (it still
        counts as fresh input): an eye tracker's jitter then leaves the robot still. 0: off.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 20320,
        size_px: tuple[int, int] = DEFAULT_SIZE_PX,
        stale_timeout_s: float = 0.5,
        deadband_px: float = 0.0,
    ) -> None:
        if not (math.isfinite(deadband_px) and deadband_px >= 0):  # (NaN: no point taken)
            raise ConfigError(f"--deadband must be >= 0 pixels, got {deadband_px!r}")
        self.host, self.port, self.size_px = host, int(port), size_px
        self.stale_timeout_s, self.deadband_px = stale_timeout_s, float(deadband_px)
        self._sock: socket.socket | None = None
        self._latest: tuple[float, float] | None = None
        self._sender: Any = None  # the address of the latest point
        self._sender_t = -math.inf  # its loop time, s
        self._warned: set[str] = set()
        self.received = 0
        self.rejected = 0
        self.watchdog = True
        self.updated_t: float | None = None

    def open(self) -> UdpCursor:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind((self.host, self.port))
        except OSError as exc:
            s.close()
            fix = bind_fix(
                exc, "give an IPv4 address of this machine: 127.0.0.1, or 0.0.0.0 for all"
            )
            raise SourceError(
                f"cannot listen for cursor points on udp:{self.host}:{self.port}: "
                f"{exc.strerror or exc} ({fix})"
            ) from None
        s.setblocking(False)
        self._sock = s
        self.port = s.getsockname()[1]
        return self

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def read(self, t: float) -> tuple[float, float] | None:
        """The latest point, after reading at most :data:`MAX_DATAGRAMS_PER_READ` datagrams
        and :data:`MAX_BYTES_PER_READ` (a flood on the port cannot hold the loop back: the
        rest waits for the next read)."""
        if self._sock is None:
            raise SourceError("UDP cursor source is not open")
        budget = MAX_BYTES_PER_READ
        for _ in range(MAX_DATAGRAMS_PER_READ):
            if budget <= 0:
                break
            try:
                data, _, flags, sender = self._sock.recvmsg(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                raise SourceError(f"udp:{self.host}:{self.port}: receive failed: {exc}") from None
            budget -= len(data)
            if flags & socket.MSG_TRUNC:
                self._refuse("long", f"datagrams longer than {MAX_DATAGRAM} bytes")
                continue
            if sender != self._sender and t - self._sender_t <= self.stale_timeout_s + 1e-9:
                self._refuse("sender", f"datagrams from {sender}, while {self._sender} sends")
                continue
            for line in data.decode("ascii", errors="replace").splitlines():
                p = parse_point(line)
                if p is None:
                    if line.strip():
                        self._refuse("line", f"lines that are not 'x y' pixels, such as {line!r}")
                else:
                    if self._latest is None or math.dist(p, self._latest) >= self.deadband_px:
                        self._latest = p
                    self._sender, self._sender_t = sender, t
                    self.updated_t = t
                    self.received += 1
        return self._latest

    def _refuse(self, kind: str, what: str) -> None:
        """Count a refused line or datagram; warn once for each ``kind``."""
        self.rejected += 1
        if kind not in self._warned:
            self._warned.add(kind)
            _log.warning(
                "udp:%s:%d: ignoring %s (further ones are not reported)", self.host, self.port, what
            )

    def describe(self) -> dict[str, Any]:
        return {
            "kind": "udp",
            "host": self.host,
            "port": self.port,
            "deadband_px": self.deadband_px,
        }


def parse_point(line: str) -> tuple[float, float] | None:
    """``"x y"`` (or ``"x,y"``) in pixels -> (x, y); None when malformed or not finite, or
    not exactly two numbers (``"t x y"`` would read its time as x)."""
    parts = line.replace(",", " ").split()
    if len(parts) != 2:
        return None
    try:
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        return None
    if not (math.isfinite(x) and math.isfinite(y)):
        return None
    return x, y


class TkCursor(_Base):
    """The mouse in a Tk window that draws the workspace, the target and the robot's links.

    The view maps the base triangle into the window (``view`` metres -> pixels); the default
    teleop calibration for this source is that view's inverse, so the target sits under the
    mouse pointer.

    The window runs in a process of its own (:mod:`motionbase.mouse_window`), so that losing
    the X display, which ends the process Tk is in, does not end this one: it ends the input
    instead (``finished``, with ``ended`` saying why) and the robot parks. The window sends
    the pointer about 100 times a second and the E-stop keys; :meth:`read` and
    :meth:`finished` take what arrived, without waiting. :meth:`show` sends a drawing only
    when the window drew the previous one; while it is behind, only the latest is kept.

    Parameters
    ----------
    rrr3 : Rrr3
        The robot (its workspace at phi = 0 is drawn once).
    size_px : (int, int)
        Window size.
    """

    #: Why the input ended ("" while it goes on): the window closed, its display went away,
    #: its process ended or stopped answering (said in the run's summary).
    ended = ""

    def __init__(self, rrr3: Any, size_px: tuple[int, int] = (720, 640)) -> None:
        self.rrr3 = rrr3
        self.size_px = (int(size_px[0]), int(size_px[1]))
        L = rrr3.geometry.base_side
        w, h = self.size_px
        # the cranks reach a crank length beyond the base triangle: keep them and the motor
        # labels inside the window
        a = rrr3.geometry.crank
        margin = 26
        H = L * math.sqrt(3) / 2
        s = min((w - 2 * margin) / (L + 2 * a), (h - 2 * margin) / (H + 2 * a))
        ox = (w - s * L) / 2
        oy = h - (h - s * H) / 2
        self.scale, self.origin = s, (ox, oy)
        self._proc: Any = None
        self._conn: Any = None
        self._latest: tuple[float, float] | None = None
        self._stop: Any = None
        self.watchdog = True
        self.updated_t: float | None = None
        self._moved = False
        self._drawing = False  # a drawing was sent and not drawn yet
        self._pending: Any = None  # the latest drawing not sent yet
        self._heard = self._pumped = 0.0  # time.monotonic() of the window's latest message, s

    def bind_stop(self, stop: Any) -> None:
        """E-stop ``stop`` (a :class:`~motionbase.pipeline.StopRequest`) on Escape or space."""
        self._stop = stop

    def view(self, xy: Any) -> np.ndarray:
        """Metres (..., 2) -> window pixels (..., 2) (v down)."""
        p = np.asarray(xy, dtype=float)
        return np.stack(
            [self.origin[0] + self.scale * p[..., 0], self.origin[1] - self.scale * p[..., 1]], -1
        )

    def unview(self, px: Any) -> np.ndarray:
        """Window pixels (..., 2) -> metres (..., 2)."""
        p = np.asarray(px, dtype=float)
        return np.stack(
            [(p[..., 0] - self.origin[0]) / self.scale, (self.origin[1] - p[..., 1]) / self.scale],
            -1,
        )

    def open(self) -> TkCursor:
        ctx = multiprocessing.get_context("spawn")
        self._conn, there = ctx.Pipe()
        self._proc = ctx.Process(
            target=mouse_window.main, name="motionbase mouse window", daemon=True,
            args=(there, "motionbase teleop: 3-RRR", self.size_px),
        )  # fmt: skip
        # this process handles the stop signals and parks; the window's starts with them
        # blocked, then ignores them
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, mouse_window.PARENT_SIGNALS)
        try:
            self._proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            there.close()
        # closed before multiprocessing's own exit handler waits for its processes (this one
        # ignores the SIGTERM that handler sends)
        atexit.register(self.close)
        try:
            msg: Any = None
            end = time.monotonic() + OPEN_TIMEOUT_S
            while msg is None and time.monotonic() < end:
                if self._conn.poll(0.05):
                    msg = self._conn.recv()
            if msg == ("ready",):
                self._conn.send(self._workspace_ops())
        except (EOFError, OSError):
            self._proc.join(5.0)
            msg = ("error", f"its process ended ({_exit_status(self._proc)})")
        if msg != ("ready",):
            self.close()
            why = msg[1] if msg else f"it did not open within {OPEN_TIMEOUT_S:g} s"
            raise SourceError(
                f"cannot open the mouse window: {why} (no display? run under Xvfb: "
                "xvfb-run motionbase teleop ...)"
            )
        self._heard = self._pumped = time.monotonic()
        return self

    def _workspace_ops(self) -> list[Any]:
        """The drawing of the workspace, the base and the legend (drawn once)."""
        ops: list[Any] = []
        ws = self.rrr3.workspace(150, 150, 1, phi_range=(0.0, 0.0))
        dx = (ws.x[1] - ws.x[0]) * self.scale / 2 + 0.5
        dy = (ws.y[1] - ws.y[0]) * self.scale / 2 + 0.5
        for i, j in zip(*np.nonzero(ws.valid[:, :, 0]), strict=True):
            u, v = self.view([ws.x[i], ws.y[j]])
            ops.append(_op("rectangle", u - dx, v - dy, u + dx, v + dy, fill="#bcd3f0", outline=""))
        A = self.view(self.rrr3.geometry.base_points)
        ops.append(_op("polygon", *A.ravel(), outline="#888888", fill=""))
        for i, (u, v) in enumerate(A):
            ops.append(_op("oval", u - 6, v - 6, u + 6, v + 6, fill="#555555", outline=""))
            ops.append(
                _op("text", u, v + (16 if i < 2 else -16), text=f"motor {i + 1}", fill="#555555")
            )
        ops.append(
            _op(
                "text", 8, 8, anchor="nw", fill="#333333",
                text="blue: reachable centre (phi = 0)\n"
                "ring: target (green ok, red held/stale)\n"
                "Esc or space: E-stop",
            )
        )  # fmt: skip
        return ops

    def _pump(self) -> None:
        """Take the window's messages (never waits); note when it is gone, and why."""
        if self._conn is None or self.ended:
            return
        now = time.monotonic()
        if now - self._pumped > 1.0:  # this process was away (suspended): no word is due yet
            self._heard = now
        self._pumped = now
        try:
            while self._conn.poll():
                msg = self._conn.recv()
                self._heard = now
                if msg[0] == "pointer" and msg[3]:  # over the window: live input
                    self._latest, self._moved = (msg[1], msg[2]), True
                elif msg[0] == "drawn":
                    self._drawing = False
                elif msg[0] == "key" and self._stop is not None:
                    self._stop.set(f"key {msg[1]}", estop=True)
                elif msg[0] == "closed":
                    self.ended = "end of input"
                elif msg[0] == "error":
                    self.ended = f"the mouse window failing: {msg[1]}"
        except (EOFError, OSError):  # its process ended: said once its exit status is known
            code = self._proc.exitcode
            if code is not None:
                # (Xlib's end: exit(1) when the display goes away, or on an X error)
                self.ended = (
                    "the mouse window losing its X display" if code == 1
                    else f"the mouse window's process ending, {_exit_status(self._proc)}"
                )  # fmt: skip
        if not self.ended and now - self._heard > SILENT_S:
            self.ended = f"the mouse window not answering for {SILENT_S:g} s"
        if self._pending is not None and not self._drawing and not self.ended:
            try:
                self._conn.send(self._pending)
                self._drawing, self._pending = True, None
            except OSError:  # (its process ended: the next look says why)
                pass

    def read(self, t: float) -> tuple[float, float] | None:
        if self._conn is None:
            raise SourceError("mouse window is not open")
        self._pump()
        if self._moved:
            self.updated_t = t
            self._moved = False
        return self._latest

    def finished(self, t: float) -> bool:
        self._pump()
        return bool(self.ended)

    def show(
        self,
        *,
        points: Any = None,
        target: Any = None,
        held: bool = False,
        parking: bool = False,
        **_: Any,
    ) -> None:
        """Draw the links (A-B-C per chain), the platform (C1 C2 C3, see-through so the
        workspace stays visible), its centre (the controlled point) and the cursor target:
        sent to the window when it drew the previous drawing, else kept (the latest only)."""
        ops: list[Any] = []
        if points is not None:
            A, B, C = (self.view(p) for p in points)
            ops.append(
                _op(
                    "polygon", *C.ravel(), fill="#e07b39", stipple="gray50", outline="#8a4514",
                    width=2,
                )
            )  # fmt: skip
            for i in range(3):
                ops.append(_op("line", *A[i], *B[i], fill="#222222", width=4))
                ops.append(_op("line", *B[i], *C[i], fill="#666666", width=2))
                for p, r in ((B[i], 3), (C[i], 3)):
                    ops.append(_op("oval", p[0] - r, p[1] - r, p[0] + r, p[1] + r, fill="#222222"))
            u, v = C.mean(axis=0)
            ops.append(_op("oval", u - 4, v - 4, u + 4, v + 4, fill="#8a4514"))
        if target is not None and np.all(np.isfinite(target)):
            u, v = self.view(target)
            color = "#c0392b" if held else "#27ae60"
            ops.append(_op("oval", u - 7, v - 7, u + 7, v + 7, outline=color, width=2))
            ops.append(_op("line", u - 11, v, u + 11, v, fill=color))
            ops.append(_op("line", u, v - 11, u, v + 11, fill=color))
        self._pending = ("draw", ops, "E-STOP: parking at home" if parking else "")
        self._pump()

    def close(self) -> None:
        if self._proc is None:
            return
        atexit.unregister(self.close)
        with contextlib.suppress(OSError):
            self._conn.send(("quit",))
        self._proc.join(2.0)
        if self._proc.is_alive():  # (it ignores SIGTERM)
            self._proc.kill()
            self._proc.join()
        self._conn.close()
        self._proc = self._conn = None

    def describe(self) -> dict[str, Any]:
        return {"kind": "mouse", "size_px": list(self.size_px)}


#: The longest wait for the mouse window to open, s (a loaded machine starts Python slowly).
OPEN_TIMEOUT_S = 60.0
#: Without a message from the mouse window for this long, s, it is taken as gone (a remote
#: display that hangs instead of closing): the input ends and the robot parks.
SILENT_S = 5.0


def _op(kind: str, *coords: Any, **options: Any) -> tuple[str, list[float], dict[str, Any]]:
    """A drawing op for the mouse window: ``create_<kind>(*coords, **options)``."""
    return kind, [float(c) for c in coords], options


def _exit_status(proc: Any) -> str:
    """How a process ended, in words."""
    code = proc.exitcode
    if code is not None and code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit status {code}"


def open_cursor_source(
    spec: str,
    rrr3: Any = None,
    stale_timeout_s: float = 0.5,
    deadband_px: float = 0.0,
    size_px: tuple[int, int] | None = None,
) -> Any:
    """Build a source from ``mouse``, ``udp:HOST:PORT`` (or ``udp:PORT``) or ``file:PATH.csv``
    (``stale_timeout_s``, ``deadband_px``: a UDP source's, see :class:`UdpCursor`;
    ``size_px``: the screen or window size, pixels, unless the source's default).

    Raises
    ------
    SourceError
        An unknown or malformed spec.
    """
    if deadband_px and not spec.startswith("udp:"):
        raise SourceError(f"--deadband is for udp: input (an eye tracker), not --input {spec!r}")
    sized: dict[str, Any] = {} if size_px is None else {"size_px": tuple(size_px)}
    if spec == "mouse":
        return TkCursor(rrr3, **sized)
    if spec.startswith("udp:"):
        parts = spec[4:].rsplit(":", 1)
        if len(parts) == 1:
            parts.insert(0, "127.0.0.1")
        # a port out of range or a host that does not resolve, said as such
        host = parts[0].removeprefix("[").removesuffix("]") or "127.0.0.1"  # ([::1]: IPv6)
        host, port = check_host_port(f"--input {spec!r}", host, parts[1])
        return UdpCursor(
            host, port, stale_timeout_s=stale_timeout_s, deadband_px=deadband_px, **sized
        )
    if spec.startswith("file:"):
        return FileCursor(spec[5:], **sized)
    raise SourceError(f"--input {spec!r}: expected mouse, udp:HOST:PORT or file:PATH.csv")
