"""Live MAVLink telemetry (or a MAVLink/DataFlash log) as a fixed-rate source.

:class:`MavlinkSource` opens any pymavlink connection string, builds
:class:`~motionbase.state.AircraftState` samples from the IMU and attitude
messages of one vehicle, and yields them at the fixed pipeline rate, holding the
latest sample between messages (never extrapolating).

Freshness
---------
The iterator yields plain :class:`~motionbase.state.AircraftState` objects (the
:class:`~motionbase.io.base.Source` protocol). After each ``next()``, the
attributes :attr:`MavlinkSource.fresh`, :attr:`MavlinkSource.sample_age_s` and
:attr:`MavlinkSource.tick` (a frozen :class:`MavlinkTick`) describe the state
just yielded. A tick is *fresh* when both the specific-force sample (an IMU
message) and the attitude sample are at most ``stale_timeout_s`` old. When no
fresh sample arrives the source keeps ticking at the pipeline rate, holding the
last state (or the neutral state ``f = (0, 0, -g)`` before any sample), with
``fresh`` False, so the pipeline's watchdog can fade the platform to neutral.

Messages and units
------------------
* Specific force and body rates, best source first: ``HIGHRES_IMU`` (m/s^2,
  rad/s), ``SCALED_IMU``, ``SCALED_IMU2``, ``SCALED_IMU3`` (mG, mrad/s), and
  ``RAW_IMU``. The MAVLink spec defines ``RAW_IMU`` in raw sensor units, so it
  is ignored, except from an ArduPilot vehicle (HEARTBEAT autopilot
  ``MAV_AUTOPILOT_ARDUPILOTMEGA``), which fills it with the same mG and mrad/s
  values as ``SCALED_IMU`` (checked on ``vtol.tlog``). A worse source is used
  only while every better one is stale. MAVLink accelerometers read specific
  force in body FRD: level and at rest, ``zacc`` is about -9.81 m/s^2 (-1000 mG).
* Attitude: ``ATTITUDE`` (rad), or ``ATTITUDE_QUATERNION`` while no fresh
  ``ATTITUDE`` arrives, converted to Z-Y-X Euler angles.
* Flight phase (:attr:`~motionbase.state.AircraftState.on_ground`):
  ``EXTENDED_SYS_STATE.landed_state``, ``MAV_LANDED_STATE_ON_GROUND`` on the ground,
  ``IN_AIR``, ``TAKEOFF`` and ``LANDING`` in the air; ``UNDEFINED`` keeps the last one.
  Held like the other values; None until the first message.
* DataFlash ``.bin`` logs: ``IMU`` (first instance; AccX/Y/Z m/s^2, GyrX/Y/Z
  rad/s) and ``ATT`` (Roll/Pitch/Yaw in degrees, converted to rad, yaw wrapped
  to [-pi, pi)).

Body rates come from the IMU message that gives the specific force (same
instant). ``HIGHRES_IMU.fields_updated`` is not consulted.

Logs are resampled on their own clock: a ``.tlog`` by default on the vehicle's
``time_boot_ms``/``time_usec`` (the ground station's receive stamps in
``vtol.tlog`` arrive in bursts with 1-2 s holes, which would make 58 % of the
ticks stale; the vehicle clock gives 94 % fresh), a DataFlash log on its
``TimeUS``/``TimeMS``. Ticks start at the first record, ``t = k / rate_hz``.

Filtering and safety
--------------------
Only messages from ``sysid`` (and ``compid`` when given) are used
(``msg.get_srcSystem()``: pymavlink's ``recv_match`` has no system filter), each
component's from one UDP address at a time: the first, until it is silent for
``stale_timeout_s`` (a second vehicle with the same ids is rejected, with a warning).
With a signing key, unsigned and badly signed messages are rejected. Bytes that
do not parse are counted as ``bad_data`` (runs of them) and ``bad_bytes``; they
never take good frames down with them (see :class:`_FrameReader`: a frame may
span datagrams, as a serial-to-UDP bridge sends it, and parsing resynchronises
on the next frame start after a frame that fails). Values that are NaN, infinite or
physically absurd (beyond the pipeline's plausibility bounds, :mod:`motionbase.physics`)
are rejected and counted. Nothing rejected reaches the state.

MAVLink 2
---------
Signing needs the MAVLink 2 dialect, which pymavlink chooses when it is first
imported, from the ``MAVLINK20`` environment variable. This module sets
``os.environ["MAVLINK20"] = "1"`` before importing ``pymavlink.mavutil``, and
switches an already imported mavutil to MAVLink 2 if needed. MAVLink 2 parsing
still accepts MAVLink 1 packets.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import stat
import string
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

os.environ["MAVLINK20"] = "1"  # must precede the first import of pymavlink.mavutil

from pymavlink import DFReader, mavutil  # noqa: E402

from motionbase.errors import ConfigError, SourceError  # noqa: E402
from motionbase.io.live_source import (  # noqa: E402
    ATT_SLOTS,
    LiveTick,
    SampleHoldSource,
    TickStats,
    attitude_ok,
    finite_within,
    is_loopback,
    positive_number,
    wrap_pi,
)
from motionbase.io.net_address import bind_fix, check_host_port  # noqa: E402
from motionbase.physics import (  # noqa: E402
    MAX_ANGULAR_VELOCITY,
    MAX_SPECIFIC_FORCE,
    STANDARD_GRAVITY,
    euler_zyx_from_quaternion,
)
from motionbase.state import AircraftState  # noqa: E402

if getattr(mavutil.mavlink, "WIRE_PROTOCOL_VERSION", "1.0") != "2.0":  # imported earlier as v1
    mavutil.set_dialect(mavutil.current_dialect)

__all__ = ["MavlinkSource", "MavlinkStats", "MavlinkTick", "load_signing_key"]

_log = logging.getLogger("motionbase")

MG_TO_MS2 = STANDARD_GRAVITY * 1e-3
"""One milli-g in m/s^2."""
MRAD_TO_RAD = 1e-3

# IMU messages, best first: name -> (rank, scale of acc to m/s^2, scale of gyro to rad/s)
_IMU_TYPES: dict[str, tuple[int, float, float]] = {
    "HIGHRES_IMU": (0, 1.0, 1.0),
    "SCALED_IMU": (1, MG_TO_MS2, MRAD_TO_RAD),
    "SCALED_IMU2": (2, MG_TO_MS2, MRAD_TO_RAD),
    "SCALED_IMU3": (3, MG_TO_MS2, MRAD_TO_RAD),
    "RAW_IMU": (4, MG_TO_MS2, MRAD_TO_RAD),  # ArduPilot only (see module docstring)
}
_IMU_WITH_INSTANCE = frozenset({"HIGHRES_IMU", "RAW_IMU"})  # messages with an `id` field
_ATT_TYPES: dict[str, int] = {"ATTITUDE": 0, "ATTITUDE_QUATERNION": 1}
#: EXTENDED_SYS_STATE.landed_state -> on the ground (UNDEFINED, 0, is left out: unknown)
_LANDED: dict[int, bool] = {
    mavutil.mavlink.MAV_LANDED_STATE_ON_GROUND: True,
    mavutil.mavlink.MAV_LANDED_STATE_IN_AIR: False,
    mavutil.mavlink.MAV_LANDED_STATE_TAKEOFF: False,
    mavutil.mavlink.MAV_LANDED_STATE_LANDING: False,
}
_LOG_SUFFIXES = (".tlog", ".bin", ".mavlink", ".log", ".raw", ".px4log")

#: The longest MAVLink frame, bytes: a MAVLink 2 header (10), 255 bytes of payload, the
#: checksum (2) and a signature (13).
MAX_FRAME_BYTES = 280
#: How long the first bytes of a frame wait for the rest by default, s (``partial_timeout_s``):
#: a bridge sends the rest within a few ms (a whole 280-byte frame takes 49 ms at 57600 baud,
#: 290 ms at 9600).
PARTIAL_TIMEOUT_S = 0.5
_FRAME_STARTS = (mavutil.mavlink.PROTOCOL_MARKER_V2, mavutil.mavlink.PROTOCOL_MARKER_V1)

_REQUEST_AFTER_S = 1.0  # silence on a live link before asking for streams
_MAX_REQUESTS = 3
_HEARTBEAT_PERIOD_S = 1.0
#: Heartbeats of the vehicle missing this long, s: the next one is a vehicle that (re)appears
#: (started after us, rebooted), asked for its streams anew.
_VEHICLE_GONE_S = 3.0
_GCS_SYSID = 255
_GCS_COMPID = 190  # MAV_COMP_ID_MISSIONPLANNER


@dataclass(frozen=True)
class MavlinkStats(TickStats):
    """A snapshot of the source's counters (see :attr:`MavlinkSource.stats`).

    Besides those of :class:`~motionbase.io.live_source.TickStats` (``received``:
    messages decoded from any source, not counting bad data and signature
    rejects; ``accepted``: messages from the configured system and component
    that passed the signature check; ``bad_data``: chunks of bytes that did not
    parse as MAVLink, garbage or a bad CRC):

    Attributes
    ----------
    used : int
        Accepted IMU and attitude messages whose values entered the state.
    rejected_sysid, rejected_compid : int
        Messages from another system id (or with our system and component ids from a
        second address while the first one sends: a second vehicle with the same ids), or
        from another component id when ``compid`` is set.
    rejected_unsigned, rejected_bad_signature : int
        With signing on: unsigned messages, and signed messages whose signature
        or timestamp is wrong. ``rejected_signature`` is their sum.
    ignored_raw_imu : int
        ``RAW_IMU`` messages ignored because the vehicle is not ArduPilot.
    per_type : Mapping[str, int]
        Accepted messages by type.
    imu_source : str
        Message type that currently gives the specific force ("" before any).
    stream_request : str
        Stream requests on a live link: ``"off"`` (a log, or disabled),
        ``"idle"`` (nothing asked yet), ``"sent"`` (asked, waiting),
        ``"acknowledged"`` (COMMAND_ACK accepted, waiting for data),
        ``"rejected"`` (COMMAND_ACK refused: an answer to our outstanding request,
        addressed to us or to no one), ``"ignored"`` (no data after
        ``request_timeout_s``) or ``"streaming"`` (fresh data arriving).
    """

    used: int = 0
    rejected_sysid: int = 0
    rejected_compid: int = 0
    rejected_unsigned: int = 0
    rejected_bad_signature: int = 0
    ignored_raw_imu: int = 0
    per_type: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    imu_source: str = ""
    stream_request: str = "off"

    @property
    def rejected_signature(self) -> int:
        """Unsigned plus badly signed messages rejected."""
        return self.rejected_unsigned + self.rejected_bad_signature

    @property
    def rejected(self) -> int:
        """Every message rejected for its source, signature or values."""
        return (
            self.rejected_sysid
            + self.rejected_compid
            + self.rejected_signature
            + self.rejected_invalid
        )


MavlinkTick = LiveTick
"""The freshness of a tick (the name this module exported before the live sources shared it)."""


#: The most of a signing key file read, bytes (64 hex digits and whitespace fit many times).
_MAX_KEY_FILE = 4096


def load_signing_key(path: str | os.PathLike[str]) -> bytes:
    """Read a 32-byte MAVLink 2 signing key from a file.

    Parameters
    ----------
    path : str or path-like
        A file holding exactly 32 raw bytes, or 64 hexadecimal digits (text,
        surrounding whitespace allowed).

    Returns
    -------
    bytes
        The 32-byte secret key.

    Raises
    ------
    ConfigError
        The file is missing, unreadable, or not a 32-byte key.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:  # (a device such as /dev/urandom never ends)
            data = fh.read(_MAX_KEY_FILE + 1)
    except OSError as exc:
        raise ConfigError(
            f"signing key {p}: cannot read ({exc.strerror}); give the path of a 32-byte key file"
        ) from None
    if len(data) == 32:
        return data
    text = data.strip()
    make = "(make one with: head -c 32 /dev/urandom > key.bin)"
    if len(data) > _MAX_KEY_FILE:
        raise ConfigError(
            f"signing key {p}: expected 32 raw bytes or 64 hex digits, got more than "
            f"{_MAX_KEY_FILE} bytes {make}"
        )
    if len(text) == 64 and text.isascii():
        chars = text.decode("ascii")
        bad = next((i for i, c in enumerate(chars) if c not in string.hexdigits), None)
        if bad is None:
            return bytes.fromhex(chars)
        raise ConfigError(
            f"signing key {p}: 64 characters, but {chars[bad]!r} (character {bad + 1}) is "
            f"not a hexadecimal digit (0-9, a-f); give 64 hex digits or 32 raw bytes {make}"
        )
    raise ConfigError(
        f"signing key {p}: expected 32 raw bytes or 64 hex digits, got {len(data)} bytes {make}"
    )


# Network URL prefixes of pymavlink, and whether the address is one to listen on.
_NET_PREFIXES = {
    "udpin:": True,
    "udp:": True,
    "tcpin:": True,
    "udpout:": False,
    "udpbcast:": False,
    "tcp:": False,
}


# Every kind of pymavlink connection string (mavutil.mavlink_connection), by its prefix.
_KINDS = frozenset("udpin udpout udp udpbcast tcp tcpin mcast uds unix ws wss wsserver csv".split())
_FORMS = (
    "udpin:HOST:PORT (listen), udpout:HOST:PORT, tcp:HOST:PORT, a serial device "
    "(e.g. /dev/ttyACM0) or a log file (.tlog, .bin)"
)


def _check_link_kind(url: str) -> None:
    """A live link's string names a kind of connection pymavlink knows, or a serial device
    (a character device): one line (ConfigError) for an unknown ``KIND:`` prefix, or for an
    ordinary file that is not named as a log (pymavlink would open it as a serial port)."""
    kind, colon, _ = url.partition(":")
    if colon and kind in _KINDS:
        return
    try:
        mode = os.stat(url).st_mode
    except (OSError, ValueError):  # no such path (a device that is not plugged in)
        if colon:
            raise ConfigError(
                f"mavlink {url}: unknown kind of link {kind!r}; give {_FORMS}"
            ) from None
        return
    if not stat.S_ISCHR(mode):
        raise ConfigError(
            f"mavlink {url}: neither a MAVLink log (a file whose name ends in "
            f"{', '.join(_LOG_SUFFIXES)}) nor a serial device (a character device, "
            "e.g. /dev/ttyUSB0)"
        )


def _check_link_address(url: str, free_port: bool) -> None:
    """A port out of range (0 only to listen, with ``free_port``) or a host that does not
    resolve, in one line (ConfigError)."""
    for prefix, bind in _NET_PREFIXES.items():
        if url.startswith(prefix):
            host, colon, port = url[len(prefix) :].rpartition(":")
            if not colon:
                raise ConfigError(
                    f"mavlink {url}: expected {prefix}HOST:PORT, e.g. {prefix}127.0.0.1:14550"
                )
            if ":" in host or host.startswith("["):  # pymavlink's sockets are AF_INET
                raise ConfigError(
                    f"mavlink {url}: {host} is an IPv6 address; MAVLink links here are IPv4 "
                    f"only: give an IPv4 address or a host name, e.g. {prefix}127.0.0.1:14550"
                )
            check_host_port(f"mavlink {url}", host, port, free_port=bind and free_port)
            return


class _Discard:
    """A text stream that drops what is written (pymavlink's prints)."""

    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass


@contextlib.contextmanager
def _quiet(fds: bool = False) -> Iterator[None]:
    """Silence pymavlink's prints: it reports every bad byte of a log (``bad header``, thousands
    of lines for a file that is not a log) and each TCP retry on stdout/stderr. What matters
    reaches the user as one error line or in the counters.

    ``fds=True`` also points the process's file descriptors 1 and 2 at /dev/null, for the
    compiled DataFlash indexer, which prints from C (only while a source opens: no other
    thread of ours writes then).
    """
    saved = sys.stdout, sys.stderr
    for stream in saved:
        with contextlib.suppress(Exception):
            stream.flush()
    held: list[tuple[int, int]] = []
    if fds:
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                for fd in (1, 2):
                    held.append((fd, os.dup(fd)))
                    os.dup2(null, fd)
            finally:
                os.close(null)
        except OSError:
            pass  # no file descriptors to redirect (an embedded interpreter): prints stay
    sys.stdout = sys.stderr = _Discard()
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved
        for fd, copy in reversed(held):
            os.dup2(copy, fd)
            os.close(copy)


def _is_log_url(url: str) -> bool:
    return url.lower().endswith(_LOG_SUFFIXES) and not url.lower().startswith(
        ("udp", "tcp", "ws", "mcast", "uds", "unix")
    )


def _quat_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float] | None:
    """Euler angles of MAVLink's ``q1..q4`` (w, x, y, z), or None unless about unit length."""
    if not (0.9 <= math.sqrt(w * w + x * x + y * y + z * z) <= 1.1):  # also rejects NaN
        return None
    return euler_zyx_from_quaternion(x, y, z, w)


#: The longest gap a telemetry log's vehicle clock may leave between two samples, s: a
#: longer one (a clock glitch, or hours without telemetry) is shortened to it, so a replay
#: holds it stale (the platform fades to neutral) for this long, not for hours.
MAX_LOG_GAP_S = 10.0
#: How long a log's samples must go on behind its vehicle clock to be a reboot, s (its own
#: time): shorter runs (a late burst of old messages) are out of order, dropped.
REBOOT_S = 1.0


class _VehicleClock:
    """Sample times of a telemetry log from the vehicle's own clock, s.

    A ``.tlog`` stamps each message with the ground station's receive time, which bunches up
    when the radio link is bursty. The vehicle's ``time_boot_ms`` / ``time_usec`` fields
    give the true, evenly spaced sample times. Messages without them (HEARTBEAT), or from
    other systems or components, keep the last time: the clock is that of ``compid``, else
    of the first component of ``sysid`` to send an IMU message, the autopilot (each
    component counts from its own boot: a gimbal's ATTITUDE does not take the clock). The
    result never goes backwards: a reboot (boot time jumping back, and the samples going on
    from there for :data:`REBOOT_S`) re-anchors the clock where it was; samples more than 1 s
    behind the clock before that (a ground station's late burst of old messages, one bad
    sample) are out of order: :meth:`advance` gives None, and they are dropped. A sample more
    than 1 s ahead of the clock is held back too (None), and the next sample stamped at
    another time decides: back near the clock (or behind it: a reboot is judged from the
    clock as it was), the one ahead was an outlier (a corrupt time), forgotten: only it is
    lost, the clock goes on smoothly; ahead as well, not more than 1 s before it, the jump is
    real (a radio dropout) and that next sample is taken, so at a genuine gap the first
    sample after it is lost (with its messages stamped at the same time, such as a crafted
    IMU and attitude pair); more than 1 s before it, that one is held back in its place.
    Two outliers in a row that agree look like a jump: the clock takes it (and the second's
    values), and the good samples after it, behind, are dropped until they are a reboot
    after :data:`REBOOT_S`. The very first sample anchors the clock, with nothing to judge it
    by (an outlier there: the good samples after it are a reboot). A jump ahead of more
    than :data:`MAX_LOG_GAP_S` is shortened to it (``gaps_shortened`` counts them). A
    DataFlash log's times (already the vehicle's) take the same path through :meth:`advance`.
    """

    def __init__(self, sysid: int, compid: int | None = None) -> None:
        self.sysid = sysid
        self.compid = compid
        self.last = -math.inf
        self.offset = 0.0
        self.gaps_shortened = 0
        self._behind: float | None = None  # a sample behind the clock, not yet a reboot
        self._ahead: float | None = None  # a sample ahead of the clock, not yet a jump

    def __call__(self, msg: Any) -> float | None:
        t = None
        comp = msg.get_srcComponent()  # (no compid: the first to send an IMU message's)
        if msg.get_srcSystem() == self.sysid and (
            comp == self.compid or self.compid is None and msg.get_type() in _IMU_TYPES
        ):
            ms = getattr(msg, "time_boot_ms", None)
            if ms:  # (0: not filled in, as a simulator may leave it)
                t = ms * 1e-3
            else:
                us = getattr(msg, "time_usec", None)
                if us is not None and 0 < us < 1e12:  # since boot (not a UNIX epoch time)
                    t = us * 1e-6
        if t is None:
            return self.last if math.isfinite(self.last) else msg._timestamp
        self.compid = comp
        if not math.isfinite(self.last):
            self.offset = msg._timestamp - t  # start at the log's wall-clock time
        return self.advance(t)

    def advance(self, t: float) -> float | None:
        """The clock's time for a sample stamped ``t`` (s, before the offset), None for one
        not used (out of order, or ahead and not yet confirmed): a DataFlash log's own times
        go through here directly, for the same reboots and gaps."""
        t += self.offset
        ahead, self._ahead = self._ahead, None  # (any other sample settles one held ahead)
        if t > self.last + 1.0 and math.isfinite(self.last):  # a jump ahead, or an outlier
            if ahead is None or t == ahead or t < ahead - 1.0:
                self._ahead = t  # (the same time: the same sample; far before: a new one)
                return None  # not (yet) confirmed by the next sample
        elif t < self.last - 1.0:  # a reboot or clock reset, or samples out of order
            self._behind = t if self._behind is None else min(self._behind, t)
            if t - self._behind < REBOOT_S:
                return None  # not (yet) a reboot: out of order
            self.offset += self.last - self._behind  # behind and going on: a reboot
            t += self.last - self._behind
        self._behind = None
        if t > self.last + MAX_LOG_GAP_S and math.isfinite(self.last):
            self.offset -= t - (self.last + MAX_LOG_GAP_S)
            t = self.last + MAX_LOG_GAP_S
            self.gaps_shortened += 1
        self.last = max(t, self.last)
        return self.last


def _next_frame_start(data: bytes, lo: int, hi: int) -> int:
    """Index of the first start-of-frame byte (0xFD or 0xFE) in ``data[lo:hi]``, or -1."""
    found = [i for i in (data.find(m, lo, hi) for m in _FRAME_STARTS) if i >= 0]
    return min(found) if found else -1


class _FrameReader:
    """The messages of a live link, read through pymavlink's parser without letting bad
    bytes take good frames down with them.

    pymavlink parses a link as one stream of bytes, UDP datagrams included. That is right
    for a serial-to-UDP bridge (socat, ser2net), which cuts the stream into datagrams
    anywhere: the start of a frame waits in the parser for the rest. But the parser takes
    the length a frame's header announces on trust: a frame cut short, or garbage holding a
    start-of-frame byte, takes that many bytes, the good frames behind it included, and
    drops them all when its checksum fails (or returns them as one message of an unknown
    type), or holds them while it waits for bytes that may never come. This reader keeps
    pymavlink's parser and undoes that:

    * a candidate frame that fails (checksum, header flags) is garbage for its first byte
      only: the rest goes back into the parser, which resumes at the next start-of-frame
      byte (0xFD, MAVLink 2; 0xFE, MAVLink 1);
    * a candidate of a message type the dialect does not know (its checksum cannot be
      checked without the type's CRC_EXTRA) yields to a whole frame starting inside it
      that passes its checksum;
    * a candidate still waiting for bytes yields to a whole frame behind it that passes its
      checksum (it is overtaken);
    * the start of a frame waits at most ``partial_timeout_s`` for the rest, then it is
      garbage, so it never joins bytes that come much later. While it waits it is shorter
      than the frame its header announces (:data:`MAX_FRAME_BYTES` at most): more bytes
      would complete it.

    Whether a frame passes its checksum is asked of a second pymavlink parser, on a copy;
    signatures are checked only by the link's own parser, once.

    Parameters
    ----------
    conn : Any
        The open live link (a ``mavutil.mavfile``).
    counters : dict of str to int
        The source's counters: garbage goes into ``bad_data`` (one per run of consecutive
        bad bytes) and ``bad_bytes``.
    partial_timeout_s : float
        How long the start of a frame waits for the rest, s.
    """

    def __init__(self, conn: Any, counters: dict[str, int], partial_timeout_s: float) -> None:
        ml = mavutil.mavlink
        self._conn = conn
        self._c = counters
        self._timeout = partial_timeout_s
        self._bad = ml.MAVLink_bad_data
        self._unknown = ml.MAVLink_unknown
        self._check = ml.MAVLink(None)  # framing and checksums of copies
        self._check.robust_parsing = True
        self._check_expect = ml.HEADER_LEN_V1 + 2  # (the parser's initial expectation)
        self._waiting_since: float | None = None  # since when the parser holds a frame start
        self._scanned = b""  # the waiting bytes last searched for a whole frame
        self._in_garbage = False  # the bytes consumed last were garbage

    def read(self) -> tuple[bool, Any]:
        """Read the link (over UDP, one datagram at most) and parse the next message.

        Returns
        -------
        progress : bool
            False when nothing was there to read or parse (the link is drained for now).
        message : Any
            The next message, or None (garbage consumed, the start of a frame kept, or
            nothing). A message refused for its signature comes as pymavlink's
            ``BAD_DATA`` with the reason "Invalid signature".

        Raises
        ------
        OSError
            The link failed.
        """
        conn = self._conn
        parser = conn.mav
        if (
            self._waiting_since is not None
            and parser.buf_len()
            and time.monotonic() - self._waiting_since > self._timeout
        ):
            self._garbage(parser.buf_len())
            parser.buf, parser.buf_index = bytearray(), 0
            self._waiting_since = None
        msg = None
        if parser.buf_len():  # whole frames already in the parser go before new bytes
            msg = parser.parse_char(b"")
            if msg is not None:
                conn.post_message(msg)
        if msg is None:
            before = parser.total_bytes_received
            msg = conn.recv_msg()
            if msg is None:
                arrived = parser.total_bytes_received != before
                if not parser.buf_len():
                    self._waiting_since = None
                    return arrived, None
                if self._overtaken(parser):
                    return True, None
                if self._waiting_since is None:
                    self._waiting_since = time.monotonic()
                return arrived, None
        self._waiting_since = None
        if isinstance(msg, self._bad):
            reason = msg.reason
            if reason == "Invalid signature":  # a whole frame: the source counts it
                self._in_garbage = False
                return True, msg
            if reason == "Bad prefix":  # the bytes up to the next frame start
                self._garbage(len(msg.data))
            else:  # a candidate frame that failed: only its first byte is known to be bad
                self._put_back(parser, msg.data, 1)
            return True, None
        if isinstance(msg, self._unknown):
            data = bytes(msg.data)
            after = parser.buf[parser.buf_index : parser.buf_index + MAX_FRAME_BYTES]
            inside = self._whole_frame(data + bytes(after), 1, len(data))
            if inside is not None:
                self._put_back(parser, data, inside)
                return True, None
        self._in_garbage = False
        return True, msg

    def _garbage(self, n: int) -> None:
        """Count ``n`` bad bytes (a new run unless the last bytes were bad too)."""
        if not self._in_garbage:
            self._c["bad_data"] += 1
            self._in_garbage = True
        self._c["bad_bytes"] += n

    def _put_back(self, parser: Any, data: bytes | bytearray, skip: int) -> None:
        """Give a consumed candidate frame ``data`` back to the parser, all but its first
        ``skip`` bytes (garbage), in front of what it still holds."""
        self._garbage(skip)
        rest = parser.buf[parser.buf_index :]
        parser.buf = bytearray(data[skip:])
        parser.buf += rest
        parser.buf_index = 0

    def _overtaken(self, parser: Any) -> bool:
        """Drop the frame start the parser waits on when a whole frame that passes its
        checksum lies behind it; True when it did."""
        waiting = bytes(parser.buf[parser.buf_index :])
        if waiting == self._scanned:  # searched already, nothing came since
            return False
        self._scanned = waiting
        at = self._whole_frame(waiting, 1, len(waiting))
        if at is None:
            return False
        self._garbage(at)
        parser.buf_index += at
        return True

    def _whole_frame(self, data: bytes, lo: int, hi: int) -> int | None:
        """The first index in ``data[lo:hi]`` where a whole frame starts that passes its
        checksum (a message type of the dialect), or None."""
        check = self._check
        at = lo
        while (at := _next_frame_start(data, at, hi)) >= 0:
            check.buf = bytearray(data[at : at + MAX_FRAME_BYTES])
            check.buf_index = 0
            check.expected_length = self._check_expect
            msg = check.parse_char(b"")
            if msg is not None and not isinstance(msg, self._bad | self._unknown):
                return at
            at += 1
        return None


class MavlinkSource(SampleHoldSource):
    """Aircraft states from MAVLink telemetry or a log, at a fixed rate.

    Parameters
    ----------
    url : str
        A pymavlink connection string: ``udpin:HOST:PORT`` (listen; port 0
        picks a free port with ``free_port``, see :attr:`local_address`),
        ``udpout:HOST:PORT``, ``tcp:HOST:PORT``, a serial device (``/dev/ttyACM0``,
        115200 baud), or a ``.tlog`` / ``.bin`` log file. The default listens on loopback only;
        listening on every interface needs an explicit ``udpin:0.0.0.0:PORT``.
    rate_hz : float
        Fixed output rate, Hz (> 0). Also the rate asked of the vehicle.
    sysid : int
        MAVLink system id of the vehicle, 1..255; other systems are rejected.
    compid : int or None
        Component id to accept (1..255); None accepts every component of
        ``sysid``.
    signing_key : str, path-like or None
        Path of a 32-byte MAVLink 2 signing key file (see
        :func:`load_signing_key`). When given, unsigned and badly signed
        messages are rejected and outgoing messages are signed. Live links only.
    duration_s : float or None
        Stop after this much source time, s; None runs until the log ends (or
        forever on a live link).
    realtime : bool
        For a log: whether the run replays it at the recorded timing (recorded in the
        log's metadata). The source itself never waits on a log: the pipeline's loop
        paces the ticks (``run(..., paced=True)``). A live link's ticks always come on
        the wall clock.
    busy_wait : bool
        Wait for the next tick by busy-waiting (polling the link) instead of
        sleeping: one processor at 100 %, fewer late ticks at 1 kHz (see
        :mod:`motionbase.pacing`).
    request_streams : bool
        On a live link, ask a vehicle silent on either for HIGHRES_IMU and ATTITUDE at
        ``rate_hz`` with MAV_CMD_SET_MESSAGE_INTERVAL (three times at most, and anew when
        its heartbeats come back after a pause: started later, rebooted), and send a
        ground-station HEARTBEAT once a second.
    stale_timeout_s : float
        A tick is stale when its IMU or attitude sample is older than this, s
        (> 0).
    request_timeout_s : float
        Time to wait for data after a stream request before warning that the
        vehicle ignored it and asking again, s (> 0).
    log_clock : {"vehicle", "receive"}
        For a ``.tlog``: time the samples by the vehicle's clock
        (``time_boot_ms``/``time_usec``, evenly spaced as sampled; default) or
        by the ground station's receive time stamped in the log (bursty when
        the radio link was). DataFlash logs always use the vehicle clock.
    free_port : bool
        A ``udpin:`` (``udp:``, ``tcpin:``) URL may listen on port 0, any free
        port (see :attr:`local_address`); False refuses it, as ``motionbase
        stream`` does: nobody could send to a port it does not show.
    drain_budget_s : float, optional
        On a live link: how long a tick may go on reading messages past its due
        time, s (>= 0); None: a tenth of a period. The rest waits for the next tick
        (see :class:`~motionbase.io.live_source.SampleHoldSource`).
    partial_timeout_s : float
        On a live link: how long the first bytes of a frame wait for the rest, s (>= 0;
        a serial-to-UDP bridge cuts frames across datagrams); then they are counted as bad
        data. See :class:`_FrameReader`.

    Attributes
    ----------
    paces_itself : bool
        True on a live link: ticks come on the wall clock (the pipeline's loop does not
        pace them again). False for a log.
    due_time : float or None
        When the last tick was due, s on :func:`time.monotonic` (paced ticks only; the
        pipeline counts a command late from it).

    Examples
    --------
    >>> with MavlinkSource("vtol.tlog", realtime=False) as src:  # doctest: +SKIP
    ...     for state in src:
    ...         if not src.fresh:
    ...             ...  # the watchdog fades to neutral
    """

    kind = "mavlink"
    label = "MAVLink"
    _COUNTERS = (
        "received",
        "used",
        "rejected_sysid",
        "rejected_compid",
        "rejected_unsigned",
        "rejected_bad_signature",
        "rejected_invalid",
        "ignored_raw_imu",
        "bad_data",
        "bad_bytes",
        *SampleHoldSource._COUNTERS,
    )

    def __init__(
        self,
        url: str = "udpin:127.0.0.1:14550",
        *,
        rate_hz: float = 100.0,
        sysid: int = 1,
        compid: int | None = None,
        signing_key: str | os.PathLike[str] | None = None,
        duration_s: float | None = None,
        realtime: bool = True,
        busy_wait: bool = False,
        request_streams: bool = True,
        stale_timeout_s: float = 0.5,
        request_timeout_s: float = 3.0,
        log_clock: str = "vehicle",
        free_port: bool = True,
        drain_budget_s: float | None = None,
        partial_timeout_s: float = PARTIAL_TIMEOUT_S,
    ) -> None:
        if not isinstance(url, str) or not url.strip():
            raise ConfigError("mavlink url: empty; give e.g. udpin:127.0.0.1:14550 or a .tlog path")
        super().__init__(
            url.strip(),
            rate_hz=rate_hz,
            duration_s=duration_s,
            busy_wait=busy_wait,
            stale_timeout_s=stale_timeout_s,
            drain_budget_s=drain_budget_s,
        )
        if not (isinstance(sysid, int) and 1 <= sysid <= 255):
            raise ConfigError(f"mavlink sysid: must be an integer 1..255, got {sysid!r}")
        if compid is not None and not (isinstance(compid, int) and 1 <= compid <= 255):
            raise ConfigError(
                f"mavlink compid: must be a component id 1..255, got {compid!r}; leave it out "
                "to accept every component"
            )
        self.request_timeout_s = positive_number(
            self.kind, "request_timeout_s", request_timeout_s, "s"
        )
        self.partial_timeout_s = positive_number(
            self.kind, "partial_timeout_s", partial_timeout_s, "s", zero_ok=True
        )
        self.sysid = sysid
        self.compid = compid
        self.realtime = bool(realtime)
        self.free_port = bool(free_port)
        self.request_streams = bool(request_streams)
        if log_clock not in ("vehicle", "receive"):
            raise ConfigError(f"mavlink log_clock: 'vehicle' or 'receive', got {log_clock!r}")
        self.log_clock = log_clock
        self.is_log = _is_log_url(self.url)
        if not self.is_log:
            _check_link_kind(self.url)
        self._signing_key_path = None if signing_key is None else str(signing_key)
        self._key: bytes | None = None
        if signing_key is not None:
            if self.is_log:
                raise ConfigError(
                    f"mavlink signing_key: applies to live links only, not to the log {self.url}"
                )
            self._key = load_signing_key(signing_key)

        self._conn: Any = None
        self._frames: _FrameReader | None = None  # a live link's reader
        self._reset_state()

    # ------------------------------------------------------------------ lifecycle

    def _reset_state(self) -> None:
        super()._reset_state()
        self._per_type: dict[str, int] = {}
        self._imu_rank = 99
        self._imu_name = ""
        self._att_rank = 99
        self._ardupilot = False
        self._req_state = "idle" if (self.request_streams and not self.is_log) else "off"
        self._req_time = math.nan
        self._req_count = 0
        self._warned_ignored = False
        self._last_hb = -math.inf
        self._vehicle_hb = -math.inf  # arrival of the vehicle's last HEARTBEAT
        self._vehicle_addr: Any = None  # udpin: where the last message from sysid came from
        self._senders: dict[int, tuple[Any, float]] = {}  # compid: address, last arrival
        self._warned_twin = False
        self._on_ground: bool | None = None

    @property
    def _imu_time(self) -> float:
        """Arrival of the IMU values in the state, source clock s (-inf before any)."""
        return self._times[0]

    @property
    def _att_time(self) -> float:
        """Arrival of the attitude in the state, source clock s (-inf before any)."""
        return self._times[ATT_SLOTS.start]

    def open(self) -> None:
        """Open the connection (called by ``with``).

        Raises
        ------
        SourceError
            The log file does not exist, or the port cannot be opened.
        ConfigError
            A network URL's port is out of range (0 without ``free_port``) or its host
            name does not resolve.
        """
        if self._conn is not None:
            return
        if self.is_log and not os.path.isfile(self.url):  # (pathlib: raises for a long name)
            raise SourceError(f"mavlink log {self.url}: no such file (check the path)")
        if not self.is_log:
            _check_link_address(self.url, self.free_port)
        self._reset_state()
        try:
            with _quiet(fds=self.is_log):
                if self.is_log:
                    conn = mavutil.mavlink_connection(self.url)
                else:  # tcp: one attempt, no retry loop (a refused port is an answer)
                    conn = mavutil.mavlink_connection(
                        self.url,
                        source_system=_GCS_SYSID,
                        source_component=_GCS_COMPID,
                        retries=0,
                    )
        except ConnectionRefusedError:
            raise SourceError(
                f"mavlink {self.url}: connection refused, nothing listens there (start the "
                "vehicle or SITL first, or check the address)"
            ) from None
        except Exception as exc:  # pymavlink raises many types (OSError, SerialException, ...)
            if self.is_log:  # the file is there (checked above): its content is not a log
                raise SourceError(
                    f"mavlink log {self.url}: cannot read it as a MAVLink log ({exc}); is it "
                    "a whole telemetry .tlog or DataFlash .bin?"
                ) from None
            fix = f"check the connection string ({_FORMS})"
            if isinstance(exc, OSError):  # (a port in use: a ground station listens there?)
                fix = bind_fix(exc, fix)
            raise SourceError(f"mavlink {self.url}: cannot open ({exc}); {fix}") from None
        self._conn = conn
        if self.is_log:  # before the run opens its log: a file without them is refused
            self._check_log_has_messages()
        if not self.is_log:
            _end_tcp_at_eof(conn)
            if getattr(conn, "udp_server", False):
                self._reply_to_vehicle(conn)
            conn.mav.robust_parsing = True
            self._frames = _FrameReader(conn, self._c, self.partial_timeout_s)
            if self._key is not None:
                conn.setup_signing(
                    self._key, sign_outgoing=True, allow_unsigned_callback=_reject_unsigned
                )
                _forgeries_leave_stream_times(conn.mav)
            host = self._bind_host()
            if host is not None and not is_loopback(host):
                _log.warning("MAVLink: listening on %s (not loopback), as requested", host)

    def _reply_to_vehicle(self, conn: Any) -> None:
        """udpin: send to the vehicle's address only. pymavlink sends each message to every
        address a datagram ever came from, for ever (a reflector for spoofed garbage, and a
        sendto per address inside a tick). Here ``last_address`` is the sender of the last
        datagram, and our messages go to that of the last message accepted from ``sysid``;
        to nobody before one (a vehicle sends heartbeats: we talk to the one we hear)."""
        port = conn.port

        def recv(n: int | None = None) -> bytes | str:
            try:
                data, conn.last_address = port.recvfrom(65535)
            except (BlockingIOError, ConnectionRefusedError):
                return ""  # (pymavlink's "nothing yet")
            return data

        def write(buf: bytes) -> None:
            addr = self._vehicle_addr
            if addr is not None:
                with contextlib.suppress(OSError):
                    port.sendto(buf, addr)

        conn.recv, conn.write = recv, write

    def close(self) -> None:
        """Close the connection. Idempotent."""
        conn, self._conn = self._conn, None
        self._frames = None
        if conn is not None:
            try:
                conn.close()
            except Exception:  # noqa: BLE001 - closing must not raise
                pass

    def _bind_host(self) -> str | None:
        port = getattr(self._conn, "port", None)
        if getattr(self._conn, "udp_server", False) and port is not None:
            return str(port.getsockname()[0])
        return None

    @property
    def local_address(self) -> tuple[str, int] | None:
        """(host, port) the UDP listener is bound to, or None (not a ``udpin:`` link)."""
        port = getattr(self._conn, "port", None)
        if port is None or not hasattr(port, "getsockname"):
            return None
        try:
            host, p = port.getsockname()[:2]
        except OSError:
            return None
        return str(host), int(p)

    # ------------------------------------------------------------------ public state

    @property
    def stats(self) -> MavlinkStats:
        """A frozen snapshot of the counters."""
        return MavlinkStats(
            **self._c,
            per_type=MappingProxyType(dict(self._per_type)),
            last_sample_age_s=self._tick.sample_age_s,
            message_rate_hz=self._rate_hz,
            imu_source=self._imu_name,
            stream_request=self._req_state,
        )

    def stats_line(self) -> str:
        """One line for the end of a run: messages, rejects, stale ticks."""
        st = self.stats
        return (
            f"MAVLink: {st.received} messages received, {st.accepted} accepted, "
            f"{st.rejected} rejected (other system {st.rejected_sysid}, signature "
            f"{st.rejected_signature}, invalid {st.rejected_invalid}), {st.bad_data} garbled; "
            f"{st.stale_ticks} of {st.ticks} ticks stale, {st.gaps} gaps"
        )

    def describe(self) -> dict[str, Any]:
        """Plain-data description for the log's metadata (never the key itself)."""
        return {
            "kind": "mavlink",
            "url": self.url,
            "log": self.is_log,
            "rate_hz": self.rate_hz,
            "sysid": self.sysid,
            "compid": self.compid,
            "signing": self._key is not None,
            "signing_key_file": self._signing_key_path,
            "duration_s": self.duration_s,
            "realtime": self.realtime,
            "busy_wait": self.busy_wait,
            "request_streams": self.request_streams,
            "stale_timeout_s": self.stale_timeout_s,
            "log_clock": self.log_clock if self.is_log else None,
            "imu_messages": list(_IMU_TYPES),
            "attitude_messages": list(_ATT_TYPES),
            "dialect": mavutil.current_dialect,
            "mavlink_version": mavutil.mavlink.WIRE_PROTOCOL_VERSION,
        }

    # ------------------------------------------------------------------ iteration

    @property
    def paces_itself(self) -> bool:
        """True on a live link (its ticks come on the wall clock); a log never waits."""
        return not self.is_log

    def _link(self) -> Any:
        return self._conn

    def _iterate(self) -> Iterator[AircraftState]:
        return self._iter_log() if self.is_log else self._iter_live()

    def _peer(self) -> str:
        return f" from system {self.sysid}"

    def _service(self, now: float) -> None:
        if self._req_state != "off":
            self._service_requests(self._conn, now)

    def _reader(self, conn: Any) -> tuple[Callable[[], bool], Any]:
        frames = self._frames
        if frames is None:  # (opened as a log: never iterated live)
            raise SourceError(f"mavlink {self.url}: not a live link")
        read = frames.read
        handle = self._handle
        clock = time.monotonic

        def read_one() -> bool:
            try:
                progress, msg = read()
            except OSError as exc:
                raise SourceError(f"mavlink {self.url}: link failed ({exc})") from None
            if msg is not None:
                handle(msg, clock())
            return progress

        return read_one, getattr(conn, "fd", None)

    @staticmethod
    def _log_types(conn: Any) -> list[str]:
        """The messages a log's states are made of (a DataFlash log's, or a telemetry log's)."""
        if isinstance(conn, DFReader.DFReader):
            return ["IMU", "ATT"]
        return [*_IMU_TYPES, *_ATT_TYPES, "HEARTBEAT", "EXTENDED_SYS_STATE"]

    def _no_messages(self, types: list[str]) -> SourceError:
        try:  # pymavlink reads a log by its name: one named for the other format has none
            with open(self.url, "rb") as fh:
                head = fh.read(9)
        except OSError:
            head = b""
        if types == ["IMU", "ATT"] and head[8:] in (b"\xfd", b"\xfe"):
            hint = "it is a telemetry log (MAVLink frames): give it a name ending in .tlog"
        elif types != ["IMU", "ATT"] and head[:2] == b"\xa3\x95":
            hint = "it is a DataFlash log: give it a name ending in .bin"
        else:
            hint = "is it a telemetry .tlog or a DataFlash .bin with IMU and ATT?"
        return SourceError(f"mavlink log {self.url}: no {' or '.join(types)} messages; {hint}")

    def _check_log_has_messages(self) -> None:
        """A log without a message of the states is refused when opened, before a run
        writes its own log (over an existing file, too), not at the run's first tick: a
        DataFlash log by the index pymavlink made of it, a telemetry log read through a
        connection of its own up to its first such message."""
        conn = self._conn
        types = self._log_types(conn)
        if isinstance(conn, DFReader.DFReader):
            counts, ids = getattr(conn, "counts", None), getattr(conn, "name_to_id", None)
            if not isinstance(counts, list) or not isinstance(ids, dict):
                return  # (a text DataFlash log: found at the first tick)
            found = any(counts[ids[t]] for t in types if t in ids)
        else:
            try:
                with _quiet(fds=True):
                    probe = mavutil.mavlink_connection(self.url)
                    try:
                        found = probe.recv_match(type=types) is not None
                    finally:
                        probe.close()
            except Exception as exc:  # noqa: BLE001 - pymavlink's parser raises many types
                self.close()
                raise SourceError(
                    f"mavlink log {self.url}: cannot read it as a MAVLink log ({exc}); is it "
                    "a whole telemetry .tlog or DataFlash .bin?"
                ) from None
        if not found:
            self.close()
            raise self._no_messages(types)

    def _iter_log(self) -> Iterator[AircraftState]:
        conn = self._conn
        period = 1.0 / self.rate_hz
        n_max = self._tick_count()
        types = self._log_types(conn)
        if isinstance(conn, DFReader.DFReader):
            handle = self._handle_dataflash
            # DataFlash times already come from the vehicle's clock; its gaps are shortened too
            clock: _VehicleClock | None = _VehicleClock(self.sysid)
            dataflash = True
        else:
            handle = self._handle
            clock = _VehicleClock(self.sysid, self.compid) if self.log_clock == "vehicle" else None
            dataflash = False

        def next_msg() -> tuple[Any, float]:
            t = None
            while t is None:  # (None: out of order, old data never fed in as new: invalid)
                with _quiet():  # pymavlink prints each bad byte range of a log
                    msg = conn.recv_match(type=types)
                if msg is None:
                    return None, math.inf
                if clock is None:
                    return msg, msg._timestamp
                shortened = clock.gaps_shortened
                t = clock.advance(msg._timestamp) if dataflash else clock(msg)
                if t is None:
                    for key in ("received", "accepted", "rejected_invalid"):
                        self._c[key] += 1
            if clock.gaps_shortened == 1 and not shortened:
                _log.warning(
                    "mavlink log %s: its vehicle clock jumps ahead by more than %g s; such a "
                    "gap is held for %g s (the platform fades to neutral), not replayed in full",
                    self.url,
                    MAX_LOG_GAP_S,
                    MAX_LOG_GAP_S,
                )
            return msg, t

        self._iterating = True
        try:
            pending, t_pending = next_msg()
            if pending is None:  # (checked when opened: the file changed since)
                raise self._no_messages(types)
            t0 = t_pending
            k = 0
            self.ended = ""
            while n_max is None or k < n_max:
                t_tick = t0 + k * period
                while t_pending <= t_tick:
                    handle(pending, t_pending)
                    pending, t_pending = next_msg()
                self._update_rate(t_tick)
                yield self._make_state(k, t_tick)
                k += 1
                if pending is None:
                    return
            self.ended = "duration"
        finally:
            self._iterating = False

    # ------------------------------------------------------------------ messages

    def _handle(self, msg: Any, arrival: float) -> None:
        """Filter one decoded MAVLink message and fold it into the state."""
        c = self._c
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            reason = getattr(msg, "reason", "")
            if reason == "Invalid signature":
                data = msg.data
                if len(data) > 2 and data[0] == 0xFD and (data[2] & 0x01):
                    c["rejected_bad_signature"] += 1
                else:
                    c["rejected_unsigned"] += 1
            else:
                c["bad_data"] += 1
                c["bad_bytes"] += len(msg.data)
            return
        c["received"] += 1
        if msg.get_srcSystem() != self.sysid:
            c["rejected_sysid"] += 1
            return
        if self.compid is not None and msg.get_srcComponent() != self.compid:
            c["rejected_compid"] += 1
            return
        addr = getattr(self._conn, "last_address", None)
        comp = msg.get_srcComponent()
        first, seen = self._senders.get(comp, (addr, -math.inf))
        if addr != first and arrival - seen <= self.stale_timeout_s:
            c["rejected_sysid"] += 1  # the same ids from a second address: one vehicle at a time
            if not self._warned_twin:
                self._warned_twin = True
                _log.warning(
                    "MAVLink: system %d is heard from %s and from %s (two vehicles with the "
                    "same system id, or one over two routes); only the first is used while it "
                    "sends: give each vehicle its own id (ArduPilot SYSID_THISMAV, PX4 "
                    "MAV_SYS_ID) and pick one with --sysid",
                    self.sysid,
                    _address(first),
                    _address(addr),
                )
            return
        c["accepted"] += 1
        self._vehicle_addr, self._senders[comp] = addr, (addr, arrival)
        self._per_type[mtype] = self._per_type.get(mtype, 0) + 1

        imu = _IMU_TYPES.get(mtype)
        if imu is not None:
            rank, ka, kg = imu
            if mtype == "RAW_IMU" and not self._ardupilot:
                c["ignored_raw_imu"] += 1
                return
            if mtype in _IMU_WITH_INSTANCE and msg.id != 0:  # only the first IMU instance
                return
            if rank > self._imu_rank and arrival - self._imu_time <= self.stale_timeout_s:
                return  # a better IMU message is still fresh
            acc = (msg.xacc * ka, msg.yacc * ka, msg.zacc * ka)
            gyr = (msg.xgyro * kg, msg.ygyro * kg, msg.zgyro * kg)
            if not self._store_imu(acc, gyr, arrival):
                return
            self._imu_rank, self._imu_name = rank, mtype
            return

        att_rank = _ATT_TYPES.get(mtype)
        if att_rank is not None:
            if att_rank > self._att_rank and arrival - self._att_time <= self.stale_timeout_s:
                return
            if att_rank == 0:
                att: tuple[float, float, float] | None = (msg.roll, msg.pitch, msg.yaw)
            else:
                att = _quat_to_euler(msg.q1, msg.q2, msg.q3, msg.q4)
            if self._store_attitude(att, arrival):
                self._att_rank = att_rank
            return

        if mtype == "EXTENDED_SYS_STATE":
            self._on_ground = _LANDED.get(msg.landed_state, self._on_ground)
        elif mtype == "HEARTBEAT":
            if msg.autopilot != mavutil.mavlink.MAV_AUTOPILOT_INVALID:  # not a GCS/companion
                self._ardupilot = msg.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
                if arrival - self._vehicle_hb > _VEHICLE_GONE_S:  # (re)appears: ask anew
                    self._req_count, self._req_state = 0, "idle"  # (not asked yet: no warning)
                    self._warned_ignored = False
                self._vehicle_hb = arrival
        elif mtype == "COMMAND_ACK":
            self._on_command_ack(msg)

    def _make_state(self, k: int, now: float) -> AircraftState:
        """Tick k's state (a hold of the latest values), with the last flight phase."""
        state = super()._make_state(k, now)
        if self._on_ground is None:
            return state
        return replace(state, on_ground=self._on_ground)

    def _handle_dataflash(self, msg: Any, arrival: float) -> None:
        """Fold one DataFlash IMU or ATT record into the state. A record without its type's
        fields, or with text in them (its FMT record damaged, or a text log's), is invalid
        input: counted and left out, as a NaN is."""
        c = self._c
        mtype = msg.get_type()
        c["received"] += 1
        c["accepted"] += 1
        self._per_type[mtype] = self._per_type.get(mtype, 0) + 1
        try:
            if mtype == "IMU":
                if getattr(msg, "I", 0) != 0:
                    return
                acc = (float(msg.AccX), float(msg.AccY), float(msg.AccZ))
                gyr = (float(msg.GyrX), float(msg.GyrY), float(msg.GyrZ))
            else:  # ATT, degrees
                att = (math.radians(msg.Roll), math.radians(msg.Pitch), math.radians(msg.Yaw))
        except (AttributeError, TypeError, ValueError):
            c["rejected_invalid"] += 1
            return
        if mtype == "IMU":
            if self._store_imu(acc, gyr, arrival):
                self._imu_name = "IMU"
        else:
            self._store_attitude(att, arrival)

    def _store_imu(self, acc: tuple[float, ...], gyr: tuple[float, ...], arrival: float) -> bool:
        """Specific force (m/s^2) and body rates (rad/s) into the state, or count them invalid."""
        if not (
            finite_within(acc, MAX_SPECIFIC_FORCE) and finite_within(gyr, MAX_ANGULAR_VELOCITY)
        ):
            self._c["rejected_invalid"] += 1
            return False
        self._store(0, (*acc, *gyr), arrival)
        self._c["used"] += 1
        return True

    def _store_attitude(self, att: tuple[float, float, float] | None, arrival: float) -> bool:
        """Euler angles (rad; None: not convertible) into the state, yaw wrapped to [-pi, pi),
        or count them invalid."""
        if att is None or not attitude_ok(*att):
            self._c["rejected_invalid"] += 1
            return False
        self._store(ATT_SLOTS.start, (att[0], att[1], wrap_pi(att[2])), arrival)
        self._c["used"] += 1
        return True

    # ------------------------------------------------------------------ stream requests

    def _target_compid(self) -> int:
        return self.compid if self.compid is not None else mavutil.mavlink.MAV_COMP_ID_AUTOPILOT1

    def _send(self, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except OSError as exc:
            _log.debug("MAVLink: send failed on %s: %s", self.url, exc)

    def _service_requests(self, conn: Any, now: float) -> None:
        """Heartbeat and MAV_CMD_SET_MESSAGE_INTERVAL requests on a live link."""
        ml = mavutil.mavlink
        if now - self._last_hb >= _HEARTBEAT_PERIOD_S:
            self._last_hb = now
            self._send(conn.mav.heartbeat_send, ml.MAV_TYPE_GCS, ml.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        timeout = self.stale_timeout_s
        if now - self._imu_time <= timeout and now - self._att_time <= timeout:
            self._req_state = "streaming"
            self._req_count = 0
            self._warned_ignored = False
            return
        state = self._req_state
        if state in ("idle", "streaming"):  # silent: either of them (one alone moves nothing)
            silent_since = max(min(self._imu_time, self._att_time), self._live_start)
            if now - silent_since >= _REQUEST_AFTER_S and self._req_count < _MAX_REQUESTS:
                self._send_requests(conn, now)
        elif state in ("sent", "acknowledged", "ignored") and (
            now - self._req_time >= self.request_timeout_s
        ):
            c = self._c
            if not self._warned_ignored and c["accepted"] == 0:
                self._warned_ignored = True
                if c["rejected_unsigned"] + c["rejected_bad_signature"]:
                    _log.warning(
                        "MAVLink: messages arrive on %s but every one was rejected for its "
                        "signature (%d unsigned, %d signed with another key): the vehicle signs "
                        "with no key or another one; give --signing-key the vehicle's key",
                        self.url,
                        c["rejected_unsigned"],
                        c["rejected_bad_signature"],
                    )
                elif c["rejected_sysid"] + c["rejected_compid"]:
                    _log.warning(
                        "MAVLink: %d messages arrive on %s, none from system %d%s; check "
                        "--sysid (and --compid)",
                        c["rejected_sysid"] + c["rejected_compid"],
                        self.url,
                        self.sysid,
                        "" if self.compid is None else f" component {self.compid}",
                    )
                else:
                    _log.warning(
                        "MAVLink: nothing heard from system %d on %s %.1f s after asking for "
                        "streams; is the vehicle sending to this address (and with this sysid)?",
                        self.sysid,
                        self.url,
                        self.request_timeout_s,
                    )
            elif not self._warned_ignored:
                self._warned_ignored = True
                slots = (("IMU", self._imu_time), ("attitude", self._att_time))
                missing = " and ".join(n for n, t in slots if now - t > timeout)
                _log.warning(
                    "MAVLink: system %d ignored MAV_CMD_SET_MESSAGE_INTERVAL (%s, no %s data "
                    "%.1f s later); check the link and the vehicle's stream settings",
                    self.sysid,
                    "acknowledged" if state == "acknowledged" else "no COMMAND_ACK",
                    missing,
                    self.request_timeout_s,
                )
            self._req_state = "ignored"
            if self._req_count < _MAX_REQUESTS:
                self._send_requests(conn, now)

    def _send_requests(self, conn: Any, now: float) -> None:
        ml = mavutil.mavlink
        interval_us = 1e6 / self.rate_hz
        msg_ids = [ml.MAVLINK_MSG_ID_HIGHRES_IMU, ml.MAVLINK_MSG_ID_ATTITUDE]
        if self._req_count >= 1:  # second try: also the SCALED_IMU fallback
            msg_ids.append(ml.MAVLINK_MSG_ID_SCALED_IMU)
        for mid in msg_ids:
            self._send(
                conn.mav.command_long_send,
                self.sysid,
                self._target_compid(),
                ml.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                float(mid),
                float(interval_us),
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            )
        self._req_count += 1
        self._req_time = now
        self._req_state = "sent"
        _log.info(
            "MAVLink: asked system %d for HIGHRES_IMU and ATTITUDE at %.0f Hz "
            "(MAV_CMD_SET_MESSAGE_INTERVAL, try %d)",
            self.sysid,
            self.rate_hz,
            self._req_count,
        )

    def _on_command_ack(self, msg: Any) -> None:
        ml = mavutil.mavlink
        if msg.command != ml.MAV_CMD_SET_MESSAGE_INTERVAL or self._req_state not in (
            "sent",
            "acknowledged",
            "ignored",
        ):
            return  # no request of ours outstanding: an answer to someone else
        if getattr(msg, "target_system", 0) not in (0, _GCS_SYSID):
            return  # addressed to another ground station (0: a sender that does not say)
        if msg.result == ml.MAV_RESULT_ACCEPTED:
            if self._req_state == "sent":
                self._req_state = "acknowledged"
        elif self._req_state != "rejected":  # said once: a vehicle may repeat its refusal
            name = ml.enums["MAV_RESULT"].get(msg.result)
            label = name.name if name is not None else str(msg.result)
            _log.warning(
                "MAVLink: system %d refused MAV_CMD_SET_MESSAGE_INTERVAL (%s); configure its "
                "telemetry streams on the vehicle",
                self.sysid,
                label,
            )
            self._req_state = "rejected"


def _end_tcp_at_eof(conn: Any) -> None:
    """A ``tcp:`` link whose peer closes its side fails (a ``ConnectionError``, which the
    reader turns into a SourceError) instead of printing "EOF on TCP socket" at every read
    of a dead link for ever: pymavlink reconnects only with ``autoreconnect``, which we do
    not ask for. Its print before a reset is dropped too (the reset error follows).

    ``tcpin:``: the end of the peer's stream drops that connection and listens again for
    the next one (pymavlink read the finished connection for ever, taking no other)."""
    if isinstance(conn, mavutil.mavtcpin):
        recv = conn.recv

        def recv_until_eof(n: int | None = None) -> Any:
            port = conn.port
            data = recv(n)
            if port is not None and conn.port is port and isinstance(data, bytes) and not data:
                port.close()  # (an empty str is pymavlink's "nothing yet")
                conn.port = None
                conn.fd = conn.listen.fileno()
            return data

        conn.recv = recv_until_eof
        return
    if not isinstance(conn, mavutil.mavtcp):
        return

    def eof() -> None:
        raise ConnectionError("the peer closed the connection")

    conn.handle_eof = eof
    conn.handle_disconnect = lambda: None


def _forgeries_leave_stream_times(mav: Any) -> None:
    """A frame that fails its signature check leaves its stream's last timestamp as it was.
    pymavlink records a signed frame's timestamp before it checks the signature: one forged
    frame (no key needed) stamped far ahead, with the link id, system and component of the
    vehicle's stream, made every genuine frame after it "old", for good. A pymavlink whose
    parser lacks these names (``check_signature``, ``signing.stream_timestamps``: another
    version) is left as it is, not made to fail on its first signed frame."""
    check = getattr(mav, "check_signature", None)
    if check is None or not isinstance(getattr(mav.signing, "stream_timestamps", None), dict):
        _log.debug("MAVLink: pymavlink's signing check not wrapped (its names differ)")
        return

    def checked(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        stamps = mav.signing.stream_timestamps
        stream = (msgbuf[-13], src_system, src_component)  # (link id, system, component)
        before = stamps.get(stream)
        if check(msgbuf, src_system, src_component):
            return True
        if before is None:
            stamps.pop(stream, None)
        else:
            stamps[stream] = before
        return False

    mav.check_signature = checked


def _address(addr: Any) -> str:
    """A UDP peer's (host, port) as ``host:port``."""
    return f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else str(addr)


def _reject_unsigned(mav: Any, msgid: int) -> bool:
    """Signing callback: accept no unsigned message (pymavlink then yields BAD_DATA)."""
    return False
