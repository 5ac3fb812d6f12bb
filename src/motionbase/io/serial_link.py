"""Serial sink for the 3-RRR servos: the thesis's protocol over any pyserial URL.

``ServoSerialSink`` opens a port with :func:`serial.serial_for_url` (``/dev/ttyACM0``,
``loop://``, ``socket://host:port``, ...), waits for the board's ready line (``Rolling``; an
Arduino resets when the port opens), then sends the three servo commands of
:mod:`motionbase.io.servo_protocol`. It writes at most ``rate_hz`` frames per second, and no
more than the line carries at its baud rate, and only when a value changed or ``keepalive_s``
passed since the last frame. It never waits for the line: frames so spaced find the port's
buffer empty, so a write returns at once, and only closing drains the buffer (the last frame).
A port that vanishes (USB unplugged) raises :class:`~motionbase.errors.SinkError` with a clear
message; the port is closed first, so the caller can stop cleanly.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

import serial

from motionbase.errors import SinkError
from motionbase.io.servo_protocol import encode
from motionbase.state import PipelineOutput

__all__ = ["ServoSerialSink", "READY_LINE", "SERIAL_ERRORS", "open_serial_port", "close_quietly"]

READY_LINE = b"Rolling"
log = logging.getLogger(__name__)

# What a port that vanished or failed raises (pyserial wraps most, not all, OSErrors).
SERIAL_ERRORS = (serial.SerialException, OSError)


def open_serial_port(
    url: str, baud: int, *, timeout: float | None = 0.05, write_timeout: float | None = 2.0
) -> Any:
    """Open a pyserial URL or device path; a failure is a :class:`SinkError` saying what to check.

    Parameters
    ----------
    url : str
        A device path or pyserial URL (``/dev/ttyUSB0``, ``loop://``, ``socket://host:port``).
    baud : int
        Baud rate.
    timeout, write_timeout : float or None
        Read and write timeouts, s (None blocks).
    """
    try:
        return serial.serial_for_url(
            url, baudrate=int(baud), timeout=timeout, write_timeout=write_timeout
        )
    except (serial.SerialException, OSError, ValueError, OverflowError) as exc:
        # (OverflowError: a baud rate past a C long, baud=99999999999999999999)
        raise SinkError(
            f"cannot open serial port {url!r}: {exc} (check the device or URL, "
            "and that you may use it: e.g. membership of the 'dialout' group)"
        ) from None


def close_quietly(port: Any) -> None:
    """Close a port that may already be gone (errors ignored)."""
    if port is None:
        return
    try:
        port.close()
    except SERIAL_ERRORS:
        pass


class ServoSerialSink:
    """Send servo degrees to the Arduino sketch of ``firmware/motionbase_3rrr``.

    Parameters
    ----------
    url : str
        A pyserial URL or device path (``/dev/ttyACM0``, ``loop://``, ``socket://h:p``).
    baud : int
        Baud rate (the sketch uses 19200).
    rate_hz : float
        Most frames per second written (with 25 % tolerance for a caller's jitter: a frame
        comes at least ``0.75 / rate_hz`` after the previous one), and never more than the
        line carries (a longest frame's 10 bits a byte at ``baud``, plus 10 %); a command
        arriving sooner is kept and sent at the next call after the interval (or on close).
    keepalive_s : float
        Re-send the last frame when nothing was sent for this long, s.
    ready_timeout_s : float
        Wait this long for the ready line after opening; then go on with a warning.
    ready_line : bytes
        The ready line's text.
    clock : callable
        Monotonic time source in seconds (injected by tests).

    Attributes
    ----------
    frames_sent : int
    bytes_sent : int
    ready : bool
        Whether the ready line was seen.
    """

    def __init__(
        self,
        url: str,
        *,
        baud: int = 19200,
        rate_hz: float = 50.0,
        keepalive_s: float = 1.0,
        ready_timeout_s: float = 2.0,
        ready_line: bytes = READY_LINE,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if rate_hz <= 0 or keepalive_s <= 0 or ready_timeout_s < 0 or baud <= 0:
            raise SinkError(
                "serial sink: baud, rate_hz and keepalive_s must be > 0 and ready_timeout_s >= 0"
            )
        self.url = url
        self.baud = int(baud)
        # the line's time for a longest frame (start + 8 data + stop bits a byte), with a
        # margin: frames never queue up behind one another in the port's buffer
        self.line_s = 1.1 * 10 * len(encode((180, 180, 180))) / self.baud
        self.min_interval = 1.0 / float(rate_hz)
        self.keepalive_s = float(keepalive_s)
        self.ready_timeout_s = float(ready_timeout_s)
        self.ready_line = ready_line
        self._clock = clock
        self._port: Any = None
        self._last: tuple[int, int, int] | None = None
        self._pending: tuple[int, int, int] | None = None
        self._last_time = -float("inf")
        self.frames_sent = 0
        self.bytes_sent = 0
        self.ready = False

    # -- lifecycle ----------------------------------------------------------------------------
    def open(self) -> ServoSerialSink:
        """Open the port and wait for the ready line (warning after ``ready_timeout_s``)."""
        if self._port is not None:
            return self
        self._port = open_serial_port(self.url, self.baud, timeout=0.05, write_timeout=2.0)
        self._wait_ready()
        return self

    def _wait_ready(self) -> None:
        deadline = time.monotonic() + self.ready_timeout_s
        buf = b""
        while time.monotonic() < deadline:
            try:
                chunk = self._port.read(64)
            except (serial.SerialException, OSError) as exc:
                self._fail(f"failed while waiting for the ready line: {exc}")
            buf += chunk
            if self.ready_line in buf:
                self.ready = True
                return
            buf = buf[-256:]
        msg = (
            f"serial port {self.url!r}: no {self.ready_line.decode(errors='replace')!r} line "
            f"within {self.ready_timeout_s:g} s; going on (is the motionbase_3rrr sketch "
            "loaded?)"
        )
        log.warning(msg)  # (once: a RuntimeWarning printed it again, with a source line)

    def close(self) -> None:
        """Send a pending frame, then close the port (idempotent)."""
        if self._port is None:
            return
        try:
            if self._pending is not None:
                self._send(self._pending, self._clock())
            self._port.flush()  # the last frame out before the port closes
        except (SinkError, *SERIAL_ERRORS):
            pass
        finally:
            port, self._port = self._port, None
            close_quietly(port)

    def __enter__(self) -> ServoSerialSink:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ----------------------------------------------------------------------------
    def write(self, output: PipelineOutput | Sequence[int], t: float | None = None) -> bool:
        """Offer the current servo command; returns True when a frame went out.

        Parameters
        ----------
        output : sequence of 3 int, or an object with a ``servo_deg`` attribute
            Integer degrees 0..180 for servos 1, 2, 3.
        t : float, optional
            The caller's loop time, s, used instead of the clock for the rate and keep-alive
            decisions (so a replay sends the same frames however it is paced).
        """
        if self._port is None:
            raise SinkError(f"serial port {self.url!r} is not open (use 'with' or open())")
        deg = getattr(output, "servo_deg", output)
        cmd = _as_command(deg)
        now = self._clock() if t is None else float(t)
        changed = cmd != self._last
        due = now - self._last_time >= self.keepalive_s
        if not (changed or due):
            self._pending = None
            self._drain()
            return False
        if now - self._last_time < max(0.75 * self.min_interval, self.line_s):
            self._pending = cmd  # too soon: send at the next opportunity
            return False
        self._send(cmd, now)
        return True

    def _send(self, cmd: tuple[int, int, int], now: float) -> None:
        frame = encode(cmd)
        try:
            self._port.write(frame)  # (no flush: spaced as above, it never waits for the line)
        except (serial.SerialException, OSError) as exc:
            self._fail(f"write failed: {exc}")
        self._last, self._last_time, self._pending = cmd, now, None
        self.frames_sent += 1
        self.bytes_sent += len(frame)
        self._drain()

    def _drain(self) -> None:
        """Discard what the board prints, so its output never fills the buffers."""
        try:
            n = self._port.in_waiting
            if n:
                self._port.read(n)
        except (serial.SerialException, OSError) as exc:
            self._fail(f"read failed: {exc}")

    def _fail(self, what: str) -> None:
        port, self._port = self._port, None
        close_quietly(port)
        raise SinkError(
            f"serial port {self.url!r} vanished or failed ({what}); the link is closed and "
            "no further commands are sent (reconnect the board and restart)"
        )

    def describe(self) -> dict[str, Any]:
        """Plain-data description for the log's metadata."""
        return {
            "kind": "servo_serial",
            "url": self.url,
            "baud": self.baud,
            "rate_hz": 1.0 / self.min_interval,
            "keepalive_s": self.keepalive_s,
            "ready": self.ready,
        }


def _as_command(deg: Sequence[int] | Any) -> tuple[int, int, int]:
    try:
        vals = [int(v) for v in deg]
        exact = all(int(v) == v for v in deg)
    except (TypeError, ValueError):
        raise SinkError(f"servo command: expected 3 integer degrees, got {deg!r}") from None
    if len(vals) != 3 or not exact or any(not 0 <= v <= 180 for v in vals):
        raise SinkError(
            f"servo command: expected 3 integers in 0..180 deg, got {list(deg)!r} (refused)"
        )
    return vals[0], vals[1], vals[2]
