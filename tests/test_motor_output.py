"""Motor-drive output through real pseudo-terminals and real UDP sockets on loopback.

The readers here decode frames with their own parsers (regex, struct, binascii), not the
library's, and turn drive values back into crank angles with their own formulas.
"""

from __future__ import annotations

import binascii
import logging
import math
import os
import pty
import re
import socket
import struct
import threading
import time
import tty
from collections.abc import Callable
from urllib.parse import quote

import numpy as np
import pytest
from drive_wire import (
    UdpDrive,
    check_steps,
    check_sweep,
    check_wire_limits,
    decode,
    keep_sender_clock,
    past_rest,
)
from pty_board import Board

from motionbase.app import fly, load_config
from motionbase.cli import main
from motionbase.config import preset_path
from motionbase.errors import ConfigError, SinkError
from motionbase.io.mcap_source import read_messages, read_metadata
from motionbase.io.motor_output import (
    MotorOutput,
    crc16_ccitt,
    crc16_modbus,
    mapping_for,
    open_output,
    open_outputs,
    ramp_offline,
)
from motionbase.pipeline import Pipeline, run
from motionbase.platform import OutputMapping, Rus6Geometry
from motionbase.safety import UNSAFE_TARGET, ActuatorLimits, limit_command
from motionbase.state import AircraftState

GEOMETRY = Rus6Geometry.preset("ceart")
QMIN, QMAX = math.radians(-60.0), math.radians(60.0)
LO, HI = np.full(6, QMIN), np.full(6, QMAX)
MIRROR = [1, -1, 1, -1, 1, -1]
#: The rounding of a position on the wire of :class:`drive_wire.UdpDrive` (four decimals of a
#: degree), rad.
TEXT_ROUNDING = math.radians(0.5e-4)


# --------------------------------------------------------------------------- peers


class PtyPeer(Board):
    """The drive's end of a pseudo-terminal: records every byte until closed (a board that
    prints no ready line)."""

    def __init__(self) -> None:
        super().__init__(ready=False)

    def frames(self, split: Callable[[bytes], list[bytes]]) -> list[bytes]:
        return split(bytes(self.data))


class UdpPeer:
    """A UDP listener on loopback: one datagram per frame."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.port = self.sock.getsockname()[1]
        self.datagrams: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.datagrams.append(self.sock.recv(65536))
            except TimeoutError:
                continue
            except OSError:
                return

    def frames(self, split) -> list[bytes]:
        return list(self.datagrams)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


def wait_until(pred: Callable[[], bool], timeout: float = 30.0) -> bool:
    """Whether ``pred()`` came true within ``timeout`` s (a watchdog, not a bound)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


# --------------------------------------------------------------------------- independent decoders


def _text_split(pattern: bytes) -> Callable[[bytes], list[bytes]]:
    rx = re.compile(pattern)
    return lambda data: [m.group(0) for m in rx.finditer(data)]


def _fixed_split(header: bytes, size: int, valid) -> Callable[[bytes], list[bytes]]:
    def split(data: bytes) -> list[bytes]:
        out, pos = [], 0
        while True:
            k = data.find(header, pos)
            if k < 0 or k + size > len(data):
                return out
            frame = data[k : k + size]
            if valid(frame):
                out.append(frame)
                pos = k + size
            else:
                pos = k + 1

    return split


def _crc_modbus_bitwise(data: bytes) -> int:
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def _range_to_angle(v, sign, lo=0, hi=4095):
    frac = (np.asarray(v, float) - lo) / (hi - lo)
    span = QMAX - QMIN
    return np.where(np.asarray(sign) > 0, QMIN + frac * span, QMAX - frac * span)


FLYPT = rb"A(\d+)B(\d+)C(\d+)D(\d+)E(\d+)F(\d+)\n"
HEX16 = rb"([0-9A-F]{4}) ([0-9A-F]{4}) ([0-9A-F]{4}) ([0-9A-F]{4}) ([0-9A-F]{4}) ([0-9A-F]{4})\r\n"
DEG2 = rb"M" + rb";".join([rb"(-?\d+\.\d\d)"] * 6) + rb"\n"

# name: (format, mapping table, split, decode -> drive values, drive -> crank angle, tolerance)
CASES = {
    "text-flypt-range12": (
        r"text:A{1}B{2}C{3}D{4}E{5}F{6}\n",
        {"unit": "range", "sign": MIRROR, "range_lo": 0, "range_hi": 4095},
        _text_split(FLYPT),
        lambda f: [int(x) for x in re.fullmatch(FLYPT, f).groups()],
        lambda v: _range_to_angle(v, MIRROR),
        math.radians(120.0) / 4095,
    ),
    "text-hex-range16": (
        r"text:{1:04X} {2:04X} {3:04X} {4:04X} {5:04X} {6:04X}\r\n",
        {"unit": "range", "range_lo": 0, "range_hi": 65535},
        _text_split(HEX16),
        lambda f: [int(x, 16) for x in re.fullmatch(HEX16, f).groups()],
        lambda v: _range_to_angle(v, [1] * 6, 0, 65535),
        math.radians(120.0) / 65535,
    ),
    "text-simtools-deg": (
        r"text:M<Axis1a>;<Axis2a>;<Axis3a>;<Axis4a>;<Axis5a>;<Axis6a>\n",
        {"unit": "deg", "sign": MIRROR},
        _text_split(rb"M(?:-?\d+;){5}-?\d+\n"),
        lambda f: [int(x) for x in f[1:-1].split(b";")],
        lambda v: np.radians(v) * np.array(MIRROR),
        math.radians(1.0),
    ),
    "text-float-deg": (
        r"text:M{1:.2f};{2:.2f};{3:.2f};{4:.2f};{5:.2f};{6:.2f}\n",
        {"unit": "deg", "zero_offset_deg": 90.0},
        _text_split(DEG2),
        lambda f: [float(x) for x in re.fullmatch(DEG2, f).groups()],
        lambda v: np.radians(np.asarray(v) - 90.0),
        math.radians(0.01),
    ),
    "bin-u16be-sum8": (
        "bin:0xFFFE,6xu16be,sum8@2",
        {"unit": "range", "sign": MIRROR, "range_lo": 0, "range_hi": 4095},
        _fixed_split(b"\xff\xfe", 15, lambda f: sum(f[2:14]) & 0xFF == f[14]),
        lambda f: list(struct.unpack(">6H", f[2:14])),
        lambda v: _range_to_angle(v, MIRROR),
        math.radians(120.0) / 4095,
    ),
    "bin-i32le-crc16-counts-geared": (
        "bin:0xAA55 6xi32le crc16",
        {"unit": "counts", "counts_per_rev": 131072, "gear_ratio": 10.0, "sign": MIRROR},
        _fixed_split(
            b"\xaa\x55",
            28,
            lambda f: _crc_modbus_bitwise(f[:26]) == int.from_bytes(f[26:], "little"),
        ),
        lambda f: list(struct.unpack("<6i", f[2:26])),
        lambda v: np.asarray(v) * 2 * math.pi / 131072 / 10.0 * np.array(MIRROR),
        2 * math.pi / 131072 / 10.0,
    ),
    "bin-i16le-centideg-ccitt": (
        "bin:0x02,6xi16le*100,crc16ccitt",
        {"unit": "deg"},
        _fixed_split(
            b"\x02", 15, lambda f: binascii.crc_hqx(f[:13], 0xFFFF) == int.from_bytes(f[13:], "big")
        ),
        lambda f: [x / 100 for x in struct.unpack("<6h", f[1:13])],
        lambda v: np.radians(v),
        math.radians(0.01),
    ),
    "bin-u24be-xor8": (
        "bin:0x7E,1:u24be,2:u24be,3:u24be,4:u24be,5:u24be,6:u24be,xor8@1",
        {"unit": "range", "range_lo": 0, "range_hi": 16777215},
        _fixed_split(
            b"\x7e", 20, lambda f: np.bitwise_xor.reduce(np.frombuffer(f[1:19], np.uint8)) == f[19]
        ),
        lambda f: [int.from_bytes(f[1 + 3 * i : 4 + 3 * i], "big") for i in range(6)],
        lambda v: _range_to_angle(v, [1] * 6, 0, 16777215),
        math.radians(120.0) / 16777215,
    ),
}


def mapping(table) -> OutputMapping:
    return OutputMapping.from_dict(table, angle_min=LO, angle_max=HI)


def commands() -> list[np.ndarray]:
    rng = np.random.default_rng(8)
    cmds = [np.zeros(6), LO.copy(), HI.copy(), np.radians([10, -20, 30, -40, 50, -55.5])]
    cmds += list(rng.uniform(QMIN, QMAX, size=(3, 6)))
    return cmds


def url_for(transport: str, peer, fmt: str, rate: float = 200.0) -> str:
    where = f"serial:{peer.path}" if transport == "pty" else f"udp:127.0.0.1:{peer.port}"
    return f"{where}?rate={rate:g}&format={quote(fmt, safe='')}"


@pytest.fixture(params=["pty", "udp"])
def peer(request):
    p = PtyPeer() if request.param == "pty" else UdpPeer()
    p.kind = request.param
    yield p
    p.close()


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("case", list(CASES))
def test_each_format_round_trips_within_one_unit(peer, case):
    fmt, table, split, decode, to_angle, tol = CASES[case]
    m = mapping(table)
    with open_output(url_for(peer.kind, peer, fmt), m) as sink:
        for q in commands():
            assert sink.write(q)

            def got(q=q) -> bool:
                frames = peer.frames(split)
                if not frames:
                    return False
                back = to_angle(decode(frames[-1]))
                return bool(np.all(np.abs(back - q) <= tol * (1 + 1e-9)))

            assert wait_until(got), f"{case}: never saw {np.degrees(q)} deg on the wire"
    frames = peer.frames(split)
    assert len(frames) >= len(commands())
    # every frame on the wire decodes to one of the commands (no torn or stray frames)
    cmds = commands()
    for f in frames:
        back = to_angle(decode(f))
        assert any(np.all(np.abs(back - q) <= tol * (1 + 1e-9)) for q in cmds)


def test_mirrored_motor_goes_the_other_way_on_the_wire():
    fmt, table, split, decode, _, _ = CASES["bin-u16be-sum8"]
    peer = UdpPeer()
    try:
        with open_output(url_for("udp", peer, fmt), mapping(table)) as sink:
            seen = []
            for deg in (0.0, 10.0):
                sink.write(np.full(6, math.radians(deg)))
                n = len(peer.datagrams)
                assert wait_until(lambda n=n: len(peer.datagrams) > n + 2)
                seen.append(np.array(decode(peer.datagrams[-1])))
        up = seen[1] - seen[0]
        assert np.all(up[0::2] > 0) and np.all(up[1::2] < 0)  # motors 2, 4, 6 are mirrored
        assert np.all(np.abs(up[0::2] + up[1::2]) <= 1)  # equal and opposite, up to rounding
        # 10 deg of a 120 deg crank range over 4095 steps
        assert abs(up[0] - 4095 * 10 / 120) <= 1
    finally:
        peer.close()


def test_checksum_reference_values():
    assert crc16_modbus(b"123456789") == 0x4B37 == _crc_modbus_bitwise(b"123456789")
    assert crc16_ccitt(b"123456789") == 0x29B1 == binascii.crc_hqx(b"123456789", 0xFFFF)


# --------------------------------------------------------------------------- never send bad values


def test_out_of_range_commands_are_never_sent(caplog):
    fmt, table, split, decode, to_angle, tol = CASES["text-flypt-range12"]
    peer = PtyPeer()
    good = np.radians([5.0, -5.0, 10.0, 0.0, 0.0, 0.0])
    try:
        with caplog.at_level(logging.WARNING, logger="motionbase.io.motor_output"):
            with open_output(url_for("pty", peer, fmt), mapping(table)) as sink:
                assert sink.write(good)
                assert wait_until(lambda: len(peer.frames(split)) >= 2)
                beyond = good.copy()
                beyond[2] = math.radians(61.0)  # past the crank limit
                nan = good.copy()
                nan[4] = np.nan
                assert not sink.write(beyond)
                assert not sink.write(nan)
                assert not sink.write(beyond)
                n = len(peer.frames(split))
                assert wait_until(lambda: len(peer.frames(split)) >= n + 5)  # still sending
                assert sink.held == 3 and sink.commands == 1
        for f in peer.frames(split):
            values = decode(f)
            assert all(0 <= v <= 4095 for v in values)
            np.testing.assert_allclose(to_angle(values), good, atol=tol)
        held = [r for r in caplog.records if "holding the last frame" in r.getMessage()]
        assert len(held) == 1 and "motor 3" in held[0].getMessage()  # one line per episode
    finally:
        peer.close()


def test_a_value_too_wide_for_the_field_is_never_sent():
    # counts up to +-2000 do not fit a u8 field
    m = mapping({"unit": "counts", "counts_per_rev": 12000})
    peer = UdpPeer()
    try:
        with open_output(f"udp:127.0.0.1:{peer.port}?format=bin:0x55,6xu8", m) as sink:
            assert sink.write(np.radians([1.0, 2, 3, 4, 5, 6]))  # 33..200 counts: fits
            assert not sink.write(np.radians([1.0, 2, 3, 4, 5, 10]))  # 333 counts: does not
            assert not sink.write(np.radians([-1.0, 2, 3, 4, 5, 6]))  # negative: does not
            assert wait_until(lambda: len(peer.datagrams) >= 3)
        assert {d for d in peer.datagrams} == {bytes([0x55, 33, 67, 100, 133, 167, 200])}
    finally:
        peer.close()


# --------------------------------------------------------------------------- rate and park


def test_fixed_rate_sends_only_the_latest_command():
    fmt, table, split, decode, to_angle, tol = CASES["bin-i16le-centideg-ccitt"]
    peer = UdpPeer()
    try:
        sink = open_output(url_for("udp", peer, fmt, rate=20), mapping(table))
        with sink:
            sink.write(np.zeros(6))
            assert wait_until(lambda: len(peer.datagrams) >= 3)  # repeated without new writes
            first = set(peer.datagrams)
            qs = np.linspace(0, math.radians(50), 2000)
            for a in qs:
                sink.write(np.full(6, a))
        # 2000 commands in a burst: far fewer frames (no queue), the last one the last command
        assert sink.commands == 2001
        assert sink.frames_sent < 1000 and len(peer.datagrams) < 1000
        assert wait_until(lambda: len(peer.datagrams) == sink.frames_sent)
        assert len(first) == 1
        np.testing.assert_allclose(to_angle(decode(peer.datagrams[-1])), qs[-1], atol=tol)
    finally:
        peer.close()


def test_the_last_frame_is_the_park_command_after_a_pipeline_run(peer):
    fmt, table, split, decode, to_angle, tol = CASES["bin-u16be-sum8"]
    config = load_config(rate_hz=120.0)
    states = [
        AircraftState(k / 120, np.array([2.0, 1.0, -9.80665]), np.array([0.1, 0.2, 0.0]))
        for k in range(120)
    ]
    sink = open_output(url_for(peer.kind, peer, fmt), mapping(table))
    with sink:
        summary = run(Pipeline(config), states, [sink])
    assert summary.samples > 120
    park = np.full(6, GEOMETRY.park_angle)
    assert wait_until(lambda: len(peer.frames(split)) == sink.frames_sent)
    frames = peer.frames(split)
    np.testing.assert_allclose(to_angle(decode(frames[-1])), park, atol=tol)
    # every command of the run was accepted (the safety stage kept them in range)
    assert sink.commands == summary.samples and sink.held == 0


# --------------------------------------------------------------------------- the peer goes away


def test_killing_the_peers_warns_once_and_the_flight_and_log_go_on(tmp_path, caplog):
    fmt = CASES["text-flypt-range12"][0]
    pty_peer = PtyPeer()
    dead = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dead.bind(("127.0.0.1", 0))
    dead_port = dead.getsockname()[1]
    dead.close()  # nobody listens there: ECONNREFUSED

    def kill_when_running():
        wait_until(lambda: len(pty_peer.data) >= 500, timeout=20)
        pty_peer.close()

    killer = threading.Thread(target=kill_when_running, daemon=True)
    killer.start()
    out = tmp_path / "fly.mcap"
    with caplog.at_level(logging.WARNING, logger="motionbase.io.motor_output"):
        result = fly(
            "c1723",
            duration_s=1.0,
            out=out,
            progress=False,
            outputs=[
                f"serial:{pty_peer.path}?rate=200&format={quote(fmt, safe='')}",
                f"udp:127.0.0.1:{dead_port}?rate=200&format={quote(fmt, safe='')}",
            ],
        )
    killer.join(5)
    assert not result.failed
    assert result.summary.stopped_by == "duration"  # (of the flight, not of a drive)
    msgs = read_messages(out)
    assert len(msgs["/platform/actuators"]) == result.summary.samples > 120
    down = [r.getMessage() for r in caplog.records if "link is down" in r.getMessage()]
    # one line per outage of each output: a second "down" only after a "link back" (the
    # kernel's limit of ICMP replies a second can leave a refused datagram unreported for
    # a second when other tests send to dead ports too: seen once in a full run)
    for label in (f"serial:{pty_peer.path}", f"udp:127.0.0.1:{dead_port}"):
        said = [
            "down" if "link is down" in m else "back"
            for m in (r.getMessage() for r in caplog.records)
            if label in m and ("link is down" in m or "link back" in m)
        ]
        changes = zip(said[:-1], said[1:], strict=True)
        assert said[:1] == ["down"] and all(a != b for a, b in changes), said
    assert any("serial:" + pty_peer.path in m for m in down)
    assert any("udp:" in m and "refused" in m.lower() for m in down)
    assert all("\n" not in m for m in down)
    drives = read_metadata(out)["outputs"]  # the log says where its commands went
    assert [d["url"] for d in drives] == [
        f"serial:{pty_peer.path}?rate=200&format={quote(fmt, safe='')}",
        f"udp:127.0.0.1:{dead_port}?rate=200&format={quote(fmt, safe='')}",
    ]
    assert all(d["rate_hz"] == 200 and d["ramped_at_the_drive"] for d in drives)
    notes = "\n".join(result.notes)
    assert re.search(r"serial:\S+: \d+ frames sent .* [1-9]\d* send errors", notes)
    assert re.search(r"udp:\S+: \d+ frames sent .* [1-9]\d* send errors", notes)


# --------------------------------------------------------------------------- URLs and CLI


@pytest.mark.parametrize(
    ("url", "err", "match"),
    [
        ("tcp:1.2.3.4:5", ConfigError, "expected serial:"),
        ("udp:127.0.0.1", ConfigError, "udp:HOST:PORT"),
        ("udp:127.0.0.1:9?format=bin:0xFFF,6xu16be", ConfigError, "pairs of hex"),
        ("udp:127.0.0.1:9?format=bin:6xu16", ConfigError, "byte order"),
        ("udp:127.0.0.1:9?format=bin:0xFF,7:u8", ConfigError, "motor 7"),
        ("udp:127.0.0.1:9?format=bin:6xu16be,sum8@99", ConfigError, "start offset"),
        ("udp:127.0.0.1:9?format=bin:6xf32be", ConfigError, "unknown token"),
        ("udp:127.0.0.1:9?format=text:A%7B7%7D", ConfigError, "1..6"),
        ("udp:127.0.0.1:9?format=text:A%7B1:q%7D", ConfigError, "format spec|unsupported"),
        ("udp:127.0.0.1:9?format=text:nothing", ConfigError, "no placeholder"),
        ("udp:127.0.0.1:9?speed=3", ConfigError, "unknown key 'speed'"),
        ("udp:127.0.0.1:9?baud=250000", ConfigError, "unknown key 'baud'"),  # was ignored
        ("udp:127.0.0.1:9?rate=0", ConfigError, "rate"),
        ("serial:/dev/ttyDOES_NOT_EXIST?format=text:%7B1%7D", SinkError, "cannot open serial"),
    ],
)
def test_bad_urls_say_what_is_wrong(url, err, match):
    m = mapping({"unit": "deg"})
    with pytest.raises(err, match=match):
        open_output(url, m).open()


def test_frames_the_serial_line_cannot_carry_are_refused_before_the_run(caplog):
    """A frame rate past what the baud rate carries was a warning ("frames will be
    dropped"), and the frames queued up behind the line instead: on a slow line the drive
    read ever older commands, and its park frame seconds after the sender said it had
    parked. The frame here is 2 header bytes, six 16-bit fields and a checksum byte: 15
    bytes, 150 bits with a start and a stop bit each, 15000 baud at 100 Hz."""
    url = "serial:loop://?format=bin:0xFFFE,6xu16be,sum8@2&rate=100&baud={}"
    m = mapping({"unit": "range", "range_lo": 0, "range_hi": 4095})
    with pytest.raises(ConfigError, match=r"frames of up to 15 bytes at 100 Hz need 15000 baud"):
        open_output(url.format(14999), m)
    with open_output(url.format(15000), m):  # what the line carries
        pass
    assert not caplog.records


def test_a_text_frame_longer_between_the_ends_than_at_them_counts_at_its_longest():
    """The line's check took the longest of the frames of zeros and of the drive range's
    ends. A ``{1:g}`` field writes -60 at a crank limit but -2.84184e-14 at the 6-RUS's
    neutral (its cranks a rounding hair from 0 deg): frames of 71 bytes were taken for 25,
    and 400 Hz passed on a 115200-baud line that carries 162 of them a second."""
    robot = Pipeline(load_config()).robot
    neutral = np.degrees(robot.inverse(robot.neutral_pose))
    frame = "".join(f"{'ABCDEF'[i]}{v:g}" for i, v in enumerate(neutral)) + "\n"
    assert len(frame) * 10 * 400 > 115200  # (a frame of the run, by Python's own format)
    fmt = quote("text:A{1:g}B{2:g}C{3:g}D{4:g}E{5:g}F{6:g}\\n", safe="")
    url = "serial:loop://?baud=115200&rate={}&format=" + fmt
    with pytest.raises(ConfigError, match="need .* baud, more than the line's 115200"):
        open_outputs([url.format(400)], robot)
    for sink in open_outputs([url.format(100)], robot):  # 100 of the longest frames fit
        with sink:
            sink.write(robot.park_angles)


def test_one_udp_drive_named_by_its_host_name_and_its_address_is_refused_twice():
    """``--output udp:127.0.0.1:P`` and ``--output udp:localhost:P`` send to one drive (its
    datagrams go to the same address): two senders, each ramping from its own frames, would
    interleave two command streams on it. Only the same text was refused."""
    resolved = {
        socket.getaddrinfo(h, 4123, type=socket.SOCK_DGRAM)[0][4]
        for h in ("127.0.0.1", "localhost")
    }
    if len(resolved) != 1:
        pytest.skip(f"localhost is not 127.0.0.1 here: {resolved}")
    robot = Pipeline(load_config()).robot
    urls = ["udp:127.0.0.1:4123", "udp:localhost:4123?rate=50"]
    with pytest.raises(ConfigError, match="both send to"):
        open_outputs(urls, robot)
    assert len(open_outputs(["udp:127.0.0.1:4123", "udp:127.0.0.1:4124"], robot)) == 2


def test_a_udp_url_written_with_two_slashes_sends_to_its_drive():
    """``udp://127.0.0.1:PORT``, as URLs are usually written, was refused: "host name
    '//127.0.0.1' does not resolve"."""
    peer = UdpPeer()
    try:
        with open_output(
            f"udp://127.0.0.1:{peer.port}?format=bin:0x55,6xu8", mapping({"unit": "deg"})
        ) as sink:
            assert sink.label == f"udp:127.0.0.1:{peer.port}"
            assert sink.write(np.zeros(6))
            assert wait_until(lambda: len(peer.datagrams) >= 1)
        assert peer.datagrams[0][0] == 0x55 and len(peer.datagrams[0]) == 7
    finally:
        peer.close()


@pytest.mark.parametrize("baud", ["0", "-5"])
def test_a_baud_rate_of_zero_is_one_error_and_no_warning(baud, caplog):
    """``baud=0`` used to print the frames-will-be-dropped warning (0 baud is less than any
    frame needs) before the error."""
    url = f"serial:loop://?format=text:A%7B1%7D%0A&baud={baud}"
    with caplog.at_level("WARNING", logger="motionbase"):
        with pytest.raises(ConfigError, match=f"baud must be > 0, got {baud}"):
            open_output(url, mapping({"unit": "deg"})).open()
    assert not caplog.records, caplog.text


def test_format_from_a_toml_file_and_loop_url(tmp_path):
    path = tmp_path / "drive.toml"
    path.write_text('binary = "0xFFFE,6xu16be,sum8@2"\nrate_hz = 250\n')
    sink = open_output(f"serial:loop://?format={path}", mapping({"unit": "deg"}))
    assert sink.rate_hz == 250 and sink.format.describe() == "bin:0xFFFE,6xu16be,sum8@2"
    with sink:
        sink.write(np.radians([1.0, 2, 3, 4, 5, 6]))
        assert wait_until(lambda: sink.frames_sent > 2)
    values = struct.unpack(">6H", sink.last_frame[2:14])
    assert sink.last_frame[:2] == b"\xff\xfe" and values == (1, 2, 3, 4, 5, 6)


def test_output_test_sweeps_each_motor_in_turn_through_a_pty(tmp_path, capsys):
    geo = tmp_path / "mirrored.toml"
    geo.write_text(
        preset_path("rus6", "ceart").read_text()
        + '\n[output]\nunit = "range"\nsign = [1, -1, 1, -1, 1, -1]\nrange_lo = 0\n'
        "range_hi = 4095\n"
    )
    fmt, _, split, decode, to_angle, tol = CASES["text-flypt-range12"]
    peer = PtyPeer()
    try:
        rc = main(
            ["output", "--test", url_for("pty", peer, fmt, rate=100), "--platform", str(geo)]
            + ["--speed-deg-s", "150", "--range-deg", "5"]
        )
        assert rc == 0
    finally:
        peer.close()  # (it takes what the run wrote, to the last byte: the run has ended)
    frames = peer.frames(split)
    assert len(frames) > 300
    printed = capsys.readouterr().out
    for i in range(1, 7):
        assert f"motor {i}:" in printed
    values = np.array([decode(f) for f in frames], dtype=float)
    angles = to_angle(values)
    park = GEOMETRY.park_angle
    np.testing.assert_allclose(angles[0], park, atol=tol)
    np.testing.assert_allclose(angles[-1], park, atol=tol)
    # at neutral (0 deg) every motor sits mid-range; motor 1 goes to +5 deg and -5 deg and
    # no further, the others at neutral, then motor 2, ... (to the 12-bit range's unit)
    holds = check_sweep(angles, np.zeros(6), math.radians(5), atol=tol)
    assert np.all(np.diff(holds.ravel()) > 0), holds
    # a mirrored motor's drive value falls as its crank rises (motor 2), a plain one's rises
    assert values[holds[1, 0], 1] < 2047 < values[holds[0, 0], 0]


# --------------------------------------------------------------------------- ramped at the drive


def test_the_drive_is_ramped_within_its_limits_whatever_the_commands_do(monkeypatch):
    """Commands that jump (a burst of late ticks, a far target) reach the drive as a ramp that
    keeps the speed and acceleration limits on the wire, frame by frame on the sender's
    clock (kept by the test: :func:`drive_wire.check_steps`), and ends exactly on the last
    command (the last frame: close() finishes the ramp). On the wall clock, a loaded
    machine that keeps the sender off the processor for more than two periods leaves the
    drive standing, and the ramp starts it again from rest: under two CPU burners close()
    now and then gave up short of the target (the module docstring of :mod:`drive_wire`)."""
    config = load_config()
    limits = Pipeline(config).robot.limits
    drive = UdpDrive()
    park = np.full(6, GEOMETRY.park_angle)
    far = np.radians([40.0, -40.0, 30.0, -30.0, 20.0, -20.0])
    try:
        sink = open_output(drive.url(200), mapping_for(Pipeline(config).robot), limits=limits)
        clock = keep_sender_clock(sink, monkeypatch)
        with sink:
            sink.write(park)  # where the drive starts: sent as it is
            assert wait_until(lambda: drive.count() >= 5)
            for a in np.linspace(0.0, 1.0, 50):  # 50 ticks' worth of motion in a burst
                sink.write(park + a * (far - park))
            assert wait_until(lambda: drive.count() >= 50)
        drive.drain()
    finally:
        drive.close()
    _, q = drive.angles()
    assert len(q) == len(clock.times)  # (loopback: every frame sent arrived)
    check_steps(clock.times, q, limits.max_speed, limits.max_accel, 1 / 200, TEXT_ROUNDING, "burst")
    np.testing.assert_allclose(q[0], park, atol=math.radians(1e-4))
    np.testing.assert_allclose(q[-1], far, atol=math.radians(1e-4))
    assert sink.ramped > 0 and "frames ramped at the drive" in sink.stats_line()


class _OverrunningClock:
    """A stand-in for the ``time`` module whose sleeps overrun by 0.7 of the asked-for time
    on every other call, as a sender thread on a loaded machine does: the sender's schedule
    then catches up with a short step after each long one."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.calls = 0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.calls += 1
        self.now += seconds * (1.7 if self.calls % 2 else 1.0)


def test_a_ramp_with_uneven_steps_stops_on_its_target_without_passing_it(monkeypatch):
    """close() ramps the drive 40 deg to its last command while every other sleep of the
    sender overruns, so long and short steps alternate. Braking sized for the step it is
    given used to carry the drive past the target (the short step after a long one cannot
    shed the speed the long one allowed) and back: a reversal in the seat. The ramp skips
    steps under half a period, and its braking holds whatever the lengths of the later
    steps (:func:`motionbase.physics.uneven_stop_speed`)."""
    from motionbase.io import motor_output

    clock = _OverrunningClock()
    monkeypatch.setattr(motor_output, "time", clock)
    config = load_config()
    robot = Pipeline(config).robot
    park = robot.park_angles
    far = park + np.radians([40.0, 35.0, 30.0, 25.0, 20.0, 45.0])
    drive = UdpDrive()
    try:
        sink = open_output(drive.url(100.0), mapping_for(robot), limits=robot.limits)
        sent_at: list[float] = []  # each frame's time on the overrunning clock
        send = sink.transport.send

        def timed_send(frame: bytes) -> None:
            send(frame)
            sent_at.append(clock.now)

        sink.transport.send = timed_send
        sink.open()
        sink.write(park)  # the frozen clock: the sender sends this one frame, no more
        assert wait_until(lambda: drive.count() >= 1)
        sink.write(far)
        sink.close()  # the ramp to ``far`` runs here, on the overrunning clock
        drive.drain()
    finally:
        drive.close()
    _, q = drive.angles()
    assert len(q) == len(sent_at) > 20
    check_wire_limits(np.array(sent_at), q, robot.limits.max_speed, robot.limits.max_accel, "ramp")
    np.testing.assert_allclose(q[-1], far, atol=math.radians(1e-4))
    passed = np.max((q - far) * np.sign(far - park), axis=0)
    assert np.all(passed <= math.radians(1e-4)), np.degrees(passed)


class _SteppedClock:
    """A stand-in for the ``time`` module that reads the time it is set to: each frame of the
    sender is then taken at the time the test gives it, to the nanosecond."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now


class _Commands:
    """A sink that keeps every command of a run (the pipeline's outputs' angles)."""

    def __init__(self) -> None:
        self.angles: list[np.ndarray] = []

    def write(self, output) -> None:
        self.angles.append(np.array(output.angles))


def _sweep_commands(rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The commands of ``motionbase output --test --speed-deg-s 60 --rate RATE_HZ`` on the
    default 6-RUS, one a tick (its sweep through the pipeline, run unpaced), and neutral."""
    from motionbase.commanding import CommandPipeline, SweepSource
    from motionbase.platform.robot import robot_spec

    robot = robot_spec("rus6").make(GEOMETRY)
    pipeline = CommandPipeline(robot, rate_hz=rate_hz, mode="actuators")
    sweep = SweepSource(
        robot, range_=math.radians(5.0), speed=math.radians(60.0), rate_hz=rate_hz,
        lead_s=pipeline.soft_start_s,
    )  # fmt: skip
    out = _Commands()
    run(pipeline, sweep, [out])
    return np.array(out.angles), sweep.neutral


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("jitter", [0.3, 0.6])
def test_the_drive_never_passes_a_command_that_comes_to_rest_whatever_the_frame_timing(
    monkeypatch, seed, jitter
):
    """The wiring check's commands (``output --test --speed-deg-s 60 --rate 200``), each
    written up to ``jitter`` of a period after its tick, sampled by the sender's frames at
    200 Hz, each up to ``jitter`` of a period late (seeded; frames due sooner than half a
    period after the last wait for the next). The sender's own code makes each frame
    (``MotorOutput._tick`` at the frame's time, on a clock that reads it) and sends it to a
    UDP drive; the test reads each frame as it went on the wire with the drive's own parser
    (:func:`drive_wire.decode`). The drive never goes past a command that comes to rest
    (to the wire's rounding): the sweep reaches +-5 deg exactly, one motor at a time, the
    others at neutral; the frames keep the speed, acceleration and angle limits and end on
    park.

    The ramp used to feed forward the speed between the commands its frames sampled: a
    command sampled twice looked stopped, the next one twice as fast, and the drive went
    past the end of a move by 0.02-0.39 deg in 11 of these 12 runs."""
    from motionbase.io import motor_output

    rate = 200.0
    period = 1.0 / rate
    commands, neutral = _sweep_commands(rate)
    rng = np.random.default_rng(seed)
    written = (np.arange(len(commands)) + rng.uniform(0.0, jitter, len(commands))) * period
    n = len(commands) + int(rate)  # and a second after the last command
    due = (np.arange(n) + rng.uniform(0.0, 1.0) + rng.uniform(0.0, jitter, n)) * period
    clock = _SteppedClock()
    monkeypatch.setattr(motor_output, "time", clock)
    robot = Pipeline(load_config()).robot
    lim = robot.limits
    drive = UdpDrive()  # (the peer; the frames are read as they were put on the wire)
    times, frames, sampled = [], [], []
    try:
        # (the commands' tick: the sender's period, the default)
        sink = open_output(drive.url(rate), mapping_for(robot), limits=lim)
        sink.transport.open()  # (no sender thread: the test makes each frame)
        k = -1
        for now in due:
            while k + 1 < len(commands) and written[k + 1] <= now:
                k += 1
                sink.write(commands[k])
            clock.now = now
            sent = sink.frames_sent
            sink._tick(now)
            if sink.frames_sent > sent:
                times.append(now)
                frames.append(sink.last_frame)
                sampled.append(k)
        sink.transport.close()
    finally:
        drive.close()
    assert sink.send_errors == 0 and len(frames) > len(commands) // 2
    t = np.array(times)
    q = np.array([decode(f) for f in frames])
    rounding = math.radians(0.6e-4)  # (the wire's four decimals of a degree)
    sampled = np.array(sampled)
    passed = past_rest(commands, q, sampled)
    assert np.all(passed <= rounding), np.degrees(passed)
    check_wire_limits(t, q, lim.max_speed, lim.max_accel, "the sweep")
    assert np.all(q >= lim.lower - rounding) and np.all(q <= lim.upper + rounding)
    np.testing.assert_allclose(q[-1], commands[-1], atol=rounding)
    # the sweep exactly: each motor in turn to +5 deg and -5 deg, the others at neutral
    check_sweep(q, neutral, math.radians(5.0), atol=rounding)
    assert sink.ramped > 0  # (not vacuous: the ramp shaped frames)


def _limited_commands(rng: np.random.Generator, tick: float, n: int, limits) -> np.ndarray:
    """Commands a tick apart as the pipeline's limiter makes them: ``n`` toward targets that
    jump now and then, some beyond the angle limits (held: braked to rest where it is), then
    on toward the last one until they rest."""
    q, v, prev = np.zeros(6), np.zeros(6), np.zeros(6)
    target = np.zeros(6)
    out = [q]
    for k in range(n + int(10.0 / tick)):
        if k < n and rng.random() < 3.0 * tick:
            target = rng.uniform(-1.2, 1.2, 6) * (rng.random() < 0.8)
        q, v, status = limit_command(q, v, prev, target, tick, limits)
        prev = q.copy() if status & UNSAFE_TARGET else target
        out.append(q)
        if k >= n and not v.any():
            break
    return np.array(out)


@pytest.mark.parametrize("seed", range(10))
def test_the_ramp_never_passes_a_rest_of_any_commands_within_the_limits(seed):
    """The sender's ramp, a frame at a time (:func:`ramp_offline`, no sockets, no clock): the
    commands of a limited pipeline at 50-1000 Hz toward random targets, written late by up
    to 0.9 of a tick, the pipeline or the sender stalling now and then, sampled by frames at
    50-1000 Hz up to 0.9 of a period late (seeded). The drive never passes a command that
    comes to rest (to the float's rounding), each step keeps the speed and acceleration
    limits (a step after a stall starts from rest), every frame is within the angle limits,
    and the drive ends on the last command."""
    rng = np.random.default_rng(seed)
    lim = Pipeline(load_config()).robot.limits
    tick, period = 1.0 / rng.choice([50, 120, 200, 1000]), 1.0 / rng.choice([50, 100, 200, 1000])
    commands = _limited_commands(rng, tick, int(2.0 / tick), lim)
    jitter = rng.choice([0.3, 0.9])
    written = (np.arange(len(commands)) + rng.uniform(0.0, jitter, len(commands))) * tick
    written[rng.integers(len(written)) :] += rng.uniform(0.0, 0.1)  # a pipeline stall
    n = int((written[-1] + 1.0) / period)
    due = (np.arange(n) + rng.uniform(0.0, 1.0) + rng.uniform(0.0, jitter, n)) * period
    due[rng.integers(n) :] += rng.uniform(0.0, 0.05)  # a sender stall
    t, q, sampled = ramp_offline(commands, written, due, period=period, command_dt=tick, limits=lim)
    passed = past_rest(commands, q, sampled)
    assert np.all(passed <= 1e-12), np.degrees(passed)
    assert np.all(q >= lim.lower) and np.all(q <= lim.upper)
    # each step's speed over its time, or over a period from rest after a gap (the ramp's
    # model of a drive that got no frame for more than two periods: it stood still)
    dt = np.diff(t)
    gap = dt > 2.0 * period
    dt[gap] = period
    v = np.diff(q, axis=0) / dt[:, None]
    before = np.vstack([np.zeros(6), v[:-1]])
    before[gap] = 0.0
    assert np.all(np.abs(v) <= lim.max_speed * (1 + 1e-9))
    assert np.all(np.abs(v - before) <= lim.max_accel * dt[:, None] * (1 + 1e-9))
    assert np.array_equal(q[-1], commands[-1])


def _manoeuvring(duration_s: float, dt: float) -> list[AircraftState]:
    """Strong manoeuvring: the cranks work at their limits."""
    states = []
    for k in range(int(duration_s / dt)):
        s = math.sin(2 * math.pi * 0.7 * k * dt)
        states.append(AircraftState(k * dt, [25 * s, 20 * s, -9.80665 + 10 * s], [3 * s] * 3))
    return states


def _flight(pipeline: Pipeline, states, sink, progress) -> threading.Thread:
    """A paced run of ``states`` into ``sink`` (entered and closed by it), in a thread."""

    def flight() -> None:
        with sink:
            run(pipeline, states, [sink], paced=True, progress=progress)

    return threading.Thread(target=flight, daemon=True)


#: Cranks of +-60 deg at 30 deg/s and 50 deg/s^2: the tests of narrow drive ranges.
NARROW_TEST_LIMITS = ActuatorLimits.broadcast(
    6, -math.radians(60), math.radians(60), math.radians(30.0), math.radians(50.0)
)


def _deg_drive(limits: ActuatorLimits, drive_min: float, drive_max: float) -> OutputMapping:
    """Degrees to drives whose range is ``drive_min..drive_max`` deg."""
    return OutputMapping.from_dict(
        {"unit": "deg", "drive_min": drive_min, "drive_max": drive_max},
        angle_min=limits.lower, angle_max=limits.upper,
    )  # fmt: skip


def _speeding_up(start: float, n: int, limits: ActuatorLimits, dt: float = 0.01) -> np.ndarray:
    """``n`` commands every ``dt`` s from ``start`` (rad), speeding up within ``limits``'
    acceleration to their speed, then on at it."""
    vmax, amax = limits.max_speed[0], limits.max_accel[0]
    return start + np.cumsum(np.minimum(vmax, amax * dt * np.arange(1, n + 1)) * dt)


def _paced_to_drive(
    drive: UdpDrive,
    url: str,
    mapping: OutputMapping,
    commands: np.ndarray,
    monkeypatch,
    dt: float = 0.01,
    limits: ActuatorLimits = NARROW_TEST_LIMITS,
) -> tuple[MotorOutput, np.ndarray]:
    """Write ``commands`` (one angle, rad, for every motor) every ``dt`` s to ``url``, a
    sender ramping within ``limits`` on a clock the test keeps (:class:`drive_wire.
    SenderClock`), closed after the last; the frames are ``drive``'s (drained). The sink,
    and each frame's time on the sender's clock."""
    sink = open_output(url, mapping, limits=limits, command_dt=dt)
    clock = keep_sender_clock(sink, monkeypatch)
    with sink:
        start = time.monotonic()
        for k, c in enumerate(commands):
            sink.write(np.full(6, c))
            time.sleep(max(0.0, start + (k + 1) * dt - time.monotonic()))
    drive.drain()
    assert drive.count() == len(clock.times)  # (loopback: every frame sent arrived)
    return sink, np.array(clock.times)


def test_a_drive_range_narrower_than_the_limits_is_braked_for_not_hit(caplog, monkeypatch):
    """An ``[output]`` drive range of -20..20 deg on cranks limited to +-60 deg: commands
    within the limits (speeding up at 50 deg/s^2 to 30 deg/s) run past 20 deg. The frames
    beyond are never sent, and the drive used to get the last one it could and stop there
    from 30 deg/s at once: 4.9 rad/s^2 over 0.1 s windows on the wire, against a limit of
    0.87. It now brakes within the limit before the edge (it needs 30^2 / (2 * 50) = 9 deg),
    every frame within -20..20 deg, and ends on the last command it could be sent.

    The limits are checked per frame on the sender's clock, which the test keeps
    (:func:`drive_wire.check_steps`): that is what the ramp guarantees. On the wall clock
    a sender kept off the processor for two periods leaves the drive standing (3.8 rad/s^2
    over 0.1 s windows, under two CPU burners), which no sender can help."""
    limits = NARROW_TEST_LIMITS
    vmax, amax = limits.max_speed[0], limits.max_accel[0]
    mapping = _deg_drive(limits, -20.0, 20.0)
    dt = 0.01
    commands = _speeding_up(0.0, 250, limits, dt)  # to 66 deg in 2.5 s
    drive = UdpDrive()
    try:  # the last command held 0.5 s: the drive comes to rest
        held = [*commands, *[commands[-1]] * 50]
        url = drive.url(100.0)
        sink, t = _paced_to_drive(drive, url, mapping, np.array(held), monkeypatch, dt)
    finally:
        drive.close()
    _, q = drive.angles()
    assert sink.held > 0  # the commands past 20 deg were never sent
    assert np.degrees(q).max() <= 20.0 + 1e-4
    check_steps(t, q, vmax, amax, 0.01, TEXT_ROUNDING, "braking for the drive range")
    # at rest, last, on the last command it could be sent (the frames' four decimals)
    last = commands[np.degrees(commands) <= 20.0].max()
    np.testing.assert_allclose(q[-1], last, rtol=0, atol=math.radians(1e-4))


def test_a_drive_range_holding_neither_the_middle_nor_the_limits_is_braked_for(monkeypatch):
    """Crank limits -60..90 deg (their middle 15 deg) and a drive range of -58..5 deg: it
    holds park and neutral but neither limit nor their middle. The cut of the ramp's limits
    looked for a position sent only there, found none and left the limits whole, so the
    commands speeding up past 5 deg were held and the drive stopped at 5 deg from 30 deg/s
    at once. It must brake within the limits (on the sender's clock, as above), every frame
    within -58..5 deg."""
    vmax, amax = math.radians(30.0), math.radians(50.0)
    limits = ActuatorLimits.broadcast(6, -math.radians(60), math.radians(90), vmax, amax)
    mapping = _deg_drive(limits, -58.0, 5.0)
    dt = 0.01
    commands = _speeding_up(math.radians(-20.0), 200, limits, dt)  # -20 deg to about 30 deg
    drive = UdpDrive()
    try:  # the last command held 0.5 s
        held = np.array([*commands, *[commands[-1]] * 50])
        sink, t = _paced_to_drive(drive, drive.url(100.0), mapping, held, monkeypatch, dt, limits)
    finally:
        drive.close()
    _, q = drive.angles()
    assert sink.held > 0 and len(q) > 100
    assert np.degrees(q).max() <= 5.0 + 1e-4
    check_steps(t, q, vmax, amax, 0.01, TEXT_ROUNDING, "braking for a drive range off the middle")


def test_a_command_at_a_limit_reaches_the_drive_exactly(caplog, monkeypatch):
    """The drive range of the default mapping is the limits' own image: a command exactly
    at a crank limit (a clamped pose can put one there) is sent as it is, the ramp's limits
    untouched by the braking for narrower drive ranges (cut a hair inside, they held such a
    command: the drive stopped at 59.9855 deg, "may not be at the last command")."""
    limits = NARROW_TEST_LIMITS
    mapping = OutputMapping.default(limits.lower, limits.upper)
    commands = np.linspace(math.radians(55.0), limits.upper[0], 60)  # 5 deg in 0.6 s
    drive = UdpDrive()
    try:
        with caplog.at_level(logging.WARNING, logger="motionbase.io.motor_output"):
            held = np.array([*commands, *[commands[-1]] * 30])
            _paced_to_drive(drive, drive.url(100.0), mapping, held, monkeypatch)
    finally:
        drive.close()
    _, q = drive.angles()
    np.testing.assert_array_equal(np.round(np.degrees(q[-1]), 4), np.full(6, 60.0))
    assert not [r for r in caplog.records if "may not be" in r.getMessage()]


def test_a_command_sent_at_the_edge_of_a_narrow_drive_range_is_reached(monkeypatch):
    """Braking for a drive range of -60..3 deg on +-60 deg cranks must not refuse a command
    the drive can be sent: the ramp's edge was put a hair inside 3 deg, and a command a hair
    less than 3 deg (drive value <= 3, sent) lay beyond it, so the ramp held the drive at
    2.99 deg. The edge is now the last position sent, and the drive reaches the command."""
    limits = NARROW_TEST_LIMITS
    mapping = _deg_drive(limits, -60.0, 3.0)
    top = math.radians(3.0)
    while mapping.to_drive(np.full(6, top))[0] > 3.0:  # the largest angle sent as <= 3 deg
        top = np.nextafter(top, 0.0)
    assert 3.0 - 1e-12 < mapping.to_drive(np.full(6, top))[0] <= 3.0
    drive = UdpDrive()
    try:
        commands = np.array([*np.linspace(0.0, top, 40), *[top] * 40])
        sink, _ = _paced_to_drive(drive, drive.url(100.0), mapping, commands, monkeypatch)
    finally:
        drive.close()
    _, q = drive.angles()
    assert sink.held == 0
    np.testing.assert_array_equal(np.round(np.degrees(q[-1]), 4), np.full(6, 3.0))


def test_a_frame_field_narrower_than_the_limits_is_braked_for_not_hit(monkeypatch):
    """The same with the frame's fields: ``bin:6xu16be*1000`` of degrees with a 60 deg zero
    offset (thousandths of a degree from -60) carries the park and neutral commands but no
    value past 65.535 - 60 = 5.535 deg. Commands within the limits at 30 deg/s ran past it
    and the drive stopped there at once (4.9 rad/s^2 on the wire against 0.87). It now
    brakes within the limits (on the sender's clock, as above), every frame, read here by
    ``struct``, at most 5.535 deg."""
    limits = NARROW_TEST_LIMITS
    vmax, amax = limits.max_speed[0], limits.max_accel[0]
    mapping = OutputMapping.from_dict(
        {"unit": "deg", "zero_offset_deg": 60.0}, angle_min=limits.lower, angle_max=limits.upper
    )
    dt = 0.01
    commands = _speeding_up(math.radians(-30.0), 300, limits, dt)  # -30 deg to about 50 deg
    drive = UdpDrive()  # (its frames as they came; decoded here)
    try:
        url = f"udp:127.0.0.1:{drive.port}?rate=100&format=bin:6xu16be*1000"
        held = np.array([*commands, *[commands[-1]] * 50])
        sink, t = _paced_to_drive(drive, url, mapping, held, monkeypatch)
    finally:
        drive.close()
    q = np.radians(np.array([struct.unpack(">6H", f) for _, f in drive.frames]) / 1000.0 - 60.0)
    assert sink.held > 0 and len(q) > 100
    assert np.degrees(q).max() <= 5.535 + 1e-9
    rounding = math.radians(0.5e-3)  # (thousandths of a degree)
    check_steps(t, q, vmax, amax, 0.01, rounding, "braking for the frame's field")


def test_a_udp_drive_back_from_an_outage_is_ramped_from_where_it_last_was(caplog, monkeypatch):
    """The drive vanishes in full motion (its port refuses: send errors) and returns 1.5 s of
    motion later: its first frame after the outage is within one frame's travel of the last
    one it got (at most two frames at full speed, plus a first step from rest), and from there
    (where it stands while the link is on probation) the frames keep the speed and
    acceleration limits, per frame on the sender's clock (:func:`drive_wire.check_steps`);
    the run ends parked."""
    config = load_config()
    pipeline = Pipeline(config)
    limits = pipeline.robot.limits
    dt = config.dt
    drive = UdpDrive()
    rate = 100.0
    sink = open_output(drive.url(rate), mapping_for(Pipeline(config).robot), limits=limits)
    clock = keep_sender_clock(sink, monkeypatch)
    ticks = [0]

    def count(_out) -> None:
        ticks[0] += 1

    runner = _flight(pipeline, _manoeuvring(6.0, dt), sink, count)
    with caplog.at_level(logging.WARNING, logger="motionbase.io.motor_output"):
        runner.start()
        try:
            assert wait_until(lambda: ticks[0] >= int(2.5 / dt), timeout=60)  # full motion
            drive.vanish()
            n_before = drive.count()  # (its reader has stopped)
            gone_at = ticks[0]
            assert wait_until(lambda: not sink.link_up, timeout=30)
            assert wait_until(lambda: ticks[0] >= gone_at + int(1.5 / dt), timeout=60)
            drive.come_back()
            runner.join(120)
            assert not runner.is_alive()
            drive.drain()
        finally:
            drive.close()
    _, q = drive.angles()
    assert len(q) > n_before + 100
    last_before, first_after = q[n_before - 1], q[n_before]
    period = 1.0 / rate
    reach = 2 * limits.max_speed * period + limits.max_accel * period**2
    assert np.all(np.abs(first_after - last_before) <= reach), np.degrees(first_after - last_before)
    # the frames after it are the last ones sent (loopback: every one arrived)
    after_t = clock.times[n_before - len(q) :]
    vmax, amax = limits.max_speed, limits.max_accel
    check_steps(after_t, q[n_before:], vmax, amax, period, TEXT_ROUNDING, "after the outage")
    np.testing.assert_allclose(q[-1], pipeline.robot.park_angles, atol=math.radians(1e-4))
    assert sink.send_errors > 0
    said = [r.getMessage() for r in caplog.records]
    assert any("link is down" in m for m in said) and any("link back" in m for m in said)


def test_a_drive_that_reads_nothing_at_first_is_ramped_from_park_when_it_starts():
    """A serial drive that is not reading when the run starts (its pseudo-terminal's buffer
    full): the first frames time out and the link is down. When it starts reading, 7 s into
    a wiring check, it was sent the command of that moment, the cranks on their way from
    park (-55 deg) to neutral: a step of about 10 deg in one frame. It is now ramped from
    park, where the run started: after the bytes it had not read, its first frame is within
    one frame's travel of park, and no two frames in a row are further apart than the
    speed limit allows over two periods (the longest step the ramp takes while moving)."""
    from motionbase.app import output_test
    from motionbase.platform.robot import robot_spec

    robot = robot_spec("rus6").make(Rus6Geometry.preset("ceart"))
    master, slave = pty.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    fill = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
    try:  # the drive's buffer is full: it reads nothing yet
        while True:
            os.write(fill, b"Z" * 1024)
    except BlockingIOError:
        pass
    finally:
        os.close(fill)
    got = bytearray()

    def read_later() -> None:
        time.sleep(7.0)
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:
                return
            if not chunk:
                return
            got.extend(chunk)

    reader = threading.Thread(target=read_later, daemon=True)
    reader.start()
    rate = 100.0
    fmt = quote(r"text:{1:.4f},{2:.4f},{3:.4f},{4:.4f},{5:.4f},{6:.4f}\n", safe="")
    try:
        output_test(
            f"serial:{path}?rate={rate:g}&format={fmt}", robot, speed_deg_s=30.0,
            echo=lambda s: None,
        )  # fmt: skip
        wait_until(lambda: got.endswith(b"\n") and len(got) > 20000, timeout=5)
    finally:
        os.close(slave)
        reader.join(5)
        os.close(master)
    frames = re.findall(rb"(-?\d+\.\d{4}(?:,-?\d+\.\d{4}){5})\n", bytes(got).lstrip(b"Z"))
    q = np.radians([[float(x) for x in f.split(b",")] for f in frames])
    assert len(q) > 1000
    one = float(robot.limits.max_speed.max()) / rate  # the farthest a frame moves a drive
    np.testing.assert_allclose(q[0], robot.park_angles, rtol=0, atol=one)
    steps = np.abs(np.diff(q, axis=0)).max(axis=1)
    assert steps.max() <= 2 * one + math.radians(1e-4), np.degrees(steps.max())
    np.testing.assert_allclose(q[-1], robot.park_angles, rtol=0, atol=math.radians(1e-4))


@pytest.mark.parametrize("outage_s", [0.05])
def test_a_drive_that_drops_out_while_the_run_parks_is_still_parked(outage_s, caplog):
    """The drive's link fails for a moment while the pipeline ramps to park, and returns
    before the run ends (or just after). Its last frame is the park command: the sender waits
    out the link's probation and ramps it there. It used to give up at once on a link still
    on probation, so the drive stayed where the outage left it. Within the limits all along
    (that the catch-up does not pass its target: the test of uneven steps above)."""
    config = load_config()
    pipeline = Pipeline(config)
    limits = pipeline.robot.limits
    park = pipeline.robot.park_angles
    drive = UdpDrive()
    sink = open_output(drive.url(100.0), mapping_for(pipeline.robot), limits=limits)
    parking = threading.Event()

    def watch(out) -> None:
        if out.phase == "stopping":
            parking.set()

    runner = _flight(pipeline, _manoeuvring(2.5, config.dt), sink, watch)
    with caplog.at_level(logging.WARNING, logger="motionbase.io.motor_output"):
        runner.start()
        try:
            assert parking.wait(60)
            time.sleep(1.5)  # late in the 2 s ramp to park: the link's probation outlasts it
            drive.vanish()
            assert wait_until(lambda: not sink.link_up, timeout=30)
            time.sleep(outage_s)
            drive.come_back()
            runner.join(120)
            assert not runner.is_alive()
            drive.drain()
        finally:
            drive.close()
    t, q = drive.angles()
    np.testing.assert_allclose(q[-1], park, atol=math.radians(1e-4))
    check_wire_limits(t, q, limits.max_speed, limits.max_accel, "an outage while parking")
    said = [r.getMessage() for r in caplog.records]
    assert not any("may not be at the last command" in m for m in said), said


def test_a_drive_that_never_comes_back_is_said_not_to_be_parked(caplog):
    """A drive gone for good at the end of a run: close() waits for it a moment, then one
    warning says it may not be at the park command."""
    config = load_config()
    pipeline = Pipeline(config)
    drive = UdpDrive()
    sink = open_output(drive.url(100.0), mapping_for(pipeline.robot), limits=pipeline.robot.limits)
    try:
        with caplog.at_level(logging.WARNING, logger="motionbase.io.motor_output"):
            with sink:
                sink.write(pipeline.robot.park_angles)
                assert wait_until(lambda: drive.count() >= 3)
                sink.write(pipeline.robot.inverse(np.zeros(6)))  # away from park
                drive.vanish()
                assert wait_until(lambda: not sink.link_up, timeout=30)
                closing = time.monotonic()
            waited = time.monotonic() - closing
    finally:
        drive.close()
    said = [r.getMessage() for r in caplog.records]
    warned = [m for m in said if "may not be at the last command" in m]
    assert warned, said
    # the time it says is the time it waited (the return wait, the link's probation and the
    # ramp): it used to say the ramp's time alone, 1.4 s on ceart, after waiting 4.4 s
    stated = float(re.search(r"within ([0-9.]+) s", warned[0]).group(1))
    assert waited - 1.0 <= stated <= waited + 0.1, (stated, waited)


@pytest.mark.parametrize(
    ("fmt", "needle"),
    [
        # the --output help's old example: unsigned fields, the 6-RUS parks at -55 deg
        ("bin:0xFFFE,6xu16be,sum8@2", "park command's drive values (-55, -55"),
        ("text:A%7B1:04x%7D%0A", "do not fit the frame format 'text:A{1:04x}\\n'"),  # hex
    ],
)
def test_a_format_that_can_never_send_is_refused_before_the_run(fmt, needle, capsys, tmp_path):
    """An output whose frame cannot carry the park command would hold every frame of the
    run (the summary said "0 frames sent, 241 held out of range"): refused before anything
    moves, in one line, exit 2."""
    from motionbase.platform.robot import robot_spec

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    try:
        url = f"udp:127.0.0.1:{sock.getsockname()[1]}?format={fmt}"
        out = tmp_path / "f.mcap"
        code = main(["fly", "c1723", "--duration", "1", "--out", str(out), "--output", url])
        err = capsys.readouterr().err
        assert code == 2
        assert needle in err and len(err.strip().splitlines()) == 1, err
        with pytest.raises(socket.timeout):
            sock.recv(4096)
        # a signed field in centidegrees carries them
        robot = robot_spec("rus6").make(Rus6Geometry.preset("ceart"))
        url = f"udp:127.0.0.1:{sock.getsockname()[1]}?format=bin:0xFFFE,6xi16be*100,sum8@2"
        assert len(open_outputs([url], robot)) == 1
    finally:
        sock.close()


#: A frame of whole drive units, as the default format writes them: ``A-60B...``.
WHOLE_UNITS = rb"A(-?\d+)B(-?\d+)C(-?\d+)D(-?\d+)E(-?\d+)F(-?\d+)\n"


def test_a_field_that_rounds_never_puts_a_value_past_the_drive_range(monkeypatch):
    """Motors whose zero is 0.3 deg off (``zero_offset_deg = 0.3``: drive values -59.7..60.3
    deg across the +-60 deg cranks) and the default frame format, whole degrees. The
    commands run down to the lower crank limit and rest there. The drive range's check took
    the value before the frame rounded it: -59.7 went out as -60, the crank at -60.3 deg,
    past its limit. Read back here (the wire's whole degrees less the offset), every frame
    is within the limits: the drive stops at the last whole degree within them, -59."""
    limits = NARROW_TEST_LIMITS
    mapping = OutputMapping.from_dict(
        {"unit": "deg", "zero_offset_deg": 0.3}, angle_min=limits.lower, angle_max=limits.upper
    )
    down = -_speeding_up(0.0, 300, limits)  # 0 to past -60 deg at 30 deg/s
    commands = np.maximum(down, limits.lower[0])  # clamped at the limit, as a flight's are
    drive = UdpDrive()
    try:
        url = f"udp:127.0.0.1:{drive.port}?rate=100"  # the default format: A{1}B{2}...
        held = np.array([*commands, *[commands[-1]] * 50])
        _paced_to_drive(drive, url, mapping, held, monkeypatch)
    finally:
        drive.close()
    wire = np.array(
        [[int(x) for x in re.fullmatch(WHOLE_UNITS, f).groups()] for _, f in drive.frames]
    )
    crank_deg = wire - 0.3
    assert len(wire) > 100 and crank_deg.min() >= -60.0, crank_deg.min()
    np.testing.assert_array_equal(wire[-1], np.full(6, -59))


def test_an_output_whose_rounding_puts_park_past_a_limit_is_refused(tmp_path, capsys):
    """``unit = "rad"`` with the default format (whole radians) on cranks limited to
    -57..60 deg, parked at -52 deg: park is written -1 rad, -57.3 deg, past the lower limit.
    The wiring check sent it 100 times a second; it is refused before a frame is sent, in
    one line, exit status 2."""
    text = preset_path("rus6", "ceart").read_text()
    text = text.replace("angle_min_deg = -60.0", "angle_min_deg = -57.0")
    text = re.sub(r"park_angle_deg = -55\.0.*", "park_angle_deg = -52.0", text)
    geo = tmp_path / "rad.toml"
    geo.write_text(text + '\n[output]\nunit = "rad"\n')
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    try:
        url = f"udp:127.0.0.1:{sock.getsockname()[1]}"
        code = main(["output", "--test", url, "--platform", str(geo)])
        err = capsys.readouterr().err
        assert code == 2 and "park command" in err and len(err.strip().splitlines()) == 1, err
        with pytest.raises(socket.timeout):
            sock.recv(4096)
    finally:
        sock.close()


def test_a_motor_that_no_output_carries_is_refused_before_the_run(tmp_path, capsys):
    """A frame format made for a three-actuator robot (``A{1}B{2}C{3}\\n``) on the Stewart
    platform's six: the flight sent lengths for actuators 1 to 3 and nothing for 4 to 6,
    which stood still while the others moved. Refused before anything is sent, in one line
    naming them, exit 2. Two drives that share the motors between them are fine."""
    from motionbase.platform import Stewart6Geometry
    from motionbase.platform.robot import robot_spec

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.5)
    port = sock.getsockname()[1]
    try:
        url = f"udp:127.0.0.1:{port}?format=" + quote("A{1}B{2}C{3}\n", safe="")
        args = ["fly", "c1723", "--platform", "stewart6", "--duration", "1"]
        code = main([*args, "--out", str(tmp_path / "f.mcap"), "--output", url])
        err = capsys.readouterr().err
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert "motors 4, 5, 6" in err, err
        with pytest.raises(socket.timeout):
            sock.recv(4096)
        robot = robot_spec("stewart6").make(Stewart6Geometry.preset("seat"))
        other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        other.bind(("127.0.0.1", 0))
        try:
            second = f"udp:127.0.0.1:{other.getsockname()[1]}?format=" + quote(
                "A{4}B{5}C{6}\n", safe=""
            )
            assert len(open_outputs([url, second], robot)) == 2
        finally:
            other.close()
    finally:
        sock.close()
