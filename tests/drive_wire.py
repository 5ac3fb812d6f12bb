"""A motor drive on loopback UDP for the tests: every frame on the wire with its arrival time.

The drive reads a text frame of six crank angles in degrees with four decimals (the default
``[output]`` mapping is degrees), decodes it with its own parser, and stamps each datagram
with the kernel's arrival time (``SO_TIMESTAMPNS``), so the thread reading the socket adds
no jitter of its own. It can vanish (its port then refuses datagrams, as a drive that was
switched off) and come back on the same port.

The limits are measured on the frames as they arrived, with

* the speed over sliding windows of ``W`` seconds: ``|q(t + W) - q(t)| / W``;
* the acceleration over the same windows: ``|q(t + 2W) - 2 q(t + W) + q(t)| / W^2``;

with ``q`` interpolated linearly between arrivals: a drive that moves within its speed and
acceleration limits satisfies both, whatever the frames' spacing. Arrival times may be off
by up to ``JITTER_S`` (a loaded machine's scheduling of the sender), which the tolerances
allow for: ``vmax (W + 2 J) / W`` and ``amax + 4 vmax J / W^2``.

That holds only while the sender keeps its schedule. A sender thread kept off the
processor for more than two periods (a loaded machine) leaves the drive standing at its
last frame, and the ramp starts it again from rest (:func:`motionbase.io.motor_output.
ramp_step`): on the wall clock the drive stopped at once, which no sender can help. What
the ramp guarantees is per frame, on the sender's own clock: :class:`SenderClock` keeps
that clock for a test, and :func:`check_steps` checks the frames against it.
"""

from __future__ import annotations

import math
import re
import socket
import struct
import threading
import time
from urllib.parse import quote

import numpy as np


def frame_format(n: int = 6) -> str:
    """``n`` actuator positions in degrees (or mm), four decimals: quantisation 1e-4, far
    below the limits."""
    return "text:" + ",".join(f"{{{i}:.4f}}" for i in range(1, n + 1)) + "\\n"


def _frame_regex(n: int) -> re.Pattern[bytes]:
    return re.compile(b",".join([rb"(-?\d+\.\d{4})"] * n) + rb"\n")


FORMAT = frame_format(6)
_FRAME = _frame_regex(6)
WINDOW_S = 0.1
JITTER_S = 0.005
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)


def decode(frame: bytes, pattern: re.Pattern[bytes] = _FRAME) -> np.ndarray:
    """Crank angles of one frame, rad."""
    m = pattern.fullmatch(frame)
    assert m is not None, f"not a drive frame: {frame!r}"
    return np.radians([float(x) for x in m.groups()])


class UdpDrive:
    """A drive of ``n`` actuators listening on a loopback UDP port (0: a free one)."""

    def __init__(self, port: int = 0, n: int = 6) -> None:
        self.n = n
        self._format = frame_format(n)
        self._pattern = _frame_regex(n)
        self.frames: list[tuple[float, bytes]] = []  # (arrival s, datagram)
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self.port = self._listen(port)

    def url(self, rate_hz: float = 100.0) -> str:
        return f"udp:127.0.0.1:{self.port}?rate={rate_hz:g}&format={quote(self._format, safe='')}"

    def _listen(self, port: int) -> int:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        sock.bind(("127.0.0.1", port))
        sock.settimeout(0.05)
        self._sock = sock
        self._start_reading(sock)
        return sock.getsockname()[1]

    def _start_reading(self, sock: socket.socket) -> None:
        self._paused = threading.Event()
        self._thread = threading.Thread(target=self._read, args=(sock, self._paused), daemon=True)
        self._thread.start()

    def _read(self, sock: socket.socket, paused: threading.Event) -> None:
        while not paused.is_set():
            try:
                data, anc, _, _ = sock.recvmsg(65536, socket.CMSG_SPACE(16))
            except TimeoutError:
                continue
            except OSError:  # closed: vanished
                return
            self._keep(data, anc)

    def _keep(self, data: bytes, anc: list) -> None:
        stamp = math.nan  # the kernel's arrival time of the datagram
        for level, kind, raw in anc:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                sec, nsec = struct.unpack("qq", raw[:16])
                stamp = sec + nsec * 1e-9
        with self._lock:
            self.frames.append((stamp, data))

    def vanish(self) -> None:
        """Stop listening: datagrams to the port are refused (the sender sees send errors)."""
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()
        if self._thread is not None:
            self._thread.join(2)

    def come_back(self) -> None:
        """Listen on the same port again."""
        self._listen(self.port)

    def close(self) -> None:
        self.vanish()

    def count(self) -> int:
        with self._lock:
            return len(self.frames)

    def drain(self) -> None:
        """Read the datagrams already sent, every one: the reader thread is paused and the
        socket's queue read to its end here (a datagram sent on loopback is in that queue
        when its send returns), then the thread goes on. (It waited for 0.2 s without a new
        datagram, which a reader thread kept off the processor on a loaded machine could
        also give.)"""
        sock = self._sock
        if sock is None:  # vanished: nothing more to read
            return
        self._paused.set()
        if self._thread is not None:
            self._thread.join()
        sock.setblocking(False)
        try:
            while True:
                try:
                    data, anc, _, _ = sock.recvmsg(65536, socket.CMSG_SPACE(16))
                except BlockingIOError:
                    break
                self._keep(data, anc)
        finally:
            sock.settimeout(0.05)
        self._start_reading(sock)

    def angles(self, start: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(arrival times s, positions (k, n): rad, or m / 1000 for mm) of the frames from
        index ``start``."""
        with self._lock:
            frames = self.frames[start:]
        t = np.array([a for a, _ in frames], dtype=float)
        q = np.array([decode(f, self._pattern) for _, f in frames], dtype=float)
        q = q.reshape(-1, self.n)
        return t, q


def _at(t: np.ndarray, q: np.ndarray, times: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(times, t, q[:, i]) for i in range(q.shape[1])], axis=1)


def window_speed(t: np.ndarray, q: np.ndarray, w: float = WINDOW_S) -> np.ndarray:
    """Largest ``|q(t + w) - q(t)| / w`` per motor over the frames (rad/s)."""
    starts = t[t + w <= t[-1]]
    if starts.size == 0:
        return np.zeros(q.shape[1])
    return (np.abs(_at(t, q, starts + w) - _at(t, q, starts)) / w).max(axis=0)


def window_accel(t: np.ndarray, q: np.ndarray, w: float = WINDOW_S) -> np.ndarray:
    """Largest ``|q(t + 2w) - 2 q(t + w) + q(t)| / w^2`` per motor over the frames (rad/s^2)."""
    starts = t[t + 2 * w <= t[-1]]
    if starts.size == 0:
        return np.zeros(q.shape[1])
    second = _at(t, q, starts + 2 * w) - 2 * _at(t, q, starts + w) + _at(t, q, starts)
    return (np.abs(second) / w**2).max(axis=0)


def check_wire_limits(t: np.ndarray, q: np.ndarray, vmax, amax, what: str = "") -> tuple:
    """Assert the frames keep the speed and acceleration limits (per motor, or one for all;
    tolerances: module docstring); returns the worst speed and acceleration per motor."""
    assert np.isfinite(t).all(), "a frame without its arrival time"
    assert np.all(np.diff(t) >= 0)
    vmax = np.broadcast_to(np.asarray(vmax, dtype=float), (q.shape[1],))
    amax = np.broadcast_to(np.asarray(amax, dtype=float), (q.shape[1],))
    w, j = WINDOW_S, JITTER_S
    speed, accel = window_speed(t, q), window_accel(t, q)
    assert np.all(speed <= vmax * (w + 2 * j) / w), (
        f"{what}: {np.round(speed, 3)} rad/s on the wire, limits {vmax}"
    )
    assert np.all(accel <= amax + 4 * vmax * j / w**2), (
        f"{what}: {np.round(accel, 2)} rad/s^2 on the wire, limits {amax}"
    )
    return speed, accel


class SenderClock:
    """The clock of a :class:`~motionbase.io.motor_output.MotorOutput`'s sender, kept by a
    test: it reads the time the sender has waited for (its waits still take that long), so
    the sender's steps are one period apart whatever the machine's load did to its thread;
    ``times`` holds the time of each frame put on the wire (by the sender's thread, or by
    ``close()`` once that thread has stopped: one writer at a time).

    Install it before the sink opens: ``monkeypatch.setattr(motor_output, "time", clock)``
    (:func:`keep_sender_clock`).
    """

    def __init__(self, sink) -> None:
        self.now = 1000.0
        self.times: list[float] = []
        send = sink.transport.send

        def timed_send(frame: bytes) -> None:
            send(frame)  # (not kept when refused: it raises)
            self.times.append(self.now)

        clock = self

        class Waits(threading.Event):  # the sender thread's waits between frames
            def wait(self, timeout: float | None = None) -> bool:
                if super().wait(timeout):
                    return True
                clock.now += timeout
                return False

        sink.transport.send = timed_send
        sink._stop = Waits()

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)
        self.now += seconds


def keep_sender_clock(sink, monkeypatch) -> SenderClock:
    """Give ``sink`` (not yet open) a :class:`SenderClock`."""
    from motionbase.io import motor_output

    clock = SenderClock(sink)
    monkeypatch.setattr(motor_output, "time", clock)
    return clock


def check_steps(t, q, vmax, amax, period: float, rounding: float = 0.0, what: str = "") -> None:
    """Assert the drive-side ramp's guarantee (:func:`motionbase.io.motor_output.ramp_step`)
    on frames ``q`` (k, n) put on the wire at ``t`` (s) by a sender on a clock the test
    keeps (:class:`SenderClock`: it is never late): each step's speed over its time is at
    most ``vmax``, and its change from the step before at most ``amax`` times its time.

    The drive holds each frame until the next. Where none came for more than two periods
    the ramp takes it to have stood still and starts it again from rest, over one period:
    so it must have come to rest within one period of the step before (a sender that
    stops sending a moving drive stops it at once: a drive range it could not send used
    to); and after the last frame (the end of the ramp) likewise. A frame at the time of
    the one before must be the same (a frame sent again). ``rounding``: the wire's rounding
    of a position (half its unit), allowed for on each position.
    """
    t, q = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
    again = np.flatnonzero(np.diff(t) == 0) + 1
    assert np.array_equal(q[again], q[again - 1]), f"{what}: two frames at one time"
    t, q = np.delete(t, again), np.delete(q, again, axis=0)
    dt = np.diff(t)
    assert np.all(dt > 0), f"{what}: frames out of order"
    gap = dt > 2.0 * period
    dt[gap] = period
    v = np.diff(q, axis=0) / dt[:, None]
    slack = 2.0 * rounding / dt  # (a speed's error from its two rounded positions)
    over_v = np.abs(v) - vmax * (1 + 1e-9) - slack[:, None]
    assert np.all(over_v <= 0), f"{what}: a step {over_v.max():.3g} over the speed limit"
    # each step's change from the one before (from rest at the start and after a gap), and
    # the stops where the frames pause or end: (change, its time, the speeds' rounding)
    zero = np.zeros(q.shape[1])
    changes, prev, prev_slack = [], zero, 0.0
    for k in range(len(v)):
        if gap[k]:
            changes.append((prev, period, prev_slack))
            prev, prev_slack = zero, 0.0
        changes.append((v[k] - prev, dt[k], slack[k] + prev_slack))
        prev, prev_slack = v[k], slack[k]
    changes.append((prev, period, prev_slack))
    for k, (dv, h, err) in enumerate(changes):
        assert np.all(np.abs(dv) <= amax * h * (1 + 1e-9) + err), (
            f"{what}: {np.round(np.abs(dv) / h, 3)} on change {k} of {len(changes)}, limits {amax}"
        )


def sweep_holds(q: np.ndarray, neutral, half_range: float, atol: float) -> np.ndarray:
    """Where a wiring check's sweep (``motionbase output --test``) holds at the drive: for
    each motor ``i`` (0-based) and side (``+half_range``, then ``-half_range``), the index of
    the first frame with motor ``i`` there and every other motor at ``neutral`` (to
    ``atol``), -1 when no frame is. Shape (n, 2).

    The sweep rests at each end of a motor's move, and the drive-side ramp lands exactly on
    a command it holds: these frames are exactly the sweep's. In between the ramp runs a
    little behind the moving command (it keeps the limits), so the shape of a move is not
    the commands' there; :func:`check_sweep` checks a whole sweep.
    """
    dev = np.asarray(q, dtype=float) - np.asarray(neutral, dtype=float)
    n = dev.shape[1]
    first = np.full((n, 2), -1)
    for i in range(n):
        others = np.all(np.abs(np.delete(dev, i, axis=1)) <= atol, axis=1)
        for j, side in enumerate((1.0, -1.0)):
            hit = np.flatnonzero(others & (np.abs(dev[:, i] - side * half_range) <= atol))
            if hit.size:
                first[i, j] = hit[0]
    return first


def check_sweep(q: np.ndarray, neutral, half_range: float, atol: float) -> np.ndarray:
    """Assert that frames ``q`` (k, n) hold a whole wiring-check sweep exactly, and return
    :func:`sweep_holds`.

    From the first frame with all motors but one at most at ``neutral`` (to ``atol``: they
    come from park together) until they all leave it on one side (the move to park; or the
    last frame): each motor in turn (1, 2, ...) away, each reaching ``+half_range`` and
    ``-half_range`` and going no further (to ``atol``). The drive-side ramp lands exactly on
    a command at rest and never passes one, so ``atol`` is the wire's rounding. Two motors
    may be away at once for a few frames: a sender that ran late (a loaded machine) ramps
    the drive from rest, and it lags a moving command (seen under the whole test suite on
    two processes: motor 1 0.2 deg from neutral as motor 2 set off).
    """
    dev = np.asarray(q, dtype=float) - np.asarray(neutral, dtype=float)
    start = np.flatnonzero((np.abs(dev) > atol).sum(axis=1) <= 1)
    assert start.size, "no frame with the motors at neutral"
    together = np.flatnonzero(np.all(dev < -atol, axis=1) | np.all(dev > atol, axis=1))
    together = together[together > start[0]]
    swept = dev[start[0] : together[0] if together.size else len(dev)]
    away = np.abs(swept) > atol
    order = [int(np.flatnonzero(a)[0]) for a in away if a.any()]
    assert list(dict.fromkeys(order)) == list(range(dev.shape[1])), order
    np.testing.assert_allclose(swept.max(axis=0), half_range, rtol=0, atol=atol)
    np.testing.assert_allclose(swept.min(axis=0), -half_range, rtol=0, atol=atol)
    return sweep_holds(q, neutral, half_range, atol)


def past_rest(commands: np.ndarray, q: np.ndarray, sampled: np.ndarray) -> np.ndarray:
    """How far the drive went past commands that came to rest, per motor (the worst; 0 when
    never; in the commands' unit).

    A rest is a command equal to the next one, reached by a move (steps under 1e-12 count
    as none): the frames that sampled a command of that move or of the rest (``sampled[j]``
    is the index in ``commands`` of the command frame ``j`` was heading for), from the
    first on the near side of the rest on (a drive still coming back from beyond, after a
    reversal it lagged, has not passed it), must not be beyond it.
    """
    commands, q = np.asarray(commands, dtype=float), np.asarray(q, dtype=float)
    steps = np.diff(commands, axis=0)
    steps[np.abs(steps) < 1e-12] = 0.0
    worst = np.zeros(commands.shape[1])
    for i in range(commands.shape[1]):
        side = np.sign(steps[:, i])  # side[k]: the way from command k to command k + 1
        for k in np.flatnonzero((side[1:] == 0) & (side[:-1] != 0)) + 1:
            end = k
            while end < len(side) and side[end] == 0:
                end += 1
            start = k - 1
            while start > 0 and side[start - 1] == side[k - 1]:
                start -= 1
            frames = np.flatnonzero((sampled >= start) & (sampled <= end))
            beyond = (q[frames, i] - commands[k, i]) * side[k - 1]
            near = np.flatnonzero(beyond <= 0.0)
            if near.size:
                worst[i] = max(worst[i], beyond[near[0] :].max())
    return worst


def read_complete_log(path) -> dict[str, list[dict]]:
    """Every message of a finished MCAP log by topic, read by the ``mcap`` library's indexed
    reader, which needs the summary and footer that only a properly closed log has."""
    import json

    from mcap.reader import make_reader

    out: dict[str, list[dict]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, f"{path}: not finished"
        for _, channel, message in reader.iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    assert sum(len(v) for v in out.values()) == summary.statistics.message_count
    return out


def states_of_a_killed_run(path, timeout: float = 20.0) -> list:
    """The states of the log of a run killed with SIGKILL, once its writer process (which
    outlives the run) has finished the file with what it was given; fails if it never does."""
    import time

    from motionbase.io.mcap_source import McapSource

    deadline = time.monotonic() + timeout
    while True:
        with McapSource(path) as source:
            states = list(source)
            truncated = source.truncated
        if not truncated or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert not truncated, "the writer process did not finish the log of the killed run"
    return states
