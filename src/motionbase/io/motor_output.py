r"""Motor-drive output: safe crank angles streamed to servo drives over serial or UDP.

A drive output is chosen by a URL (``--output URL`` on ``fly``, ``replay`` and ``stream``)::

    serial:/dev/ttyUSB0?baud=250000&rate=500&format=...   any pyserial URL or device path
    serial:loop://?format=...                             (``loop://``, a pty path, ...)
    udp:192.168.1.50:4123?rate=1000&format=...

Query keys: ``format`` (below; default ``A{1}B{2}C{3}D{4}E{5}F{6}\n``, one letter a motor:
``A{1}B{2}C{3}\n`` for the 3-RRR; URL-encode it: ``%7B`` ``{``, ``%7D`` ``}``, ``%2B`` ``+``,
``%26`` ``&``, ``%23`` ``#``; a literal ``+`` means a space), ``rate`` (frames per second,
default 100), ``baud`` (serial, default 115200). Other keys of a serial URL go to pyserial.

Format language
---------------
``format=text:TEMPLATE`` (or a template without a prefix): the frame is the template with each
placeholder ``{N}`` or ``{N:SPEC}`` replaced by motor N's drive value (N = 1..6). SPEC is
Python's format mini-language: ``{1:d}`` decimal (the default), ``{1:04x}`` four hex digits,
``{1:X}``, ``{1:o}``, ``{1:b}``, ``{1:+06d}``, ``{1:.2f}`` two decimals (``f``/``e``/``g``
keep the value as a float; every other type rounds it to an integer). A zero-padded width
(``04x``) is an exact width: a value needing more digits is never sent. Negative values are
never sent with ``x``/``X``/``o``/``b``. A field's width and precision are at most
:data:`MAX_FIELD_WIDTH` (64) characters. ``{{`` and ``}}`` are literal braces; ``\n``, ``\r``,
``\t``, ``\\`` and ``\xHH`` are escapes; SimTools' ``<Axis1a>`` means ``{1}``. Example (FlyPT
Mover style): ``text:A{1}B{2}C{3}D{4}E{5}F{6}\n``.

``format=bin:TOKENS`` (tokens separated by commas or spaces): a binary frame, built from

* ``0xHEX`` literal bytes (an even number of hex digits), e.g. a header ``0xFFFE``;
* an axis field ``[N:]TYPE[*SCALE]``: TYPE is ``u8``/``i8``, or ``u16``/``i16``/``u24``/
  ``i24``/``u32``/``i32`` followed by ``be`` (big endian) or ``le`` (little endian); the value
  sent is ``round(drive value * SCALE)`` (default SCALE 1; e.g. ``i16le*100`` sends
  centidegrees for ``unit = "deg"``). Without ``N:`` a field takes the next motor;
  ``6xTYPE`` repeats a field for the next 6 motors. A value that does not fit the type, or
  that its rounding puts past the drive range (as any field's), is never sent;
* a checksum ``sum8`` (sum of bytes mod 256), ``xor8``, ``crc16`` (CRC-16/MODBUS, appended
  little endian) or ``crc16ccitt`` (CRC-16/CCITT-FALSE, appended big endian), over every byte
  before it, or from byte offset K with ``sum8@K`` (e.g. ``@2`` to skip a 2-byte header).

Example: ``bin:0xFFFE,6xu16be,sum8@2``.

``format=PATH.toml``: a file with ``text = "..."`` or ``binary = "..."`` (the same languages;
TOML strings need no URL encoding) and optionally ``rate_hz``.

Behaviour
---------
* ``write(output)`` (pipeline thread) maps ``output.angles`` (the safe crank angles, after the
  safety stage) through the :class:`~motionbase.platform.output_map.OutputMapping`, checks
  every value against the drive range and the wire format, and encodes the frame. A command
  that does not fit is never sent: the last good frame is held and ``held`` counts it.
* A sender thread sends at a fixed rate, independent of the pipeline's rate (no queue: a
  command not sent before the next one is replaced).
* Sinks never wait: ``write`` returns at once. In a real-time run only the pipeline's loop keeps
  time (:func:`motionbase.pipeline.run`), on the wall clock, never on the samples' own times.
* Ramped at the drive (``limits``, which ``motionbase fly/replay/stream --output`` and
  ``motionbase output --test`` always give: the geometry's): the sender keeps what the drive
  last received, its speed and when, and each frame moves the drive toward the latest
  command no faster than the speed and acceleration limits allow over the wall-clock time
  since that frame (:func:`ramp_step`, :func:`motionbase.safety.ramp_command`). So the
  limits hold at the drive whatever the ticks did (late ticks, a burst after a stall,
  timestamps squeezed in a recording): a frame the limiter changed is counted in
  ``ramped``. The positions are also kept within the drive range (:func:`drive_limits`):
  a drive range narrower than the actuator limits is braked for, as an angle limit is. A
  drive whose last frame is more than two periods old (a link that was down, a sender
  stall) is taken to stand at that frame and is ramped from there, from rest.
* The ramp feeds forward each command's own speed: its step from the command of the tick
  before, over the pipeline's tick (``command_dt``), never the speed between the frames
  that happened to sample it (the sender samples the commands at its own rate: one
  sampled twice would look stopped, the next one twice as fast, and the drive was carried
  past the end of a move). It never approaches the nearest point where the command could
  come to rest (braking within the acceleration limit from its own speed) faster than it
  can itself stop before it, whatever its own steps' lengths: it never passes a command
  that comes to rest within the limits, as the pipeline's do. Commands whose steps break
  the limits (a jump) are each taken as a command at rest.
* ``close()`` stops the sender, ramps the drive the rest of the way to the latest command (a
  command at rest now) and sends it once more: the pipeline ramps to park before the sinks
  close, so the last frame on the wire is the park command.
* A peer that goes away (a closed pty, a USB port unplugged, nobody listening on UDP) gives one
  warning line; the pipeline and its log go on; a serial port is reopened once a second and
  sending resumes (``link back`` line) when it returns. Frames sent while the link is
  reported down (from the first failed send until a second of sends without errors) count as not
  received, and hold the drive at the last frame sent before (at the first command, park, when
  none got through): once the link is back it is ramped on from there, from rest. (UDP cannot tell
  whether a datagram arrived: on a network that drops frames without an error, the
  drive-side limiter still bounds each step by the time elapsed.)
"""

from __future__ import annotations

import binascii
import functools
import logging
import math
import operator
import os
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple
from urllib.parse import parse_qsl, urlencode

import numpy as np

from motionbase.config import as_float, read_toml
from motionbase.errors import ConfigError, SinkError
from motionbase.io.net_address import check_host_port
from motionbase.io.serial_link import SERIAL_ERRORS, close_quietly, open_serial_port
from motionbase.platform.output_map import OutputMapping
from motionbase.platform.robot import Robot
from motionbase.safety import RATE_LIMITED, ActuatorLimits, ramp_command
from motionbase.state import PipelineOutput

__all__ = [
    "BinaryFormat",
    "Drive",
    "DriveCommand",
    "MotorOutput",
    "TextFormat",
    "crc16_ccitt",
    "crc16_modbus",
    "check_sendable",
    "drive_limits",
    "mapping_for",
    "open_output",
    "open_outputs",
    "parse_format",
    "ramp_offline",
    "ramp_step",
]

log = logging.getLogger(__name__)

#: The text format of a URL without ``format``, for six motors; :func:`default_text` gives
#: the same for any number (the 3-RRR's three servos: ``A{1}B{2}C{3}\\n``).
DEFAULT_TEXT = "A{1}B{2}C{3}D{4}E{5}F{6}\\n"


def default_text(n: int) -> str:
    """The frame format of a URL without ``format``: :data:`DEFAULT_TEXT` for six motors,
    its first ``n`` fields for fewer (``A{1}B{2}C{3}\\n`` for the 3-RRR), more letters
    for more."""
    return "".join(f"{chr(ord('A') + i)}{{{i + 1}}}" for i in range(n)) + "\\n"


DEFAULT_RATE_HZ = 100.0
#: The slowest frame rate, Hz: at 1e-320 Hz the sender's wait for its next frame overflowed
#: (a traceback in its thread, one frame sent, exit 0).
MIN_RATE_HZ = 1.0
#: Seconds of sends without an error before a link that was down counts as back (UDP reports
#: a refused datagram on a later send).
LINK_PROBATION_S = 1.0
#: Seconds :meth:`MotorOutput.close` waits for a drive whose link is down to come back, so
#: that it can still be brought to the park command.
RETURN_WAIT_S = 2.0
#: Shortest step of the drive-side ramp, in periods: a frame due sooner after the last one
#: (the sender catching up after a late tick) waits for the sender's next tick. The ramp's
#: braking holds for any later steps at least this long
#: (:func:`motionbase.physics.uneven_stop_speed`). The longest step that continues a motion
#: is two periods (after a longer gap the ramp starts from rest).
MIN_STEP_PERIODS = 0.5
DEFAULT_BAUD = 115200
#: Widest text field (width or precision), characters: a 64-bit number in binary fits.
MAX_FIELD_WIDTH = 64


# --------------------------------------------------------------------------- checksums


def _modbus_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_MODBUS = _modbus_table()


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS (poly 0x8005 reflected, init 0xFFFF); ``b"123456789"`` gives 0x4B37."""
    crc = 0xFFFF
    for b in data:
        crc = (crc >> 8) ^ _MODBUS[(crc ^ b) & 0xFF]
    return crc


def crc16_ccitt(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF); ``b"123456789"`` gives 0x29B1."""
    return binascii.crc_hqx(data, 0xFFFF)


_CHECKSUMS: dict[str, tuple[Callable[[bytes], int], int, str]] = {
    "sum8": (lambda d: sum(d) & 0xFF, 1, "big"),
    "xor8": (lambda d: functools.reduce(operator.xor, d, 0), 1, "big"),
    "crc16": (crc16_modbus, 2, "little"),
    "crc16ccitt": (crc16_ccitt, 2, "big"),
}


# --------------------------------------------------------------------------- formats

_INT_TYPES = "dxXob"  # the types a text field takes (one character each)
_FLOAT_TYPES = "fFeEgG"
_SPEC_RE = re.compile(
    r"^(?:(?P<fill>.)?(?P<align>[<>=^]))?(?P<sign>[-+ ])?(?P<alt>#)?(?P<zero>0)?"
    r"(?P<width>\d+)?(?P<grouping>[,_])?(?:\.(?P<prec>\d+))?(?P<type>[a-zA-Z%])?$"
)
_ESCAPES = {"n": "\n", "r": "\r", "t": "\t", "\\": "\\", "0": "\0"}
_ESCAPE_RE = re.compile(r"\\(?:([nrt\\0])|x([0-9a-fA-F]{2}))")


@dataclass(frozen=True)
class _TextField:
    axis: int  # 0-based
    spec: str
    integer: bool
    unsigned: bool
    exact_width: int | None
    rounding: str  # a float field's spec of the value it writes (its precision and type)


class TextFormat:
    """A text template frame (see the module docstring for the language).

    Parameters
    ----------
    template : str
        The template, escapes not yet expanded (``A{1}B{2}\\n``).
    n_axes : int
        Number of motors; a placeholder above it is an error.
    """

    #: The drive range (drive_min, drive_max) no value is written past: the sink's mapping's.
    bounds: tuple[Sequence[float], Sequence[float]] | None = None

    def __init__(self, template: str, n_axes: int = 6) -> None:
        self.template = template
        src = re.sub(r"<Axis(\d+)a>", r"{\1}", template)
        # \n, \r, \t, \\, \0 and \xHH expanded, left to right; any other backslash is kept
        src = _ESCAPE_RE.sub(lambda m: _ESCAPES.get(m[1]) or chr(int(m[2], 16)), src)
        # the text between the tokens, and the tokens: literal, token, literal, ..., literal
        parts = re.split(r"(\{\{|\}\}|\{[^{}]*\}|[{}])", src)
        literals = [parts[0]]  # literal, field, literal, field, ..., literal
        fields: list[_TextField] = []
        for tok, literal in zip(parts[1::2], parts[2::2], strict=True):
            if tok in ("{{", "}}"):
                literals[-1] += tok[0]
            elif len(tok) == 1:
                raise ConfigError(f"text format {template!r}: unmatched {tok!r} (write {tok * 2})")
            else:
                fields.append(self._field(tok[1:-1], n_axes))
                literals += ["", ""]
            literals[-1] += literal
        if not fields:
            raise ConfigError(f"text format {template!r}: no placeholder like {{1}} (add one)")
        if any(ord(c) > 0xFF for c in src):  # (frames are encoded as latin-1)
            raise ConfigError(f"text format {template!r}: only 8-bit characters")
        self.fields = tuple(fields)
        self._literals = literals
        self.axes = sorted({f.axis for f in fields})

    def _field(self, body: str, n_axes: int) -> _TextField:
        where = f"text format {self.template!r}: placeholder {{{body}}}"
        num, _, spec = body.partition(":")
        if not num.strip().isdigit() or not 1 <= int(num) <= n_axes:
            raise ConfigError(f"{where}: the motor number must be 1..{n_axes}")
        m = _SPEC_RE.match(spec)
        if m is None:
            raise ConfigError(f"{where}: {spec!r} is not a format spec (e.g. 04x, .2f, d)")
        if not m.group("type"):
            spec += "d"
        typ = spec[-1]  # (the type ends a spec)
        if typ not in _INT_TYPES + _FLOAT_TYPES:
            raise ConfigError(f"{where}: unsupported type {typ!r} (use d, x, X, o, b, f, e, g)")
        integer = typ in _INT_TYPES
        if integer and m.group("prec"):
            raise ConfigError(f"{where}: an integer type takes no precision")
        width = int(m.group("width")) if m.group("width") else None
        for what, digits in (("width", m.group("width")), ("precision", m.group("prec"))):
            if digits and int(digits) > MAX_FIELD_WIDTH:
                raise ConfigError(
                    f"{where}: {what} {int(digits)} is more than {MAX_FIELD_WIDTH} characters "
                    "(no drive reads a field that long; fix the format)"
                )
        zero = bool(m.group("zero")) or (m.group("fill") == "0" and m.group("align") in "=>")
        exact = width if zero and width else None
        rounding = f".{m.group('prec')}{typ}" if m.group("prec") else typ
        return _TextField(int(num) - 1, spec, integer, typ in "xXob", exact, rounding)

    def encode(self, values: Sequence[float]) -> bytes | None:
        """The frame for drive values (one per motor), or None when a value cannot be written."""
        out = self._literals[:]
        for k, f in enumerate(self.fields):
            text = self._text(f, values[f.axis])
            if text is None:
                return None
            out[2 * k + 1] = text
        return "".join(out).encode("latin-1")

    def _text(self, f: _TextField, v: float) -> str | None:
        if v != v:  # NaN
            return None
        if f.integer:
            v = int(round(v))
            if f.unsigned and v < 0:
                return None
        text = format(v, f.spec)
        if f.exact_width is not None and len(text) != f.exact_width:
            return None
        written = v if f.integer else float(format(v, f.rounding))
        return text if _within(self.bounds, f.axis, written) else None

    def axis_ok(self, axis: int, value: float) -> bool:
        """Whether every field of motor ``axis`` (0-based) can carry drive value ``value``."""
        return all(self._text(f, value) is not None for f in self.fields if f.axis == axis)

    def longest(self, drive_min: Sequence[float], drive_max: Sequence[float]) -> int:
        """Bytes of the longest frame of drive values within ``drive_min..drive_max``: each
        field at its longest on its own (a number is longest at an end of its range, or,
        written ``e`` or ``g``, as a value with every digit and the widest exponent:
        ``-2.84184e-14``, a crank at neutral, against ``-60`` at a limit)."""
        total = sum(len(lit) for lit in self._literals)
        for f in self.fields:
            lo, hi = float(drive_min[f.axis]), float(drive_max[f.axis])
            values = [lo, hi] + ([0.0, -0.0] if lo <= 0.0 <= hi else [])
            if not f.integer:
                values += [
                    v
                    for e in range(-325, 310)
                    for m in (1.2345678901234567, -1.2345678901234567)
                    if lo <= (v := m * 10.0**e if e < 308 else m * 1e308) <= hi
                ]
            total += max((len(t) for v in values if (t := self._text(f, v)) is not None), default=0)
        return total

    def describe(self) -> str:
        return f"text:{self.template}"


_TYPE_RE = re.compile(r"^(?P<s>[ui])(?P<bits>8|16|24|32)(?P<end>be|le)?$")


@dataclass(frozen=True)
class _BinField:
    kind: str  # "lit", "axis", "sum"
    data: bytes = b""
    axis: int = 0
    size: int = 0
    order: str = "big"
    signed: bool = False
    scale: float = 1.0
    lo: int = 0
    hi: int = 0
    checksum: str = ""
    start: int = 0


class BinaryFormat:
    """A binary frame (see the module docstring for the language).

    Parameters
    ----------
    spec : str
        Tokens such as ``0xFFFE,6xu16be,sum8@2``.
    n_axes : int
        Number of motors.
    """

    bounds: tuple[Sequence[float], Sequence[float]] | None = None  # (as TextFormat's)

    def __init__(self, spec: str, n_axes: int = 6) -> None:
        self.spec = spec
        where = f"binary format {spec!r}"
        items: list[_BinField] = []
        next_axis = offset = 0
        tokens = [t for t in re.split(r"[,\s]+", spec.strip()) if t]
        if not tokens:
            raise ConfigError(f"{where}: empty (e.g. 0xFFFE,6xu16be,sum8@2)")
        for tok in tokens:
            low = tok.lower()
            if low.startswith("0x"):
                hexd = tok[2:]
                if not hexd or len(hexd) % 2 or not re.fullmatch(r"[0-9a-fA-F]+", hexd):
                    raise ConfigError(f"{where}: {tok!r}: literal bytes need pairs of hex digits")
                items.append(_BinField("lit", data=bytes.fromhex(hexd)))
                offset += len(hexd) // 2
                continue
            name, _, start = low.partition("@")
            if name in _CHECKSUMS:
                k = int(start) if start.isdigit() else 0 if not start else -1
                if k < 0 or k > offset:
                    raise ConfigError(f"{where}: {tok!r}: start offset must be 0..{offset}")
                items.append(_BinField("sum", checksum=name, start=k, size=_CHECKSUMS[name][1]))
                offset += _CHECKSUMS[name][1]
                continue
            m = re.fullmatch(r"(?:(\d+)x)?(?:(\d+):)?([a-z0-9]+)(?:\*([0-9.eE+-]+))?", low)
            t = _TYPE_RE.match(m.group(3)) if m else None
            if m is None or t is None:
                raise ConfigError(
                    f"{where}: unknown token {tok!r} (expected 0xHEX, [N:]u16be[*SCALE], "
                    "6xu16le, sum8, xor8, crc16, crc16ccitt)"
                )
            bits = int(t.group("bits"))
            if bits > 8 and not t.group("end"):
                raise ConfigError(f"{where}: {tok!r}: say the byte order, e.g. {tok}be or {tok}le")
            repeat = int(m.group(1)) if m.group(1) else 1
            if m.group(2) and repeat != 1:
                raise ConfigError(f"{where}: {tok!r}: use either N: or Kx, not both")
            try:
                scale = float(m.group(4)) if m.group(4) else 1.0
            except ValueError:
                raise ConfigError(f"{where}: {tok!r}: bad scale") from None
            if not (scale > 0 and math.isfinite(scale)):
                raise ConfigError(f"{where}: {tok!r}: the scale must be > 0")
            signed = t.group("s") == "i"
            lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
            for _ in range(repeat):
                axis = int(m.group(2)) - 1 if m.group(2) else next_axis
                if not 0 <= axis < n_axes:
                    raise ConfigError(f"{where}: {tok!r}: motor {axis + 1} is not 1..{n_axes}")
                next_axis = axis + 1
                order = "little" if t.group("end") == "le" else "big"
                items.append(
                    _BinField("axis", axis=axis, size=bits // 8, order=order, signed=signed,
                              scale=scale, lo=lo, hi=hi)
                )  # fmt: skip
                offset += bits // 8
        if not any(i.kind == "axis" for i in items):
            raise ConfigError(f"{where}: no axis field (add e.g. 6xu16be)")
        self.items = tuple(items)
        self.axes = sorted({i.axis for i in items if i.kind == "axis"})

    def encode(self, values: Sequence[float]) -> bytes | None:
        """The frame for drive values (one per motor), or None when a value does not fit."""
        out = bytearray()
        for i in self.items:
            kind = i.kind
            if kind == "axis":
                iv = self._int(i, values[i.axis])
                if iv is None:
                    return None
                out += iv.to_bytes(i.size, i.order, signed=i.signed)
            elif kind == "lit":
                out += i.data
            else:
                fn, size, order = _CHECKSUMS[i.checksum]
                out += fn(bytes(out[i.start :])).to_bytes(size, order)
        return bytes(out)

    def _int(self, i: _BinField, value: float) -> int | None:
        v = value * i.scale
        if not (i.lo - 0.5 <= v <= i.hi + 0.5):  # False for NaN
            return None
        iv = int(round(v))
        ok = i.lo <= iv <= i.hi and _within(self.bounds, i.axis, iv / i.scale)
        return iv if ok else None

    def longest(self, drive_min: Sequence[float], drive_max: Sequence[float]) -> int:
        """Bytes of a frame (the same for every frame, whatever the drive values)."""
        return sum(len(i.data) if i.kind == "lit" else i.size for i in self.items)

    def axis_ok(self, axis: int, value: float) -> bool:
        """Whether every field of motor ``axis`` (0-based) can carry drive value ``value``."""
        return all(
            self._int(i, value) is not None
            for i in self.items
            if i.kind == "axis" and i.axis == axis
        )

    def describe(self) -> str:
        return f"bin:{self.spec}"


FrameFormat = TextFormat | BinaryFormat


def _within(bounds: tuple[Sequence[float], Sequence[float]] | None, axis: int, v: float) -> bool:
    """Whether drive value ``v`` as a field writes it (rounded: ``{1}`` to whole units) is
    within the drive range ``bounds`` (drive_min, drive_max; to its floating-point noise).
    The range was checked before the rounding alone: -59.7 deg went out as -60."""
    if bounds is None:
        return True
    lo, hi = bounds[0][axis], bounds[1][axis]
    return lo - 1e-9 * (hi - lo) <= v <= hi + 1e-9 * (hi - lo)


def parse_format(text: str, n_axes: int = 6) -> tuple[FrameFormat, dict[str, Any]]:
    """A frame format from its text: ``text:...``, ``bin:...``, a ``.toml`` path or a template.

    Returns the format and the extra settings a TOML file gave (``rate_hz``).
    """
    if text.startswith("bin:"):
        return BinaryFormat(text[4:], n_axes), {}
    if text.startswith("text:"):
        return TextFormat(text[5:], n_axes), {}
    path = _format_path(text)
    if path is not None:
        data = read_toml(path)
        extra = {k: v for k, v in data.items() if k not in ("text", "binary")}
        unknown = set(extra) - {"rate_hz"}
        if unknown or ("text" in data) == ("binary" in data):
            raise ConfigError(
                f"{path}: a format file needs exactly one of 'text' or 'binary' "
                "(and optionally rate_hz)"
            )
        key = "text" if "text" in data else "binary"
        if not isinstance(data[key], str):
            raise ConfigError(f"{path}: field {key!r}: expected a string, got {data[key]!r}")
        if "rate_hz" in extra:
            as_float(path, "rate_hz", extra["rate_hz"], min_value=0.0, strict_min=True, unit="Hz")
        frame_format = TextFormat if key == "text" else BinaryFormat
        return frame_format(data[key], n_axes), extra
    return TextFormat(text, n_axes), {}


def _format_path(text: str) -> str | None:
    """The frame-format file a ``format`` value names (``drive.toml``, ``@drive.toml``)."""
    path = text[1:] if text.startswith("@") else text
    return path if path.endswith(".toml") and not text.startswith(("bin:", "text:")) else None


def format_file(url: str) -> str | None:
    """The frame-format file an output URL reads (its ``format=...toml``), if any: a run
    must not write its log over it."""
    formats = [
        v for k, v in parse_qsl(url.partition("?")[2], keep_blank_values=True) if k == "format"
    ]
    return _format_path(formats[-1]) if formats else None  # (the last one counts)


# --------------------------------------------------------------------------- transports


class _SerialTransport:
    def __init__(self, url: str, baud: int) -> None:
        self.url, self.baud = url, baud
        self.port: Any = None
        self.label = f"serial:{url}"
        self.reopen_on_error = True

    def open(self) -> None:
        self.port = open_serial_port(self.url, self.baud, timeout=0, write_timeout=0.2)

    def reopen(self) -> bool:
        self.close()
        try:
            self.open()
            return True
        except SinkError:
            return False

    def send(self, frame: bytes) -> None:
        if self.port is None:
            raise OSError("port closed")
        try:
            self.port.write(frame)
            n = self.port.in_waiting  # drain what the drive prints
            if n:
                self.port.read(n)
        except SERIAL_ERRORS as exc:
            raise OSError(str(exc)) from None

    def close(self) -> None:
        close_quietly(self.port)
        self.port = None


class _UdpTransport:
    def __init__(self, host: str, port: int) -> None:
        self.host, self.port_no = host, port
        self.sock: socket.socket | None = None
        self.label = f"udp:{host}:{port}"
        self.reopen_on_error = False  # the socket stays usable; errors are per datagram

    def open(self) -> None:
        try:
            infos = socket.getaddrinfo(self.host, self.port_no, type=socket.SOCK_DGRAM)
            family, _, _, _, addr = infos[0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
            sock.setblocking(False)
            sock.connect(addr)  # connected: the kernel reports ECONNREFUSED on a later send
        except OSError as exc:
            raise SinkError(
                f"cannot open UDP output {self.label}: {exc} (check the host)"
            ) from None
        self.sock = sock

    def send(self, frame: bytes) -> None:
        self.sock.send(frame)  # type: ignore[union-attr]

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


# --------------------------------------------------------------------------- the ramp


class DriveCommand(NamedTuple):
    """A command as the sender holds it: its angles and frame, and its own steps.

    Attributes
    ----------
    angles : ndarray, shape (n,)
        Actuator command, rad (or m).
    frame : bytes
        Its frame.
    step : ndarray, shape (n,)
        Its step from the command of the tick before (zeros: none known).
    step_before : ndarray, shape (n,)
        That command's own step (zeros: none known).
    """

    angles: np.ndarray
    frame: bytes
    step: np.ndarray
    step_before: np.ndarray

    @classmethod
    def at_rest(cls, angles: np.ndarray, frame: bytes) -> DriveCommand:
        """A command whose ticks before are not known (the first, one after a held command,
        the last once the pipeline is done): taken as a command at rest."""
        zeros = np.zeros_like(angles)
        return cls(angles, frame, zeros, zeros)

    def then(self, angles: np.ndarray, frame: bytes) -> DriveCommand:
        """The command of the next tick."""
        return DriveCommand(angles, frame, angles - self.angles, self.step)


class Drive(NamedTuple):
    """What a drive last received: angles (rad or m), their speed (per s) and when (s, on the
    sender's clock)."""

    q: np.ndarray
    v: np.ndarray
    t: float


def ramp_offline(
    commands: np.ndarray,
    written: np.ndarray,
    frames: np.ndarray,
    *,
    period: float,
    command_dt: float,
    limits: ActuatorLimits,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sender's ramp run offline, as :class:`MotorOutput` runs it, with no clock, thread
    or socket: for each frame time, the latest command written by then and one
    :func:`ramp_step` toward it (a frame each; a frame that is not due is not sent).

    Parameters
    ----------
    commands : ndarray, shape (k, n)
        The pipeline's commands, one a ``command_dt``.
    written : ndarray, shape (k,)
        When each command reached the sender, s.
    frames : ndarray, shape (m,)
        When a frame is due, s (the same clock, increasing).
    period, command_dt : float
        The sender's period and the commands' tick, s.
    limits : ActuatorLimits

    Returns
    -------
    times : ndarray, shape (j,)
        The frames sent, s.
    q : ndarray, shape (j, n)
        The drive's angles in them.
    sampled : ndarray of int, shape (j,)
        The index in ``commands`` of the command each frame was heading for.
    """
    drive: Drive | None = None
    command: DriveCommand | None = None
    k = -1
    times, q, sampled = [], [], []
    for now in frames:
        while k + 1 < len(commands) and written[k + 1] <= now:
            k += 1
            c = commands[k]
            command = DriveCommand.at_rest(c, b"") if command is None else command.then(c, b"")
        if command is None:
            continue
        step = ramp_step(drive, command, now, period=period, command_dt=command_dt, limits=limits)
        if step is None:
            continue
        drive = Drive(step[0], step[1], now)
        times.append(now)
        q.append(drive.q)
        sampled.append(k)
    return np.array(times), np.array(q), np.array(sampled)


def ramp_step(
    drive: Drive | None,
    command: DriveCommand,
    now: float,
    *,
    period: float,
    command_dt: float,
    limits: ActuatorLimits,
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The drive's next frame toward ``command`` at ``now``: the sender's ramp, one frame.

    A drive that got nothing yet starts where the command is (:class:`MotorOutput` takes a
    drive whose first frame did not get through to stand at that first command, park, and
    passes it here as ``drive``). One that got its last frame
    more than two periods ago stood still at it (a sender stall, a link that was down): the
    ramp starts again from there, at rest, on a step of one period. A step shorter than
    :data:`MIN_STEP_PERIODS` is not taken (None: no frame now). Otherwise
    :func:`motionbase.safety.ramp_command` over the time since the last frame.

    Parameters
    ----------
    drive : Drive or None
        What the drive last received (None: nothing).
    command : DriveCommand
        The latest command.
    now : float
        The frame's time, s (the clock of ``drive.t``).
    period : float
        The sender's period, s.
    command_dt : float
        The commands' tick, s.
    limits : ActuatorLimits

    Returns
    -------
    (q, v, status) or None
        The frame's angles (``command.angles`` itself when they are the command's), their
        speed, and :func:`motionbase.safety.ramp_command`'s status bits.
    """
    target = command.angles
    if drive is None:
        return target, np.zeros_like(target), 0
    q0, v0, t0 = drive
    if q0 is target and not v0.any():  # there and at rest: the common case
        return target, v0, 0
    elapsed = now - t0
    if elapsed < MIN_STEP_PERIODS * period:
        return None
    dt = elapsed
    if elapsed > 2.0 * period:
        dt, v0 = period, np.zeros_like(q0)  # from rest
    q, v, status = ramp_command(
        q0, v0, target, command.step, command.step_before, dt, limits,
        dt_min=MIN_STEP_PERIODS * period, command_dt=command_dt,
    )  # fmt: skip
    return (target if np.array_equal(q, target) else q), v, status


def drive_limits(
    limits: ActuatorLimits,
    mapping: OutputMapping,
    frame_format: FrameFormat | None = None,
    inside: np.ndarray | None = None,
) -> ActuatorLimits:
    """The ramp's limits: ``limits`` with each actuator's range cut to the positions that
    are sent: whose drive values are within the drive range (``mapping.drive_min..
    drive_max``) and, given ``frame_format``, carried by its fields (a field's bounds, an
    exact width).

    A drive range (or a frame field) narrower than the actuator limits holds the commands
    beyond it: the drive got the last one it could and stopped there at once, from whatever
    speed (4.9 rad/s^2 on the wire against a 0.87 limit). With the range in the ramp's
    limits it brakes before the edge, as the limiter brakes before an angle limit. Each
    edge is the last position sent (by bisection to adjacent floats: a position sent is
    within it, one beyond is not); the limits are returned unchanged when both of an
    actuator's limits are sent (the default mapping: the drive range is their image).

    The bisection starts from a position that is sent: ``inside`` (a command that was sent,
    shape (n,)) when given, else the first sent of the middle of the limits, the limits
    themselves, the positions of the drive range's middle and ends, and a grid across the
    limits. (It tried only the middle and the limits: a drive range that held neither, 605
    ..790 mm of 600..1000 mm actuators, left the limits uncut, and the drive was stopped at
    its edge from full speed.)
    """
    axes = set(frame_format.axes) if frame_format is not None else set()
    probe = np.array(limits.lower, dtype=float)

    def sent(i: int, x: float) -> bool:
        probe[i] = x  # (the other motors' values do not matter to motor i's)
        v = float(mapping.to_drive(probe)[i])
        if not mapping.drive_min[i] <= v <= mapping.drive_max[i]:  # False for NaN
            return False
        return i not in axes or frame_format.axis_ok(i, v)  # type: ignore[union-attr]

    lower, upper = np.array(limits.lower, dtype=float), np.array(limits.upper, dtype=float)
    for i in range(len(lower)):
        lo, hi = float(lower[i]), float(upper[i])
        lo_ok, hi_ok = sent(i, lo), sent(i, hi)
        if lo_ok and hi_ok:
            continue
        good = next((x for x in _seeds(i, lo, hi, mapping, inside) if sent(i, x)), None)
        if good is None:  # nothing found sent (check_sendable refuses such an output)
            continue
        for bad, side in ((lo, lo_ok), (hi, hi_ok)):
            if side:
                continue
            g = good
            for _ in range(2000):  # to adjacent floats
                m = 0.5 * (g + bad)
                if m in (g, bad):
                    break
                if sent(i, m):
                    g = m
                else:
                    bad = m
            if bad < good:
                lower[i] = g
            else:
                upper[i] = g
    if np.array_equal(lower, limits.lower) and np.array_equal(upper, limits.upper):
        return limits
    return ActuatorLimits(lower, upper, limits.max_speed, limits.max_accel)


def _seeds(
    i: int, lo: float, hi: float, mapping: OutputMapping, inside: np.ndarray | None
) -> Iterator[float]:
    """Positions of actuator ``i`` within ``lo..hi`` to try for one that is sent."""
    if inside is not None and lo <= float(inside[i]) <= hi:
        yield float(inside[i])
    yield 0.5 * (lo + hi)
    yield lo
    yield hi
    dmin, dmax = mapping.drive_min[i], mapping.drive_max[i]
    for value in (0.5 * (dmin + dmax), dmin, dmax, 0.0):
        values = np.full(mapping.n, float(value))
        x = float(mapping.from_drive(values)[i])
        if lo <= x <= hi:  # (False for NaN)
            yield x
    yield from (float(x) for x in np.linspace(lo, hi, 4097)[1:-1])


# --------------------------------------------------------------------------- the sink


class MotorOutput:
    """A fixed-rate motor-drive sink (see the module docstring).

    Parameters
    ----------
    transport : object
        ``open()``, ``send(bytes)`` (raises OSError), ``close()``, a ``label`` and
        ``reopen_on_error``: True when a send error breaks the link, to be mended by
        ``reopen() -> bool`` (made by :func:`open_output`).
    frame_format : TextFormat or BinaryFormat
    mapping : OutputMapping
    rate_hz : float
        Frames per second (fixed, independent of the pipeline's rate).
    limits : ActuatorLimits, optional
        The actuators' angle, speed and acceleration limits (rad, rad/s, rad/s^2; the
        geometry's). When given, every frame is ramped at the drive: the sender knows what
        the drive last received and when, and moves it toward the latest command no faster
        than these limits allow over the wall-clock time elapsed (:func:`ramp_step`),
        whatever the pipeline's ticks did (see the module docstring), and within the
        positions the drive range can carry (:func:`drive_limits`). None: frames carry the
        latest command as it is, and ``close()`` sends it once (the sender alone; every
        ``motionbase`` command that drives motors gives the limits).
    command_dt : float, optional
        The commands' own tick, s: the pipeline's ``dt`` (one :meth:`write` a tick). The
        ramp feeds forward each command's step over it. Default: the sender's period. (A
        longer one than the pipeline's only makes the ramp lag more; a shorter one takes
        the pipeline's steps for faster than they are.)
    url : str
        The URL it was opened from (messages and metadata).

    Attributes
    ----------
    frames_sent, commands, held, send_errors : int
        Frames on the wire; commands accepted; commands never sent because a value was
        outside the drive's range or the wire format; failed sends.
    ramped : int
        Frames the drive-side limiter moved short of the latest command.
    link_up : bool
    """

    def __init__(
        self,
        transport: Any,
        frame_format: FrameFormat,
        mapping: OutputMapping,
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        limits: ActuatorLimits | None = None,
        command_dt: float | None = None,
        url: str = "",
    ) -> None:
        if not MIN_RATE_HZ <= rate_hz <= 10_000:  # (a NaN too)
            raise ConfigError(
                f"output {url}: rate must be in [{MIN_RATE_HZ:g}, 10000] Hz, got {rate_hz!r} "
                f"(below {MIN_RATE_HZ:g} frame a second a drive hears of a stop seconds late)"
            )
        command_dt = 1.0 / rate_hz if command_dt is None else float(command_dt)
        if not (command_dt > 0 and math.isfinite(command_dt)):
            raise ConfigError(f"output {url}: the commands' tick must be > 0 s, got {command_dt!r}")
        missing = [a + 1 for a in frame_format.axes if a >= mapping.n]
        if missing:
            raise ConfigError(
                f"output {url}: the format uses motor {missing[0]} but the mapping has {mapping.n}"
            )
        if limits is not None and len(limits.max_speed) != mapping.n:
            raise ConfigError(
                f"output {url}: limits for {len(limits.max_speed)} motors, the mapping has "
                f"{mapping.n}"
            )
        self.transport = transport
        frame_format.bounds = (mapping.drive_min, mapping.drive_max)  # (written, rounded)
        self.format = frame_format
        self.mapping = mapping
        self.rate_hz = float(rate_hz)
        self.limits = None if limits is None else drive_limits(limits, mapping, frame_format)
        # the limits as given: cut again from the first command sent (a position that is
        # sent, whatever the drive range), on the sender's thread
        self._given_limits = limits
        self.command_dt = command_dt
        self.url = url or transport.label
        self.label = transport.label  # the URL without its query, for messages
        self.frames_sent = self.commands = self.held = self.send_errors = self.ramped = 0
        self.link_up = True
        # the latest accepted command, replaced as one object
        self._command: DriveCommand | None = None
        # what the drive last received (limits only), on time.monotonic
        self._drive: Drive | None = None
        self._last_sent: bytes | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None  # the sender, while open
        self._holding = False
        self._next_retry = 0.0
        self._last_error = -math.inf
        self._sent_ok_since = -math.inf  # the first of the sends since the last error
        self._broken = False

    # -- lifecycle --------------------------------------------------------------------------
    def open(self) -> MotorOutput:
        if self._thread is not None:
            return self
        self.transport.open()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"output {self.url}", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the sender, bring the drive to the latest command (the park command at the end
        of a run: the pipeline ramps to park before the sinks close) and send it once more,
        close the link. Idempotent.

        With ``limits``, the drive is ramped the rest of the way within them, for at most the
        time the limits need to cross the whole range; a drive whose link is down is waited
        for (:data:`RETURN_WAIT_S`, then its probation) and ramped when it returns.
        """
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(5.0)
        command = self._command
        if command is not None:
            if self.limits is None:
                self._send(command.frame, time.monotonic(), final=True)
            else:
                self._finish_ramp(command)
        self.transport.close()
        self._thread = None

    def __enter__(self) -> MotorOutput:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the pipeline side ------------------------------------------------------------------
    def write(self, output: PipelineOutput | np.ndarray) -> bool:
        """Offer the latest safe command; returns False when it was held (never sent).

        Never waits: the pipeline's loop keeps time, the sender thread sends.

        Parameters
        ----------
        output : PipelineOutput, or an object with ``angles`` (rad, shape (n,)), or an array
            of crank angles (rad).
        """
        angles = np.array(getattr(output, "angles", output), dtype=float)
        values = self.mapping.to_drive(angles)
        frame = self._encode(values)
        if frame is None:
            self.held += 1
            if not self._holding:
                self._holding = True
                log.warning("output %s: %s; holding the last frame", self.label, self._why(values))
        else:
            if self._holding or self._command is None:  # (no command accepted the tick before)
                self._command = DriveCommand.at_rest(angles, frame)
            else:
                self._command = self._command.then(angles, frame)
            self._holding = False
            self.commands += 1
        return frame is not None

    def _encode(self, values: np.ndarray) -> bytes | None:
        """The frame for drive values, or None when one is outside the range or the format."""
        vals = values.tolist()  # plain floats: much faster to format than numpy scalars
        for x, lo, hi in zip(vals, self.mapping.drive_min, self.mapping.drive_max, strict=True):
            if not lo <= x <= hi:  # False for NaN
                return None
        return self.format.encode(vals)

    def _why(self, values: np.ndarray) -> str:
        ok = self.mapping.in_range(values)
        for i in range(len(values)):
            if not ok[i]:
                return (
                    f"motor {i + 1} value {values[i]:g} is outside the drive range "
                    f"{self.mapping.drive_min[i]:g}..{self.mapping.drive_max[i]:g}"
                )
        return f"values {np.round(values, 3).tolist()} do not fit {self.format.describe()!r}"

    # -- the sender thread ------------------------------------------------------------------
    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        nxt = time.monotonic()
        while not self._stop.is_set():
            self._tick(time.monotonic())
            nxt += period
            delay = nxt - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            elif delay < -period:
                nxt = time.monotonic()  # overrun: skip, never burst

    def _tick(self, now: float) -> bool:
        """Send one frame toward the latest command; True once the drive is there, at rest."""
        command = self._command
        if command is None:
            return True
        if self.limits is None:
            self._send(command.frame, now)
            return True
        if self._given_limits is not None:  # (once: the first command is sent)
            self.limits = drive_limits(
                self._given_limits, self.mapping, self.format, inside=command.angles
            )
            self._given_limits = None
        if not self.link_up and self._drive is not None:
            # down or on probation: the frames that do arrive hold the drive where it was
            # last known to be, and it is ramped on from rest once the link is back. (They
            # were steps from rest toward the command, changing direction, and then the
            # ramp went on at the last one's speed: up to twice the acceleration limit.)
            held = self._encode(self.mapping.to_drive(self._drive.q))
            if held is not None:
                self._send(held, now)
            return False
        # the next frame toward the command (:func:`ramp_step`)
        step = ramp_step(
            self._drive, command, now,
            period=1.0 / self.rate_hz, command_dt=self.command_dt, limits=self.limits,
        )  # fmt: skip
        if step is None:  # no frame due now
            return False
        q, v, status = step
        frame = command.frame
        if q is not command.angles:  # short of the command: a frame of its own
            if status & RATE_LIMITED:
                self.ramped += 1
            frame = self._encode(self.mapping.to_drive(q))
            if frame is None:  # not sendable: the drive stays where it is
                return False
        sent = time.monotonic()  # (not before ``now``: the step was sized for less time)
        if self._send(frame, sent) and self.link_up:
            # received (as far as the sender can know): the drive is there now
            self._drive = Drive(q, v, sent)
            return frame is command.frame and not v.any()
        if self._drive is None:
            # The first frame did not get through (a drive not reading yet): the drive is
            # taken to stand at the first command, the park command every run starts from,
            # and is ramped from there when it returns. It used to be sent the command of the
            # moment it returned, a jump of 10 deg in one frame 7 s into a wiring check.
            self._drive = Drive(q, np.zeros_like(q), sent)
        return False

    def _finish_ramp(self, command: DriveCommand) -> None:
        """After the sender stopped: ramp the drive to the latest command, ``command`` (the
        park command at the end of a run), then send it again.

        A link that is down, or back for less than its probation (:data:`LINK_PROBATION_S`:
        a refused datagram shows on a later send), is given that probation and the time a
        ramp across the whole range takes: a drive that returns in the last moments of a run
        is still parked. When it is not there in that time, a warning says the drive may
        not be at the last command.
        """
        lim = self.limits
        assert lim is not None
        period = 1.0 / self.rate_hz
        # the pipeline is done: its last command is at rest
        self._command = DriveCommand.at_rest(command.angles, command.frame)
        span = lim.upper - lim.lower
        speed_up_and_brake = 2.0 * lim.max_speed / lim.max_accel
        bound = float(np.max(span / lim.max_speed + speed_up_and_brake)) + 0.5
        start = now = time.monotonic()
        end = now + bound
        nxt = now
        there = False
        while now < end and not (there := self._tick(now)):
            if not self.link_up:  # time for the probation and the ramp after the last error
                end = max(end, self._last_error + LINK_PROBATION_S + bound)
                end = min(end, start + RETURN_WAIT_S + LINK_PROBATION_S + bound)
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))
            now = time.monotonic()
        if there and self._last_sent is not None:
            self._send(self._last_sent, time.monotonic(), final=True)
        else:  # (the time waited: it used to say the ramp's time alone, ``bound``)
            log.warning(
                "output %s: the drive may not be at the last command (park at the end of a "
                "run): its link was down or it could not get there within %.1f s",
                self.label,
                time.monotonic() - start,
            )

    def _send(self, frame: bytes, now: float, final: bool = False) -> bool:
        """Put ``frame`` on the wire; False when it could not be sent."""
        if self._broken:  # a serial port that failed: reopen it once a second
            if now < self._next_retry and not final:
                return False
            self._next_retry = now + 1.0
            if not self.transport.reopen():
                return False
            self._broken = False
        try:
            self.transport.send(frame)
        except OSError as exc:
            self.send_errors += 1
            self._last_error = now
            self._sent_ok_since = math.inf
            self._broken = self.transport.reopen_on_error
            self._next_retry = now + 1.0
            if self.link_up:
                self.link_up = False
                reason = exc.strerror or str(exc) or type(exc).__name__
                log.warning(
                    "output %s: the drive link is down (%s); the pipeline and its log go on, "
                    "frames are dropped until it returns, then the drive is ramped from the "
                    "last frame it was sent before",
                    self.label,
                    reason,
                )
            return False
        self.frames_sent += 1
        self._last_sent = frame
        # UDP reports a refused datagram on a later send: call the link back only after a
        # second of sends without errors (not after a second without sends: a sender that
        # stalled for a second after an error has its next send go through, and the error
        # shows on the one after)
        self._sent_ok_since = min(self._sent_ok_since, now)
        if not self.link_up and now - self._sent_ok_since >= LINK_PROBATION_S:
            self.link_up = True
            log.warning("output %s: link back, sending again", self.label)
        return True

    @property
    def last_frame(self) -> bytes | None:
        """The last frame put on the wire."""
        return self._last_sent

    def describe(self) -> dict[str, Any]:
        """Plain data for the log's metadata."""
        return {
            "kind": "motor_output",
            "url": self.url,
            "format": self.format.describe(),
            "rate_hz": self.rate_hz,
            "mapping": self.mapping.to_dict(),
            "ramped_at_the_drive": self.limits is not None,
        }

    def stats_line(self) -> str:
        return (
            f"output {self.label}: {self.frames_sent} frames sent at {self.rate_hz:g} Hz, "
            f"{self.commands} commands, {self.held} held out of range, "
            f"{self.send_errors} send errors"
            + (f", {self.ramped} frames ramped at the drive" if self.limits is not None else "")
        )


# --------------------------------------------------------------------------- opening


def open_output(
    url: str,
    mapping: OutputMapping,
    *,
    rate_hz: float | None = None,
    limits: ActuatorLimits | None = None,
    command_dt: float | None = None,
) -> MotorOutput:
    """A motor-drive sink for ``url`` (not yet open: use ``with`` or ``open()``).

    Parameters
    ----------
    url : str
        ``serial:PYSERIAL_URL?baud=..&rate=..&format=..`` or ``udp:HOST:PORT?rate=..&format=..``
        (see the module docstring).
    mapping : OutputMapping
        Crank angle to drive value, per motor.
    rate_hz : float, optional
        The frame rate, Hz, when the URL gives none (the URL's ``rate``, when it has one,
        must then be the same: a ConfigError otherwise).
    limits : ActuatorLimits, optional
        Ramp every frame at the drive within these limits (see :class:`MotorOutput`).
    command_dt : float, optional
        The commands' own tick, s (the pipeline's ``dt``; default: the output's period).
    """
    scheme, colon, rest = url.partition(":")
    if not colon or scheme not in ("serial", "udp"):
        raise ConfigError(
            f"output {url!r}: expected serial:DEVICE_OR_PYSERIAL_URL?... or udp:HOST:PORT?..."
        )
    base, _, query = rest.partition("?")  # (no "?": an empty query, no keys)
    pairs = parse_qsl(query, keep_blank_values=True)
    ours = {k: v for k, v in pairs if k in ("format", "rate", "baud")}  # (the last one counts)
    other = [(k, v) for k, v in pairs if k not in ours]
    fmt, extra = parse_format(ours.get("format", default_text(mapping.n)), mapping.n)
    given = ours.get("rate", extra.get("rate_hz"))  # the URL's (or its format file's)
    try:
        rate = float(DEFAULT_RATE_HZ if given is None else given)
    except (TypeError, ValueError):
        raise ConfigError(f"output {url!r}: rate must be a number of frames per second") from None
    if rate_hz is not None:
        if given is not None and float(rate_hz) != rate:  # (a NaN in the URL differs too)
            raise ConfigError(
                f"output {url!r}: the {'URL' if 'rate' in ours else 'format file'}'s rate "
                f"{given} Hz and the {rate_hz:g} Hz asked for differ: give the rate once"
            )
        rate = float(rate_hz)
    if scheme == "serial":
        try:
            baud = int(ours.get("baud", DEFAULT_BAUD))
        except ValueError:
            raise ConfigError(f"output {url!r}: baud must be an integer") from None
        if baud <= 0:
            raise ConfigError(f"output {url!r}: baud must be > 0, got {baud}")
        if not base:
            raise ConfigError(f"output {url!r}: give a device or pyserial URL after 'serial:'")
        dev = base + ("?" + urlencode(other) if other else "")
        size = fmt.longest(mapping.drive_min, mapping.drive_max)
        if size * 10 * rate > baud:  # (10 bits a byte: start, 8 data, stop)
            raise ConfigError(
                f"output {url!r}: frames of up to {size} bytes at {rate:g} Hz need "
                f"{math.ceil(size * 10 * rate)} baud, more than the line's {baud}: they would "
                "queue up behind it and reach the drive ever later, the park frame last (raise "
                "baud=, which a USB serial device ignores, or lower rate=)"
            )
        transport: Any = _SerialTransport(dev, baud)
    else:
        if other or "baud" in ours:  # (baud is a serial line's: it was ignored here)
            key = other[0][0] if other else "baud"
            raise ConfigError(f"output {url!r}: unknown key {key!r} (format, rate)")
        host, colon, port = base.rpartition(":")
        if not colon:
            raise ConfigError(f"output {url!r}: expected udp:HOST:PORT (e.g. udp:127.0.0.1:4123)")
        host = host.removeprefix("//").strip("[]")  # (udp://HOST:PORT, as URLs are written)
        host, port_no = check_host_port(f"output {url!r}", host, port)
        transport = _UdpTransport(host, port_no)
    return MotorOutput(
        transport, fmt, mapping, rate_hz=rate, limits=limits, command_dt=command_dt, url=url
    )


def open_outputs(
    urls: Sequence[str] | None, robot: Robot, command_dt: float | None = None
) -> list[MotorOutput]:
    """Motor-drive sinks for a job's ``--output`` URLs, mapped by :func:`mapping_for` and
    ramped at the drive within the robot's actuator limits (each checked by
    :func:`check_sendable`); ``command_dt`` is the pipeline's tick, s (see
    :class:`MotorOutput`)."""
    if not urls:
        return []
    mapping = mapping_for(robot)
    sinks = [open_output(u, mapping, limits=robot.limits, command_dt=command_dt) for u in urls]
    seen: dict[str, str] = {}
    for sink in sinks:
        drive = _drive_key(sink.label)
        if drive in seen:  # two senders, each ramping from its own frames, on one line
            raise ConfigError(
                f"--output {sink.url!r} and {seen[drive]!r} both send to {sink.label}: give "
                "each drive once"
            )
        seen[drive] = sink.url
        check_sendable(sink, robot)
    unsent = sorted(set(range(robot.n)).difference(*(s.format.axes for s in sinks)))
    if unsent:  # (a format for a 3-actuator robot on six: 4..6 stood still as 1..3 moved)
        raise ConfigError(
            f"--output: motors {', '.join(str(i + 1) for i in unsent)} of the {robot.n} are in "
            "no output's frame format, so they would stand still while the others move: give "
            "each motor a field, e.g. " + default_text(robot.n).replace("\\n", "")
        )
    return sinks


def _drive_key(label: str) -> str:
    """What identifies a drive's link: a UDP drive by the address its datagrams go to (the
    first of its host's, as the sender takes; ``localhost`` and ``127.0.0.1`` are one
    drive), a serial device by its real path (a symlink such as ``/dev/serial/by-id/...``
    names the same port)."""
    kind, _, rest = label.partition(":")
    if kind == "serial" and rest.startswith("/"):
        return f"serial:{os.path.realpath(rest.split('?')[0])}"
    if kind == "udp":
        host, _, port = rest.rpartition(":")
        try:
            addr = socket.getaddrinfo(host.strip("[]"), int(port), type=socket.SOCK_DGRAM)[0][4]
        except (OSError, ValueError):  # (the sender says so when it opens)
            return label
        return f"udp:{addr[0]}:{addr[1]}"
    return label


def check_sendable(sink: MotorOutput, robot: Robot) -> None:
    """A ConfigError unless ``sink`` can send ``robot``'s park and neutral commands: else not
    one frame of the run would be sent (each would be held), and the drive would never move.

    The usual cause is a frame field that cannot carry the drive values (an unsigned field
    for negative degrees, a 1-byte field for thousands of counts), or an ``[output]`` table
    whose drive range leaves them out.
    """
    for what, q in (("park", robot.park_angles), ("neutral", robot.inverse(robot.neutral_pose))):
        values = sink.mapping.to_drive(np.asarray(q, dtype=float))
        shown = ", ".join(f"{v:g}" for v in values)
        if not sink.mapping.in_range(values).all():
            raise ConfigError(
                f"output {sink.url!r}: the {what} command's drive values ({shown}) are outside "
                "the [output] drive range of the geometry; no frame would be sent: widen it"
            )
        if sink.format.encode(values.tolist()) is None:
            raise ConfigError(
                f"output {sink.url!r}: the {what} command's drive values ({shown}) do not fit "
                f"the frame format {sink.format.describe()!r}; no frame would be sent: use "
                "fields that hold them (signed ones for negative values: i16, {1:d}; decimals "
                "where whole units round past the drive range: {1:.3f}, i16*1000), or map "
                "them into the fields' range with an [output] table in the geometry (unit = "
                '"range", range_lo, range_hi)'
            )


def mapping_for(robot: Robot) -> OutputMapping:
    """The geometry's ``[output]`` mapping; when it has none, the robot's default
    (:meth:`Robot.default_output`): degrees for every crank (rotary actuators), millimetres
    (linear ones, ``robot.actuator_unit == "m"``), servo degrees for the 3-RRR's hobby
    servos (its ``[servo]`` zero offsets and directions)."""
    out = getattr(robot.geometry, "output", None)
    if out is not None:
        return out
    default = getattr(robot, "default_output", None)  # (a plug-in robot may predate it)
    return default() if default is not None else Robot.default_output(robot)
