"""The UDP cursor source against crafted datagrams from real loopback senders."""

from __future__ import annotations

import logging
import select
import socket

import numpy as np
import pytest

from motionbase.io.cursor_input import UdpCursor


@pytest.fixture
def udp():
    """An open UdpCursor on a free loopback port, and a function that sends one datagram
    from a given socket and waits until it is queued on the source's socket."""
    src = UdpCursor("127.0.0.1", 0).open()  # (stale timeout 0.5 s)
    senders: list[socket.socket] = []

    def sender() -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        senders.append(s)
        return s

    def send(tx: socket.socket, data: bytes) -> None:
        tx.sendto(data, ("127.0.0.1", src.port))
        assert select.select([src._sock], [], [], 5.0)[0], "the datagram did not arrive"

    try:
        yield src, sender, send
    finally:
        for s in senders:
            s.close()
        src.close()


def test_a_datagram_too_long_for_the_buffer_is_refused_not_cut_into_another_number(udp):
    """A 4100-byte datagram ending in ``1234.5 678.25``: the read took its first 4096 bytes,
    whose last line is ``1234.5 678`` (the rest cut off), and the robot was sent to
    (1234.5, 678.0), a point nobody sent. The datagram is refused whole, and counted."""
    src, sender, send = udp
    tx = sender()
    datagram = b"#" * 4085 + b"\n" + b"1234.5 678.25\n"  # byte 4096 is the 5 of .25
    assert datagram[:4096].endswith(b"\n1234.5 678")
    send(tx, datagram)
    assert src.read(0.0) is None
    assert src.rejected == 1 and src.received == 0
    send(tx, b"1234.5 678.25\n")  # the same point alone is taken
    assert src.read(0.02) == (1234.5, 678.25)


@pytest.mark.parametrize("line", [b"12.5 30 40", b"1700000000.25 640 360", b"640"])
def test_a_line_of_other_than_two_numbers_is_refused(udp, line):
    """A tracker that sends ``t x y`` (time first) or ``x y extra``: its first two numbers
    were taken as the point, so a timestamp drove the robot as x. Exactly two numbers."""
    src, sender, send = udp
    send(sender(), line + b"\n")
    assert src.read(0.0) is None and src.rejected == 1


def test_one_sender_at_a_time_the_other_is_taken_once_the_first_is_stale(udp, caplog):
    """Two trackers (or a tracker and a test script) sending to the port at once: every
    read took the latest datagram, whichever sender it came from, and the robot shook
    between their two points at full acceleration (58 reversals in 3 s on the wire, two
    senders at 60 and 43 Hz). While one sender is fresh the other is refused, with one
    warning; once the first has been silent for the stale timeout, the other is taken."""
    src, sender, send = udp
    a, b = sender(), sender()
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        send(a, b"100 200\n")
        assert src.read(0.0) == (100.0, 200.0)
        send(b, b"900 450\n")
        assert src.read(0.02) == (100.0, 200.0)
        send(a, b"110 210\n")
        assert src.read(0.04) == (110.0, 210.0)
        send(b, b"900 450\n")
        assert src.read(0.50) == (110.0, 210.0)  # 0.46 s after a's last point: a is fresh
        send(b, b"900 450\n")
        assert src.read(0.60) == (900.0, 450.0)  # 0.56 s: a is stale, b takes over
        send(a, b"120 220\n")
        assert src.read(0.62) == (900.0, 450.0)  # now a is the other one
    assert src.rejected == 3 and src.received == 3 and src.updated_t == 0.60
    warnings = [r.getMessage() for r in caplog.records if "udp:" in r.getMessage()]
    assert len(warnings) == 1 and str(b.getsockname()) in warnings[0], warnings


def test_each_kind_of_refusal_is_said_once(udp, caplog):
    """Malformed lines were counted and never reported: a tracker sending ``x;y`` gave a
    run that did nothing, with nothing saying why. One warning per kind, quoting a line."""
    src, sender, send = udp
    tx = sender()
    with caplog.at_level(logging.WARNING, logger="motionbase"):
        for k, line in enumerate([b"640;360", b"640;361", b"\xff\xfe 1 2", b"nan 3"]):
            send(tx, line)
            assert src.read(0.01 * k) is None
    assert src.rejected == 4
    warnings = [r.getMessage() for r in caplog.records if "udp:" in r.getMessage()]
    assert len(warnings) == 1 and "'640;360'" in warnings[0], warnings


def test_the_deadband_keeps_the_point_in_use_through_jitter_but_not_a_move(udp):
    """``deadband_px``: a point closer than it to the one in use is not taken, yet it is
    fresh input (the watchdog is fed); a point as far or farther is taken."""
    src, sender, send = udp
    src.close()
    src = UdpCursor("127.0.0.1", 0, deadband_px=20.0).open()
    tx = sender()
    try:
        for k, (point, used) in enumerate([
            ((600, 400), (600, 400)),
            ((610, 395), (600, 400)),  # 11.2 px away
            ((614, 414), (600, 400)),  # 19.8 px
            ((600, 420), (600, 420)),  # 20 px: taken
            ((590, 410), (600, 420)),  # 14.1 px from the new one
        ]):  # fmt: skip
            tx.sendto(f"{point[0]} {point[1]}\n".encode(), ("127.0.0.1", src.port))
            assert select.select([src._sock], [], [], 5.0)[0]
            assert src.read(0.02 * k) == used and src.updated_t == 0.02 * k
    finally:
        src.close()


@pytest.mark.parametrize("deadband_px", [0.0, 12.0])
def test_eye_tracker_jitter_moves_the_servos_only_without_a_deadband(deadband_px):
    """A gaze held on one point, with a tracker's jitter (3 px standard deviation, one
    datagram a tick over loopback UDP): without a dead band the servo commands flip by a
    degree many times a second (15 changes a second at 50 Hz on the wire); with one of
    four times the jitter they stay put once the robot has arrived."""
    from motionbase.platform import CursorCalibration, Rrr3, Rrr3Geometry
    from motionbase.teleop import run_teleop

    rrr3 = Rrr3(Rrr3Geometry.preset("udesc"))
    cal = CursorCalibration.default(rrr3, 1310, 715)
    src = UdpCursor("127.0.0.1", 0, deadband_px=deadband_px).open()
    gaze = np.array([800.0, 400.0]) + np.random.default_rng(7).normal(0.0, 3.0, (200, 2))

    class Tracker:
        """The servo sink's place: records the commands, then sends the next gaze point."""

        def __init__(self):
            self.tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.commands = []

        def write(self, servo, t=None):
            self.commands.append(tuple(servo))
            u, v = gaze[min(len(self.commands), len(gaze)) - 1]
            self.tx.sendto(f"{u:.2f} {v:.2f}\n".encode(), ("127.0.0.1", src.port))
            assert select.select([src._sock], [], [], 5.0)[0]
            return True

    tracker = Tracker()
    try:
        run_teleop(src, rrr3, cal, sink=tracker, realtime=False, duration_s=3.0)
    finally:
        tracker.tx.close()
        src.close()
    held = tracker.commands[75:150]  # from 1.5 s on: arrived (a 4 mm move), gaze held
    changes = sum(a != b for a, b in zip(held, held[1:], strict=False))
    if deadband_px:
        assert changes == 0, held
    else:
        assert changes > 10, held  # the jitter alone moved the servos


@pytest.mark.parametrize("deadband_px", [float("nan"), -1.0, float("inf")])
def test_a_deadband_that_is_no_distance_is_refused(deadband_px):
    """A NaN dead band took the first point and then none (every comparison false)."""
    from motionbase.errors import ConfigError

    with pytest.raises(ConfigError, match="--deadband"):
        UdpCursor("127.0.0.1", 0, deadband_px=deadband_px)
