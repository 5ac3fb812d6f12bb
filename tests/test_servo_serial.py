"""The servo protocol and the serial sink, through real pseudo-terminals and pyserial's loop://."""

from __future__ import annotations

import threading
import time
import warnings

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pty_board import Board

from motionbase.errors import SinkError
from motionbase.io.serial_link import ServoSerialSink
from motionbase.io.servo_protocol import ServoDecoder, decode, encode

triples = st.tuples(*[st.integers(0, 180)] * 3)


@settings(max_examples=200)
@given(triples)
def test_encode_decode_round_trip(cmd):
    frame = encode(cmd)
    assert frame == f"{cmd[0]}p{cmd[1]}q{cmd[2]}r".encode()
    assert decode(frame) == [(0, cmd[0]), (1, cmd[1]), (2, cmd[2])]


@settings(max_examples=100)
@given(st.lists(triples, min_size=1, max_size=8), st.integers(1, 7))
def test_decoder_handles_any_split(cmds, chunk):
    data = b"".join(encode(c) for c in cmds)
    dec = ServoDecoder()
    out = []
    for i in range(0, len(data), chunk):
        out += dec.feed(data[i : i + chunk])
    assert out == [(k, c[k]) for c in cmds for k in range(3)]


def test_decoder_ignores_what_the_firmware_ignores():
    dec = ServoDecoder()
    assert dec.feed(b"200p") == []  # above 180
    assert dec.feed(b"p") == []  # letter without digits (the thesis's sketch wrote 0)
    assert dec.feed(b"9x0p") == []  # a command broken by a stray byte is dropped whole
    assert dec.feed(b"00090p") == []  # too many digits
    assert dec.feed(b"\r\n90p 45q\n120r") == [(0, 90), (1, 45), (2, 120)]
    assert dec.feed(b"180r0p") == [(2, 180), (0, 0)]
    assert dec.dropped == 4


@pytest.mark.parametrize(
    "bad", [(181, 0, 0), (0, -1, 0), (0, 0, 1.5), (90, 90), (0, float("nan"), 0)]
)
def test_encoder_refuses_out_of_range(bad):
    with pytest.raises(SinkError):
        encode(bad)


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def wait_for(board: Board, n: int) -> None:
    """Until the board has ``n`` bytes (30 s: a watchdog, not a bound; it gave up silently
    after 2 s, leaving a loaded machine's late bytes to fail a later assertion)."""
    deadline = time.monotonic() + 30.0
    while len(board.data) < n:
        assert time.monotonic() < deadline, f"the board got {len(board.data)} of {n} bytes"
        threading.Event().wait(0.01)


def test_protocol_round_trip_through_a_pty():
    board = Board()
    clock = FakeClock()
    sent = [(90, 90, 90), (92, 88, 73), (0, 180, 45), (180, 0, 180), (45, 46, 47)]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # the ready line must be seen: no warning
            with ServoSerialSink(board.path, clock=clock) as sink:
                assert sink.ready
                for cmd in sent:
                    clock.t += 0.02
                    assert sink.write(cmd)
                expected = b"".join(encode(c) for c in sent)
                wait_for(board, len(expected))
        assert bytes(board.data) == expected
        got = decode(bytes(board.data))
        assert [tuple(v for _, v in got[i : i + 3]) for i in range(0, len(got), 3)] == sent
        assert sink.frames_sent == len(sent)
    finally:
        board.close()


def test_sends_only_on_change_or_keepalive_at_limited_rate():
    clock = FakeClock()
    sink = ServoSerialSink(
        "loop://", rate_hz=50, keepalive_s=1.0, ready_timeout_s=0.0, clock=clock
    ).open()
    with sink:
        assert sink.write((90, 90, 90))  # first frame
        clock.t = 0.5
        assert not sink.write((90, 90, 90))  # unchanged, keep-alive not due
        clock.t = 1.0
        assert sink.write((90, 90, 90))  # keep-alive
        clock.t = 1.005
        assert not sink.write((91, 90, 90))  # changed but within 1/50 s: held
        clock.t = 1.01
        assert not sink.write((92, 90, 90))  # newer value replaces the held one
        clock.t = 1.021
        assert sink.write((92, 90, 90))
        assert sink.frames_sent == 3
        with pytest.raises(SinkError, match="0..180"):
            sink.write((90, 200, 90))
        with pytest.raises(SinkError):
            sink.write((90, float("nan"), 90))
    assert sink.bytes_sent == 3 * len(b"90p90q90r")


def test_missing_ready_line_warns_once_and_goes_on(fresh_logger, caplog):
    """The warning is one logged line; a RuntimeWarning printed it a second time, with the
    caller's source line, at the command line (``teleop --serial``)."""
    board = Board(ready=False)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            sink = ServoSerialSink(board.path, ready_timeout_s=0.2).open()
        said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
        assert len(said) == 1 and "no 'Rolling' line within 0.2 s" in said[0]
        assert not sink.ready
        assert sink.write((10, 20, 30))
        sink.close()
        wait_for(board, 9)
        assert decode(bytes(board.data)) == [(0, 10), (1, 20), (2, 30)]
    finally:
        board.close()


def test_vanished_port_gives_clear_error_and_clean_stop():
    board = Board()
    clock = FakeClock()
    sink = ServoSerialSink(board.path, clock=clock).open()
    assert sink.write((90, 90, 90))
    board.close()  # the board goes away: both ends of the pty closed
    clock.t = 1.0
    with pytest.raises(SinkError, match="vanished"):
        for k in range(50):
            clock.t += 0.1
            sink.write((k, 90, 90))
    sink.close()  # idempotent after the failure
    with pytest.raises(SinkError, match="not open"):
        sink.write((90, 90, 90))


def test_unopenable_port_is_a_sink_error():
    with pytest.raises(SinkError, match="cannot open serial port"):
        ServoSerialSink("/dev/ttyDOES_NOT_EXIST").open()


def test_frames_never_outpace_the_line_so_a_write_never_waits_for_it():
    """Teleop at 1 kHz (the sink's rate is the loop's) over the sketch's 19200 baud: a frame
    of up to 12 bytes takes 6.25 ms on the wire (10 bits a byte), so at most 160 frames a
    second fit. The sink used to write one a tick and wait for each to leave (a flush): the
    loop was paced by the serial line, 5-6 ms a tick. Frames now go no closer than the line
    carries them, each the latest command, and the board still gets every final value."""
    board = Board()
    clock = FakeClock()
    rate_hz, baud = 1000.0, 19200
    try:
        with ServoSerialSink(board.path, baud=baud, rate_hz=rate_hz, clock=clock) as sink:
            times = []
            for k in range(1000):  # one second of ticks, a new command each
                clock.t = k / rate_hz
                if sink.write((k % 181, 90, 90)):
                    times.append(clock.t)
            sink.write((7, 8, 9))  # the last command, too soon after the last frame: held
        gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
        line_s = 10 * len(b"180p180q180r") / baud  # (independent of the sink's own figure)
        assert min(gaps) >= line_s
        assert 0.8 / line_s <= len(times) <= 1.0 / line_s + 1  # the line used, not much less
        wait_for(board, sink.bytes_sent)
        assert decode(bytes(board.data))[-3:] == [(0, 7), (1, 8), (2, 9)]  # sent on close
    finally:
        board.close()
